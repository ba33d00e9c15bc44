"""Legs clear of the terrain (issue 34; paper 000 Fig. 2): the thigh and shank of every leg kept
above the ground at dense samples of stance and swing.

Fig. 9 (``data/fig9``) ended 42 of A*'s 71 failed walks and 37 of CapPlanner's with a leg link
on the terrain: the MF shank on a stair riser (knee out), the side front legs on box fields.
The feet were clear; nothing kept the legs off. Here each leg's links are a few points
(``legs.LinkPoints``, placed along the collision capsules of the URDF) whose positions follow
from the body pose and the foot by the leg's inverse kinematics (``legs.py``), and each point
must stay ``margin`` above the *clearance field*: the raw heightmap's maximum within
``footprint`` of it (the capsule's radius plus ``BlcParameters.leg_clearance_footprint``, and a
cell more so that the interpolant stays above it, _EXTRA_CELLS), interpolated with exact
derivatives by the same
shape-preserving bicubic as the feet's terrain (``GridTerrain``). On raw cells a riser is a
vertical wall at the cell border; the smoothed surface the feet stand on would move it half a
cell and round it off, which is why the field is built from the raw cells.

The rows exist only where the terrain has relief a link could meet (an edge or a riser, as the
support constraint finds them): on flat ground and gentle slopes the program is unchanged.

``dense_link_check`` is the verdict's half: every link sampled every ``DENSE_LINK_SPACING``
along its capsule at the verdict's 100 Hz, each sample a sphere of the capsule's radius tested
against the raw cells under it (the column model Drake's box terrain is).
"""

from __future__ import annotations

import dataclasses
import types

import numpy as np

from qz_drake.errors import TerrainError, bad_value
from qz_drake.trajopt.constraints import SampledConstraint, _Block
from qz_drake.trajopt.legs import LinkPoints, link_geometry, link_points
from qz_drake.trajopt.splines import LinearSamples
from qz_drake.trajopt.terrain import FlatTerrain, GridTerrain, grid_window

# Grid step for closed-form terrains (sampled over the task's region), as support.py. [m]
CLOSED_FORM_RESOLUTION = 0.02
# Spacing of the dense verdict's samples along a link. [m]
DENSE_LINK_SPACING = 0.015
# The field's dilation reaches this many cells beyond the footprint: the interpolant between
# two nodes is no higher than the higher node, so a node must cover the ground a disc about
# any point up to a cell away overlaps. Measured on 20 000 random points (issue 34): with half
# a cell (the cells a disc overlaps) the field lay up to 0.13 m below the highest ground near
# a step's riser; with one cell, nowhere near a straight edge and at most 0.08 m (99.9th
# percentile 0.02 m) near the corners of a box field; 1.5 cells, nowhere, at the cost of a
# 2.5 cm wider strip kept clear.
_EXTRA_CELLS = 1.0


@dataclasses.dataclass
class ClearanceField:
    """The raw ground's highest point within ``footprint`` of each grid cell, interpolated."""

    resolution: float
    origin: tuple[float, float]
    footprint: float
    # The raw heights the field was built from, the dilated (and smoothed) ones, and how much
    # higher than each cell the highest raw cell within reach of it is. [m]
    raw: np.ndarray
    dilated: np.ndarray
    relief: np.ndarray
    # The dilated heights as an interpolated terrain (exact derivatives).
    surface: GridTerrain
    # Whether any cell has relief a link could meet (see ``relief_limit`` of clearance_field).
    has_relief: bool


def _disc(radius_cells: float) -> np.ndarray:
    r = int(np.ceil(radius_cells))
    i, j = np.mgrid[-r:r + 1, -r:r + 1]
    return i * i + j * j <= radius_cells * radius_cells + 1e-9


