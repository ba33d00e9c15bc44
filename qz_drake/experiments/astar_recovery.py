"""The A* baseline with CapPlanner's recovery (issue 38): when the BLC cannot plan a mission,
A* goes round it from where the robot stands, as CapPlanner's TLC does.

Without it the comparison of Fig. 9 was uneven in one place: CapPlanner went round a mission
the BLC could not plan while A* stopped (7 of CapPlanner's 12 wins in the first run were A*'s
planning failures). Both now answer a refused mission the same two ways, with the same limit
(``max_recoveries``, CapabilityVIPlanner's default):

* a mission longer than one step (``split_length``; A*'s missions are up to
  ``mission_length`` long, CapPlanner's several actions) is handed out again in two halves, the
  second ending where it did (CapPlanner: one action per mission);
* a short mission is blocked: the cells within ``block_radius`` of its target that are nearer
  it than the robot become impassable in A*'s cost map (AStarBaseline.block: the robot keeps a
  way out) and A* plans again from the robot's measured position to the goal (CapPlanner
  forbids the action from that state and solves value iteration again).

When A* finds no route from where the robot stands, the robot backs out of the dead end to where
the last walked mission started and A* routes from there (qz_drake.planning.back_out; CapPlanner
does the same when no way on is left). After ``max_recoveries`` refused missions, or when A*
finds no route from there either, the goal is unreachable,
with the reason, and the robot stands (the refused mission is held on the outputs, so that
the BLC system, which does not solve one mission twice, leaves it where it is).

With a route check (qz_drake.planning.route_check, as CapPlanner's), the next missions are
planned ahead by the walk's BLC before they are handed out, and a refusal it foresees is gone
round the same two ways from where the robot will stand, before the robot walks there.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from qz_drake.errors import ConfigError, bad_value
from qz_drake.experiments.astar_baseline import AStarBaseline, Route
from qz_drake.planning.back_out import BackOut
from qz_drake.simulation import FixedRoute
from qz_drake.state_layout import BASE_XY, base_rpy
from qz_drake.systems.mission_sequencer import RecoveringSequencer, RecoveryLog, split_route, unwrapped_yaws

# Refused missions either planner goes round (CapabilityVIPlanner's max_recoveries).
MAX_RECOVERIES = 4
# Radius of the disc blocked around a refused mission's target: half a capability cell, the
# place CapPlanner's forbidden action leads to. [m]
BLOCK_RADIUS = 0.5


@dataclasses.dataclass
class AStarRecoveryLog(RecoveryLog):
    """The missions handed out, the ones gone round (RecoveryLog's fields: ``recoveries`` says
    "split" or "blocked") and A*'s own record."""

    # A* routes planned after a refusal: (time, start (x, y), found).
    replans: list = dataclasses.field(default_factory=list)
    planning_time_s: float = 0.0
    # Ways back out of a dead end handed out (qz_drake.planning.back_out).
    back_outs: int = 0
    # Refusals the route check foresaw (time, target (x, y, yaw), topology, index in the route).
    foreseen: list = dataclasses.field(default_factory=list)


@dataclasses.dataclass(frozen=True)
class AStarMission:
    """One mission of the A* route: the local target (x, y, yaw) and the topology."""

    target: tuple[float, float, float]
    topology: str


