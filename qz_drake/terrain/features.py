"""Terrain features and cost maps for body-path planning (paper 003, section 2.1-2.2, Eq. 2-16).

Every feature is computed for the whole map at once: sums over a disc around every cell are
FFT correlations, maxima over a disc are 1-D running maxima row by row, and a sliding window is
a loop over its handful of offsets, never over cells. Outside the map the border heights extend
as a plateau (``mode="nearest"``), the convention of ``HeightMap.height``.

The extracted paper lost its symbols; this is how we reconstructed the equations.

Body (section 2.1), over the cells in a disc of radius ``r`` around the body centre c:

* Eq. 2-7, slope: the least-squares plane z = a x + b y + d through the points
  (x_i, y_i, z_i) of the disc (Eq. 2), written with the design matrix A = [x y 1] (Eq. 3) and
  the vector Z of heights (Eq. 4); the normal equations A^T A p = A^T Z (Eq. 5-6) are diagonal
  for a symmetric disc centred on c, so a = sum(dx z) / sum(dx^2), b = sum(dy z) / sum(dy^2).
  The normal is n = (-a, -b, 1) / |.|, the slope its angle to vertical (Eq. 7):
  ``slope = arccos(n_z) = arctan(hypot(a, b))`` [rad].
* Eq. 8, roughness: the standard deviation of the heights in the disc [m].
* Eq. 9, step height: for each cell g, d(g) is the largest |z(g') - z(g)| over a square window
  of half-width ``step_window`` around g, reached at g_max(g); its line slope is
  s(g) = d(g) / |g_max - g|. With h_max(c) the largest d over the disc and n_s(c) the number of
  disc cells with s(g) > ``critical_slope``, ``h_step = min(1, n_s / n_critical) * h_max``: a
  big height difference is a step only if enough cells see a steep edge (a ramp or a lone
  spike is not), which is how we read "combines the slope value and the height value".
* Traversability (2.1.4 i): t = 1 where h_step <= ``max_step_height``, else the cell is blocked.
* Eq. 10, body cost: ``C_body = t * sqrt(sum_i (w_i * min(f_i / f_i,max, 1))^2)`` over slope,
  roughness and step height, with sum_i w_i^2 = 1 (we normalise the given weights). We read the
  paper's "weighted sum" with squared weights as this weighted Euclidean norm: it is the only
  reading in which the normalisation sum w_i^2 = 1 keeps C_body in [0, 1], which Eq. 16 relies
  on. Blocked cells cost ``inf``.

Footholds (section 2.2), each at two radii r1 < r2 (Eq. 11):

* curvature: the surface variation lambda_min / (lambda_1 + lambda_2 + lambda_3) of the
  covariance of the points in the disc (the usual point-cloud curvature; the paper's "sphere"
  becomes the vertical cylinder over the disc so that it vectorises; closed form below);
* slope: angle between the fitted plane's normal and vertical [rad];
* convexity: the mean angle between the normal at p and the vectors from p to eight points
  spread evenly on the ring of radius r around it, minus pi/2 [rad]: 0 on a plane, positive on
  a convex bump, negative in a hollow (the paper's concave/convex feature, shifted);
* uphill: for motion direction u, ``arctan(grad z . u)``, the angle from vertical to the normal
  projected on the vertical plane through u, positive when the ground rises ahead [rad].
* Eq. 12-13: a foothold's cost is w . phi, phi the features normalised to [0, 1] by maxima
  (convexity counts only when positive: hollows are preferred, "as long as the foot cannot be
  stuck", which curvature already penalises); front feet pay for downhill, hind feet for uphill
  ("the front foot prefers uphill terrain, while the back foot prefers downhill"); feet at
  x = 0 have no preference. Weights are >= 0 and normalised to sum 1, so the cost is in [0, 1].
* Eq. 14: each foot's cost is the mean foothold cost over an equilateral triangle centred on its
  default foothold (apex pointing along the heading); Eq. 15: the feet's cost is the mean of
  the per-foot costs. Default footholds rotate with the heading, one of the 8 move directions.
* Eq. 16: ``C = w_b * C_body + w_f * C_feet`` with w_b + w_f = 1, per heading: (8, H, W).
"""

import dataclasses
import math

import numpy as np
from scipy import ndimage

