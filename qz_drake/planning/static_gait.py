"""Static-gait search with recursive backtracking (paper 003, section 3, Eq. 21-29).

A quadruped walks a standard crawl, swinging one foot at a time in the order LF, RB, RF, LB
(section 3.1). Before each swing the body shifts so that its ground projection lies inside the
triangle of the three standing feet; then the swing foot moves along a box path to its new
foothold. Each step chooses a robot state (foothold of the swing foot, body height, pitch,
roll; Eq. 22) among ordered candidates (Eq. 23-28) and a recursive search with backtracking
(section 3.3.2) commits the first state from which ``depth`` steps can be taken in a row.

The extracted paper lost its symbols and tables; this is how we reconstructed them.

* Eq. 21, body projection: with X the crossing of the feet quadrilateral's diagonals and M the
  midpoint of the standing side pair opposite the swing foot (RF-RB when LF swings), the body
  projection is ``p = X + lambda (M - X)``, lambda in (0, 1) (``support_ratio``). The triangle
  (X, side pair) is the "interaction triangle" of two consecutive support triangles, so p lies
  inside the support triangle; we also require its distance to every edge of the support
  triangle to be at least ``stability_margin`` (``support_margin``).
* Body pose (section 3.1 a-c): the plane through the three standing feet gives the ground under
  p; the body centre is ``h`` above it. The yaw is the direction from the mid-point of the hind
  feet to that of the front feet (swing foot at its target, Fig. 4); roll and pitch are the
  support plane's plus the candidate offsets. Angles in Drake's roll-pitch-yaw convention:
  positive pitch lowers the nose, positive roll raises the left side.
* Eq. 23-28, candidates: footholds on a grid in a rectangle around the default foothold, the
  invalid ones (near an edge) dropped and the others ordered by cost (distance to the default
  foothold plus the local height spread, section 4.2); heights ``h0, h0 + dh, h0 - dh, ...``;
  pitch and roll ``0, +d, -d, ...`` offsets. Priority (Eq. 29): foothold, then height, then
  pitch, then roll (the foothold changes last).
* Kinematics (Tables 3-6 lost): a leg reaches a point when it lies below its hip, the
  abduction angle and the hip swing angle are within limits and the hip-to-foot distance in the
  leg plane is within ``[min_reach, max_reach]`` of thigh + shank: the workspace of a 3-DoF
  abduction-hip-knee leg.
* Table 1, swing box: lift the foot straight up to ``swing_height`` above the higher end point,
  move it across, lower it. The swing collides when terrain under the box's top edge (the foot
  sphere swept along the segment) rises above it; both top corners must be reachable.
* Table 2, body adjustment: five poses interpolated from the previous body pose to the new one;
  at each the body's underside must clear the terrain by ``body_clearance`` and all four feet
  (standing) must be reachable.
* Pruning rules (section 3.3.2): (i) a height whose pose is out of reach rules out larger
  heights; (ii) a body collision at the rear at pitch theta rules out pitches that lower the
  rear further (smaller pitch); (iii) a collision on the left (right) side at roll phi rules out
  rolls that lower that side further (smaller (larger) roll in Drake's convention; the paper's
  "larger" uses the opposite roll sign).

Only the states on the current branch are stored; ``max_nodes`` bounds one decision. When no
chain of ``depth`` states exists the first state of the deepest chain found is committed (the
receding-horizon reading of "searching several steps at a time"). ``record_tree`` keeps every
checked candidate for drawing the search tree (Fig. 7); the search itself does not use it.
The standing footholds are chosen like the others (the best valid one around each default
foothold), so a walk never starts with a foot on an edge.
"""

import dataclasses
import math

import numpy as np
from scipy import ndimage

from qz_drake.errors import ConfigError, bad_value
from qz_drake.robot.quadruped import LEGS, QuadrupedGeometry

