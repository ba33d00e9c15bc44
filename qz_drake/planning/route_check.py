"""Checking a route with the BLC alone before walking it (issue 54: routes that hold).

Whether the BLC plans a mission is decided by the mission's start (the base pose and the feet
it plans from), its target and the map: no simulation is needed to know it (the plan chains of
qz_drake.capability.plan_chains label datasets that way). A route source that hands the BLC its
missions one by one meets a refusal only when the robot stands at the refused mission's start;
by then it has walked there, and going round means turning in place beside the obstacle that
refused it, backing out, or trying the next diagonal into the same row of boxes (CapPlanner's
failed tuning walks, session 45: every one of the six began with such refusals, and four ended
in a leg contact or a slip while turning in place beside a box).

:class:`RouteCheck` plans the next ``horizon`` missions of a route ahead, each from the end
state the plan before it expects (``blc_plan.expected_end``, the start the BLC system itself
plans a mission handed out ahead from), with the walk's BLC: its parameters, and a refused
solve tried again on the walk's ladder, as TrajectoryOptimizationBLC does. The first mission
refused is *foreseen*; the route source goes round it as it goes round a refusal (a mission
of several moves split, a single move forbidden or blocked) and plans again from where the
robot will stand, before the robot walks anywhere. The chain stops at a topology change (a
switch is planned from the standing robot) and at a way back out of a dead end.

A foreseen refusal is a prediction from the expected stance, not the robot's: it costs no
recovery (``max_recoveries`` counts the refusals the walk meets), and where going round it
leaves no route the route is walked as it was, for the walk's own recovery to answer. The
check costs wall time (one or more BLC solves per mission handed out), never simulated time.

A helper of both recovering route sources (CapPlanner's TLC and the A* baseline's), as
``back_out`` is, rather than part of their shared base in qz_drake.systems, which the
capability dataset's fingerprint covers.
"""

from __future__ import annotations

import dataclasses
import time

from qz_drake.errors import bad_value

# Most refusals foreseen (and gone round) before one route is handed out: each costs a replan
# and the solves of its ladder; past this the route is handed out as it stands.
MAX_FORESEEN = 4


def check_route_check(value, field: str = "route_check") -> int:
    """A route check's horizon (missions ahead) as an int; a QzError naming ``field`` for
    anything but a whole number >= 0."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise bad_value(field, value, "must be a whole number of missions >= 0 (0: no check)")
    return int(value)


@dataclasses.dataclass
class Foreseen:
    """A refusal foreseen by the check: the mission's index in the route checked, its target
    (x, y, yaw) and topology, and the first solve's reason."""

    index: int
    target: tuple
    topology: str
    reason: str


class RouteCheck:
    """The BLC of a walk, planning a route's next missions ahead without the robot.

    Args:
        heightmap: the map the walk's BLC plans on.
        params: the robot's parameters (RobotParams).
        timing: the mission timing (ControllerConfig.timing: speed, phase_duration).
        blc_params: the walk's BlcParameters.
        ladder: the rungs a refused mission is solved again on (blc_plan.parse_ladder), the
            walk's: its ladder, or its retries' (blc_plan.retry_ladder).
        horizon: missions checked ahead of the robot (>= 1).
    """

    def __init__(self, heightmap, params, timing, blc_params, ladder=(), horizon: int = 1):
        from qz_drake.systems.blc_plan import blc_mission_planner, parse_ladder

        if check_route_check(horizon, "horizon") < 1:
            raise bad_value("horizon", horizon, "must be at least 1 mission")
        self.horizon = int(horizon)
        self.ladder = parse_ladder(ladder, "ladder")
        self._planner = blc_mission_planner(heightmap, params, timing, blc_params=blc_params)
        # Solves made and their wall time, for the walk's metrics.
        self.solves = 0
        self.time_s = 0.0

    def first_refused(self, start, missions, topology: str) -> Foreseen | None:
        """The first of ``missions[:horizon]`` the BLC refuses, each planned from the expected
        end of the one before (the first from ``start``, a MissionStart), standing in
        ``topology``; None when all of them plan, or the chain reaches a topology change or a
        way back out first."""
        from qz_drake.capability.plan_chains import solve_on_ladder
        from qz_drake.systems.blc_plan import expected_end

        clock = time.perf_counter()
        try:
            for i, mission in enumerate(missions[:self.horizon]):
                if mission.topology != topology or getattr(mission, "back_out", False):
                    return None
                plan, reason, _ = solve_on_ladder(self._planner, self.ladder, start, tuple(mission.target),
                                                  mission.topology)
                self.solves += 1
                if plan is None:
                    return Foreseen(i, tuple(float(v) for v in mission.target), mission.topology, reason)
                start = expected_end(plan)
            return None
        finally:
            self.time_s += time.perf_counter() - clock


def route_check_for(horizon: int, heightmap, params, timing, blc_params, ladder) -> RouteCheck | None:
    """A RouteCheck of ``horizon`` missions (None for 0: no check)."""
    horizon = check_route_check(horizon)
    return None if horizon == 0 else RouteCheck(heightmap, params, timing, blc_params, ladder, horizon)


__all__ = ["MAX_FORESEEN", "Foreseen", "RouteCheck", "check_route_check", "route_check_for"]