from qz_drake.errors import TerrainError, bad_value

HEADINGS = np.arange(8) * (math.pi / 4.0)
"""The 8 move directions of the grid planners, heading k * pi / 4 (see planning.grid_search)."""


# -- configuration ------------------------------------------------------------------------------
@dataclasses.dataclass
class BodyFeatureConfig:
    # Disc radius; Qingzhui's 1.2 m x 0.8 m trunk has a half-diagonal of 0.72 m. [m]
    radius: float = 0.7
    # Half-width of the step-height sliding window: two 0.05 m cells. [m]
    step_window: float = 0.1
    # Rise over run above which a height difference is a step edge, not a ramp (45 deg). [-]
    critical_slope: float = 1.0
    # Steep cells in the disc for a full step (n_crit): an 0.2 m long edge seen from both sides.
    critical_count: int = 8


@dataclasses.dataclass
class BodyCostConfig:
    # Weights of (slope, roughness, step height), normalised to squares summing to 1; the step
    # height also blocks cells, so it weighs least (the paper sets it lower too).
    weights: list[float] = dataclasses.field(default_factory=lambda: [2.0, 2.0, 1.0])
    # Slope at which the slope term saturates: 30 deg, Qingzhui's steepest tested ramp. [rad]
    max_slope: float = 0.52
    # Roughness at which its term saturates: about the foot-sphere diameter. [m]
    max_roughness: float = 0.06
    # Step height at which its term saturates; also the traversability threshold. A 0.2 m
    # stair is what Qingzhui's leg workspace allows (robot/params.py). [m]
    max_step_height: float = 0.2


@dataclasses.dataclass
class FootholdFeatureConfig:
    # The two radii of Eq. 11: the cells under the foot, and the ground around it. [m]
    radii: list[float] = dataclasses.field(default_factory=lambda: [0.05, 0.15])


@dataclasses.dataclass
class FootholdCostConfig:
    # Weights (Eq. 13) of (curvature, slope, convexity, uphill) at radius r1, then at r2;
    # normalised to sum 1. The paper learns them from experts; these favour flat, level ground.
    weights: list[float] = dataclasses.field(
        default_factory=lambda: [0.15, 0.2, 0.1, 0.05, 0.15, 0.2, 0.1, 0.05])
    # Surface variation at which curvature saturates (a right-angled edge gives about 0.1). [-]
    max_curvature: float = 0.1
    # Foothold slope at which its term saturates (35 deg, where a foot starts to slip). [rad]
    max_slope: float = 0.6
    # Convexity at which its term saturates. [rad]
    max_convexity: float = 0.3
    # Uphill/downhill angle at which its term saturates. [rad]
    max_uphill: float = 0.4
    # Side of the triangle of candidate footholds around a default foothold (Eq. 14). [m]
    triangle_side: float = 0.2


@dataclasses.dataclass
class CostMapConfig:
    body_features: BodyFeatureConfig = dataclasses.field(default_factory=BodyFeatureConfig)
    body_cost: BodyCostConfig = dataclasses.field(default_factory=BodyCostConfig)
    foothold_features: FootholdFeatureConfig = dataclasses.field(default_factory=FootholdFeatureConfig)
    foothold_cost: FootholdCostConfig = dataclasses.field(default_factory=FootholdCostConfig)
    # Weight of the body cost in Eq. 16 (the feet get 1 - body_weight): the body's terrain
    # decides traversability, the feet refine it.
    body_weight: float = 0.6