LEG_ORDER = ("LF", "RB", "RF", "LB")
"""The standard swing order of section 3.1."""
# The largest search a user may ask for. A decision tries up to max_nodes states, about 2 ms
# each (measured on scenarios/static_gait/static_gait_cuboids.yaml), and recurses one level
# per step looked ahead; paper 003 looks 1-4 steps ahead, its depth study tries 2000 states.
MAX_STEPS = 1000  # swings, 250 gait cycles
MAX_DEPTH = 100  # steps looked ahead
MAX_NODES = 100_000  # states tried per decision: minutes of search
MAX_CANDIDATES = 100  # of each kind: footholds kept, heights, pitches, rolls
MAX_FOOTHOLD_GRID = 10_000  # points of the candidate foothold grid (foothold_half_size / spacing)
# The standing side pair opposite each swing foot (Eq. 21's faced edge).
_OPPOSITE_SIDE = {"LF": ("RF", "RB"), "RB": ("LF", "LB"), "RF": ("LF", "LB"), "LB": ("RF", "RB")}


@dataclasses.dataclass
class StaticGaitConfig:
    geometry: QuadrupedGeometry = dataclasses.field(default_factory=QuadrupedGeometry)
    # Forward advance of every foot per gait cycle (four steps). [m]
    stride: float = 0.08
    # lambda of Eq. 21: 0 puts the body at the diagonals' crossing, 1 on the side edge. [-]
    support_ratio: float = 0.5
    # Smallest distance of the body projection to a support triangle edge (Eq. 21). [m]
    stability_margin: float = 0.01
    # Half sizes (along, across the heading) of the candidate foothold rectangle (Eq. 23). [m]
    foothold_half_size: list[float] = dataclasses.field(default_factory=lambda: [0.03, 0.02])
    # Spacing of the candidate foothold grid. [m]
    foothold_spacing: float = 0.01
    # Footholds kept per step, best first (n_f of Eq. 27).
    foothold_count: int = 5
    # A foothold whose surroundings (foot_radius) span more height than this is on an edge. [m]
    edge_threshold: float = 0.01
    # Radius of the foot sphere: edges closer than this make a foothold invalid. [m]
    foot_radius: float = 0.012
    # Default body height above the support plane, and its step (Eq. 26). [m]
    height: float = 0.12
    height_step: float = 0.015
    height_count: int = 2
    # Pitch and roll offsets: step and count (Eq. 24-25). [rad]
    pitch_step: float = 0.08
    pitch_count: int = 2
    roll_step: float = 0.08
    roll_count: int = 2
    # Height of the swing box above the higher end point (Table 1). [m]
    swing_height: float = 0.04
    # Clearance of the body's underside over the terrain (Table 2). [m]
    body_clearance: float = 0.01
    # Largest number of states tried for one committed step.
    max_nodes: int = 400


@dataclasses.dataclass(frozen=True)
class RobotState:
    """One step of the gait (Eq. 22): a swing and the body pose it is taken from."""

    # Step index from the start; the swing leg is LEG_ORDER[step % 4].
    step: int
    leg: str
    # (4, 3) feet positions after the swing, in LEGS order, world frame. [m]
    feet: np.ndarray
    # Body centre in the world frame during the swing. [m]
    p_WB: np.ndarray
    # Body roll, pitch, yaw (Drake's convention) during the swing. [rad]
    rpy: np.ndarray
    # Candidate indices (foothold, height, pitch, roll) chosen.
    choice: tuple[int, int, int, int]


@dataclasses.dataclass(frozen=True)
class SearchNode:
    """One candidate state the search checked, for drawing the search tree (Fig. 7)."""

    # Visit index, and the index of the node it was expanded from (-1: the committed state the
    # decision started from).
    index: int
    parent: int
    # The step it would take, and the decision (committed step) during which it was checked.
    step: int
    decision: int
    # Passed the checks (kinematics, collisions); else the first failed check.
    ok: bool
    why: str
    # Was committed as the gait's state of ``step``.
    committed: bool = False


