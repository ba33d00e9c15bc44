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

    def __init__(self, heightmap, config: AStarBaselineConfig = AStarBaselineConfig()):
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
        result = astar(self.cost_map, start, goal, config=AStarConfig(distance_weight=1.0 - config.safety_weight,
                                                                     safety_weight=config.safety_weight))
        elapsed = time.perf_counter() - clock
        if not result.found:
            return Route(False, f"A*: {result.reason}", [], elapsed, np.zeros((0, 2)))
        return Route(True, "", waypoints_along(result.xy, goal, config.waypoint_spacing), elapsed, result.xy)


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