@dataclasses.dataclass(frozen=True, eq=False)
class Footprint:
    """Default footholds (ground projections of the hips' nominal stance) in the body frame."""

    # Foot names, e.g. LEG_NAMES for Qingzhui.
    names: tuple[str, ...]
    # (n, 2) default foothold (x, y) per foot, body frame, x forward. [m]
    offsets: np.ndarray

    def __post_init__(self):
        p = np.asarray(self.offsets, dtype=float)
        if p.ndim != 2 or p.shape[1] != 2 or len(p) < 1 or len(p) != len(self.names):
            raise bad_value("footprint.offsets", f"array of shape {p.shape}",
                            f"expected ({len(self.names)}, 2), one (x, y) per foot", TerrainError)
        if not np.isfinite(p).all():
            raise bad_value("footprint.offsets", p.tolist(), "must be finite", TerrainError)
        object.__setattr__(self, "offsets", p)

    @classmethod
    def qingzhui(cls) -> "Footprint":
        """Qingzhui's six nominal footholds (robot/params.py), legs in LEG_NAMES order."""
        from qz_drake.robot.params import DEFAULT_PARAMS, LEG_NAMES, NUM_LEGS

        offsets = np.array([DEFAULT_PARAMS.nominal_foothold(i)[:2] for i in range(NUM_LEGS)])
        return cls(LEG_NAMES, offsets)

    @classmethod
    def quadruped(cls, half_length: float = 0.2, half_width: float = 0.15) -> "Footprint":
        """A quadruped's four footholds at (+-half_length, +-half_width), order LF, RF, LB, RB.
        Defaults are LittleDog-like shoulders plus a little abduction. [m]"""
        hl, hw = float(half_length), float(half_width)
        return cls(("LF", "RF", "LB", "RB"), np.array([[hl, hw], [hl, -hw], [-hl, hw], [-hl, -hw]]))

    def rotated(self, heading: float) -> np.ndarray:
        """(n, 2) footholds of a body at yaw ``heading``, relative to its centre, world axes."""
        c, s = math.cos(heading), math.sin(heading)
        return self.offsets @ np.array([[c, s], [-s, c]])


# -- results ------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class BodyFeatures:
    """Body-scale features of every cell (Eq. 2-9), arrays (H, W)."""

    # Slope of the least-squares plane over the disc (Eq. 7). [rad]
    slope: np.ndarray
    # Standard deviation of the heights in the disc (Eq. 8). [m]
    roughness: np.ndarray
    # Step height (Eq. 9). [m]
    step_height: np.ndarray
    resolution: float
    config: BodyFeatureConfig


@dataclasses.dataclass(frozen=True)
class FootholdFeatures:
    """Foothold features of every cell at the radii of the config, arrays (R, H, W), R = 2."""

    # Surface variation lambda_min / trace of the points' covariance. [-]
    curvature: np.ndarray
    # Angle of the fitted plane's normal to vertical. [rad]
    slope: np.ndarray
    # Mean angle to eight ring points minus pi/2; > 0 convex, < 0 concave. [rad]
    convexity: np.ndarray
    # Gradient (dz/dx, dz/dy) of the fitted plane, (R, 2, H, W); gives uphill for any heading.
    gradient: np.ndarray
    resolution: float
    config: FootholdFeatureConfig

    def uphill(self, heading: float) -> np.ndarray:
        """(R, H, W) angle by which the ground rises along ``heading`` (Eq. 11's fourth feature). [rad]"""
        return np.arctan(self.gradient[:, 0] * math.cos(heading) + self.gradient[:, 1] * math.sin(heading))


@dataclasses.dataclass(frozen=True)
class CostMap:
    """Body cost, feet cost per heading, and the features behind them, on a heightmap's grid."""

    body: BodyFeatures
    # (H, W) body cost in [0, 1], inf where not traversable (Eq. 10).
    body_cost: np.ndarray
    foothold: FootholdFeatures
    # (8, H, W) mean cost of the feet's triangles for a body heading k * pi / 4 (Eq. 15).
    feet_cost: np.ndarray
    resolution: float
    # World (x, y) of cell (row 0, col 0). [m]
    origin: tuple[float, float]
    footprint: Footprint
    config: CostMapConfig

    @property
    def shape(self) -> tuple[int, int]:
        return self.body_cost.shape

    @property
    def traversable(self) -> np.ndarray:
        return np.isfinite(self.body_cost)

    def heading_cost(self) -> np.ndarray:
        """(8, H, W) total cost of Eq. 16 for each heading, in [0, 1]; inf where blocked."""
        w = float(self.config.body_weight)
        return w * self.body_cost[None] + (1.0 - w) * self.feet_cost

    def cell(self, x: float, y: float) -> tuple[int, int]:
        """(row, col) of the cell containing world point (x, y); may lie off the map."""
        return (int(round((float(y) - self.origin[1]) / self.resolution)),
                int(round((float(x) - self.origin[0]) / self.resolution)))

    def xy(self, cells: np.ndarray) -> np.ndarray:
        """World (x, y) of the centres of (K, 2) cells (row, col). [m]"""
        cells = np.asarray(cells, dtype=float).reshape(-1, 2)
        return np.stack([self.origin[0] + cells[:, 1] * self.resolution,
                         self.origin[1] + cells[:, 0] * self.resolution], axis=1)


