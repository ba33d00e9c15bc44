"""Named, seeded terrain generators (in the style of legged_gym's ``utils/terrain.py``).

Each generator is a small function of its difficulty parameters and a seed returning a
HeightMap. Ground level is 0 at the robot's start (0, 0), which faces +x; maps reach 2 m behind
and 4 m ahead by default. Box-like features (stairs, steps, gaps, pits, obstacles) have their
edges on cell boundaries (parameters are rounded to whole cells), so their heights are
piecewise constant and the station can simulate them as exact boxes.
"""

from __future__ import annotations

import inspect
import math
from importlib import resources

import numpy as np
from scipy.ndimage import gaussian_filter

from qz_drake.errors import TerrainError, bad_value
from qz_drake.terrain.heightmap import HeightMap

DEFAULT_RESOLUTION = 0.05  # [m]


def _grid(x_range, y_range, resolution):
    """Cell-centre coordinates of a map whose cell boundaries fall on multiples of resolution
    from x_range[0] / y_range[0]."""
    nx = int(round((x_range[1] - x_range[0]) / resolution))
    ny = int(round((y_range[1] - y_range[0]) / resolution))
    origin = (x_range[0] + resolution / 2, y_range[0] + resolution / 2)
    xs = origin[0] + resolution * np.arange(nx)
    ys = origin[1] + resolution * np.arange(ny)
    X, Y = np.meshgrid(xs, ys)
    return X, Y, origin


def _check(name, value, *, positive=False, nonnegative=False):
    if not math.isfinite(value) or (positive and value <= 0) or (nonnegative and value < 0):
        why = "must be positive" if positive else "must be non-negative" if nonnegative else "must be finite"
        raise bad_value(f"terrain.{name}", value, why, TerrainError)


def flat(*, length: float = 6.0, width: float = 4.0, resolution: float = DEFAULT_RESOLUTION,
         seed: int = 0) -> HeightMap:
    """Level ground. length along x [m], width along y [m]."""
    _check("resolution", resolution, positive=True)
    X, _, origin = _grid((-2.0, length - 2.0), (-width / 2, width / 2), resolution)
    return HeightMap(np.zeros_like(X), resolution, origin)


def slope(*, angle_deg: float = 15.0, start_x: float = 0.5, length: float = 6.0, width: float = 4.0,
          resolution: float = DEFAULT_RESOLUTION, seed: int = 0) -> HeightMap:
    """Flat, then an incline rising along +x from start_x at angle_deg [deg]."""
    _check("angle_deg", angle_deg)
    X, _, origin = _grid((-2.0, length - 2.0), (-width / 2, width / 2), resolution)
    return HeightMap(np.maximum(X - start_x, 0.0) * math.tan(math.radians(angle_deg)), resolution, origin)


def stairs(*, rise: float = 0.1, run: float = 0.4, count: int = 2, start_x: float = 0.5,
           length: float = 6.0, width: float = 4.0, resolution: float = DEFAULT_RESOLUTION,
           seed: int = 0) -> HeightMap:
    """``count`` steps up along +x, each ``rise`` high [m] and ``run`` deep [m], the first edge at
    start_x [m]; the top landing continues to the end. The BLC paper's scene: two stairs 0.4 m
    wide starting 0.5 m ahead."""
    _check("rise", rise)
    _check("run", run, positive=True)
    if int(count) != count or count < 0:
        raise bad_value("terrain.count", count, "must be a non-negative whole number", TerrainError)
    X, _, origin = _grid((-2.0, length - 2.0), (-width / 2, width / 2), resolution)
    step = np.floor((X - start_x) / run) + 1
    return HeightMap(rise * np.clip(step, 0, int(count)), resolution, origin)


def step(*, height: float = 0.2, start_x: float = 0.5, depth: float = math.inf, length: float = 6.0,
         width: float = 4.0, resolution: float = DEFAULT_RESOLUTION, seed: int = 0) -> HeightMap:
    """A block of ``height`` [m] from start_x over ``depth`` [m] along x (inf: a step that stays)."""
    _check("height", height)
    if not depth > 0:
        raise bad_value("terrain.depth", depth, "must be positive", TerrainError)
    X, _, origin = _grid((-2.0, length - 2.0), (-width / 2, width / 2), resolution)
    inside = (X >= start_x) & (X < start_x + depth)
    return HeightMap(np.where(inside, height, 0.0), resolution, origin)