def field_from_grid(heights, resolution: float, origin, footprint: float,
                    relief_limit: float, smoothing: float = 0.0) -> ClearanceField:
    """The ClearanceField of raw heights[iy, ix].

    A cell's value is first the highest cell whose centre lies within ``footprint`` plus
    ``smoothing`` plus _EXTRA_CELLS cells of its centre, then, with ``smoothing``, the mean of those values over the square of
    half-width ``smoothing`` around it: along a straight edge the mean over a window about p
    of maxima over discs reaching that much further is at least the maximum over the disc of
    ``footprint`` about p itself, so the smoothing loses no clearance there (near a corner the
    dense verdict is the judge); it turns a riser's one-cell jump into a ramp 2 smoothing
    wide."""
    from scipy.ndimage import maximum_filter, uniform_filter

    heights = np.asarray(heights, dtype=float)
    half = int(round(smoothing / resolution))
    reach = footprint / resolution + half + _EXTRA_CELLS
    footprint_cells = _disc(reach)
    dilated = maximum_filter(heights, footprint=footprint_cells, mode="nearest")
    # Ground higher than a cell within reach of it: what a link over the cell could meet (a
    # plane has little of it: 0.035 m on a 15 degree slope at this reach).
    relief = dilated - heights
    if half:
        dilated = uniform_filter(dilated, size=2 * half + 1, mode="nearest")
    grid = types.SimpleNamespace(heights=dilated, resolution=float(resolution), origin=tuple(origin))
    return ClearanceField(resolution=float(resolution), origin=tuple(float(v) for v in origin),
                          footprint=float(footprint), raw=heights, dilated=dilated,
                          relief=relief, surface=GridTerrain(grid),
                          has_relief=bool(np.any(relief > relief_limit + 1e-6)))


def clearance_field(terrain, footprint: float, relief_limit: float, region,
                    smoothing: float = 0.0) -> ClearanceField | None:
    """The ClearanceField of a BLC terrain over ``region`` (xmin, xmax, ymin, ymax): a
    GridTerrain's own cells (cached on the terrain), a closed-form terrain sampled every
    CLOSED_FORM_RESOLUTION; None on flat ground."""
    if isinstance(terrain, FlatTerrain):
        return None
    if isinstance(terrain, GridTerrain):
        terrain = terrain.given  # the links clear the map as given
        key = tuple(round(float(v), 6) for v in (footprint, relief_limit, smoothing))
        cache = terrain.__dict__.setdefault("_clearance_fields", {})
        if key not in cache:
            cache[key] = field_from_grid(terrain.heights, terrain.resolution, terrain.origin,
                                         footprint, relief_limit, smoothing)
        field = cache[key]
        return field if _relief_in(field, region, relief_limit) else None
    xmin, xmax, ymin, ymax = (float(v) for v in region)
    heights, origin, resolution = terrain.grid(xmin, xmax, ymin, ymax, CLOSED_FORM_RESOLUTION)
    field = field_from_grid(heights, resolution, origin, footprint, relief_limit, smoothing)
    return field if field.has_relief else None


def _relief_in(field: ClearanceField, region, relief_limit: float) -> bool:
    """Whether a cell of ``region`` has more relief than relief_limit within the footprint."""
    if not field.has_relief:
        return False
    window = grid_window(field.origin, field.resolution, field.raw.shape, region)
    return bool(np.any(field.relief[window] > relief_limit + 1e-6))


def constraint_points(robot, spacing: float, thigh_start: bool = False) -> LinkPoints:
    """Points along each leg's collision capsules at most ``spacing`` apart: the shank's from
    the knee to where its capsule ends, the thigh's up to the knee, from where its capsule
    starts with ``thigh_start`` (the dense verdict), else from one spacing further (the
    constraint: the capsule's start is 9 cm from the hip, at the trunk's height, where the
    trunk would meet the ground first)."""
    def along(a, b):
        count = max(1, int(np.ceil((b - a) / spacing - 1e-9)))
        return tuple(np.linspace(a, b, count + 1))
    thigh = along(*robot.thigh_collision)
    shank = along(*robot.shank_collision)[1:]  # the knee is the thigh's last point
    return LinkPoints.along(thigh if thigh_start else thigh[1:], shank)