# -- helpers ------------------------------------------------------------------------------------
def _heights(heights, resolution) -> tuple[np.ndarray, float, tuple[float, float]]:
    """Accepts a HeightMap (anything with .heights and .resolution) or an array + resolution."""
    origin = (0.0, 0.0)
    if hasattr(heights, "heights") and hasattr(heights, "resolution"):
        resolution = heights.resolution if resolution is None else resolution
        origin = tuple(float(v) for v in getattr(heights, "origin", origin))
        heights = heights.heights
    z = np.asarray(heights, dtype=float)
    if z.ndim != 2 or min(z.shape) < 2:
        raise bad_value("heights", f"array of shape {z.shape}", "expected a 2-D array of at least 2 x 2",
                        TerrainError)
    if not np.isfinite(z).all():
        iy, ix = np.argwhere(~np.isfinite(z))[0]
        raise bad_value(f"heights[{iy}, {ix}]", float(z[iy, ix]), "heights must be finite", TerrainError)
    try:
        res = float(resolution)
    except (TypeError, ValueError):
        raise bad_value("resolution", resolution, "expected a cell size in metres", TerrainError) from None
    if not (math.isfinite(res) and res > 0):
        raise bad_value("resolution", resolution, "must be finite and positive", TerrainError)
    return z, res, origin


def _positive(field: str, value: float, minimum: float = 0.0) -> float:
    v = float(value)
    if not (math.isfinite(v) and v > minimum):
        raise bad_value(field, value, f"must be finite and > {minimum}", TerrainError)
    return v


def _weights(field: str, values, n: int, norm: str) -> np.ndarray:
    w = np.asarray(values, dtype=float).reshape(-1)
    if w.size != n or not np.isfinite(w).all() or (w < 0).any() or not w.any():
        raise bad_value(field, list(values), f"expected {n} non-negative weights, not all zero", TerrainError)
    return w / (np.linalg.norm(w) if norm == "l2" else w.sum())


def _disc(radius: float, resolution: float, field: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mask, dx, dy) of the cells whose centres lie within ``radius``; dx, dy in metres."""
    if not radius >= resolution:
        raise bad_value(field, radius, f"must be at least one cell ({resolution} m)", TerrainError)
    r = int(math.floor(radius / resolution + 1e-9))
    off = np.arange(-r, r + 1) * resolution
    dy, dx = np.meshgrid(off, off, indexing="ij")
    mask = dx ** 2 + dy ** 2 <= radius ** 2 + 1e-12
    return mask.astype(float), dx * mask, dy * mask


class _DiscSums:
    """Sums of maps over fixed stencils around every cell, by FFT (circular correlation of the
    edge-padded map; the padding keeps the wrap-around out of the cells we keep)."""

    def __init__(self, shape: tuple[int, int], pad: int):
        # scipy.fft is imported by the cost maps that use it, not by every importer of
        # qz_drake.planning (qz plan's start: 30 ms).
        from scipy import fft

        self.fft = fft
        self.shape, self.pad = shape, pad
        self.fft_shape = tuple(fft.next_fast_len(n + 2 * pad, real=True) for n in shape)

    def transform(self, z: np.ndarray) -> np.ndarray:
        (H, W), p, (FH, FW) = self.shape, self.pad, self.fft_shape
        return self.fft.rfft2(np.pad(z, ((p, FH - H - p), (p, FW - W - p)), mode="edge"))

    def kernel(self, stencil: np.ndarray) -> np.ndarray:
        p, k = self.pad, stencil.shape[0] // 2
        padded = np.zeros(self.fft_shape)
        padded[p - k:p + k + 1, p - k:p + k + 1] = stencil
        return np.conj(self.fft.rfft2(padded))

    def sum(self, z_hat: np.ndarray, kernel_hat: np.ndarray) -> np.ndarray:
        H, W = self.shape
        return self.fft.irfft2(z_hat * kernel_hat, s=self.fft_shape)[:H, :W]


def _shift(z: np.ndarray, drow: int, dcol: int) -> np.ndarray:
    """out[r, c] = z[r + drow, c + dcol], the border extended outside the map."""
    H, W = z.shape
    rows = np.clip(np.arange(H) + drow, 0, H - 1)
    cols = np.clip(np.arange(W) + dcol, 0, W - 1)
    return z[rows[:, None], cols[None, :]]


def _disc_maximum(z: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Maximum of z over a disc around every cell: running maxima along rows, one per chord."""
    r = mask.shape[0] // 2
    half = mask.sum(axis=1).astype(int) // 2
    rows_max = {h: ndimage.maximum_filter1d(z, 2 * h + 1, axis=1, mode="nearest") for h in set(half)}
    out = np.full_like(z, -np.inf)
    for i, h in enumerate(half):
        np.maximum(out, _shift(rows_max[h], i - r, 0), out=out)
    return out


