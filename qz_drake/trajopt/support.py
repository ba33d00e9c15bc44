"""Support under a stance foot: stance footholds kept off edges (issue 11).

The BLC's terrain constraint puts a stance sphere on the interpolated heightmap, where a pit's
rim or a step's nose is a smooth ramp one cell wide; a foothold a few centimetres from a
0.2 m drop meets every constraint, and in Drake, after a few centimetres of tracking error,
the sphere slides off the rim (the demo's seed-0 crossing: 9.3 cm). So a stance foothold also
needs *support*: the raw ground within ``radius`` (the foot's radius plus a margin) of it lies
within ``drop`` of its own height. Where it does not, the point is *unsupported*: near a drop
(an edge), a riser the sphere or the shank would touch, or ground steeper on average than
atan(drop / radius).

``SupportField`` holds, on the heightmap's grid, the signed distance to the unsupported set
(positive where a foot may stand, negative inside, metres), interpolated with exact first and
second derivatives (``GridTerrain``'s bicubic), so that "signed distance >= 0" is a smooth
constraint on each free stance foothold with an exact Jacobian; its nearest-supported-point
map moves a foothold guess out of an unsupported spot; and ``unsupported_at`` answers the raw
question for the dense verdict.
"""

from __future__ import annotations

import dataclasses
import types

import numpy as np

from qz_drake.trajopt.constraints import SampledConstraint, _Block
from qz_drake.trajopt.splines import LinearSamples
from qz_drake.trajopt.terrain import GridTerrain, grid_window

# Distances beyond this are clipped: the constraint is inactive there anyway. [m]
_CLIP = 0.3
# Grid step for terrains given in closed form (sampled over the task's region). [m]
CLOSED_FORM_RESOLUTION = 0.02


@dataclasses.dataclass
class SupportField:
    """Where a stance foot has support, on a grid (see the module docstring)."""

    # Grid: cell (ix, iy) at origin + (ix, iy) * resolution. [m]
    resolution: float
    origin: tuple[float, float]
    # The support radius and the largest height difference within it. [m]
    radius: float
    drop: float
    # Largest height difference within the radius of each cell, the cells where it exceeds
    # drop, and for each cell the (iy, ix) of its nearest supported cell. [m]
    relief: np.ndarray
    unsupported: np.ndarray
    nearest: np.ndarray
    # Signed distance to the unsupported set, interpolated (a TerrainModel over the field).
    distance: GridTerrain
    # nearest_clear's (iy, ix) maps, per margin (computed on first use).
    _clear: dict = dataclasses.field(default_factory=dict, repr=False, compare=False)

    def margin(self, x, y) -> np.ndarray:
        """Signed distance to the nearest unsupported point (negative: unsupported). [m]"""
        return self.distance.height(x, y)

    def _cells(self, x, y):
        H, W = self.unsupported.shape
        ix = np.clip(np.rint((np.asarray(x, dtype=float) - self.origin[0]) / self.resolution), 0, W - 1).astype(int)
        iy = np.clip(np.rint((np.asarray(y, dtype=float) - self.origin[1]) / self.resolution), 0, H - 1).astype(int)
        return iy, ix

    def unsupported_at(self, x, y) -> np.ndarray:
        """Whether the grid cell under each point is unsupported (the raw check, no interpolation)."""
        iy, ix = self._cells(x, y)
        return self.unsupported[iy, ix]

    def any_unsupported(self, region) -> bool:
        """Whether any cell within (xmin, xmax, ymin, ymax) is unsupported."""
        window = grid_window(self.origin, self.resolution, self.unsupported.shape, region)
        return bool(self.unsupported[window].any())

    def relief_at(self, x, y) -> np.ndarray:
        """The largest height difference within the radius of each point's cell. [m]"""
        iy, ix = self._cells(x, y)
        return self.relief[iy, ix]

    def nearest_supported(self, x, y) -> np.ndarray:
        """(..., 2) the centre of the nearest supported cell (the point's own cell where it is
        supported, the point itself kept then)."""
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        iy, ix = self._cells(x, y)
        jy, jx = self.nearest[0][iy, ix], self.nearest[1][iy, ix]
        moved = self.unsupported[iy, ix]
        out = np.stack([x, y], axis=-1).astype(float)
        out[moved, 0] = self.origin[0] + jx[moved] * self.resolution
        out[moved, 1] = self.origin[1] + jy[moved] * self.resolution
        return out

    def nearest_clear(self, x, y, margin: float) -> np.ndarray:
        """(..., 2) the centre of the nearest cell at least ``margin`` from unsupported ground
        (the signed distance at its centre >= margin; the point itself where its own cell is).
        Where no cell is that clear, the nearest supported one. [m]"""
        key = round(float(margin), 6)
        if key not in self._clear:
            from scipy.ndimage import distance_transform_edt

            blocked = self.distance.heights < key - 1e-9
            if blocked.all():
                self._clear[key] = (self.nearest, self.unsupported)
            else:
                _, nearest = distance_transform_edt(blocked, return_indices=True)
                self._clear[key] = (nearest, blocked)
        nearest, blocked = self._clear[key]
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        iy, ix = self._cells(x, y)
        moved = blocked[iy, ix]
        out = np.stack([x, y], axis=-1).astype(float)
        out[moved, 0] = self.origin[0] + nearest[1][iy, ix][moved] * self.resolution
        out[moved, 1] = self.origin[1] + nearest[0][iy, ix][moved] * self.resolution
        return out