@dataclasses.dataclass
class LinkClearance:
    """What the constraint checks, for one pose at a time (the initial guess's use)."""

    geometry: dict
    points: LinkPoints
    field: ClearanceField
    # Least height of a link point above the field. [m]
    lower: float

    def heights(self, com, rpy, feet) -> np.ndarray:
        """(L, J) height of each link point above the field with the body at com (3,), rpy
        (3,) and the feet at feet (L, 3). [m]"""
        pts, _ = link_points(self.geometry, self.points, np.asarray(com, dtype=float)[None],
                             np.asarray(rpy, dtype=float)[None], np.asarray(feet, dtype=float)[None],
                             with_gradient=False)
        return pts[0, ..., 2] - self.field.surface.height(pts[0, ..., 0], pts[0, ..., 1])

    def depth(self, leg: int, com, rpy, feet) -> np.ndarray:
        """How far (>= 0) the links of ``leg`` would sink below ``lower`` above the field with
        the body at com and rpy ((3,), or (m, 3): one pose per foot) and that leg's foot at
        each of feet (m, 3). [m]"""
        feet = np.asarray(feet, dtype=float)
        m = len(feet)
        one = {k: v[leg:leg + 1] for k, v in self.geometry.items()}
        com = np.broadcast_to(np.asarray(com, dtype=float), (m, 3))
        rpy = np.broadcast_to(np.asarray(rpy, dtype=float), (m, 3))
        pts, _ = link_points(one, self.points, com, rpy, feet[:, None, :], with_gradient=False)
        height = pts[..., 2] - self.field.surface.height(pts[..., 0], pts[..., 1])
        return np.maximum(0.0, self.lower - height.min(axis=(1, 2)))


class LegClearanceConstraint(SampledConstraint):
    """Every link point above the clearance field: p_z - F(p_x, p_y) >= lower, at each sample
    time, for each leg and point (rows ordered time, leg, point)."""

    name = "leg_clearance"

    def __init__(self, variables, times, geometry: dict, points: LinkPoints,
                 field: ClearanceField, lower: float):
        v = variables
        self.times = t = np.atleast_1d(np.asarray(times, dtype=float))
        n, L, J = len(t), v.num_legs, points.num_points
        self.num_legs, self.num_points = L, J
        self.rows_per_sample = L * J
        self.geometry, self.points, self.field = geometry, points, field
        self.lower = np.full(n * L * J, float(lower))
        self.upper = np.full(n * L * J, np.inf)
        self.rpy = v.base_rpy.sample(t, 0)
        self.com = v.base_position.sample(t, 0)
        self.feet = LinearSamples.concatenate([v.foot_position[leg].sample(t, 0) for leg in range(L)])
        rows_all = np.arange(n * L * J).reshape(n, L * J)
        leg_rows = rows_all.reshape(n, L, J).transpose(1, 0, 2).reshape(L * n, J)
        self._set_blocks([_Block(rows_all, self.rpy), _Block(rows_all, self.com),
                          _Block(leg_rows, self.feet)])

    def _heights(self, x, with_partials):
        """(n, L, J) every link point's height above the field and, with_partials, its gradient
        (n, L, J, 9) with respect to (com, rpy, that leg's foot) of the same sample."""
        n, L = len(self.times), self.num_legs
        rpy = self.rpy.value(x)
        com = self.com.value(x)
        feet = self.feet.value(x).reshape(L, n, 3).transpose(1, 0, 2)
        pts, grad = link_points(self.geometry, self.points, com, rpy, feet, with_partials)
        h, hx, hy, *_ = self.field.surface.height_derivatives(pts[..., 0], pts[..., 1])
        if not with_partials:
            return pts[..., 2] - h, None
        # The z row of the gradient minus the field's slope times the x and y rows.
        return pts[..., 2] - h, grad[..., 2, :] - hx[..., None] * grad[..., 0, :] - hy[..., None] * grad[..., 1, :]

    def _compute(self, x, with_partials):
        n, L, J = len(self.times), self.num_legs, self.num_points
        height, dg = self._heights(x, with_partials)
        g = height.reshape(-1)
        if not with_partials:
            return g, None
        dg = dg.reshape(n, L * J, 9)
        d_feet = dg[..., 6:9].reshape(n, L, J, 3).transpose(1, 0, 2, 3).reshape(L * n, J, 3)
        return g, [dg[..., 3:6], dg[..., 0:3], d_feet]

    @property
    def point_lower(self) -> np.ndarray:
        """Each link point's least clearance, rows ordered time, leg, point. [m]"""
        return self.lower

    def with_point_lower(self, lower) -> "LegClearanceConstraint":
        """This constraint with other per-point bounds (a copy sharing the rest, as ``on``)."""
        return self.on(lower=np.asarray(lower, dtype=float))