@dataclasses.dataclass(frozen=True)
class GaitSearchResult:
    # True when all requested steps were found.
    success: bool
    # The committed states, in order.
    states: list[RobotState]
    # "found", or why the search stopped (step and the checks that failed).
    reason: str
    # Candidate states checked in all.
    nodes_expanded: int
    config: StaticGaitConfig
    # The standing pose the gait starts from: feet (4, 3) in LEGS order, body centre and
    # roll-pitch-yaw, world frame. [m], [rad]
    start_feet: np.ndarray | None = None
    start_p_WB: np.ndarray | None = None
    start_rpy: np.ndarray | None = None
    # With ``record_tree``: every candidate state checked, in visiting order (Fig. 7).
    tree: list[SearchNode] | None = None


def _offsets(count: int, step: float) -> list[float]:
    """0, +s, -s, +2s, ...: ``count`` values by priority."""
    out = [0.0]
    k = 1
    while len(out) < count:
        out.append(k * step)
        if len(out) < count:
            out.append(-k * step)
        k += 1
    return out


def _rotation(rpy) -> np.ndarray:
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def support_margin(point_xy, triangle_xy) -> float:
    """Signed distance of a point to the nearest edge of a triangle (> 0 inside). [m]"""
    p = np.asarray(point_xy, dtype=float)[:2]
    t = np.asarray(triangle_xy, dtype=float)[:, :2]
    area = (t[1, 0] - t[0, 0]) * (t[2, 1] - t[0, 1]) - (t[1, 1] - t[0, 1]) * (t[2, 0] - t[0, 0])
    if abs(area) < 1e-12:
        return -math.inf
    sign = 1.0 if area > 0 else -1.0
    margins = []
    for i in range(3):
        a, b = t[i], t[(i + 1) % 3]
        edge = b - a
        cross = edge[0] * (p[1] - a[1]) - edge[1] * (p[0] - a[0])
        margins.append(sign * cross / math.hypot(*edge))
    return float(min(margins))


def body_projection(feet_xy: np.ndarray, swing_leg: str, ratio: float) -> np.ndarray:
    """Eq. 21: the body's ground projection for a swing of ``swing_leg`` (feet in LEGS order)."""
    f = {leg: np.asarray(feet_xy[i, :2], dtype=float) for i, leg in enumerate(LEGS)}
    # Crossing X of the diagonals LF-RB and RF-LB.
    a, b, c, d = f["LF"], f["RB"], f["RF"], f["LB"]
    m = np.array([b - a, c - d]).T
    try:
        s = np.linalg.solve(m, c - a)[0]
        cross = a + s * (b - a)
    except np.linalg.LinAlgError:
        cross = 0.25 * (a + b + c + d)
    side = _OPPOSITE_SIDE[swing_leg]
    mid = 0.5 * (f[side[0]] + f[side[1]])
    return cross + ratio * (mid - cross)


class _Terrain:
    """Heightmap lookups for the checks: nearest-cell heights, the foot-sphere maximum, edges."""

    def __init__(self, heightmap, config: StaticGaitConfig):
        self.map = heightmap
        z = np.asarray(heightmap.heights)
        res = heightmap.resolution
        k = max(1, int(round(config.foot_radius / res)))
        size = 2 * k + 1
        self.top = ndimage.maximum_filter(z, size=size, mode="nearest")
        spread = self.top - ndimage.minimum_filter(z, size=size, mode="nearest")
        self.valid = spread <= config.edge_threshold
        self.spread = spread

    def _index(self, x, y):
        res = self.map.resolution
        H, W = self.top.shape
        col = np.clip(np.rint((np.asarray(x) - self.map.origin[0]) / res).astype(int), 0, W - 1)
        row = np.clip(np.rint((np.asarray(y) - self.map.origin[1]) / res).astype(int), 0, H - 1)
        return row, col

    def height(self, x, y):
        return self.map.heights[self._index(x, y)]

    def max_height(self, x, y):
        return self.top[self._index(x, y)]

    def foothold(self, x, y):
        idx = self._index(x, y)
        return self.valid[idx], self.spread[idx], self.map.heights[idx]