def _disc(radius_cells: float) -> np.ndarray:
    r = int(np.floor(radius_cells))
    i, j = np.mgrid[-r:r + 1, -r:r + 1]
    return i * i + j * j <= radius_cells * radius_cells + 1e-9


def field_from_grid(heights: np.ndarray, resolution: float, origin, radius: float, drop: float) -> SupportField:
    """The SupportField of a gridded heightmap (heights[iy, ix]).

    On the grid: a cell is unsupported when a cell whose centre lies within ``radius`` of its
    centre differs from it by more than ``drop``; the signed distance's zero lies half way
    between a supported and an unsupported cell's centres. On a 0.05 m heightmap with the
    default 0.08 m radius the cells on both sides of an edge are unsupported, so a foothold's
    centre stays at least 0.05 m from the edge (the demo's slipping foot stood 0.03 m from it);
    on finer grids the clearance approaches the radius."""
    from scipy.ndimage import distance_transform_edt, maximum_filter, minimum_filter

    heights = np.asarray(heights, dtype=float)
    footprint = _disc(radius / resolution)
    low = minimum_filter(heights, footprint=footprint, mode="nearest")
    high = maximum_filter(heights, footprint=footprint, mode="nearest")
    relief = np.maximum(heights - low, high - heights)
    # A relief of exactly ``drop`` is supported (a 5 cm step sampled from a closed form must
    # not flicker between the two by rounding).
    unsupported = relief > drop + 1e-6
    if unsupported.all():
        nearest = np.indices(heights.shape)
        signed = np.full(heights.shape, -_CLIP)
    else:
        inside, nearest = distance_transform_edt(unsupported, return_indices=True)
        outside = distance_transform_edt(~unsupported) if unsupported.any() else \
            np.full(heights.shape, np.inf)
        # Cell-centred distances; the boundary lies half a cell from either side's centre.
        signed = np.where(unsupported, -(inside - 0.5), outside - 0.5) * resolution
        signed = np.clip(signed, -_CLIP, _CLIP)
    grid = types.SimpleNamespace(heights=signed, resolution=resolution, origin=tuple(origin))
    return SupportField(resolution=float(resolution), origin=tuple(float(v) for v in origin),
                        radius=float(radius), drop=float(drop), relief=relief, unsupported=unsupported, nearest=nearest,
                        distance=GridTerrain(grid))


def support_field(terrain, radius: float, drop: float, region=None) -> SupportField:
    """The SupportField of a BLC terrain: a GridTerrain's own grid (computed once per terrain
    object and radius, drop), or a closed-form terrain sampled every CLOSED_FORM_RESOLUTION
    over ``region`` (xmin, xmax, ymin, ymax)."""
    key = (round(float(radius), 6), round(float(drop), 6))
    if isinstance(terrain, GridTerrain):
        terrain = terrain.given  # footholds are supported by the map as given
        cache = terrain.__dict__.setdefault("_support_fields", {})
        if key not in cache:
            cache[key] = field_from_grid(terrain.heights, terrain.resolution, terrain.origin, radius, drop)
        return cache[key]
    if region is None:
        raise ValueError("support_field: a closed-form terrain needs a region")
    xmin, xmax, ymin, ymax = (float(v) for v in region)
    heights, origin, resolution = terrain.grid(xmin, xmax, ymin, ymax, CLOSED_FORM_RESOLUTION)
    return field_from_grid(heights, resolution, origin, radius, drop)


class SupportConstraint(SampledConstraint):
    """Support under the free stance footholds: lower <= signed distance to the unsupported
    set at (p_x, p_y) (``SupportField.margin``), one row per foothold."""

    name = "support"

    def __init__(self, samples: LinearSamples, field: SupportField, lower: float = 0.0):
        self.samples = samples
        self.field = field
        m = samples.num_samples
        self.lower = np.full(m, float(lower))
        self.upper = np.full(m, np.inf)
        self.segments = [(a, min(a + 32, m)) for a in range(0, m, 32)]
        self._set_blocks([_Block(np.arange(m)[:, None], samples)])

    def _compute(self, x, with_partials):
        p = self.samples.value(x)
        d, dx, dy, *_ = self.field.distance.height_derivatives(p[:, 0], p[:, 1])
        if not with_partials:
            return d, None
        return d, [np.stack([dx, dy, np.zeros_like(dx)], axis=-1)[:, None, :]]