class AStarRecoverySequencer(RecoveringSequencer):
    """The A* route's missions for TrajectoryOptimizationBLC, going round the ones it refuses.

    .. pydrake_system::

        name: AStarRecoverySequencer
        input_ports:
        - state
        - plan
        - failed_missions
        - robot_topology
        output_ports:
        - target
        - topology

    The ports, Context state and standing robot are those of RecoveringSequencer (shared with
    CapPlanner's TLC); the module docstring says what it does on a refusal. The A* baseline
    (its cost map with the blocked cells) and ``log`` stay on ``self``: one sequencer serves
    one walk.

    Args:
        targets: the first route's local targets (x, y, yaw, topology) (split_route).
        baseline: the AStarBaseline the route came from (its cost map is changed in place).
        goal: (x, y) of the goal. [m]
        mission_length: longest mission of a new route. [m]
        split_length: a refused mission longer than this is split in two before any cell
            is blocked (None: half the mission length). [m]
        block_radius: radius blocked around a refused short mission's target. [m]
        max_recoveries: refused missions gone round before the goal is unreachable.
        back_out: back out of a dead end (see the module docstring).
        plan_ahead: hand out the next target this long before the current plan ends. [s]
        check_period: how often the plan is looked at. [s]
        route_check: a RouteCheck (qz_drake.planning.route_check; None: none).
        check_start: the MissionStart the first route is checked from (None: not checked).
        params: the robot's parameters (the measured stance after a refusal, for the check).
    """

    def __init__(self, *, targets, baseline: AStarBaseline, goal, mission_length: float,
                 split_length: float | None = None, block_radius: float = BLOCK_RADIUS,
                 max_recoveries: int = MAX_RECOVERIES, plan_ahead: float = 0.0, check_period: float = 0.05,
                 back_out: bool = True, route_check=None, check_start=None, params=None):
        super().__init__(log=AStarRecoveryLog(), max_recoveries=max_recoveries, plan_ahead=plan_ahead)
        if not mission_length > 0:
            raise bad_value("mission_length", mission_length, "must be positive", ConfigError)
        first = [AStarMission(tuple(float(v) for v in t[:3]), t[3]) for t in targets]
        if not first:
            raise bad_value("targets", list(targets), "needs at least one target", ConfigError)
        self._baseline = baseline
        self._goal = (float(goal[0]), float(goal[1]))
        self._mission_length = float(mission_length)
        self._split_length = 0.5 * self._mission_length if split_length is None else float(split_length)
        self._block_radius = float(block_radius)
        self._back_out = BackOut() if back_out else None
        self._route_check = route_check
        self._params = params
        if route_check is not None and params is None:
            raise bad_value("params", params, "a route check needs the robot's parameters", ConfigError)
        if check_start is not None:
            first = self._checked(0.0, check_start, first)
        self._start(first, first[0].topology, check_period)

    def counts(self) -> dict:
        return {"planning_time_s": self.log.planning_time_s, "replans": len(self.log.replans),
                "unreachable": self.log.unreachable, "tlc_recoveries": len(self.log.recoveries),
                "tlc_back_outs": self.log.back_outs, "tlc_foreseen_refusals": len(self.log.foreseen),
                **({} if self._route_check is None else {"route_check_solves": self._route_check.solves,
                                                          "route_check_time_s": self._route_check.time_s})}

    def _advance(self, context, state, plan, missions, index):
        rest = list(missions[index + 1:])
        if rest and self._route_check is not None:
            from qz_drake.systems.blc_plan import expected_end

            rest = self._checked(context.get_time(), expected_end(plan), rest)
        return rest or None

    def _checked(self, t: float, start, missions: list) -> list:
        """``missions`` with the refusals the route check foresees gone round from ``start`` (a
        MissionStart: where the robot will stand before the first), as a refusal is: a long
        mission split in two, a short one's target blocked and A* routed again from there;
        where no route is left, the route as it was (the walk's recovery answers the refusal)."""
        import time

        from qz_drake.planning.route_check import MAX_FORESEEN

        if self._route_check is None or not missions:
            return missions
        here = tuple(float(v) for v in start.xy_yaw[:2])
        yaw = float(start.xy_yaw[2])
        for _ in range(MAX_FORESEEN):
            foreseen = self._route_check.first_refused(start, missions, missions[0].topology)
            if foreseen is None:
                return missions
            self.log.foreseen.append((t, foreseen.target, foreseen.topology, foreseen.index))
            i = foreseen.index
            mission = missions[i]
            before = here if i == 0 else tuple(missions[i - 1].target[:2])
            fx, fy, _ = mission.target
            if math.hypot(fx - before[0], fy - before[1]) > self._split_length + 1e-9:
                middle = AStarMission((0.5 * (before[0] + fx), 0.5 * (before[1] + fy),
                                       math.atan2(fy - before[1], fx - before[0])), mission.topology)
                missions = unwrapped_yaws(missions[:i] + [middle] + missions[i:], yaw)
                continue
            self._baseline.block((fx, fy), self._block_radius, keep_clear=before)
            clock = time.perf_counter()
            route = self._route_from(here)
            self.log.planning_time_s += time.perf_counter() - clock
            self.log.replans.append((t, here, route.found))
            if not route.found:
                return missions
            missions = unwrapped_yaws([AStarMission(tuple(r[:3]), r[3])
                                       for r in split_route(here, route.waypoints, self._mission_length)], yaw)
        return missions

    def _route_from(self, here):
        """A*'s route from ``here`` to the goal round the blocked cells; from a point off the map
        (a robot that walked past its edge, or a mission expected to end there) no route, with
        the reason, as a route that is not found: the walk reports it, it does not crash."""
        from qz_drake.planning.astar import off_map

        x, y = float(here[0]), float(here[1])
        reason = off_map(self._baseline.cost_map, x, y)
        if reason:
            return Route(False, f"A*: start = {(x, y)}: {reason}", [], 0.0, np.zeros((0, 2)))
        return self._baseline.route(here, self._goal)

    def _go_round(self, context, state, failed, missions, index):
        import time

        x = self._state.Eval(context)
        here = tuple(float(v) for v in x[BASE_XY])
        yaw = float(base_rpy(x)[2])
        fx, fy, _ = failed.target
        if math.hypot(fx - here[0], fy - here[1]) > self._split_length + 1e-9:
            # Shorter missions are easier for the BLC: the same way in two halves.
            middle = AStarMission((0.5 * (here[0] + fx), 0.5 * (here[1] + fy),
                                   math.atan2(fy - here[1], fx - here[0])), failed.topology)
            return unwrapped_yaws([middle, failed] + list(missions[index + 1:]), yaw), "split"
        self._baseline.block((fx, fy), self._block_radius, keep_clear=here)
        clock = time.perf_counter()
        route = self._route_from(here)
        self.log.planning_time_s += time.perf_counter() - clock
        self.log.replans.append((context.get_time(), here, route.found))
        if not route.found:
            # A dead end (qz_drake.planning.back_out): back to where the last walked mission
            # started, and on from there round the blocked cells, as CapPlanner does.
            back = None if self._back_out is None else self._back_out.target(self.log, here)
            if back is not None:
                route = self._route_from(back[:2])
                self.log.replans.append((context.get_time(), back[:2], route.found))
                if route.found:
                    self.log.back_outs += 1
                    targets = split_route(back[:2], route.waypoints, self._mission_length)
                    missions = [AStarMission(back, failed.topology)] + [AStarMission(tuple(t[:3]), t[3])
                                                                        for t in targets]
                    return unwrapped_yaws(missions, yaw), "backed out"
            self.log.unreachable = f"no route round the mission the BLC could not plan ({route.reason})"
            return [], "blocked"
        targets = split_route(here, route.waypoints, self._mission_length)
        missions = unwrapped_yaws([AStarMission(tuple(t[:3]), t[3]) for t in targets], yaw)
        if self._route_check is not None:
            from qz_drake.systems.mission_sequencer import measured_start

            missions = self._checked(context.get_time(), measured_start(x, context.get_time(), self._params), missions)
        return missions, "blocked"


