"""The A* baseline of paper 000 Fig. 9: a geometric top-level controller.

A* (qz_drake.planning.astar, paper 003's Eq. 16-20) over the geometric cost map of paper 003
(slope, roughness and step height at the robot's body disc, the six feet's foothold costs),
with cells blocked where the step height exceeds ``max_step_height`` or the slope exceeds
``max_slope_deg``; the path is cut into waypoints at most ``waypoint_spacing`` apart, all in
the nominal topology (A* knows no topologies), and walked by the same BLC missions as
CapPlanner's. Its thresholds are tuned on worlds that are not among the experiment's tasks
(``fig9.tune_astar``, ``qz experiment tune-astar``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from qz_drake.errors import bad_value


@dataclasses.dataclass(frozen=True)
class AStarBaselineConfig:
    # Step height above which a cell is blocked (paper 003's traversability threshold). [m]
    max_step_height: float = 0.2
    # Slope above which a cell is blocked. [deg]
    max_slope_deg: float = 30.0
    # w_2 of Eq. 17: the share of safety against distance.
    safety_weight: float = 0.5
    # Longest distance between two waypoints of the route handed to the missions. [m]
    waypoint_spacing: float = 1.0
    # Radius of the disc whose terrain makes a cell's body features (slope, roughness, step
    # height): paper 003's body footprint. 0.7 m covers Qingzhui's trunk (half-diagonal 0.72 m);
    # about 0.9 m covers its legs' reach too (the middle feet stand 0.75 m out, their boxes
    # 0.15 m further): the legs then keep clear of steps the trunk passes. Tuned. [m]
    body_radius: float = 0.7


@dataclasses.dataclass(frozen=True)
class LearnedCost:
    """The capability model's answers as A*'s edge cost and veto (issue 54's baseline from the
    field: a geometric planner that asks a learned estimator about each edge, as ArtPlanner and
    Guzzi et al. do). ``capability_map`` (capability.model_base.CapabilityMap, with the nominal
    topology) gives, for each 1 m grid cell and heading k, the chance that a move one cell along
    k walks. Every cost-map cell inside that grid cell moving along k adds ``weight`` x
    (-log p) / (the move's length) to its geometric cost of Eq. 16 (a cost per metre, weighted
    against distance by the safety weight as it is), p the least of headings k and k +- 45 deg (a
    zigzag of the fine grid's steps walks along the heading between them); crossing the grid cell
    then costs about safety_weight x weight x -log p metres more. A step is blocked for that
    heading where p < ``veto``. With safety weight 0.5 and weight 3, a move predicted to walk 9 times in
    10 costs about 0.16 m of detour, one predicted to walk half the time about 1 m."""

    capability_map: object
    # Cost per unit of -log(success) of a grid move (0: the geometric A* with the veto alone).
    weight: float = 3.0
    # Least predicted success of a grid move that A* may take (0: none vetoed).
    veto: float = 0.0

    def __post_init__(self):
        if not (math.isfinite(self.weight) and self.weight >= 0):
            raise bad_value("astar_learned_weight", self.weight, "must be finite and >= 0")
        if not (math.isfinite(self.veto) and 0.0 <= self.veto < 1.0):
            raise bad_value("astar_learned_veto", self.veto, "must be in [0, 1)")
        if "nominal" not in self.capability_map.topologies:
            raise bad_value("capability_map.topologies", self.capability_map.topologies,
                            "must include nominal (A* walks in the nominal topology)")

    def heading_cost(self, cost_map) -> np.ndarray:
        """(8, H, W) the learned cost per metre on the cost map's cells (inf where vetoed)."""
        cm = self.capability_map
        H, W = cost_map.shape
        res, (x0, y0) = cost_map.resolution, cost_map.origin
        ix = np.clip(np.rint((x0 + res * np.arange(W) - cm.xs[0]) / cm.cell_size), 0, len(cm.xs) - 1).astype(int)
        iy = np.clip(np.rint((y0 + res * np.arange(H) - cm.ys[0]) / cm.cell_size), 0, len(cm.ys) - 1).astype(int)
        p = np.asarray(cm.forward[cm.topologies.index("nominal")], dtype=float)  # (8, ny, nx)
        # A step of the fine grid along k may belong to a path (and a mission) along k +- 45 deg:
        # a zigzag of diagonal steps walks straight along the axis between them. Each step pays
        # for the worst of the three headings, or A* would zigzag past a vetoed move.
        p = np.minimum.reduce([np.roll(p, shift, axis=0) for shift in (-1, 0, 1)])
        p = p[:, iy[:, None], ix[None, :]]  # (8, H, W)
        length = cm.cell_size * np.where(np.arange(8) % 2 == 1, math.sqrt(2.0), 1.0)[:, None, None]
        with np.errstate(divide="ignore"):
            cost = self.weight * -np.log(np.clip(p, 1e-9, 1.0)) / length
        return np.where(p < self.veto, np.inf, cost)


@dataclasses.dataclass
class Route:
    """A top-level controller's answer: waypoints (x, y, yaw, topology), or why there are none."""

    found: bool
    reason: str
    waypoints: list
    planning_time_s: float
    path_xy: np.ndarray


class AStarBaseline:
    """The A* baseline over one world: the geometric cost map built once, routes from any start,
    and cells blocked where the BLC could not plan a mission (the recovery of
    :class:`AStarRecoverySequencer`, the same going round that CapPlanner does)."""

    def __init__(self, heightmap, config: AStarBaselineConfig = AStarBaselineConfig(),
                 learned: LearnedCost | None = None):
        """``learned``: the capability model's answers as an edge cost and veto on top of the
        geometric cost map (LearnedCost); None: the geometric A* of paper 000's Fig. 9."""
        from qz_drake.terrain.features import BodyCostConfig, BodyFeatureConfig, CostMapConfig, build_cost_map

        self.config = config
        cost_config = CostMapConfig(body_features=BodyFeatureConfig(radius=config.body_radius),
                                    body_cost=BodyCostConfig(max_step_height=config.max_step_height))
        cost_map = build_cost_map(heightmap, config=cost_config)
        slope = np.asarray(cost_map.body.slope)
        blocked = slope > math.radians(config.max_slope_deg)
        self.cost_map = dataclasses.replace(cost_map, body_cost=np.where(blocked, np.inf, cost_map.body_cost))
        # (x, y, radius) of the discs blocked so far. [m]
        self.blocked: list[tuple[float, float, float]] = []
        self.learned = learned
        self._learned_cost = None if learned is None else learned.heading_cost(self.cost_map)

    def block(self, xy, radius: float, *, keep_clear=None) -> None:
        """Blocks the cells within ``radius`` of ``xy`` (x, y); with ``keep_clear`` (where the
        robot stands, often inside that disc: a refused mission is short), only those nearer
        ``xy`` than the robot, so that A* can leave in every direction away from it. [m]"""
        if not radius > 0:
            raise bad_value("block radius", radius, "must be positive")
        H, W = self.cost_map.shape
        res = self.cost_map.resolution
        x0, y0 = self.cost_map.origin
        gx, gy = np.meshgrid(x0 + res * np.arange(W), y0 + res * np.arange(H))
        mask = np.hypot(gx - xy[0], gy - xy[1]) <= radius
        if keep_clear is not None:
            mask &= np.hypot(gx - xy[0], gy - xy[1]) < np.hypot(gx - keep_clear[0], gy - keep_clear[1]) - res
        body = np.array(self.cost_map.body_cost, dtype=float)
        body[mask] = np.inf
        self.cost_map = dataclasses.replace(self.cost_map, body_cost=body)
        self.blocked.append((float(xy[0]), float(xy[1]), float(radius)))

    def route(self, start, goal) -> Route:
        """A* over the cost map (with the blocked cells) from start to goal (x, y) [m]."""
        import time

        from qz_drake.planning.astar import AStarConfig, astar

        clock = time.perf_counter()
        config = self.config
        cost_map = self.cost_map
        if self._learned_cost is not None:
            cost_map = _LearnedCostMap(cost_map, self._learned_cost)
        result = astar(cost_map, start, goal, config=AStarConfig(distance_weight=1.0 - config.safety_weight,
                                                                safety_weight=config.safety_weight))
        elapsed = time.perf_counter() - clock
        if not result.found:
            return Route(False, f"A*: {result.reason}", [], elapsed, np.zeros((0, 2)))
        return Route(True, "", waypoints_along(result.xy, goal, config.waypoint_spacing), elapsed, result.xy)


class _LearnedCostMap:
    """A cost map whose heading_cost adds the learned one (what ``astar`` reads of it)."""

    def __init__(self, cost_map, learned_cost):
        self._cost_map, self._learned_cost = cost_map, learned_cost
        self.shape, self.resolution, self.origin = cost_map.shape, cost_map.resolution, cost_map.origin
        self.cell = cost_map.cell

    def heading_cost(self) -> np.ndarray:
        return self._cost_map.heading_cost() + self._learned_cost


def astar_route(heightmap, start, goal, config: AStarBaselineConfig = AStarBaselineConfig()) -> Route:
    """A* over the geometric cost map from start to goal (x, y) [m]; the planning time includes
    building the cost map."""
    import time

    clock = time.perf_counter()
    baseline = AStarBaseline(heightmap, config)
    route = baseline.route(start, goal)
    return dataclasses.replace(route, planning_time_s=time.perf_counter() - clock)


def waypoints_along(path_xy: np.ndarray, goal, spacing: float, topology: str = "nominal") -> list:
    """Waypoints (x, y, yaw, topology) at most ``spacing`` apart along a path, ending at goal;
    each faces along the path."""
    if not spacing > 0:
        raise bad_value("waypoint_spacing", spacing, "must be positive")
    path = np.vstack([np.asarray(path_xy, dtype=float).reshape(-1, 2), np.asarray(goal, dtype=float)[None]])
    step = np.linalg.norm(np.diff(path, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(step)])
    total = float(s[-1])
    if total < 1e-9:
        return [(float(goal[0]), float(goal[1]), 0.0, topology)]
    count = max(1, int(math.ceil(total / spacing - 1e-9)))
    marks = np.linspace(0.0, total, count + 1)[1:]
    points = np.column_stack([np.interp(marks, s, path[:, 0]), np.interp(marks, s, path[:, 1])])
    previous = np.vstack([path[:1], points[:-1]])
    yaw = np.arctan2(points[:, 1] - previous[:, 1], points[:, 0] - previous[:, 0])
    return [(float(x), float(y), float(a), topology) for (x, y), a in zip(points, yaw)]