def _check_config(config: StaticGaitConfig) -> None:
    for name in ("stride", "foothold_spacing", "height", "swing_height"):
        if not float(getattr(config, name)) > 0:
            raise bad_value(f"static_gait.{name}", getattr(config, name), "must be positive")
    if not 0.0 < config.support_ratio < 1.0:
        raise bad_value("static_gait.support_ratio", config.support_ratio, "must be in (0, 1)")
    for name in ("foothold_count", "height_count", "pitch_count", "roll_count", "max_nodes"):
        if int(getattr(config, name)) < 1:
            raise bad_value(f"static_gait.{name}", getattr(config, name), "must be >= 1")
        most = MAX_NODES if name == "max_nodes" else MAX_CANDIDATES
        if int(getattr(config, name)) > most:
            raise bad_value(f"static_gait.{name}", getattr(config, name), f"must be at most {most}")
    half = np.asarray(config.foothold_half_size, dtype=float)
    if half.shape != (2,) or not (np.all(np.isfinite(half)) and np.all(half >= 0)):
        raise bad_value("static_gait.foothold_half_size", list(config.foothold_half_size),
                        "expected two sizes >= 0 (along, across the heading) [m]")
    along, across = 2 * half / float(config.foothold_spacing) + 1
    if along * across > MAX_FOOTHOLD_GRID:
        raise bad_value("static_gait.foothold_spacing", config.foothold_spacing,
                        f"{along:.3g} x {across:.3g} candidate footholds in foothold_half_size "
                        f"{list(config.foothold_half_size)}; at most {MAX_FOOTHOLD_GRID}")