class AStarRoute(FixedRoute):
    """The A* baseline as a walk's route source: the first route's missions, and the recovery
    of :class:`AStarRecoverySequencer` when the BLC refuses one.

    Args:
        baseline: the AStarBaseline the route was planned with (blocked cells are added to it).
        goal: (x, y) of the goal. [m]
        max_recoveries: refused missions gone round (None: MAX_RECOVERIES, CapPlanner's).
        back_out: back out of a dead end (AStarRecoverySequencer).
    """

    name = "A*"
    # A Fig. 9 task is a goal position; the heading the robot arrives with is the route's (as
    # CapPlanner's). Judging the first route's last segment heading failed walks whose route
    # A* had planned again round a refused mission and which came in from another side (3 of
    # the 24 validation walks of session 35 "missed" a heading no task asked for).
    chooses_goal_heading = True

    def __init__(self, baseline: AStarBaseline, goal, max_recoveries: int | None = None, back_out: bool = True,
                 route_check: int = 0, check_ladder=()):
        from qz_drake.planning.route_check import check_route_check
        from qz_drake.systems.blc_plan import parse_ladder

        self._baseline = baseline
        self._goal = goal
        self._max_recoveries = MAX_RECOVERIES if max_recoveries is None else max_recoveries
        self._back_out = bool(back_out)
        self.route_check = check_route_check(route_check)
        self.check_ladder = parse_ladder(check_ladder, "check_ladder")

    def make(self, scenario, info, targets, blc_params=None) -> AStarRecoverySequencer:
        from qz_drake.planning.route_check import route_check_for
        from qz_drake.systems.mission_sequencer import measured_start

        control = scenario.controller
        check = route_check_for(self.route_check, info.heightmap, info.params, control.timing, blc_params,
                                self.check_ladder)
        return AStarRecoverySequencer(targets=targets, baseline=self._baseline, goal=self._goal,
                                      mission_length=control.mission_length, plan_ahead=control.plan_ahead,
                                      max_recoveries=self._max_recoveries, back_out=self._back_out,
                                      route_check=check, params=info.params,
                                      check_start=None if check is None else measured_start(info.initial_state, 0.0,
                                                                                             info.params))