def gap(*, gap_width: float = 0.3, depth: float = 0.5, start_x: float = 0.6, length: float = 6.0,
        width: float = 4.0, resolution: float = DEFAULT_RESOLUTION, seed: int = 0) -> HeightMap:
    """A trench ``gap_width`` [m] wide and ``depth`` [m] deep across the path, from start_x."""
    _check("gap_width", gap_width, nonnegative=True)
    _check("depth", depth, nonnegative=True)
    X, _, origin = _grid((-2.0, length - 2.0), (-width / 2, width / 2), resolution)
    inside = (X >= start_x) & (X < start_x + gap_width)
    return HeightMap(np.where(inside, -depth, 0.0), resolution, origin)


def pits(*, count: int = 6, size: float = 0.3, depth: float = 0.15, length: float = 6.0,
         width: float = 4.0, clear_radius: float = 1.0, resolution: float = DEFAULT_RESOLUTION,
         seed: int = 0) -> HeightMap:
    """``count`` square pits of side ``size`` [m] and ``depth`` [m] at random, none within
    clear_radius [m] of the start."""
    _check("size", size, positive=True)
    _check("depth", depth, nonnegative=True)
    X, Y, origin = _grid((-2.0, length - 2.0), (-width / 2, width / 2), resolution)
    h = np.zeros_like(X)
    rng = np.random.default_rng(seed)
    placed = 0
    for _ in range(100 * max(int(count), 1)):
        if placed >= count:
            break
        cx = rng.uniform(X.min(), X.max() - size)
        cy = rng.uniform(Y.min(), Y.max() - size)
        cx, cy = np.round(cx / resolution) * resolution, np.round(cy / resolution) * resolution
        if math.hypot(cx + size / 2, cy + size / 2) < clear_radius + size:
            continue
        h[(X >= cx) & (X < cx + size) & (Y >= cy) & (Y < cy + size)] = -depth
        placed += 1
    return HeightMap(h, resolution, origin)


def waves(*, amplitude: float = 0.05, wavelength: float = 1.0, length: float = 6.0, width: float = 4.0,
          resolution: float = DEFAULT_RESOLUTION, seed: int = 0) -> HeightMap:
    """Sine along x times cosine along y, ``amplitude`` [m], ``wavelength`` [m]."""
    _check("amplitude", amplitude, nonnegative=True)
    _check("wavelength", wavelength, positive=True)
    X, Y, origin = _grid((-2.0, length - 2.0), (-width / 2, width / 2), resolution)
    k = 2 * math.pi / wavelength
    return HeightMap(amplitude * np.sin(k * X) * np.cos(k * Y), resolution, origin)


def rough(*, amplitude: float = 0.04, correlation: float = 0.15, length: float = 6.0, width: float = 4.0,
          resolution: float = DEFAULT_RESOLUTION, seed: int = 0) -> HeightMap:
    """Zero-mean smooth random ground: Gaussian noise smoothed over ``correlation`` [m] and
    scaled so its largest deviation is ``amplitude`` [m]."""
    _check("amplitude", amplitude, nonnegative=True)
    _check("correlation", correlation, nonnegative=True)
    X, _, origin = _grid((-2.0, length - 2.0), (-width / 2, width / 2), resolution)
    noise = np.random.default_rng(seed).normal(size=X.shape)
    field = gaussian_filter(noise, correlation / resolution, mode="wrap") if correlation > 0 else noise
    field -= field.mean()
    peak = np.abs(field).max()
    return HeightMap(amplitude * field / peak if peak > 0 else field, resolution, origin)


def obstacles(*, count: int = 10, min_height: float = 0.05, max_height: float = 0.3, min_size: float = 0.2,
              max_size: float = 0.6, length: float = 6.0, width: float = 4.0, clear_radius: float = 0.8,
              resolution: float = DEFAULT_RESOLUTION, seed: int = 0) -> HeightMap:
    """``count`` boxes of random size and height, none within clear_radius [m] of the start."""
    _check("min_height", min_height)
    if max_height < min_height or max_size < min_size or min_size <= 0:
        raise bad_value("terrain.max_height", max_height, "need min <= max and positive sizes", TerrainError)
    X, Y, origin = _grid((-2.0, length - 2.0), (-width / 2, width / 2), resolution)
    h = np.zeros_like(X)
    rng = np.random.default_rng(seed)
    placed = 0
    for _ in range(100 * max(int(count), 1)):
        if placed >= count:
            break
        sx, sy = (np.round(rng.uniform(min_size, max_size, 2) / resolution) * resolution)
        cx = np.round(rng.uniform(X.min(), X.max() - sx) / resolution) * resolution
        cy = np.round(rng.uniform(Y.min(), Y.max() - sy) / resolution) * resolution
        nearest = math.hypot(np.clip(0.0, cx, cx + sx), np.clip(0.0, cy, cy + sy))
        if nearest < clear_radius:
            continue
        box = (X >= cx) & (X < cx + sx) & (Y >= cy) & (Y < cy + sy)
        h[box] = np.maximum(h[box], rng.uniform(min_height, max_height))
        placed += 1
    return HeightMap(h, resolution, origin)