class _Search:
    def __init__(self, heightmap, start_xy, heading, config: StaticGaitConfig):
        self.config = config
        self.geometry = config.geometry
        self.terrain = _Terrain(heightmap, config)
        self.start = np.asarray(start_xy, dtype=float)
        self.heading = float(heading)
        self.u = np.array([math.cos(heading), math.sin(heading)])
        self.v = np.array([-self.u[1], self.u[0]])
        self.heights = [config.height + o for o in _offsets(config.height_count, config.height_step)]
        self.pitches = _offsets(config.pitch_count, config.pitch_step)
        self.rolls = _offsets(config.roll_count, config.roll_step)
        self.nodes = 0
        self._candidates: dict[int, list[np.ndarray]] = {}
        self.failures: dict[str, int] = {}
        # Search-tree record (record_tree only): nodes, the current branch's and the deepest
        # branch's node indices.
        self.tree: list[SearchNode] | None = None
        self.decision = 0
        self.branch_nodes: list[int] = []
        self.best_nodes: list[int] = []

    def _record(self, step: int, ok: bool, why: str) -> int:
        if self.tree is None:
            return -1
        parent = self.branch_nodes[-1] if self.branch_nodes else -1
        self.tree.append(SearchNode(len(self.tree), parent, step, self.decision, ok, why))
        return len(self.tree) - 1

    # -- geometry -----------------------------------------------------------------------------
    def default_foothold(self, leg: str, cycle: int) -> np.ndarray:
        """Where ``leg`` lands on its swing of gait cycle ``cycle`` (0 = the standing pose)."""
        p_B = self.geometry.default_foothold_B(leg)
        return self.start + (cycle * self.config.stride) * self.u + p_B[0] * self.u + p_B[1] * self.v

    def initial_feet(self) -> np.ndarray:
        """The standing footholds: the best valid foothold around each default one (a foot
        planted on an edge would start the walk off balance), the default where none is valid."""
        feet = []
        for leg in LEGS:
            ordered = self._ordered_footholds(self.default_foothold(leg, 0))
            if ordered:
                feet.append(ordered[0])
            else:
                xy = self.default_foothold(leg, 0)
                feet.append(np.array([xy[0], xy[1], float(self.terrain.height(xy[0], xy[1]))]))
        return np.array(feet)

    def _ordered_footholds(self, target: np.ndarray) -> list[np.ndarray]:
        """Valid footholds (x, y, z) in the rectangle around ``target``, best first (Eq. 23)."""
        c = self.config
        ha, hc = c.foothold_half_size
        along = np.arange(-ha, ha + 1e-9, c.foothold_spacing)
        across = np.arange(-hc, hc + 1e-9, c.foothold_spacing)
        da, dc = (g.ravel() for g in np.meshgrid(along, across))
        xy = target + da[:, None] * self.u + dc[:, None] * self.v
        valid, spread, z = self.terrain.foothold(xy[:, 0], xy[:, 1])
        # Section 4.2: nearer the default foothold first; a height spread is a near edge.
        cost = np.hypot(da, dc) + spread
        order = [i for i in np.argsort(cost, kind="stable") if valid[i]][: c.foothold_count]
        return [np.array([xy[i, 0], xy[i, 1], z[i]]) for i in order]

    def candidates(self, step: int) -> list[np.ndarray]:
        """Ordered valid footholds (x, y, z) of a step's swing (Eq. 23)."""
        if step not in self._candidates:
            leg = LEG_ORDER[step % 4]
            self._candidates[step] = self._ordered_footholds(self.default_foothold(leg, step // 4 + 1))
        return self._candidates[step]

    def _fail(self, why: str) -> None:
        self.failures[why] = self.failures.get(why, 0) + 1

    def body_pose(self, feet: np.ndarray, leg: str, target: np.ndarray, height: float, pitch: float,
                  roll: float) -> tuple[np.ndarray, np.ndarray]:
        i = LEGS.index(leg)
        stand = [j for j in range(4) if j != i]
        p_xy = body_projection(feet, leg, self.config.support_ratio)
        # Support plane z = a x + b y + d through the three standing feet.
        A = np.column_stack([feet[stand, :2], np.ones(3)])
        try:
            a, b, d = np.linalg.solve(A, feet[stand, 2])
        except np.linalg.LinAlgError:
            a, b, d = 0.0, 0.0, float(feet[stand, 2].mean())
        after = feet.copy()
        after[i] = target
        front = 0.5 * (after[0, :2] + after[1, :2])
        hind = 0.5 * (after[2, :2] + after[3, :2])
        yaw = math.atan2(*(front - hind)[::-1])
        cy, sy = math.cos(yaw), math.sin(yaw)
        slope_along = a * cy + b * sy
        slope_across = -a * sy + b * cy
        rpy = np.array([math.atan(slope_across) + roll, -math.atan(slope_along) + pitch, yaw])
        p_WB = np.array([p_xy[0], p_xy[1], a * p_xy[0] + b * p_xy[1] + d + height])
        return p_WB, rpy

    def _reach(self, p_WB, R_WB, feet, legs) -> bool:
        for j in legs:
            if not self.geometry.reachable(LEGS[j], R_WB.T @ (feet[j] - p_WB)):
                return False
        return True

    def _body_collision(self, p_WB, R_WB) -> tuple[bool, bool, bool]:
        """(rear, left, right) parts of the body's underside that touch the terrain."""
        L, W, Hb = self.geometry.body_size
        xs, ys = np.linspace(-L / 2, L / 2, 5), np.linspace(-W / 2, W / 2, 3)
        gx, gy = np.meshgrid(xs, ys)
        p_B = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, -Hb / 2)])
        p_W = p_B @ R_WB.T + p_WB
        hit = p_W[:, 2] < self.terrain.max_height(p_W[:, 0], p_W[:, 1]) + self.config.body_clearance
        return (bool(np.any(hit & (p_B[:, 0] < 0))), bool(np.any(hit & (p_B[:, 1] > 0))),
                bool(np.any(hit & (p_B[:, 1] < 0))))

    def _swing_collides(self, start: np.ndarray, end: np.ndarray) -> tuple[bool, float]:
        top = max(start[2], end[2]) + self.config.swing_height
        n = max(2, int(math.ceil(np.linalg.norm(end[:2] - start[:2]) / self.terrain.map.resolution)) + 1)
        s = np.linspace(0.0, 1.0, n)
        xy = start[:2] + s[:, None] * (end[:2] - start[:2])
        ground = self.terrain.max_height(xy[:, 0], xy[:, 1]) + self.config.foot_radius
        return bool(np.any(ground > top)), top

    # -- one transition -----------------------------------------------------------------------
    def transition(self, feet, prev_pose, leg, target, height, pitch, roll):
        """Checks one candidate state; returns (ok, why, pose)."""
        p_WB, rpy = self.body_pose(feet, leg, target, height, pitch, roll)
        R_WB = _rotation(rpy)
        i = LEGS.index(leg)
        # Body adjustment (Table 2): five poses from the previous one, feet standing.
        p0, rpy0 = prev_pose
        for s in np.linspace(0.25, 1.0, 4):
            p = p0 + s * (p_WB - p0)
            R = _rotation(rpy0 + s * (rpy - rpy0)) if s < 1.0 else R_WB
            if not self._reach(p, R, feet, range(4)):
                return False, "reach", None
            rear, left, right = self._body_collision(p, R)
            if rear or left or right:
                return False, ("body_rear" if rear else "body_left" if left else "body_right"), None
        # Swing foot: the top corners of its box path must be reachable.
        _, top = self._swing_collides(feet[i], target)
        for corner in (feet[i], target):
            if not self.geometry.reachable(leg, R_WB.T @ (np.array([corner[0], corner[1], top]) - p_WB)):
                return False, "reach", None
        if not self.geometry.reachable(leg, R_WB.T @ (target - p_WB)):
            return False, "reach", None
        return True, "", (p_WB, rpy)

    # -- recursion ----------------------------------------------------------------------------
    def expand(self, step: int, feet, pose, remaining: int, branch: list, best: list) -> bool:
        """Depth-first search for ``remaining`` steps from ``step``; ``branch`` holds the states
        of the current path only; ``best`` keeps the deepest branch seen."""
        if remaining == 0 or step >= self.total_steps:
            return True
        leg = LEG_ORDER[step % 4]
        i = LEGS.index(leg)
        stand = [j for j in range(4) if j != i]
        p_xy = body_projection(feet, leg, self.config.support_ratio)
        if support_margin(p_xy, feet[stand]) < self.config.stability_margin:
            self._fail("support_margin")
            self._record(step, False, "support_margin")
            return False
        for fi, target in enumerate(self.candidates(step)):
            collides, _ = self._swing_collides(feet[i], target)
            if collides:
                self._fail("swing_collision")
                self._record(step, False, "swing_collision")
                continue
            height_cap = math.inf
            for hi, h in enumerate(self.heights):
                if h >= height_cap:
                    continue
                pitch_floor, roll_floor, roll_ceiling = -math.inf, -math.inf, math.inf
                for pi, pitch in enumerate(self.pitches):
                    if pitch <= pitch_floor:
                        continue
                    for ri, roll in enumerate(self.rolls):
                        if roll <= roll_floor or roll >= roll_ceiling:
                            continue
                        if self.nodes >= self.config.max_nodes:
                            return False
                        self.nodes += 1
                        self.decision_nodes += 1
                        ok, why, new_pose = self.transition(feet, pose, leg, target, h, pitch, roll)
                        node = self._record(step, ok, why)
                        if not ok:
                            self._fail(why)
                            if why == "reach":  # rule (i)
                                height_cap = min(height_cap, h)
                            elif why == "body_rear":  # rule (ii)
                                pitch_floor = max(pitch_floor, pitch)
                            elif why == "body_left":  # rule (iii)
                                roll_floor = max(roll_floor, roll)
                            elif why == "body_right":
                                roll_ceiling = min(roll_ceiling, roll)
                            continue
                        new_feet = feet.copy()
                        new_feet[i] = target
                        branch.append(RobotState(step, leg, new_feet, new_pose[0], new_pose[1], (fi, hi, pi, ri)))
                        self.branch_nodes.append(node)
                        if len(branch) > len(best):
                            best[:] = list(branch)
                            self.best_nodes = list(self.branch_nodes)
                        if self.expand(step + 1, new_feet, new_pose, remaining - 1, branch, best):
                            return True
                        branch.pop()
                        self.branch_nodes.pop()
                        if self.nodes >= self.config.max_nodes:
                            return False
        return False