class LegClearanceSoftminConstraint(LegClearanceConstraint):
    """Every leg's links above the clearance field as one row per sample and leg: the smooth
    minimum over the leg's J link points of each point's clearance beyond its bound,
    s = -log(sum_j exp(-rho a_j)) / rho >= 0, a_j = p_z - F(p_x, p_y) - lower_j.

    s lies between min_j a_j - log(J) / rho and min_j a_j, so a row that holds keeps every
    point of its leg above its bound (at most log(J) / rho more room than the point rows ask
    for, where all J points are equally close). With ``mean`` the row is s >= -log(J) / rho
    (the log-mean-exp >= 0): no more room than the point rows ask for, and a point at most
    log(J) / rho below its bound. A row depends on the body at its time and on
    that leg's foot only, as each point's row did: J times fewer rows and Jacobian entries.
    The point rows (LegClearanceConstraint) never bind on most samples (none of 3636 within
    5 cm on a stairs task, issue 53) but cost Ipopt's linear algebra as much as rows that do.
    """

    def __init__(self, variables, times, geometry: dict, points: LinkPoints,
                 field: ClearanceField, lower: float, sharpness: float, mean: bool = False):
        super().__init__(variables, times, geometry, points, field, lower)
        if not sharpness > 0:
            raise bad_value("blc.leg_clearance_softmin", sharpness, "must be positive (1/m) or null")
        n, L = len(self.times), self.num_legs
        self.sharpness = float(sharpness)
        self._point_lower = self.lower
        # ``mean`` (BlcParameters.leg_clearance_softmin_mean): the bound of the log-mean-exp,
        # s + log(J) / rho >= 0, which lets a point sink at most log(J) / rho below its bound.
        bound = -np.log(self.num_points) / self.sharpness if mean else 0.0
        self.lower, self.upper = np.full(n * L, bound), np.full(n * L, np.inf)
        self.rows_per_sample = L
        rows_all = np.arange(n * L).reshape(n, L)
        self._set_blocks([_Block(rows_all, self.rpy), _Block(rows_all, self.com),
                          _Block(rows_all.T.reshape(L * n, 1), self.feet)])

    @property
    def point_lower(self) -> np.ndarray:
        return self._point_lower

    def with_point_lower(self, lower) -> "LegClearanceSoftminConstraint":
        return self.on(_point_lower=np.asarray(lower, dtype=float))

    def _compute(self, x, with_partials):
        n, L, J = len(self.times), self.num_legs, self.num_points
        height, dg = self._heights(x, with_partials)
        a = height - self._point_lower.reshape(n, L, J)
        # Taken about the least clearance, so that no exponential overflows.
        least = a.min(axis=2)
        weight = np.exp(-self.sharpness * (a - least[..., None]))
        total = weight.sum(axis=2)
        s = (least - np.log(total) / self.sharpness).reshape(-1)
        if not with_partials:
            return s, None
        # ds/da_j is point j's softmax weight; each a_j's gradient is its point row's.
        weight /= total[..., None]
        ds = np.einsum("nlj,nljk->nlk", weight, dg)
        d_feet = ds[..., 6:9].transpose(1, 0, 2).reshape(L * n, 1, 3)
        return s, [ds[..., 3:6], ds[..., 0:3], d_feet]


@dataclasses.dataclass
class LinkCheck:
    """The dense verdict's figures for the links."""

    # Least clearance of any link sphere's bottom above the raw ground under it. [m]
    min_clearance: float
    # Where: leg id, link point name, time; None without links.
    worst: tuple | None
    # Every sphere's clearance (n, L, J) and the spheres' names (J,). [m]
    clearance: np.ndarray | None = None
    names: tuple = ()


