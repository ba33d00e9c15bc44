"""``CapabilityVIPlanner``: the top-level controller of paper 000 (TLC, section II-E.2) as a
Drake system.

At initialization it evaluates the learned capability model over the whole heightmap in one
batch (the success of every forward move and turn from every cell and heading, in every
topology), builds the capability MDP for the goal and solves it by value iteration (Eq. 9-10).
From the robot's cell, heading and topology it follows the policy's most likely path and splits
it into BLC missions (qz_drake.planning.guidance). It hands the missions' local targets and
topologies to TrajectoryOptimizationBLC one after the other, on the same ports as the fixed
route's MissionTargetSequencer, and at every mission start replans from the *expected end* of
the current mission (paper 000: "the next BLC mission is given by TLC according to current
robot position and expected end position of current BLC mission"). Where the policy's path does
not reach the goal (the MDP values turning in place above every way there), it takes the most
probable path instead (capability_mdp.most_probable_path): declining would fail the task for
certain. When no path reaches the goal, or the path's predicted chance of arriving without a
fall (the TLC going round missions the BLC cannot plan: qz_drake.planning.capability_mdp) is
below ``min_route_success``, it says so (``unreachable``) instead of walking into an obstacle.
"""

from __future__ import annotations

import dataclasses
import math
import time

from pydrake.common.value import AbstractValue

from qz_drake.capability.patches import HEADING_STEP
from qz_drake.planning.back_out import BackOut
from qz_drake.planning.guidance import (GuidedMission, MissionSplitConfig, check_target_shift, place_targets,
                                        route_ahead, split_missions)
from qz_drake.robot.params import DEFAULT_PARAMS
from qz_drake.systems.mission_sequencer import RecoveringSequencer, RecoveryLog, measured_start, unwrapped_yaws
from qz_drake.state_layout import BASE_XY, base_rpy


# What a replan at a mission's end did with the current route (CapabilityPlannerLog.route_decisions).
ROUTE_DECISIONS = ("same", "held", "changed", "off route", "new")
# The part of a route two replans are compared on (issue 54: replans that change the next 2 m
# of route without a refusal or a lost route). [m]
ROUTE_AHEAD = 2.0

def check_hold_margin(value, field: str = "hold_margin") -> float | None:
    """A hold margin (CapabilityVIPlanner's ``hold_margin``) as a float, None kept; anything but
    a finite number >= 0 is a QzError naming ``field``."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value >= 0):
        from qz_drake.errors import bad_value

        raise bad_value(field, value, "must be a finite number >= 0 (value units) or none")
    return float(value)


def check_revisit_cost(value, field: str = "revisit_cost") -> float:
    """A revisit cost (CapabilityVIPlanner's ``revisit_cost``) as a float; anything but a finite
    number >= 0 is a QzError naming ``field``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value >= 0):
        from qz_drake.errors import bad_value

        raise bad_value(field, value, "must be a finite number >= 0 (value units)")
    return float(value)


def route_counts(log) -> dict[str, int]:
    """A planner log's route decisions counted, as the walk's metrics name them (tlc_routes_*)."""
    return {route_count_key(d): sum(1 for _, x in log.route_decisions if x == d) for d in ROUTE_DECISIONS}


def route_count_key(decision: str) -> str:
    """The walk-metrics key of a route decision's count."""
    return f"tlc_routes_{decision.replace(' ', '_')}"


# A stance from which no move of the robot's topology is predicted to walk (doubted) at least
# this often is a dead end (measured_stance, back_out).
DEAD_END_SUCCESS = 0.5