def cuboid_terrain(seed: int, *, size: tuple[float, float] = (1.2, 0.6), block: tuple[float, float] = (0.1, 0.1),
                   max_height: float = 0.05, resolution: float = 0.005, origin=(-0.3, -0.3)):
    """Structured terrain of section 4.2: a grid of cuboids ``block`` [m] (length, width) with
    seeded random heights in [0, max_height] [m]; their edges are invalid footholds."""
    from qz_drake.terrain import HeightMap

    if not (resolution > 0 and max_height >= 0 and min(block) > 0):
        raise bad_value("cuboid_terrain", (block, max_height, resolution), "sizes must be positive")
    rng = np.random.default_rng(seed)
    W, H = (int(round(s / resolution)) for s in size)
    nx, ny = int(math.ceil(size[0] / block[0])) + 1, int(math.ceil(size[1] / block[1])) + 1
    blocks = rng.uniform(0.0, max_height, size=(ny, nx))
    col = (np.arange(W) * resolution / block[0]).astype(int)
    row = (np.arange(H) * resolution / block[1]).astype(int)
    return HeightMap(blocks[np.ix_(row, col)], resolution, tuple(origin))


def search_gait(heightmap, start_xy, heading: float, steps: int, depth: int = 4,
                config: StaticGaitConfig | None = None, *, record_tree: bool = False) -> GaitSearchResult:
    """Static gait of ``steps`` swings from a standing pose at ``start_xy`` walking along
    ``heading``, looking ``depth`` steps ahead at each decision (section 3.3.2).

    Args:
        heightmap: a qz_drake.terrain.HeightMap.
        start_xy: body centre at the start, world frame. [m]
        heading: walking direction. [rad]
        steps: number of swings (a gait cycle is 4).
        depth: steps searched ahead before a state is committed; 1 is greedy.
        record_tree: keep every checked candidate in ``result.tree`` (for figures; the search
            itself stores only the current branch).
    """
    config = config or StaticGaitConfig()
    _check_config(config)
    if not 1 <= int(steps) <= MAX_STEPS:
        raise bad_value("steps", steps, f"must be within [1, {MAX_STEPS}] swings")
    if not 1 <= int(depth) <= MAX_DEPTH:
        raise bad_value("depth", depth, f"must be within [1, {MAX_DEPTH}] steps ahead")
    try:
        start = np.asarray(start_xy, dtype=float).reshape(2)
    except ValueError:
        raise bad_value("start_xy", start_xy, "expected (x, y) in metres") from None
    if not np.isfinite(start).all() or not math.isfinite(float(heading)):
        raise ConfigError(f"start_xy = {start_xy!r}, heading = {heading!r}: must be finite")

    search = _Search(heightmap, start, heading, config)
    search.total_steps = int(steps)
    if record_tree:
        search.tree = []
    feet = search.initial_feet()
    p0 = np.array([start[0], start[1], float(feet[:, 2].mean()) + config.height])
    pose = (p0, np.array([0.0, 0.0, float(heading)]))
    start_pose = dict(start_feet=feet.copy(), start_p_WB=p0.copy(), start_rpy=pose[1].copy())
    states: list[RobotState] = []
    for step in range(int(steps)):
        search.decision_nodes = 0
        search.failures = {}
        search.decision = step
        search.branch_nodes, search.best_nodes = [], []
        branch: list[RobotState] = []
        best: list[RobotState] = []
        saved = search.nodes
        search.nodes = 0  # max_nodes bounds one decision
        search.expand(step, feet, pose, int(depth), branch, best)
        search.nodes += saved
        chosen = branch[0] if branch else (best[0] if best else None)
        if chosen is None:
            why = ", ".join(f"{k} x{v}" for k, v in sorted(search.failures.items(), key=lambda kv: -kv[1]))
            return GaitSearchResult(False, states, f"dead end at step {step} ({LEG_ORDER[step % 4]}): "
                                    f"{why or 'no valid foothold'}", search.nodes, config,
                                    tree=search.tree, **start_pose)
        if search.tree is not None:
            first = (search.branch_nodes or search.best_nodes)[0]
            search.tree[first] = dataclasses.replace(search.tree[first], committed=True)
        states.append(chosen)
        feet = chosen.feet
        pose = (chosen.p_WB, chosen.rpy)
    return GaitSearchResult(True, states, "found", search.nodes, config, tree=search.tree, **start_pose)