def _step_height(z: np.ndarray, res: float, mask: np.ndarray, config: BodyFeatureConfig,
                 sums: _DiscSums, mask_hat: np.ndarray) -> np.ndarray:
    w = max(1, int(round(config.step_window / res)))
    H, W = z.shape
    padded = np.pad(z, w, mode="edge")
    offsets = [(i, j) for i in range(-w, w + 1) for j in range(-w, w + 1) if (i, j) != (0, 0)]
    # Nearest offsets first and strict ">" below: ties keep the nearest cell, the steeper line.
    offsets.sort(key=lambda o: o[0] ** 2 + o[1] ** 2)
    dmax = np.zeros_like(z)
    dist = np.ones_like(z)
    for i, j in offsets:
        diff = np.abs(padded[w + i:w + i + H, w + j:w + j + W] - z)
        better = diff > dmax
        np.copyto(dmax, diff, where=better)
        np.copyto(dist, math.hypot(i, j) * res, where=better)
    steep = (dmax / dist > config.critical_slope).astype(float)
    count = np.maximum(np.rint(sums.sum(sums.transform(steep), mask_hat)), 0.0)
    h_max = _disc_maximum(dmax, mask)
    return h_max * np.minimum(1.0, count / float(config.critical_count))


# -- body ---------------------------------------------------------------------------------------
def body_features(heights, resolution: float | None = None, *,
                  config: BodyFeatureConfig | None = None) -> BodyFeatures:
    """Slope, roughness and step height under a body centred on every cell (Eq. 2-9).

    Args:
        heights: (H, W) heights [m] with heights[row, col] at y = row * resolution, x = col *
            resolution, or a HeightMap.
        resolution: cell size [m]; taken from the HeightMap when omitted.
        config: disc radius, step window and step-edge thresholds.
    """
    config = config or BodyFeatureConfig()
    z, res, _ = _heights(heights, resolution)
    _positive("body_features.step_window", config.step_window)
    _positive("body_features.critical_slope", config.critical_slope)
    if int(config.critical_count) < 1:
        raise bad_value("body_features.critical_count", config.critical_count, "must be at least 1",
                        TerrainError)
    mask, dx, dy = _disc(config.radius, res, "body_features.radius")
    n = mask.sum()
    sums = _DiscSums(z.shape, mask.shape[0] // 2)
    # Heights relative to their mean keep sum(z^2) - n mean^2 well conditioned.
    z0 = z - z.mean()
    z_hat = sums.transform(z0)
    mask_hat = sums.kernel(mask)
    a = sums.sum(z_hat, sums.kernel(dx)) / (dx ** 2).sum()
    b = sums.sum(z_hat, sums.kernel(dy)) / (dy ** 2).sum()
    mean = sums.sum(z_hat, mask_hat) / n
    var = sums.sum(sums.transform(z0 * z0), mask_hat) / n - mean ** 2
    return BodyFeatures(slope=np.arctan(np.hypot(a, b)),
                        roughness=np.sqrt(np.maximum(var, 0.0)),
                        step_height=_step_height(z, res, mask, config, sums, mask_hat),
                        resolution=res, config=config)


def traversable(step_height: np.ndarray, max_step_height: float) -> np.ndarray:
    """Traversability of section 2.1.4 (i): True where the step height is at most the threshold."""
    return np.asarray(step_height) <= max_step_height


def body_cost(features: BodyFeatures, config: BodyCostConfig | None = None) -> np.ndarray:
    """(H, W) body cost of Eq. 10 in [0, 1]; inf where the step height exceeds the threshold."""
    config = config or BodyCostConfig()
    w = _weights("body_cost.weights", config.weights, 3, "l2")
    maxima = [_positive(f"body_cost.{name}", getattr(config, name))
              for name in ("max_slope", "max_roughness", "max_step_height")]
    terms = [np.minimum(f / m, 1.0) * wi
             for f, m, wi in zip((features.slope, features.roughness, features.step_height), maxima, w)]
    cost = np.sqrt(terms[0] ** 2 + terms[1] ** 2 + terms[2] ** 2)
    cost[~traversable(features.step_height, config.max_step_height)] = np.inf
    return cost


# -- footholds ----------------------------------------------------------------------------------
def foothold_features(heights, resolution: float | None = None, *,
                      config: FootholdFeatureConfig | None = None) -> FootholdFeatures:
    """Curvature, slope, convexity and plane gradient of every cell at two radii (Eq. 11)."""
    config = config or FootholdFeatureConfig()
    z, res, _ = _heights(heights, resolution)
    radii = [float(r) for r in config.radii]
    if len(radii) != 2:
        raise bad_value("foothold_features.radii", config.radii, "expected two radii (Eq. 11)", TerrainError)
    discs = [_disc(r, res, f"foothold_features.radii[{i}]") for i, r in enumerate(radii)]
    pad = max(d[0].shape[0] // 2 for d in discs)
    sums = _DiscSums(z.shape, pad)
    z0 = z - z.mean()
    z_hat, zz_hat = sums.transform(z0), sums.transform(z0 * z0)
    curvature, slope, convexity, gradient = [], [], [], []
    for radius, (mask, dx, dy) in zip(radii, discs):
        n = mask.sum()
        s = (dx ** 2).sum() / n  # var(x) = var(y), cov(x, y) = 0 on a symmetric disc
        p = sums.sum(z_hat, sums.kernel(dx)) / n  # cov(x, z)
        q = sums.sum(z_hat, sums.kernel(dy)) / n  # cov(y, z)
        mask_hat = sums.kernel(mask)
        mean = sums.sum(z_hat, mask_hat) / n
        t = np.maximum(sums.sum(zz_hat, mask_hat) / n - mean ** 2, 0.0)  # var(z)
        # Covariance [[s, 0, p], [0, s, q], [p, q, t]]: (q, -p, 0) is an eigenvector with
        # eigenvalue s; the other two solve the 2 x 2 block [[s, rho], [rho, t]], rho = |(p, q)|.
        lam_min = 0.5 * (s + t) - np.sqrt(0.25 * (s - t) ** 2 + p * p + q * q)
        curvature.append(np.clip(lam_min, 0.0, None) / (2.0 * s + t))
        a, b = p / s, q / s
        gradient.append(np.stack([a, b]))
        slope.append(np.arctan(np.hypot(a, b)))
        norm = np.sqrt(a * a + b * b + 1.0)
        angles = np.zeros_like(z)
        for k in range(8):
            ox = int(round(radius / res * math.cos(k * math.pi / 4)))
            oy = int(round(radius / res * math.sin(k * math.pi / 4)))
            vz = _shift(z, oy, ox) - z
            vx, vy = ox * res, oy * res
            cos = (-a * vx - b * vy + vz) / (norm * np.sqrt(vx * vx + vy * vy + vz * vz))
            angles += np.arccos(np.clip(cos, -1.0, 1.0))
        convexity.append(angles / 8.0 - math.pi / 2.0)
    return FootholdFeatures(curvature=np.stack(curvature), slope=np.stack(slope),
                            convexity=np.stack(convexity), gradient=np.stack(gradient),
                            resolution=res, config=config)


def foothold_cost(features: FootholdFeatures, heading: float, role: int,
                  config: FootholdCostConfig | None = None) -> np.ndarray:
    """(H, W) cost of Eq. 12 in [0, 1] of placing a foot on every cell.

    Args:
        heading: the body's motion direction in the world frame. [rad]
        role: +1 front foot (prefers uphill), -1 hind foot (prefers downhill), 0 neither.
    """
    config = config or FootholdCostConfig()
    w = _weights("foothold_cost.weights", config.weights, 8, "l1").reshape(2, 4)
    m = [_positive(f"foothold_cost.{name}", getattr(config, name))
         for name in ("max_curvature", "max_slope", "max_convexity", "max_uphill")]
    cost = np.zeros(features.slope.shape[1:])
    uphill = features.uphill(heading) if role else None
    for i in range(2):
        cost += w[i, 0] * np.minimum(features.curvature[i] / m[0], 1.0)
        cost += w[i, 1] * np.minimum(features.slope[i] / m[1], 1.0)
        cost += w[i, 2] * np.clip(features.convexity[i] / m[2], 0.0, 1.0)
        if role:
            cost += w[i, 3] * np.clip(-role * uphill[i] / m[3], 0.0, 1.0)
    return cost


def triangle_mask(side: float, resolution: float, heading: float = 0.0) -> np.ndarray:
    """Boolean stencil of an equilateral triangle of the given side, centroid on the centre
    cell, apex pointing along ``heading``; always holds at least the centre cell."""
    side = _positive("foothold_cost.triangle_side", side)
    radius = side / math.sqrt(3.0)  # centroid to vertex
    r = int(math.ceil(radius / resolution))
    off = np.arange(-r, r + 1) * resolution
    y, x = np.meshgrid(off, off, indexing="ij")
    vertices = [(radius * math.cos(heading + k * 2 * math.pi / 3), radius * math.sin(heading + k * 2 * math.pi / 3))
                for k in range(3)]
    inside = np.ones_like(x, dtype=bool)
    for (x0, y0), (x1, y1) in zip(vertices, vertices[1:] + vertices[:1]):
        # Counter-clockwise vertices: inside is left of every edge.
        inside &= (x1 - x0) * (y - y0) - (y1 - y0) * (x - x0) >= -1e-9
    inside[r, r] = True
    return inside


def feet_cost(features: FootholdFeatures, footprint: Footprint,
              config: FootholdCostConfig | None = None) -> np.ndarray:
    """(8, H, W) mean over feet of each foot's triangle-averaged cost (Eq. 14-15), for a body
    centred on each cell and heading k * pi / 4. Feet ahead of the body centre (x > 0) are front
    feet, behind it hind feet (see foothold_cost). Footholds off the map see the border plateau."""
    config = config or FootholdCostConfig()
    res = features.resolution
    roles = np.sign(np.round(footprint.offsets[:, 0], 9)).astype(int)
    out = np.empty((8,) + features.slope.shape[1:])
    for k, heading in enumerate(HEADINGS):
        per_role = {role: foothold_cost(features, heading, role, config) for role in set(roles.tolist())}
        total = np.zeros(out.shape[1:])
        # Sum of the feet's foothold costs shifted to the body centre, then one triangle mean:
        # shifting and averaging commute, so this is Eq. 14-15 with a single correlation.
        for (x, y), role in zip(footprint.rotated(heading), roles):
            total += _shift(per_role[role], int(round(y / res)), int(round(x / res)))
        tri = triangle_mask(config.triangle_side, res, heading).astype(float)
        out[k] = ndimage.correlate(total, tri / tri.sum(), mode="nearest") / len(roles)
    return out


def build_cost_map(heights, resolution: float | None = None, *, footprint: Footprint | None = None,
                   config: CostMapConfig | None = None) -> CostMap:
    """Features and costs of Eq. 2-16 for a heightmap (HeightMap, or array + resolution).

    Args:
        footprint: default footholds; Qingzhui's six by default.
        config: all parameters; defaults suit Qingzhui on 0.05 m cells.
    """
    config = config or CostMapConfig()
    footprint = footprint or Footprint.qingzhui()
    if not 0.0 <= float(config.body_weight) <= 1.0:
        raise bad_value("cost_map.body_weight", config.body_weight, "must be in [0, 1]", TerrainError)
    z, res, origin = _heights(heights, resolution)
    body = body_features(z, res, config=config.body_features)
    foot = foothold_features(z, res, config=config.foothold_features)
    return CostMap(body=body, body_cost=body_cost(body, config.body_cost), foothold=foot,
                   feet_cost=feet_cost(foot, footprint, config.foothold_cost), resolution=res,
                   origin=origin, footprint=footprint, config=config)