def raw_ground(terrain):
    """The ground as the verdict reads it: a GridTerrain's raw cells as columns (as Drake's box
    terrain is; a point takes the height of the cell it lies in: RawCells), a closed-form
    terrain's own function."""
    if not isinstance(terrain, GridTerrain):
        return terrain.height
    return RawCells(terrain.given)


class RawCells:
    """A GridTerrain's raw cells as a function of (x, y): the height of the cell a point lies
    in, the border cells extending outward."""

    def __init__(self, terrain: GridTerrain):
        self.heights, self.origin, self.resolution = terrain.heights, terrain.origin, terrain.resolution

    def __call__(self, x, y) -> np.ndarray:
        H, W = self.heights.shape
        ix = np.clip(np.rint((np.asarray(x, dtype=float) - self.origin[0]) / self.resolution),
                     0, W - 1).astype(np.int64)
        iy = np.clip(np.rint((np.asarray(y, dtype=float) - self.origin[1]) / self.resolution),
                     0, H - 1).astype(np.int64)
        return self.heights[iy, ix]

    def highest(self, x, y, dx, dy) -> np.ndarray:
        """Per point of x, y (any shape): the highest cell under the points offset by each of
        (dx, dy) (m,), as max over m of self(x + dx, y + dy) gives it (compiled)."""
        from qz_drake.trajopt.grid_kernel import highest_cells

        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        out = np.empty(x.size)
        if not highest_cells(np.ascontiguousarray(x).reshape(-1), np.ascontiguousarray(y).reshape(-1),
                             np.ascontiguousarray(dx, dtype=float), np.ascontiguousarray(dy, dtype=float),
                             self.heights, self.origin[0], self.origin[1], self.resolution, out):
            raise bad_value("terrain query", f"{int((np.isnan(x) | np.isnan(y)).sum())} points with NaN "
                            "coordinates", "a point must be a number to have a height", TerrainError)
        return out.reshape(x.shape)


def sphere_clearance(centres, radius: float, ground) -> np.ndarray:
    """(...,) height of the bottom of spheres at ``centres`` (..., 3) above the highest ground
    under their discs (the centre and eight points on the rim, read by ``ground(x, y)``, e.g.
    ``raw_ground(terrain)``). [m]"""
    centres = np.asarray(centres, dtype=float)
    angles = np.linspace(0.0, 2 * np.pi, 8, endpoint=False)
    offsets = np.concatenate([[[0.0, 0.0]], radius * np.stack([np.cos(angles), np.sin(angles)], -1)])
    if isinstance(ground, RawCells):
        highest = ground.highest(centres[..., 0], centres[..., 1], offsets[:, 0], offsets[:, 1])
    else:
        highest = ground(centres[..., 0, None] + offsets[:, 0], centres[..., 1, None] + offsets[:, 1]).max(axis=-1)
    return centres[..., 2] - radius - highest


def dense_link_check(robot, terrain, times, com, rpy, feet, radius: float | None = None) -> LinkCheck:
    """Each leg's capsules sampled every DENSE_LINK_SPACING, at the given samples (com, rpy
    (n, 3), feet (n, L, 3)): the least height of a sphere's bottom (radius robot.link_radius,
    or ``radius``) above the highest ground under its disc (its centre and eight points on its
    rim, read by ``raw_ground``)."""
    geometry = link_geometry(robot)
    if geometry is None:
        return LinkCheck(np.inf, None)
    points = constraint_points(robot, DENSE_LINK_SPACING, thigh_start=True)
    pts, _ = link_points(geometry, points, com, rpy, feet, with_gradient=False)
    radius = float(robot.link_radius if radius is None else radius)
    if isinstance(terrain, FlatTerrain):  # level ground: the disc's highest point is its centre's
        clearance = pts[..., 2] - radius - terrain.height_value
    else:
        clearance = sphere_clearance(pts, radius, raw_ground(terrain))  # (n, L, J)
    k, leg, j = np.unravel_index(int(np.argmin(clearance)), clearance.shape)
    return LinkCheck(float(clearance[k, leg, j]), (int(leg), points.names[j], float(times[k])),
                     clearance, points.names)
