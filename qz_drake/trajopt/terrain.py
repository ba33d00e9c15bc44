"""Terrain for the BLC: heights with exact first and second derivatives (paper 000 Eq. 4-5).

The terrain constraint needs h(x, y) and its gradient; the friction pyramid lives in the
terrain's tangent frame, whose derivative with respect to the foot position needs the Hessian.
Every terrain here returns all six quantities, vectorised, and they are the exact derivatives
of the function it evaluates, so every constraint Jacobian is exact.

* ``GridTerrain`` wraps any gridded heightmap (an object with ``heights`` (H, W),
  ``resolution`` and ``origin``, such as ``qz_drake.terrain.HeightMap``) in a C1 bicubic Hermite
  interpolant. Nodal slopes are limited like PCHIP's (zero at extrema and wherever a neighbouring
  secant is flat), so steps do not ring; the twist is zero. Outside the grid the border extends
  as a plateau, like ``HeightMap.height``.
* ``FootScaleTerrain``: a fine map (a depth camera's, 2 cm cells with pixel noise) as the feet
  meet it: each cell the highest point within ``2 scale`` (the foot rests on the tops, not in
  the pits between them), averaged with Gaussian weights (sigma ``scale``) over the same disc, so
  that heights and normals are those of the foot's scale and the surface is nowhere below the
  map as given (every cell of the disc round a point is at least as high as the point). The
  NLP solves on it; the fields of the legs' links and of the footholds' support, and the dense
  verdict's clearances, read the map as given (``given``). On a map whose cells are larger than
  the disc it is the map itself (``as_terrain`` then returns the GridTerrain).
* Closed-form terrains after TOWR's ``height_map_examples.cc`` (flat, block, stairs, gap, slope),
  with their edges smoothed by a C2 quintic over ``edge_width`` so that derivatives exist
  everywhere (TOWR's block uses a 0.03 m ramp for the same reason).
"""

from __future__ import annotations

import abc
import math

import numpy as np

from qz_drake.errors import TerrainError, bad_value