@dataclasses.dataclass
class CapabilityPlannerLog(RecoveryLog):
    """The missions handed out, the ones gone round (RecoveryLog's fields: ``recoveries`` says
    "split" into single actions or "forbade" the action and replanned) and the planner's own
    record."""

    # (time, start (x, y, heading index, topology), missions planned, predicted success).
    replans: list = dataclasses.field(default_factory=list)
    planning_time_s: float = 0.0
    value_iterations: int = 0
    # Replans whose path is the most probable one because the policy's did not reach the goal
    # (capability_mdp.most_probable_path).
    most_probable: int = 0
    # Ways back out of a dead end handed out (qz_drake.planning.back_out), and of those the
    # dead ends the model foretold from the robot's stance (no move refused first).
    back_outs: int = 0
    predicted_dead_ends: int = 0
    # (time, what a replan at a mission's end did with the route it had): its next ROUTE_AHEAD
    # the "same" as the replan's; "held" against a replan worth at most hold_margin more;
    # "changed" to the replan's; the robot "off route" (its expected end not where the route
    # goes on from); or "new" (no route left to hold, a way back out, no path).
    route_decisions: list = dataclasses.field(default_factory=list)
    # Refusals the route check foresaw before handing a route out (qz_drake.planning.route_check):
    # (time, target (x, y, yaw), topology, index of the mission in the route checked).
    foreseen: list = dataclasses.field(default_factory=list)