def long_range(*, size: float = 20.0, resolution: float = 0.1, seed: int = 0) -> HeightMap:
    """A size x size [m] world mixing stairs, a slope, a gap, rough ground and obstacles; the
    start (0, 0) lies in a flat corner region and the map reaches from -1 m to size - 1 m."""
    _check("size", size, positive=True)
    X, Y, origin = _grid((-1.0, size - 1.0), (-1.0, size - 1.0), resolution)
    rng = np.random.default_rng(seed)
    h = np.zeros_like(X)
    s = size / 20.0  # features scale with the world
    # Stairs up along x in a band, then a plateau.
    band = (Y >= 3 * s) & (Y < 7 * s)
    h += np.where(band, 0.1 * np.clip(np.floor((X - 5 * s) / 0.6) + 1, 0, 3), 0.0)
    # A 12 degree slope up along y on the right.
    h += np.where(X >= 12 * s, np.clip(Y - 9 * s, 0.0, 4 * s) * math.tan(math.radians(12)), 0.0)
    # A gap across the lower-middle.
    h = np.where((X >= 9 * s) & (X < 9 * s + 0.3) & (Y < 3 * s), -0.4, h)
    # Rough patch.
    rough_field = gaussian_filter(rng.normal(size=X.shape), 0.2 / resolution)
    rough_field *= 0.05 / max(np.abs(rough_field).max(), 1e-9)
    h += np.where((X >= 2 * s) & (X < 9 * s) & (Y >= 10 * s) & (Y < 16 * s), rough_field, 0.0)
    # Obstacles scattered away from the start corner.
    for _ in range(int(25 * s * s)):
        cx, cy = rng.uniform(2 * s, size - 2), rng.uniform(2 * s, size - 2)
        sx, sy = rng.uniform(0.3, 1.0, 2)
        box = (X >= cx) & (X < cx + sx) & (Y >= cy) & (Y < cy + sy)
        h[box] += rng.uniform(0.15, 0.5)
    return HeightMap(h, resolution, origin)


def material_floor(*, materials: tuple[str, ...] = ("concrete", "wood", "foam"), patch_length: float = 2.0,
                   length: float = 8.0, width: float = 4.0, resolution: float = DEFAULT_RESOLUTION,
                   seed: int = 0) -> HeightMap:
    """Flat floor in stripes across x, each ``patch_length`` [m] of one material, cycling
    through ``materials`` from the start (x = -2 m)."""
    from qz_drake.terrain.materials import get_material

    for name in materials:
        get_material(name)
    _check("patch_length", patch_length, positive=True)
    X, _, origin = _grid((-2.0, length - 2.0), (-width / 2, width / 2), resolution)
    labels = (np.floor((X + 2.0) / patch_length).astype(np.int64)) % len(materials)
    return HeightMap(np.zeros_like(X), resolution, origin, labels, tuple(materials))


def grid_map_terrain(*, resolution: float = 0.05, min_height: float = 0.0, max_height: float = 0.4) -> HeightMap:
    """The real test field of ANYbotics grid_map (``terrain.png``, packaged), centred on (0, 0)."""
    _check("resolution", resolution, positive=True)
    with resources.as_file(resources.files("qz_drake") / "data" / "grid_map_terrain.png") as path:
        return HeightMap.from_image(path, resolution, min_height, max_height)


TERRAIN_KINDS = {f.__name__: f for f in (flat, slope, stairs, step, gap, pits, waves, rough, obstacles,
                                         long_range, material_floor)}


def terrain_param_names(kind: str) -> tuple[str, ...]:
    return tuple(p for p in inspect.signature(TERRAIN_KINDS[kind]).parameters if p != "seed")


def make_terrain(kind: str, seed: int = 0, **params) -> HeightMap:
    """Builds a named terrain; unknown kinds and parameters raise TerrainError naming them."""
    if kind not in TERRAIN_KINDS:
        raise bad_value("terrain.kind", kind, f"unknown terrain kind (valid: {', '.join(TERRAIN_KINDS)})",
                        TerrainError)
    valid = terrain_param_names(kind)
    for key, value in params.items():
        if key not in valid:
            raise bad_value(f"terrain.{key}", value, f"not a parameter of {kind} (valid: {', '.join(valid)})",
                            TerrainError)
    if "count" in params:
        params["count"] = int(params["count"])
    return TERRAIN_KINDS[kind](seed=seed, **params)