class TerrainModel(abc.ABC):
    """Base class: subclasses implement ``height_derivatives``."""

    name = "terrain"

    @abc.abstractmethod
    def height_derivatives(self, x, y):
        """Returns (h, h_x, h_y, h_xx, h_xy, h_yy), each of the broadcast shape of x and y."""

    def height(self, x, y) -> np.ndarray:
        return self.height_derivatives(x, y)[0]

    def gradient(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        d = self.height_derivatives(x, y)
        return d[1], d[2]

    def normal(self, x, y) -> np.ndarray:
        """Unit normals (..., 3)."""
        _, hx, hy, *_ = self.height_derivatives(x, y)
        n = np.stack(np.broadcast_arrays(-hx, -hy, np.ones_like(hx)), axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def grid(self, xmin: float, xmax: float, ymin: float, ymax: float,
             resolution: float = 0.02) -> tuple[np.ndarray, tuple[float, float], float]:
        """Heights sampled on a grid (heights[iy, ix], origin, resolution), e.g. to save."""
        xs = np.arange(xmin, xmax + 0.5 * resolution, resolution)
        ys = np.arange(ymin, ymax + 0.5 * resolution, resolution)
        X, Y = np.meshgrid(xs, ys)
        return self.height(X, Y), (float(xs[0]), float(ys[0])), float(resolution)


def _zeros_like(x, y):
    x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    return np.zeros(x.shape)


class FlatTerrain(TerrainModel):
    """Level ground at ``height``."""

    name = "flat"

    def __init__(self, height: float = 0.0):
        self.height_value = float(height)

    def height_derivatives(self, x, y):
        z = _zeros_like(x, y)
        return z + self.height_value, z, z, z, z, z


def smooth_step(s, width: float):
    """C2 quintic step from 0 (s <= -width/2) to 1 (s >= width/2): value, d/ds, d2/ds2."""
    u = np.clip(np.asarray(s, dtype=float) / width + 0.5, 0.0, 1.0)
    value = u ** 3 * (10 - 15 * u + 6 * u * u)
    d1 = 30 * u * u * (1 - u) ** 2 / width
    d2 = 60 * u * (1 - u) * (1 - 2 * u) / width ** 2
    return value, d1, d2


def smooth_ramp(s, width: float):
    """The integral of smooth_step: 0 before -width/2, s after width/2; value, d1, d2."""
    s = np.asarray(s, dtype=float)
    u = np.clip(s / width + 0.5, 0.0, 1.0)
    inner = width * u ** 4 * (2.5 - 3 * u + u * u)
    value = np.where(s >= 0.5 * width, s, inner)
    step, d1, _ = smooth_step(s, width)
    return value, step, d1


class _ProfileTerrain(TerrainModel):
    """A terrain that varies along x only: h(x) from _profile(x) -> (h, h', h'')."""

    @abc.abstractmethod
    def _profile(self, x):
        """(h, h', h'') along x."""

    def height_derivatives(self, x, y):
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        h, hx, hxx = self._profile(x)
        z = np.zeros(x.shape)
        return h, hx, z, hxx, z, z


class StepsTerrain(_ProfileTerrain):
    """Level pieces joined by smoothed steps: height ``heights[i]`` from ``edges[i]`` on, 0
    before the first edge. Block, stairs and gap are instances."""

    name = "steps"

    def __init__(self, edges, heights, edge_width: float = 0.03, name: str = "steps"):
        self.edges = np.asarray(edges, dtype=float).reshape(-1)
        self.heights = np.asarray(heights, dtype=float).reshape(-1)
        if self.edges.shape != self.heights.shape or np.any(np.diff(self.edges) <= edge_width):
            raise bad_value("terrain.edges", tuple(self.edges),
                            "need one height per edge and edges further apart than edge_width",
                            TerrainError)
        if not edge_width > 0:
            raise bad_value("terrain.edge_width", edge_width, "must be positive", TerrainError)
        self.rises = np.diff(np.concatenate([[0.0], self.heights]))
        self.edge_width = float(edge_width)
        self.name = name

    def _profile(self, x):
        s, d1, d2 = smooth_step(x[..., None] - self.edges, self.edge_width)
        return (s @ self.rises, d1 @ self.rises, d2 @ self.rises)


class SlopeTerrain(_ProfileTerrain):
    """Flat, then a plane rising at ``angle_deg`` from ``start_x``; with ``top_x`` it levels
    off there. Kinks are rounded over ``edge_width``."""

    name = "slope"

    def __init__(self, angle_deg: float = 15.0, start_x: float = 0.5, top_x: float | None = None,
                 edge_width: float = 0.1):
        if not math.isfinite(angle_deg) or abs(angle_deg) >= 80:
            raise bad_value("terrain.angle_deg", angle_deg, "must be finite and below 80", TerrainError)
        self.slope = math.tan(math.radians(angle_deg))
        self.start_x = float(start_x)
        self.top_x = None if top_x is None else float(top_x)
        self.edge_width = float(edge_width)

    def _profile(self, x):
        h, d1, d2 = smooth_ramp(x - self.start_x, self.edge_width)
        if self.top_x is not None:
            g, e1, e2 = smooth_ramp(x - self.top_x, self.edge_width)
            h, d1, d2 = h - g, d1 - e1, d2 - e2
        return self.slope * h, self.slope * d1, self.slope * d2


def block(start_x: float = 0.7, height: float = 0.5, length: float = 3.5,
          edge_width: float = 0.03) -> StepsTerrain:
    """TOWR's block: ``height`` [m] high from ``start_x`` over ``length`` [m]."""
    return StepsTerrain((start_x, start_x + length), (height, 0.0), edge_width, "block")


def stairs(start_x: float = 1.0, run: float = 0.4, rises=(0.2, 0.2), top_length: float = 1.0,
           edge_width: float = 0.03) -> StepsTerrain:
    """TOWR's stairs: 0.2 m at x = 1.0, 0.4 m from x = 1.4, back to 0 after the 1 m top."""
    heights = np.cumsum(rises)
    edges = start_x + run * np.arange(len(heights))
    edges = np.append(edges, edges[-1] + top_length)
    return StepsTerrain(edges, np.append(heights, 0.0), edge_width, "stairs")


def gap(start_x: float = 1.0, end_x: float = 1.5, depth: float = 1.5,
        edge_width: float = 0.03) -> StepsTerrain:
    """TOWR's gap: a trench ``depth`` [m] deep from start_x to end_x."""
    return StepsTerrain((start_x, end_x), (-depth, 0.0), edge_width, "gap")


def slope(angle_deg: float = 15.0, start_x: float = 0.5, top_x: float | None = None,
          edge_width: float = 0.1) -> SlopeTerrain:
    return SlopeTerrain(angle_deg, start_x, top_x, edge_width)


def flat(height: float = 0.0) -> FlatTerrain:
    return FlatTerrain(height)


CLOSED_FORM_TERRAINS = {"flat": flat, "block": block, "stairs": stairs, "gap": gap, "slope": slope}


def make_closed_form_terrain(kind: str, **params) -> TerrainModel:
    """Builds one of TOWR's closed-form terrains by name; bad names raise TerrainError."""
    if kind not in CLOSED_FORM_TERRAINS:
        raise bad_value("terrain", kind,
                        f"unknown closed-form terrain (valid: {', '.join(CLOSED_FORM_TERRAINS)})",
                        TerrainError)
    try:
        return CLOSED_FORM_TERRAINS[kind](**params)
    except TypeError as e:
        raise bad_value("terrain params", params, f"not accepted by {kind} ({e})", TerrainError) from None


def _limited_slopes(h: np.ndarray, axis: int, spacing: float) -> np.ndarray:
    """PCHIP-style nodal derivatives along one axis: the harmonic mean of the neighbouring
    secants where they agree in sign, zero otherwise; one-sided secants at the borders."""
    d = np.diff(h, axis=axis) / spacing
    n = h.shape[axis]
    slopes = np.zeros_like(h)
    if n < 2:
        return slopes
    left = np.take(d, np.arange(0, n - 2), axis=axis)
    right = np.take(d, np.arange(1, n - 1), axis=axis)
    same = left * right > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        harmonic = np.where(same, 2 * left * right / (left + right), 0.0)
    inner = [slice(None)] * h.ndim
    inner[axis] = slice(1, n - 1)
    slopes[tuple(inner)] = harmonic
    for end, src in ((0, 0), (n - 1, n - 2)):
        idx = [slice(None)] * h.ndim
        idx[axis] = end
        slopes[tuple(idx)] = np.take(d, src, axis=axis)
    return slopes


class GridTerrain(TerrainModel):
    """C1 bicubic Hermite interpolant of a gridded heightmap (heights[iy, ix] at
    x = origin[0] + ix * resolution, y = origin[1] + iy * resolution)."""

    name = "grid"

    def __init__(self, heightmap):
        try:
            heights = np.asarray(heightmap.heights, dtype=float)
            res = float(heightmap.resolution)
            origin = tuple(float(v) for v in np.asarray(heightmap.origin, dtype=float).reshape(2))
        except (AttributeError, TypeError, ValueError) as e:
            raise bad_value("terrain", type(heightmap).__name__,
                            f"needs heights (H, W), resolution and origin (x, y) ({e})",
                            TerrainError) from None
        if heights.ndim != 2 or min(heights.shape) < 2:
            raise bad_value("terrain.heights", f"array of shape {heights.shape}",
                            "expected at least 2 x 2 cells", TerrainError)
        if not np.all(np.isfinite(heights)):
            raise bad_value("terrain.heights", "non-finite values", "heights must be finite",
                            TerrainError)
        if not (math.isfinite(res) and res > 0):
            raise bad_value("terrain.resolution", res, "must be positive", TerrainError)
        self.heightmap = heightmap
        self.heights = heights
        self.resolution = res
        self.origin = origin
        # Nodal slopes times the cell size: the Hermite coefficients of a unit cell.
        self._hx = _limited_slopes(heights, 1, res) * res
        self._hy = _limited_slopes(heights, 0, res) * res

    def _patches(self, x, y):
        """Per point: its coordinates in its cell (s, t in [0, 1]), whether it lies inside the
        grid along x and along y, and the cell's corner data {(a, b): (value, x-slope, y-slope)}
        at (i + a, j + b). The numpy form of what ``_grid_kernel`` computes point by point
        (``height_numpy``, ``height_derivatives_numpy``)."""
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        H, W = self.heights.shape
        res = self.resolution
        u = (x - self.origin[0]) / res
        v = (y - self.origin[1]) / res
        # Outside the grid the border extends flat: clamp, and zero the clamped derivative.
        inside_u = (u > 0) & (u < W - 1)
        inside_v = (v > 0) & (v < H - 1)
        u = np.clip(u, 0.0, W - 1.0)
        v = np.clip(v, 0.0, H - 1.0)
        i = np.minimum(np.floor(u).astype(np.int64), W - 2)
        j = np.minimum(np.floor(v).astype(np.int64), H - 2)
        f, fx, fy = self.heights, self._hx, self._hy
        corners = {}
        for a in (0, 1):
            for b in (0, 1):
                corners[a, b] = (f[j + b, i + a], fx[j + b, i + a], fy[j + b, i + a])
        return u - i, v - j, inside_u, inside_v, corners

    def height_numpy(self, x, y) -> np.ndarray:
        """``height`` in numpy operations (the reference the compiled loop is tested equal to)."""
        s, t, _, _, corners = self._patches(x, y)
        return _hermite_combine(corners, _hermite_values(s), _hermite_values(t))

    def height_derivatives_numpy(self, x, y):
        """``height_derivatives`` in numpy operations (the compiled loop's reference)."""
        s, t, inside_u, inside_v, corners = self._patches(x, y)
        res = self.resolution
        bu, bu1, bu2 = _hermite_values(s), _hermite_slopes(s), _hermite_curvatures(s)
        bv, bv1, bv2 = _hermite_values(t), _hermite_slopes(t), _hermite_curvatures(t)
        h = _hermite_combine(corners, bu, bv)
        hx = np.where(inside_u, _hermite_combine(corners, bu1, bv), 0.0) / res
        hy = np.where(inside_v, _hermite_combine(corners, bu, bv1), 0.0) / res
        hxx = np.where(inside_u, _hermite_combine(corners, bu2, bv), 0.0) / res ** 2
        hxy = np.where(inside_u & inside_v, _hermite_combine(corners, bu1, bv1), 0.0) / res ** 2
        hyy = np.where(inside_v, _hermite_combine(corners, bu, bv2), 0.0) / res ** 2
        return h, hx, hy, hxx, hxy, hyy

    def _compiled(self, x, y, derivatives: bool):
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        shape = x.shape
        count = 6 if derivatives else 1
        out = np.empty((count, x.size))
        if not _grid_kernel()(np.ascontiguousarray(x).reshape(-1), np.ascontiguousarray(y).reshape(-1),
                              self.heights, self._hx, self._hy, self.origin[0], self.origin[1],
                              self.resolution, self.resolution ** 2, out):
            raise bad_value("terrain query", f"{int((np.isnan(x) | np.isnan(y)).sum())} points with NaN "
                            "coordinates", "a point must be a number to have a height", TerrainError)
        rows = [row.reshape(shape) for row in out]
        # 0-d inputs give numpy scalars, as the numpy operations did.
        return [row[()] for row in rows] if shape == () else rows

    def height(self, x, y) -> np.ndarray:
        # The value alone (the guess and the dense verdict ask for heights only): the same
        # arithmetic as height_derivatives' first output.
        return self._compiled(x, y, False)[0]

    def height_derivatives(self, x, y):
        return tuple(self._compiled(x, y, True))

    def grid(self, xmin=None, xmax=None, ymin=None, ymax=None, resolution=None):
        """The wrapped map itself (the BLC saves the map it was given)."""
        return self.heights, self.origin, self.resolution

    @property
    def given(self) -> "GridTerrain":
        """The map as given (the leg and support fields and the dense verdict read it)."""
        return self


def foot_scale_heights(heights, resolution: float, scale: float) -> np.ndarray | None:
    """The heights of FootScaleTerrain (module docstring): the highest cell within 2 scale, then
    a Gaussian mean (sigma scale) over the same disc; None when that disc holds no cell but the
    centre (the map is already at the foot's scale or coarser). [m]"""
    from scipy import ndimage

    reach = 2.0 * float(scale) / float(resolution)
    n = int(math.floor(reach + 1e-9))
    if n < 1:
        return None
    offsets = np.arange(-n, n + 1)
    dx, dy = np.meshgrid(offsets, offsets)
    d2 = dx * dx + dy * dy
    disc = d2 <= reach * reach + 1e-9
    tops = ndimage.maximum_filter(np.asarray(heights, dtype=float), footprint=disc, mode="nearest")
    sigma = float(scale) / float(resolution)
    weights = np.where(disc, np.exp(-0.5 * d2 / sigma ** 2), 0.0)
    return ndimage.correlate(tops, weights / weights.sum(), mode="nearest")


class FootScaleTerrain(GridTerrain):
    """A fine gridded map at the foot's scale (module docstring); ``given`` is the map as given."""

    name = "grid_foot_scale"

    def __init__(self, heightmap, scale: float):
        given = GridTerrain(heightmap)
        if not (isinstance(scale, (int, float)) and math.isfinite(scale) and scale > 0):
            raise bad_value("blc.terrain_foot_scale", scale, "must be a positive length", TerrainError)
        smoothed = foot_scale_heights(given.heights, given.resolution, scale)
        if smoothed is None:
            raise bad_value("blc.terrain_foot_scale", scale, f"a map of {given.resolution:g} m cells is "
                            f"already at that scale (as_terrain keeps it as it is)", TerrainError)
        import types

        super().__init__(types.SimpleNamespace(heights=smoothed, resolution=given.resolution,
                                               origin=given.origin))
        self.heightmap = heightmap
        self.scale = float(scale)
        self._given = given

    @property
    def given(self) -> GridTerrain:
        return self._given

    def grid(self, xmin=None, xmax=None, ymin=None, ymax=None, resolution=None):
        """The map as given (the BLC saves the map it was given)."""
        return self._given.grid()


def _hermite_values(a):
    """The cubic Hermite basis (phi_0, psi_0, phi_1, psi_1) on the unit cell at a."""
    a2, a3 = a * a, a * a * a
    return 2 * a3 - 3 * a2 + 1, a3 - 2 * a2 + a, -2 * a3 + 3 * a2, a3 - a2


def _hermite_slopes(a):
    a2 = a * a
    return 6 * a2 - 6 * a, 3 * a2 - 4 * a + 1, -6 * a2 + 6 * a, 3 * a2 - 2 * a


def _hermite_curvatures(a):
    return 12 * a - 6, 6 * a - 4, -12 * a + 6, 6 * a - 2


def _hermite_combine(corners, pu, pv):
    """Sum over a cell's corners of phi_a(u) phi_b(v) f + psi_a(u) phi_b(v) fx + phi_a(u) psi_b(v) fy
    for basis tuples pu (along x) and pv (along y)."""
    out = 0.0
    for a in (0, 1):
        for b in (0, 1):
            val, sx, sy = corners[a, b]
            out = out + (pu[2 * a] * pv[2 * b] * val + pu[2 * a + 1] * pv[2 * b] * sx
                         + pu[2 * a] * pv[2 * b + 1] * sy)
    return out


def _grid_kernel():
    """grid_kernel.grid_values, compiled (numba, cached on disk) at a process's first grid
    query, so that flat-ground solves never import numba."""
    from qz_drake.trajopt.grid_kernel import grid_values

    return grid_values


def grid_window(origin, resolution: float, shape, region) -> tuple[slice, slice]:
    """(rows, columns) of the cells of a grid (heights[iy, ix] at origin + (ix, iy) *
    resolution, ``shape`` (H, W)) that cover region (xmin, xmax, ymin, ymax), clipped to it."""
    xmin, xmax, ymin, ymax = region
    H, W = shape
    i0, i1 = (int(np.clip(np.floor((v - origin[0]) / resolution), 0, W)) for v in (xmin, xmax + resolution))
    j0, j1 = (int(np.clip(np.floor((v - origin[1]) / resolution), 0, H)) for v in (ymin, ymax + resolution))
    return slice(j0, j1), slice(i0, i1)


def as_terrain(terrain, foot_scale: float = 0.0) -> TerrainModel:
    """None -> flat ground; a TerrainModel as is; a gridded heightmap -> GridTerrain, or with
    ``foot_scale`` > 0 [m] and cells finer than twice that, FootScaleTerrain."""
    if terrain is None:
        return FlatTerrain()
    if isinstance(terrain, TerrainModel):
        return terrain
    if all(hasattr(terrain, a) for a in ("heights", "resolution", "origin")):
        if foot_scale and float(terrain.resolution) <= 2.0 * float(foot_scale) + 1e-12:
            return FootScaleTerrain(terrain, foot_scale)
        return GridTerrain(terrain)
    raise bad_value("terrain", type(terrain).__name__,
                    "expected a TerrainModel or a heightmap with heights, resolution, origin",
                    TerrainError)