class CapabilityVIPlanner(RecoveringSequencer):
    """Plans missions over the learned capability of the BLC-robot system (paper 000 TLC).

    .. pydrake_system::

        name: CapabilityVIPlanner
        input_ports:
        - state
        - plan
        - failed_missions (optional)
        - robot_topology (optional)
        output_ports:
        - target
        - topology
        - guidance
        - utility

    ``state`` is the station state, ``plan`` the BLC system's current
    plan (to see a mission end); ``failed_missions`` and ``robot_topology``, when connected
    (TrajectoryOptimizationBLC's outputs of the same names), tell it that the BLC could not
    plan the mission it was given: the robot stands where the last plan ended, and the planner
    goes round it, as a mature TLC must (a BLC failure is not a fall). A mission of several
    actions is handed out again one action at a time; a single action that fails is forbidden
    from that state (its transition leads to failure), value iteration is solved again, and
    the planner replans from the measured state. Each replan after the first judges the moves
    from the robot's cell by the stance it stands in (``measured_stance``; the map assumed the
    nominal footholds), a refusal predicted from it weighed as the map weighs refusals; where no
    move is left from there (all refused or forbidden, or all foretold to fail) the robot backs
    out to where its last walked move started (``back_out``). After ``max_recoveries`` refusals
    (or when no path remains) the goal is unreachable, with the reason; ``target`` (x, y, yaw) and
    ``topology`` feed TrajectoryOptimizationBLC; ``guidance`` is the current list of
    GuidedMissions and ``utility`` the (ny, nx) utility map with its cell centres (xs, ys), for
    drawing.

    State: the missions of the latest plan with the index of the current one, and the mission
    held after the last failure, are Context state. What the updates also read back stays on
    ``self``, so one planner serves one run and a cloned or reset Context does not rewind it
    (walk() makes a new planner per walk, through its route source): the capability ``mdp``
    and its ``solution`` (the whole map's transitions and values; going round a failed action
    forbids it in the MDP and solves value iteration again, and these arrays would be copied
    with the state at every update), and ``log``, ``done`` and the failures already answered,
    which the walk's loop and metrics read between steps without a Context.

    Args:
        model: a CapabilityModel (anything with its ``success``).
        heightmap: the map planned over.
        goal: goal (x, y). [m]
        start: the robot's start (x, y, yaw): the first plan is made here, so that the BLC
            system's first solve (at initialization) already has its target. [m, rad]
        initial_topology: the topology the robot stands in.
        mdp_config: CapabilityMdpConfig (rewards, discount, topologies).
        split_config: MissionSplitConfig (the BLC's reach, the merge threshold).
        min_route_success: least predicted chance of the whole path arriving without a fall
            to call the goal reachable.
        plan_ahead: hand out the next mission this long before the current plan ends. [s]
        check_period: how often the plan is looked at. [s]
        max_recoveries: most missions the BLC could not plan that the planner goes round.
        back_out: when going round finds no way on from where the robot stands (a dead end:
            its moves and turns refused or forbidden), back out to where the last walked
            mission started and plan on from there (qz_drake.planning.back_out); once per
            dead end, the way back counted as a mission like any other.
        measured_stance: at each replan after the first, the moves from the robot's cell in its
            topology are judged from the stance it stands in (the plan's end feet, or the
            measured ones after a refusal) instead of the nominal footholds the map assumes,
            a predicted refusal weighed as the map weighs refusals (the MDP's
            plan_failure_risk; capability_mdp.set_stance).
        hold_margin: a replan at a mission's end keeps the rest of the current route unless
            the new route is worth more than this (value units: the goal is worth
            ``goal_reward``, an action ``action_cost``), both valued by the MDP as it stands
            after the replan (the stance the robot stands in, the moves closed so far): near
            ties between routes (two ways round a box, two diagonals) no longer flip with
            each mission's stance, and the robot does not dither. A route that goes on from
            elsewhere than the robot's expected end (cell, heading and topology) is replaced.
            None: every replan takes the policy's path (the paper's TLC).
        refused_in_every_topology: a move the BLC refused (or the model foretold refused, in a
            dead end) is closed from that cell and heading in every topology, not only in the
            one it was refused in: on the validation probes (data/walk_probes) 9 of 9 retries of
            a refused move in another topology were refused again (BENCHMARKS "fig9", session
            39), each costing a refusal, a back-out and a topology change. False: another
            topology may try it again.
        route_check: a qz_drake.planning.route_check.RouteCheck (None: none): every route is
            planned ahead by the walk's BLC before it is handed out, from the stance the robot
            will stand in, and a refusal it foresees is gone round as a refusal is (a mission of
            several actions split, a single action forbidden, value iteration solved again) from
            where the robot stands, up to route_check.MAX_FORESEEN times per route.
        check_start: the MissionStart the first route is checked from (the robot's standing
            stance); None: the first route is not checked.
        revisit_cost: each time a mission ends in a cell, every forward move into that cell
            costs this much more (value units; capability_mdp.charge_arrivals), so that after
            going round refusals the robot goes on somewhere new instead of back and forth
            between the same cells (validation walks on box fields went round one block of
            cells for 100 s until their time ran out). 0: none (the paper's TLC).
        target_shift: each mission's target but the goal moves up to this far from its cell's
            centre, to the point of the centre's level clearest of edges
            (qz_drake.planning.guidance.place_targets): the robot does not stand, turn or
            start its next mission a few centimetres from a box's side because a cell's centre
            fell there. 0: the cell centres (the paper's TLC). [m]
    """

    def __init__(self, *, model, heightmap, goal, start, initial_topology: str = "nominal", mdp_config=None,
                 split_config: MissionSplitConfig = MissionSplitConfig(), min_route_success: float = 0.05,
                 plan_ahead: float = 0.0, check_period: float = 0.05, max_recoveries: int = 4,
                 back_out: bool = True, measured_stance: bool = True, refused_in_every_topology: bool = True,
                 hold_margin: float | None = None, route_check=None, check_start=None, revisit_cost: float = 0.0,
                 target_shift: float = 0.0):
        super().__init__(log=CapabilityPlannerLog(), max_recoveries=max_recoveries, plan_ahead=plan_ahead)
        from qz_drake.capability.model import predict_map
        from qz_drake.planning.capability_mdp import (CapabilityMdpConfig, build_capability_mdp, cells_on_map,
                                                      edge_clearances, edge_distances, solve_capability_mdp,
                                                      switchable_cells)

        # The plan from the start (a CapabilityPlan, for drawing: capability.plots.plot_plan).
        self.first_plan = None
        self._split = split_config
        self._back_out = BackOut() if back_out else None
        self._every_topology = bool(refused_in_every_topology)
        self._hold_margin = check_hold_margin(hold_margin)
        self._route_check = route_check
        self._revisit_cost = check_revisit_cost(revisit_cost)
        self._target_shift = check_target_shift(target_shift)
        # Cells missions ended in whose arrival is not charged yet (charge_arrivals, at the next replan).
        self._arrivals: list[tuple[int, int]] = []
        # The model and the map for the stance at each replan (measured_stance), and what the
        # last replan's stance replaced in the MDP (capability_mdp.set_stance).
        self._model = model if measured_stance else None
        self._heightmap = heightmap
        self._stance_saved: dict = {}
        self._min_success = float(min_route_success)
        clock = time.perf_counter()
        config = (mdp_config or CapabilityMdpConfig()).check()
        # The grid is anchored on the start: the robot starts at a cell centre.
        self.capability_map = predict_map(model, heightmap, config.topologies or None, cell_size=config.cell_size,
                                          anchor=start[:2], stance=config.stance)
        xs, ys = self.capability_map.xs, self.capability_map.ys
        self._edge_clearance = edge_clearances(heightmap, xs, ys, config) if config.needs_edge_clearance else None
        # The heightmap's distance from edges where targets move away from them (target_shift).
        self._edge_distance = edge_distances(heightmap, config.edge_height) if self._target_shift > 0 else None
        self.mdp = build_capability_mdp(self.capability_map, goal, config, switchable_cells(heightmap, xs, ys, config),
                                        cells_on_map(heightmap, xs, ys), self._edge_clearance)
        self.solution = solve_capability_mdp(self.mdp)
        self.log.planning_time_s = time.perf_counter() - clock
        self.log.value_iterations = int(self.solution.iterations)
        self._goal = tuple(float(v) for v in goal)
        # The missions of the latest replan (the first from the start) and the index of the
        # current one are the base class's Context state.
        first = self._replan(0.0, float(start[0]), float(start[1]), float(start[2]), initial_topology)
        if check_start is not None:
            first = self._checked(0.0, check_start, initial_topology, first)
        self._start(first, initial_topology, check_period)
        state_only = {self.all_state_ticket()}
        self.DeclareAbstractOutputPort("guidance", lambda: AbstractValue.Make([]), self._calc_guidance,
                                       prerequisites_of_calc=state_only)
        self.DeclareAbstractOutputPort("utility", lambda: AbstractValue.Make(None), self._calc_utility,
                                       prerequisites_of_calc={self.nothing_ticket()})

    # -- planning ------------------------------------------------------------------------------
    def _replan(self, t: float, x: float, y: float, yaw: float, topology: str, feet_W=None) -> list:
        from qz_drake.planning.capability_mdp import (CapabilityPlan, charge_arrivals, fall_free_probability,
                                                      most_likely_path, most_probable_path, restore_actions,
                                                      set_stance, solve_capability_mdp, stance_outcomes)

        clock = time.perf_counter()
        start = self._state_at(x, y, yaw, topology, "start")
        ix, iy, k, _ = self.mdp.unravel(start)
        restore_actions(self.mdp, self._stance_saved)
        self._stance_saved = {}
        # After the restore, which would undo a charge on the last start's moves.
        charged = sum(charge_arrivals(self.mdp, cx, cy, self._revisit_cost) for cx, cy in self._arrivals)
        self._arrivals = []
        from_stance = feet_W is not None and self._model is not None
        if charged and not from_stance:  # (from the stance, value iteration is solved below)
            self.solution = solve_capability_mdp(self.mdp, V0=self.solution.V)
            self.log.value_iterations += int(self.solution.iterations)
        if from_stance:
            # The first moves from the stance the robot stands in (the map assumed the nominal
            # footholds): a refusal predicted from it is a dead end.
            outcomes = stance_outcomes(self._model, self._heightmap, x, y, k, topology, feet_W)
            self._stance_saved = set_stance(self.mdp, start, outcomes)
            moves = list(self._stance_saved.get(start, {}))
            dead = bool(moves) and max(self.mdp.success[a, start] for a in moves) < DEAD_END_SUCCESS
            back = self._back_out_missions(x, y, yaw, topology) if dead else None
            if back is not None:
                # A dead end by the model's word: every move from this stance predicted to fail
                # (the BLC refusing them, mostly). Back out now rather than spend the refusals
                # the walk may afford on trying each (forbidden from here, as refused ones are).
                self._forbid_here(start, moves)
                self.log.predicted_dead_ends += 1
            self.solution = solve_capability_mdp(self.mdp, V0=self.solution.V)
            self.log.value_iterations += int(self.solution.iterations)
            if back is not None:
                self.log.replans.append((t, (x, y, k, topology), len(back), 0.0))
                self.log.planning_time_s += time.perf_counter() - clock
                return back
        steps, reaches, probability = most_likely_path(self.mdp, self.solution, start)
        if not reaches:
            # The policy prefers turning in place to every way there; declining fails the task
            # for certain, so the likeliest way is walked if min_route_success allows it.
            steps, reaches, probability = most_probable_path(self.mdp, start)
            self.log.most_probable += int(reaches)
        if self.first_plan is None:
            self.first_plan = CapabilityPlan(self.mdp, self.solution, steps, reaches, probability,
                                             self.capability_map, self._edge_clearance)
        missions = split_missions(steps, self._split, start_yaw=yaw) if reaches else []
        if missions:
            # The path ends at the goal cell's centre; the last mission goes to the goal itself
            # (within half a cell of it).
            last = missions[-1]
            last.target = (self._goal[0], self._goal[1], last.target[2])
            self._placed(missions, keep_last=True)
        self.log.replans.append((t, (x, y, k, topology), len(missions), probability))
        self.log.planning_time_s += time.perf_counter() - clock
        fall_free = fall_free_probability(steps)
        if not reaches or fall_free < self._min_success:
            self.log.unreachable = (f"no path reaches the goal {list(self._goal)}" if not reaches else
                                    f"the best path's predicted chance of no fall {fall_free:.3f} < "
                                    f"{self._min_success:g}")
            return []
        return missions

    def _advance(self, context, state, plan, missions, index):
        """The current mission ended (or is about to): replan from where it is expected to end."""
        if index + 1 >= len(missions) and not missions[index].back_out:
            return None
        from qz_drake.systems.blc_plan import expected_end

        p = plan.base_position(plan.end_time)
        return self.next_missions(context.get_time(), float(p[0]), float(p[1]), float(plan.base_rpy(plan.end_time)[2]),
                                  missions[index].topology, plan.foot_positions(plan.end_time),
                                  list(missions[index + 1:]),
                                  start=expected_end(plan) if self._route_check is not None else None) or None

    def next_missions(self, t: float, x: float, y: float, yaw: float, topology: str, feet_W, held: list,
                      start=None) -> list:
        """The missions from a mission's expected end (x, y, yaw in ``topology``, standing on
        ``feet_W`` (6, 3)), ``held`` the rest of the current route: the replan's, or ``held``
        where hold_margin keeps it (see the class docstring); [] at the goal or where no path
        is left. With a route check, the route handed out is checked from ``start`` (the
        expected end as a MissionStart; None: not checked)."""
        ix, iy = self.mdp.cell_of(x, y, field="expected end", margin=self.mdp.config.cell_size)
        if (ix, iy) == self.mdp.goal_cell:
            return []
        if self._revisit_cost > 0:
            self._arrivals.append((ix, iy))
        missions = self._replan(t, x, y, yaw, topology, feet_W)
        decision = self._route_decision(x, y, yaw, topology, held, missions)
        self.log.route_decisions.append((t, decision))
        if decision == "held":
            # The replan's record names the route walked on: the held one.
            t_, first, _, _ = self.log.replans[-1]
            self.log.replans[-1] = (t_, first, len(held), float(math.prod(s.success for m in held for s in m.steps)))
            missions = unwrapped_yaws(held, yaw)
        return missions if start is None else self._checked(t, start, topology, missions)

    def _checked(self, t: float, start, topology: str, missions: list) -> list:
        """``missions`` as the route check leaves them (see the class docstring's route_check):
        each foreseen refusal gone round from ``start`` (a MissionStart, the robot's stance
        before the first mission) until the check plans the route's first missions, or no
        route is left (then the route as it was: the walk's recovery answers the refusal), or
        MAX_FORESEEN refusals were foreseen."""
        from qz_drake.planning.route_check import MAX_FORESEEN

        if self._route_check is None or not missions or missions[0].back_out:
            return missions
        x, y, yaw = (float(v) for v in start.xy_yaw)
        for _ in range(MAX_FORESEEN):
            foreseen = self._route_check.first_refused(start, missions, topology)
            if foreseen is None:
                return missions
            self.log.foreseen.append((t, foreseen.target, foreseen.topology, foreseen.index))
            mission = missions[foreseen.index]
            if len(mission.steps) > 1:
                # As a refused mission of several actions: one mission each, the last ending
                # where it did.
                single = self._single_actions(mission)
                missions = unwrapped_yaws(missions[:foreseen.index] + single + missions[foreseen.index + 1:], yaw)
                continue
            self._close_and_solve(mission.steps[0])
            unreachable = self.log.unreachable
            replanned = self._replan(t, x, y, yaw, topology, start.feet_W)
            if not replanned:
                # No way round it from here: walk the route as it was, for the walk's own
                # recovery to answer the refusal when it comes (the action stays forbidden).
                self.log.unreachable = unreachable
                return missions
            missions = replanned
            if missions[0].back_out:
                return missions
        return missions

    def _state_at(self, x: float, y: float, yaw: float, topology: str, field: str) -> int:
        """The grid state of a pose: its cell (up to a cell beyond the grid), the nearest of the 8
        headings, the topology."""
        ix, iy = self.mdp.cell_of(x, y, field=field, margin=self.mdp.config.cell_size)
        return self.mdp.state(ix, iy, int(round(yaw / HEADING_STEP)) % 8, topology)

    def _route_decision(self, x: float, y: float, yaw: float, topology: str, held: list, missions: list) -> str:
        """What the replan at a mission's end does with ``held`` (the rest of the route) against
        its own ``missions``: one of ROUTE_DECISIONS (CapabilityPlannerLog.route_decisions)."""
        from qz_drake.planning.capability_mdp import path_value, step_state_action

        steps = [s for m in held for s in m.steps]
        if not steps or not missions or missions[0].back_out or any(m.back_out for m in held):
            return "new"
        here = self._state_at(x, y, yaw, topology, "expected end")
        if step_state_action(self.mdp, steps[0])[0] != here:
            return "off route"
        if route_ahead(missions, ROUTE_AHEAD) == route_ahead(held, ROUTE_AHEAD):
            return "same"
        if self._hold_margin is None:
            return "changed"
        gain = float(self.solution.V[here]) - path_value(self.mdp, self.solution, steps)
        return "held" if gain <= self._hold_margin else "changed"

    def _go_round(self, context, state, failed, missions, index):
        """The BLC could not plan ``failed``: go round it (see the class docstring)."""
        x = self._state.Eval(context)
        x0, y0 = (float(v) for v in x[BASE_XY])
        yaw = float(base_rpy(x)[2])
        robot = self._robot_topology.Eval(context) if self._robot_topology.HasValue(context) else ""
        topology = robot if robot in self.mdp.topologies else (failed.steps[0].topology if failed.steps
                                                                 else failed.topology)
        if failed.back_out:
            self.log.unreachable = "the BLC could not plan the way back out of a dead end"
            return [], "forbade"
        if len(failed.steps) > 1:
            # Shorter missions are easier for the BLC: the same actions, one mission each, the
            # last ending where the failed one did (the goal itself, if it was the last).
            return unwrapped_yaws(self._single_actions(failed) + list(missions[index + 1:]), yaw), "split"
        # The BLC refused the move in the action's topology from this cell and heading; which
        # topology the robot stood in before (a switch first) does not change that, so the
        # move goes from every topology's state there. (Forbidden from one state only, the TLC
        # came back to the refused move from each other topology in turn, a switch and a
        # refusal each time: CapPlanner's walk of obstacles-hard 501, session 36.) With
        # refused_in_every_topology the same move in the other topologies goes too.
        self._close_and_solve(failed.steps[0])
        standing = measured_start(x, context.get_time(), DEFAULT_PARAMS)
        missions = self._replan(context.get_time(), x0, y0, yaw, topology, standing.feet_W)
        if missions and missions[0].back_out:
            return missions, "backed out"
        if not missions:
            # A dead end: every way on from this stance refused or forbidden. Its actions stay
            # forbidden (value iteration now avoids the state), and the robot backs out to
            # where it stood when the last walked mission started, to plan on from there.
            back = self._back_out_missions(x0, y0, yaw, topology)
            if back is not None:
                return back, "backed out"
            return missions, "forbade"
        missions = self._checked(context.get_time(), standing, topology, missions)
        return missions, "backed out" if missions and missions[0].back_out else "forbade"

    def _single_actions(self, mission) -> list:
        """A mission of several actions as one mission each, the last ending where it did (the
        goal itself, if it was the last)."""
        single = split_missions(mission.steps, dataclasses.replace(self._split, min_success=1.0,
                                                                   turns_with_moves=False))
        single[-1].target = (mission.target[0], mission.target[1], single[-1].target[2])
        return self._placed(single, keep_last=True)

    def _placed(self, missions: list, keep_last: bool) -> list:
        """``missions`` with their targets moved away from edges (target_shift; the last one's
        kept with ``keep_last``)."""
        if self._edge_distance is not None:
            place_targets(missions, self._heightmap, self._edge_distance, self._target_shift,
                          self.mdp.config.edge_height, keep_last=keep_last)
        return missions

    def _close_and_solve(self, step) -> None:
        """Forbids ``step``'s action from its state (refused, or foreseen refused;
        _forbid_from) and solves value iteration again from the current values."""
        from qz_drake.planning.capability_mdp import solve_capability_mdp, step_state_action

        s, a = step_state_action(self.mdp, step)
        self._forbid_from(s, [a])
        clock = time.perf_counter()
        self.solution = solve_capability_mdp(self.mdp, V0=self.solution.V)
        self.log.planning_time_s += time.perf_counter() - clock
        self.log.value_iterations += int(self.solution.iterations)

    def _back_out_missions(self, x: float, y: float, yaw: float, topology: str) -> list | None:
        """[the way back out of a dead end] (qz_drake.planning.back_out), or None."""
        target = None if self._back_out is None else self._back_out.target(self.log, (x, y))
        if target is None:
            return None
        self.log.unreachable = ""
        self.log.back_outs += 1
        return unwrapped_yaws([GuidedMission(target, topology, [], 1.0, back_out=True)], yaw)

    def _forbid_here(self, state: int, actions) -> None:
        """Forbids the moves ``actions`` of ``state``'s topology from its cell and heading in
        every topology (as a refused move is: how the robot stood before does not change it)."""
        from qz_drake.planning.capability_mdp import MOTIONS, forbid_action

        if self._every_topology:
            self._forbid_from(state, actions)
            return
        ix, iy, k, _ = self.mdp.unravel(state)
        for a in actions:
            m = a % len(MOTIONS)
            for t, name in enumerate(self.mdp.topologies):
                forbid_action(self.mdp, self.mdp.state(ix, iy, k, name), t * len(MOTIONS) + m)

    def _forbid_from(self, state: int, actions) -> None:
        """Forbids ``actions`` (refused, or foretold refused) from ``state``'s cell and heading,
        whatever topology the robot stands in there; with refused_in_every_topology, each
        action's motion in every topology."""
        from qz_drake.planning.capability_mdp import MOTIONS, forbid_action

        ix, iy, k, _ = self.mdp.unravel(state)
        n = len(MOTIONS)
        closed = sorted({t * n + a % n for a in actions for t in range(len(self.mdp.topologies))}
                        if self._every_topology else set(actions))
        for name in self.mdp.topologies:
            for a in closed:
                forbid_action(self.mdp, self.mdp.state(ix, iy, k, name), a)

    def counts(self) -> dict:
        """The planner's numbers for the walk's metrics."""
        return {"planning_time_s": self.log.planning_time_s, "value_iterations": self.log.value_iterations,
                "replans": max(len(self.log.replans) - 1, 0), "unreachable": self.log.unreachable,
                "tlc_recoveries": len(self.log.recoveries), "tlc_most_probable": self.log.most_probable,
                "tlc_back_outs": self.log.back_outs, "tlc_predicted_dead_ends": self.log.predicted_dead_ends,
                "tlc_foreseen_refusals": len(self.log.foreseen), **route_counts(self.log),
                **({} if self._route_check is None else {"route_check_solves": self._route_check.solves,
                                                          "route_check_time_s": self._route_check.time_s})}

    # -- outputs -----------------------------------------------------------------------------
    def _calc_guidance(self, context, output):
        output.set_value(list(context.get_abstract_state(self._missions).get_value()[0]))

    def _calc_utility(self, context, output):
        V = self.solution.V[:self.mdp.goal_state].reshape(self.mdp.grid_shape).max(axis=(0, 1))
        output.set_value((V, self.mdp.xs, self.mdp.ys))


__all__ = ["CapabilityVIPlanner", "CapabilityPlannerLog"]
