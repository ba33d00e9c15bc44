"""Named, seeded terrain generators, in the style of legged_gym's ``utils/terrain.py``.

The terrains of paper 001 (CapPlanner, Sec. III-B): flat ground, slopes, stairs, gaps, sine
shaped ground, random roughness and random obstacles, plus the BLC test scene (two stairs
0.4 m deep starting 0.5 m ahead, Sec. III-A) and the material floors of paper 000.

Every generator is a keyword-only function of its parameters and a seed returning a HeightMap.
Conventions, sized for Qingzhui (60 kg, 0.55 m standing height), which starts at (0, 0) facing +x:

* Ground level is 0 at the start; the map reaches ``BEHIND_START`` (2 m) behind it, so the
  default size_x = 6 m spans x in [-2, 4] m, and size_y is centred on y = 0.
* **Cell edges lie on the world lattice**: cell boundaries are at whole multiples of the
  resolution (x = k * resolution), whatever the map size. Every feature edge (a stair's nose,
  a gap's side, a box's face, a material stripe's border) is snapped to the nearest boundary,
  so box-like terrains are piecewise constant per cell and the Drake geometry's merged boxes
  put each edge exactly where the parameters say whenever they are multiples of the resolution
  (0.5 m with 0.05 m cells); otherwise an edge moves by at most half a cell.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable
from importlib import resources

import numpy as np
from scipy.ndimage import gaussian_filter

from qz_drake.errors import TerrainError, bad_value
from qz_drake.terrain.heightmap import MAX_CELLS, HeightMap, check_cell_count

# Default cell size; Qingzhui's foot is a 2.5-3 cm sphere. [m]
DEFAULT_RESOLUTION = 0.05
# How far every map reaches behind the start along -x. [m]
BEHIND_START = 2.0
# Side of the square tiles of the long-range world. [m]
LONG_RANGE_TILE = 4.0
# Work a generator may spend on passes over the map, in cell visits (one pass per box of pits
# and obstacles; the Gaussian kernel's length per cell and axis for rough): about 5 s, measured
# at 0.5 s per 1e9 visits for boxes and 0.7 s for the smoothing.
MAX_CELL_VISITS = 1e10
# Most boxes pits and obstacles place, each a seeded search in Python (about 50 us: 5 s).
MAX_BOXES = 100_000


# -- validation -------------------------------------------------------------------------------
def _number(name: str, value, *, low: float | None = None, positive: bool = False,
            allow_inf: bool = False) -> float:
    """``value`` as a float, or TerrainError naming ``terrain.<name>``."""
    if isinstance(value, bool):
        raise bad_value(f"terrain.{name}", value, "expected a number", TerrainError)
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise bad_value(f"terrain.{name}", value, "expected a number", TerrainError) from None
    if math.isnan(number) or (math.isinf(number) and not (allow_inf and number > 0)):
        raise bad_value(f"terrain.{name}", value, "must be finite" if not allow_inf else "must not be NaN or -inf",
                        TerrainError)
    if positive and number <= 0:
        raise bad_value(f"terrain.{name}", value, "must be positive", TerrainError)
    if low is not None and number < low:
        raise bad_value(f"terrain.{name}", value, f"must be at least {low}", TerrainError)
    return number


def _count(name: str, value) -> int:
    number = _number(name, value, low=0)
    if not number.is_integer():
        raise bad_value(f"terrain.{name}", value, "must be a whole number", TerrainError)
    return int(number)


def _seed(seed) -> np.random.Generator:
    # Parameters from the command line and from a scenario's params arrive as floats (4711.0).
    whole = isinstance(seed, (int, np.integer)) or (isinstance(seed, float) and seed.is_integer())
    if isinstance(seed, bool) or not whole or seed < 0:
        raise bad_value("terrain.seed", seed, "must be a non-negative integer", TerrainError)
    return np.random.default_rng(int(seed))


# -- the cell lattice -------------------------------------------------------------------------
class _Lattice:
    """The cells of a map whose boundaries lie at whole multiples of the resolution.

    ``gx``/``gy`` are global cell indices (cell g covers [g, g + 1) * resolution), ``x``/``y`` the
    cell centres, both broadcastable to the map's (H, W) shape.
    """

    def __init__(self, x_range: tuple[float, float], y_range: tuple[float, float], resolution):
        self.resolution = _number("resolution", resolution, positive=True)
        self.gx0 = math.floor(x_range[0] / self.resolution + 0.5)
        self.gy0 = math.floor(y_range[0] / self.resolution + 0.5)
        nx = math.floor(x_range[1] / self.resolution + 0.5) - self.gx0
        ny = math.floor(y_range[1] / self.resolution + 0.5) - self.gy0
        if nx < 2 or ny < 2:
            raise bad_value("terrain.resolution", resolution,
                            f"leaves fewer than 2 x 2 cells on a {x_range[1] - x_range[0]:g} m x "
                            f"{y_range[1] - y_range[0]:g} m map", TerrainError)
        # Blame what made the map too large: the cell size if the map would fit at the default
        # one, else its longer side.
        fits_at_default = nx * ny * (self.resolution / DEFAULT_RESOLUTION) ** 2 <= MAX_CELLS
        field, value = (("resolution", resolution) if fits_at_default else
                        ("size_x", x_range[1] - x_range[0]) if nx >= ny else ("size_y", y_range[1] - y_range[0]))
        check_cell_count(f"terrain.{field}", value, ny, nx, self.resolution)
        self.gx = (self.gx0 + np.arange(nx))[None, :]
        self.gy = (self.gy0 + np.arange(ny))[:, None]
        self.x = (self.gx + 0.5) * self.resolution
        self.y = (self.gy + 0.5) * self.resolution
        self.shape = (ny, nx)

    def edge(self, position: float) -> float:
        """The index of the cell boundary nearest to ``position`` (inf stays inf)."""
        return math.floor(position / self.resolution + 0.5) if math.isfinite(position) else position

    def band_x(self, start: float, end: float) -> np.ndarray:
        """(1, W) mask of the cells between the boundaries nearest to x = start and x = end."""
        return (self.gx >= self.edge(start)) & (self.gx < self.edge(end))

    def box(self, x0: float, x1: float, y0: float, y1: float) -> np.ndarray:
        """(H, W) mask of the cells inside the snapped rectangle [x0, x1) x [y0, y1)."""
        return self.band_x(x0, x1) & (self.gy >= self.edge(y0)) & (self.gy < self.edge(y1))

    def map(self, heights, materials=None, material_names=()) -> HeightMap:
        heights = np.broadcast_to(heights, self.shape).astype(np.float64)
        origin = ((self.gx0 + 0.5) * self.resolution, (self.gy0 + 0.5) * self.resolution)
        return HeightMap(heights, self.resolution, origin, materials, material_names)


def _course(size_x, size_y, resolution) -> _Lattice:
    """The lattice of a test course: BEHIND_START behind the start, centred across y."""
    size_x = _number("size_x", size_x, positive=True)
    size_y = _number("size_y", size_y, positive=True)
    return _Lattice((-BEHIND_START, size_x - BEHIND_START), (-size_y / 2, size_y / 2), resolution)


def _random_boxes(lattice: _Lattice, rng: np.random.Generator, count: int, sizes: tuple[float, float],
                  clear_radius: float, region: tuple[float, float, float, float]) -> list[tuple]:
    """``count`` seeded axis-aligned boxes (snapped to cell boundaries) inside ``region``
    (xmin, xmax, ymin, ymax), none reaching within clear_radius of the start (0, 0).

    Returns [(gx0, gx1, gy0, gy1)] global cell ranges. Raises TerrainError naming
    ``terrain.clear_radius`` when no box fits outside the clear disc.
    """
    res = lattice.resolution
    xmin, xmax, ymin, ymax = region
    boxes = []
    for _ in range(count):
        for _attempt in range(200):
            sx, sy = (max(1, round(s / res)) for s in rng.uniform(sizes[0], sizes[1], 2))
            gx0 = int(np.floor(rng.uniform(xmin / res, max(xmin / res, xmax / res - sx))))
            gy0 = int(np.floor(rng.uniform(ymin / res, max(ymin / res, ymax / res - sy))))
            # Distance from the start to the nearest point of the box's cells.
            dx = max(gx0 * res, 0.0, -(gx0 + sx) * res)
            dy = max(gy0 * res, 0.0, -(gy0 + sy) * res)
            if math.hypot(dx, dy) >= clear_radius:
                boxes.append((gx0, gx0 + sx, gy0, gy0 + sy))
                break
        else:
            raise bad_value("terrain.clear_radius", clear_radius,
                            "leaves no room on the map for the boxes", TerrainError)
    return boxes


def _box_count(value, lattice: _Lattice) -> int:
    """``count`` of pits or obstacles, bounded by MAX_BOXES and by MAX_CELL_VISITS (each box is a
    pass over the map)."""
    count = _count("count", value)
    cells = lattice.shape[0] * lattice.shape[1]
    limit = min(MAX_BOXES, int(MAX_CELL_VISITS // cells))
    if count > limit:
        raise bad_value("terrain.count", value, f"at most {limit} boxes on this map of {cells} cells (each box is a "
                                                f"pass over the map; at most {MAX_BOXES} boxes, "
                                                f"{MAX_CELL_VISITS:.0e} cell visits)", TerrainError)
    return count


def _box_mask(lattice: _Lattice, box: tuple) -> np.ndarray:
    gx0, gx1, gy0, gy1 = box
    return (lattice.gx >= gx0) & (lattice.gx < gx1) & (lattice.gy >= gy0) & (lattice.gy < gy1)


# -- generators -------------------------------------------------------------------------------
def flat(*, size_x: float = 6.0, size_y: float = 4.0, resolution: float = DEFAULT_RESOLUTION,
         seed: int = 0) -> HeightMap:
    """Level ground at height 0."""
    _seed(seed)
    lattice = _course(size_x, size_y, resolution)
    return lattice.map(0.0)


def slope(*, angle_deg: float = 15.0, start_x: float = 0.5, length: float = math.inf,
          size_x: float = 6.0, size_y: float = 4.0, resolution: float = DEFAULT_RESOLUTION,
          seed: int = 0) -> HeightMap:
    """Flat, then an incline rising along +x from start_x [m] at angle_deg [deg] (negative:
    downhill) over ``length`` [m] along x, then a level plateau (inf: the incline continues).
    Heights are sampled at the cell centres, so the incline is exact between them."""
    _seed(seed)
    angle = _number("angle_deg", angle_deg)
    if not -90.0 < angle < 90.0:
        raise bad_value("terrain.angle_deg", angle_deg, "must be strictly between -90 and 90", TerrainError)
    start_x = _number("start_x", start_x)
    length = _number("length", length, low=0.0, allow_inf=True)
    lattice = _course(size_x, size_y, resolution)
    run = np.clip(lattice.x - start_x, 0.0, length)
    return lattice.map(run * math.tan(math.radians(angle)))


def stairs(*, rise: float = 0.1, run: float = 0.4, count: int = 2, start_x: float = 0.5,
           size_x: float = 6.0, size_y: float = 4.0, resolution: float = DEFAULT_RESOLUTION,
           seed: int = 0) -> HeightMap:
    """``count`` steps up along +x, each ``rise`` [m] high and ``run`` [m] deep, the first nose at
    start_x [m]; the top landing continues to the map's end. A negative rise makes stairs down
    (descent). |rise| may not exceed run: steeper than 45 degrees is a wall, not stairs (a single
    tall block is ``step``). Defaults are paper 001's BLC scene: two stairs 0.4 m deep starting
    0.5 m ahead (rise 0.1 m)."""
    _seed(seed)
    rise = _number("rise", rise)
    count = _count("count", count)
    start_x = _number("start_x", start_x)
    lattice = _course(size_x, size_y, resolution)
    run = _number("run", run, positive=True)
    if run < lattice.resolution:
        raise bad_value("terrain.run", run, f"must be at least one cell ({lattice.resolution} m)", TerrainError)
    if abs(rise) > run:
        raise bad_value("terrain.rise", rise, f"steeper than 45 degrees: |rise| must not exceed run = {run:g} m "
                                              f"(negative: stairs down; one tall block: kind step)", TerrainError)
    # Only noses on the map need a position: those left of it are passed everywhere, those right
    # of it nowhere (a count of 1e9 stairs was a billion passes over the map).
    res, gx_end = lattice.resolution, lattice.gx0 + lattice.shape[1]
    first = min(count, max(0, math.floor((lattice.gx0 * res - start_x) / run) - 1))
    last = min(count, max(first, math.ceil((gx_end * res - start_x) / run) + 1))
    noses = np.array([lattice.edge(start_x + k * run) for k in range(first, last)], dtype=np.int64)
    steps_passed = first + np.searchsorted(noses, lattice.gx, side="right")
    return lattice.map(rise * np.asarray(steps_passed, dtype=float))


def step(*, height: float = 0.15, start_x: float = 0.5, length: float = math.inf, size_x: float = 6.0,
         size_y: float = 4.0, resolution: float = DEFAULT_RESOLUTION, seed: int = 0) -> HeightMap:
    """A block ``height`` [m] high (negative: a step down) across the path from start_x [m] over
    ``length`` [m] along x; length = inf is a step up that stays."""
    _seed(seed)
    height = _number("height", height)
    start_x = _number("start_x", start_x)
    length = _number("length", length, positive=True, allow_inf=True)
    lattice = _course(size_x, size_y, resolution)
    return lattice.map(np.where(lattice.band_x(start_x, start_x + length), height, 0.0))


def gap(*, width: float = 0.3, depth: float = 0.5, start_x: float = 0.6, size_x: float = 6.0,
        size_y: float = 4.0, resolution: float = DEFAULT_RESOLUTION, seed: int = 0) -> HeightMap:
    """A trench across the path, ``width`` [m] along x from start_x [m] and ``depth`` [m] deep."""
    _seed(seed)
    width = _number("width", width, low=0.0)
    depth = _number("depth", depth, low=0.0)
    start_x = _number("start_x", start_x)
    lattice = _course(size_x, size_y, resolution)
    return lattice.map(np.where(lattice.band_x(start_x, start_x + width), -depth, 0.0))


def pits(*, count: int = 6, width: float = 0.3, depth: float = 0.15, clear_radius: float = 0.8,
         size_x: float = 6.0, size_y: float = 4.0, resolution: float = DEFAULT_RESOLUTION,
         seed: int = 0) -> HeightMap:
    """``count`` square pits ``width`` [m] wide and ``depth`` [m] deep at seeded places (they may
    overlap), none reaching within clear_radius [m] of the start."""
    rng = _seed(seed)
    width = _number("width", width, positive=True)
    depth = _number("depth", depth, low=0.0)
    clear_radius = _number("clear_radius", clear_radius, low=0.0)
    lattice = _course(size_x, size_y, resolution)
    count = _box_count(count, lattice)
    region = (-BEHIND_START, float(lattice.x.max()), float(lattice.y.min()), float(lattice.y.max()))
    heights = np.zeros(lattice.shape)
    for box in _random_boxes(lattice, rng, count, (width, width), clear_radius, region):
        heights[_box_mask(lattice, box)] = -depth
    return lattice.map(heights)


def waves(*, amplitude: float = 0.05, wavelength: float = 1.0, size_x: float = 6.0, size_y: float = 4.0,
          resolution: float = DEFAULT_RESOLUTION, seed: int = 0) -> HeightMap:
    """amplitude * sin(2 pi x / wavelength) * cos(2 pi y / wavelength): amplitude [m],
    wavelength [m]; height 0 at the start."""
    _seed(seed)
    amplitude = _number("amplitude", amplitude, low=0.0)
    wavelength = _number("wavelength", wavelength, positive=True)
    lattice = _course(size_x, size_y, resolution)
    k = 2.0 * math.pi / wavelength
    return lattice.map(amplitude * np.sin(k * lattice.x) * np.cos(k * lattice.y))


def rough(*, amplitude: float = 0.03, correlation_length: float = 0.2, size_x: float = 6.0,
          size_y: float = 4.0, resolution: float = DEFAULT_RESOLUTION, seed: int = 0) -> HeightMap:
    """Zero-mean smooth random ground: white noise smoothed by a Gaussian kernel whose standard
    deviation is correlation_length [m] (0: white noise), scaled so that its largest deviation
    from 0 is ``amplitude`` [m]."""
    rng = _seed(seed)
    amplitude = _number("amplitude", amplitude, low=0.0)
    correlation_length = _number("correlation_length", correlation_length, low=0.0)
    lattice = _course(size_x, size_y, resolution)
    # scipy's kernel reaches 4 standard deviations each side, along each of the two axes.
    sigma_cells = correlation_length / lattice.resolution
    visits = lattice.shape[0] * lattice.shape[1] * 2 * (8 * sigma_cells + 1)
    if visits > MAX_CELL_VISITS:
        longest = (MAX_CELL_VISITS / (2 * lattice.shape[0] * lattice.shape[1]) - 1) / 8 * lattice.resolution
        raise bad_value("terrain.correlation_length", correlation_length,
                        f"smoothing this map would take {visits:.2g} cell visits; at most {longest:.3g} m here "
                        f"({MAX_CELL_VISITS:.0e} visits)", TerrainError)
    return lattice.map(_rough_field(rng, lattice.shape, amplitude, sigma_cells))


def _rough_field(rng: np.random.Generator, shape, amplitude: float, sigma_cells: float) -> np.ndarray:
    field = rng.standard_normal(shape)
    if sigma_cells > 0:
        field = gaussian_filter(field, sigma_cells, mode="reflect")
    field -= field.mean()
    peak = np.abs(field).max()
    return amplitude * field / peak if peak > 0 else field


def obstacles(*, count: int = 12, min_height: float = 0.05, max_height: float = 0.3, min_size: float = 0.2,
              max_size: float = 0.6, clear_radius: float = 0.8, size_x: float = 6.0, size_y: float = 4.0,
              resolution: float = DEFAULT_RESOLUTION, seed: int = 0) -> HeightMap:
    """``count`` seeded boxes, each side between min_size and max_size [m] and height between
    min_height and max_height [m] (where boxes overlap the higher wins); none reaches within
    clear_radius [m] of the start."""
    rng = _seed(seed)
    min_height = _number("min_height", min_height)
    max_height = _number("max_height", max_height)
    if max_height < min_height:
        raise bad_value("terrain.max_height", max_height, f"must be >= min_height {min_height}", TerrainError)
    min_size = _number("min_size", min_size, positive=True)
    max_size = _number("max_size", max_size, positive=True)
    if max_size < min_size:
        raise bad_value("terrain.max_size", max_size, f"must be >= min_size {min_size}", TerrainError)
    clear_radius = _number("clear_radius", clear_radius, low=0.0)
    lattice = _course(size_x, size_y, resolution)
    count = _box_count(count, lattice)
    region = (-BEHIND_START, float(lattice.x.max()), float(lattice.y.min()), float(lattice.y.max()))
    heights = np.zeros(lattice.shape)
    for box in _random_boxes(lattice, rng, count, (min_size, max_size), clear_radius, region):
        mask = _box_mask(lattice, box)
        heights[mask] = np.maximum(heights[mask], rng.uniform(min_height, max_height))
    return lattice.map(heights)


# The features of the long-range world, each drawn on the central square of a tile.
_LONG_RANGE_FEATURES = ("stairs", "slope", "gap", "rough", "obstacles", "pits")


def long_range(*, size_x: float = 20.0, size_y: float = 20.0, resolution: float = DEFAULT_RESOLUTION,
               seed: int = 0) -> HeightMap:
    """A composite world for long-range planning (paper 001, Sec. III-D): size_x x size_y [m]
    from (-2, -2), so the start (0, 0) lies near the lower-left corner.

    The world is cut into 4 m tiles. The start's tile is flat; every other tile carries one
    feature on its central square (2.4-3.2 m wide, leaving flat lanes of at least 0.8 m between
    tiles): pyramid stairs, a pyramid slope, a trench, a rough patch, boxes or pits, each kind
    equally often in a seeded order, with seeded difficulty. Stairs, trenches, boxes and pits
    are piecewise constant on cell boundaries; slopes and rough patches are not.
    """
    rng = _seed(seed)
    size_x = _number("size_x", size_x, positive=True)
    size_y = _number("size_y", size_y, positive=True)
    lattice = _Lattice((-BEHIND_START, size_x - BEHIND_START), (-BEHIND_START, size_y - BEHIND_START), resolution)
    res = lattice.resolution
    heights = np.zeros(lattice.shape)
    tiles = [(tx, ty) for ty in range(int(size_y // LONG_RANGE_TILE)) for tx in range(int(size_x // LONG_RANGE_TILE))
             if (tx, ty) != (0, 0)]
    kinds = [_LONG_RANGE_FEATURES[k % len(_LONG_RANGE_FEATURES)] for k in range(len(tiles))]
    kinds = [kinds[k] for k in rng.permutation(len(kinds))]
    for (tx, ty), kind in zip(tiles, kinds):
        side = rng.uniform(2.4, 3.2)
        x0 = -BEHIND_START + tx * LONG_RANGE_TILE + (LONG_RANGE_TILE - side) / 2
        y0 = -BEHIND_START + ty * LONG_RANGE_TILE + (LONG_RANGE_TILE - side) / 2
        inside = lattice.box(x0, x0 + side, y0, y0 + side)
        rows, cols = np.nonzero(inside)
        if rows.size == 0:
            continue
        window = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))
        n_rows, n_cols = rows.max() - rows.min() + 1, cols.max() - cols.min() + 1
        # Cells from the square's border, counted inwards (0 on the outermost ring).
        ring = np.minimum(np.minimum(np.arange(n_rows)[:, None], n_rows - 1 - np.arange(n_rows)[:, None]),
                          np.minimum(np.arange(n_cols)[None, :], n_cols - 1 - np.arange(n_cols)[None, :]))
        if kind == "stairs":
            rise, run_cells = rng.uniform(0.06, 0.16), max(1, round(rng.uniform(0.3, 0.5) / res))
            feature = rise * np.minimum(ring // run_cells + 1, int(rng.integers(2, 5)))
        elif kind == "slope":
            angle = math.radians(rng.uniform(8.0, 20.0))
            feature = np.minimum((ring + 0.5) * res, rng.uniform(0.6, 1.0)) * math.tan(angle)
        elif kind == "gap":
            width_cells = max(1, round(rng.uniform(0.15, 0.45) / res))
            along_x = rng.random() < 0.5
            n = n_cols if along_x else n_rows
            lo = (n - width_cells) // 2
            band = (np.arange(n) >= lo) & (np.arange(n) < lo + width_cells)
            feature = np.where(band[None, :] if along_x else band[:, None], -rng.uniform(0.3, 0.6), 0.0)
            feature = np.broadcast_to(feature, (n_rows, n_cols))
        elif kind == "rough":
            taper = np.clip((ring + 0.5) * res / 0.3, 0.0, 1.0)  # fades in over 0.3 m
            field = _rough_field(rng, (n_rows, n_cols), rng.uniform(0.03, 0.07), rng.uniform(0.1, 0.3) / res)
            feature = taper * field
        else:
            feature = np.zeros((n_rows, n_cols))
            number, sizes, levels = ((int(rng.integers(4, 9)), (0.3, 0.8), (0.1, 0.4)) if kind == "obstacles"
                                     else (int(rng.integers(3, 7)), (0.25, 0.5), (-0.4, -0.15)))
            for _ in range(number):
                sx, sy = (max(1, round(s / res)) for s in rng.uniform(*sizes, 2))
                cx, cy = int(rng.integers(0, max(1, n_cols - sx + 1))), int(rng.integers(0, max(1, n_rows - sy + 1)))
                block = feature[cy:cy + sy, cx:cx + sx]
                level = rng.uniform(*levels)
                block[...] = np.maximum(block, level) if level > 0 else np.minimum(block, level)
        heights[window] = np.where(inside[window], feature, heights[window])
    return lattice.map(heights)


def material_floor(*, materials: tuple[str, ...] = ("concrete", "wood", "foam"), patch_length: float = 2.0,
                   patch_width: float = math.inf, size_x: float = 8.0, size_y: float = 4.0,
                   resolution: float = DEFAULT_RESOLUTION, seed: int = 0) -> HeightMap:
    """A flat floor whose cells are labelled with ground materials (paper 000's experiments).

    Stripes ``patch_length`` [m] deep along x cycle through ``materials``; the start sits in
    the middle of the first one (stripe k spans x in [(k - 1/2), (k + 1/2)) * patch_length). A
    finite ``patch_width`` [m] also cuts the stripes along y into patches, shifting the cycle by
    one per row of patches (a checkerboard for two materials).
    """
    from qz_drake.terrain.materials import MATERIALS

    _seed(seed)
    names = (materials,) if isinstance(materials, str) else tuple(materials)
    if not names or any(name not in MATERIALS for name in names):
        raise bad_value("terrain.materials", materials,
                        f"expected ground material names (valid: {', '.join(MATERIALS)})", TerrainError)
    patch_length = _number("patch_length", patch_length, positive=True)
    patch_width = _number("patch_width", patch_width, positive=True, allow_inf=True)
    lattice = _course(size_x, size_y, resolution)

    def stripe(centres, period):
        # Sampling at cell centres puts each stripe border on the nearest cell boundary.
        return np.zeros(centres.shape, np.int64) if math.isinf(period) else np.floor(centres / period + 0.5)

    labels = (stripe(lattice.x, patch_length) + stripe(lattice.y, patch_width)) % len(names)
    return lattice.map(0.0, np.broadcast_to(labels, lattice.shape).astype(np.int64), names)


def grid_map_terrain(resolution: float = 0.05, min_height: float = 0.0, max_height: float = 0.4) -> HeightMap:
    """The test field of ANYbotics grid_map (its demo ``terrain.png``, packaged with qz_drake),
    500 x 500 pixels read with ``resolution`` [m] cells and heights from min_height to
    max_height [m], centred on (0, 0). Defaults suit Qingzhui: a 25 m x 25 m field of 0-0.4 m
    features."""
    _number("resolution", resolution, positive=True)
    with resources.as_file(resources.files("qz_drake") / "data" / "grid_map_terrain.png") as path:
        return HeightMap.from_image(path, resolution, min_height, max_height)


TERRAIN_KINDS: dict[str, Callable[..., HeightMap]] = {
    f.__name__: f for f in (flat, slope, stairs, step, gap, pits, waves, rough, obstacles, long_range,
                            material_floor)}


def _kind(kind: str) -> Callable[..., HeightMap]:
    if kind not in TERRAIN_KINDS:
        raise bad_value("terrain.kind", kind, f"unknown terrain kind (valid: {', '.join(TERRAIN_KINDS)})",
                        TerrainError)
    return TERRAIN_KINDS[kind]


def terrain_param_names(kind: str) -> tuple[str, ...]:
    """The parameters a terrain kind takes (besides ``seed``)."""
    return tuple(p for p in inspect.signature(_kind(kind)).parameters if p != "seed")


def make_terrain(kind: str, seed: int = 0, **params) -> HeightMap:
    """Builds a named terrain. Unknown kinds raise TerrainError naming ``terrain.kind``; unknown
    or bad parameters name ``terrain.<param>``."""
    generator = _kind(kind)
    valid = terrain_param_names(kind)
    for key, value in params.items():
        if key not in valid:
            raise bad_value(f"terrain.{key}", value, f"not a parameter of {kind} (valid: {', '.join(valid)})",
                            TerrainError)
    return generator(seed=seed, **params)
