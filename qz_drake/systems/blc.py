"""``TrajectoryOptimizationBLC``: the bottom-level controller of paper 000 as a Drake system.

It holds the current BLC solution and solves a new one whenever a new mission starts, i.e.
whenever its local target (x, y, yaw) or topology input changes, over the heightmap on its
``heightmap`` input. If the current plan has ended, the new one starts from the *measured*
state on the ``state`` input (base pose and the feet from leg kinematics). If it is still
running (the route side asked ahead, as paper 000 does so that the robot need not stand while
the BLC solves), the new one starts where the current plan is expected to end, and takes over
on the ``plan`` output at that time. A failed solve is recorded and the mission is solved again
on the rungs of the BLC ladder, in order, until one plans (``ladder``: one or more tripod cycles
longer, or split in two halves chained; ``mission_retries``: the ladder of one more cycle per
retry); a mission no rung could plan is a failure (``log.failures``, with the first solve's
reason) and the previous plan stays on the output, so the tracker holds the robot where that
plan ended; nothing raises.

Solving takes wall time but no simulated time: like paper 000's robot, which stands while the
BLC solves, the plan starts at the simulated time of the update that asked for it.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, LeafSystem

from qz_drake.config import MissionTiming
from qz_drake.errors import ConfigError, bad_value
from qz_drake.robot.params import DEFAULT_PARAMS, NUM_LEGS
from qz_drake.robot.topology import TOPOLOGY_NAMES
from qz_drake.systems.blc_plan import expected_end, parse_ladder, retry_ladder
from qz_drake.systems.mission_sequencer import measured_start
from qz_drake.state_layout import STATE_SIZE

__all__ = ["BlcLog", "BlcSolveRecord", "TopologySwitchRecord", "TrajectoryOptimizationBLC", "expected_end"]


@dataclasses.dataclass(frozen=True)
class BlcSolveRecord:
    """One solve of the BLC system (a topology switch that could not be planned counts as a
    failed solve of its mission, with no solver time)."""

    # When the plan was to start. [s]
    start_time: float
    # The mission's local target (x, y, yaw) of the base link. [m], [rad]
    target: tuple[float, float, float]
    topology: str
    success: bool
    # Wall time of the solve. [s]
    solve_time: float
    # Why it failed ("" for a success); a rung's reason says which rung it was.
    reason: str
    # Ipopt iterations (all of a split rung's solves).
    iterations: int
    # The rung of the BLC ladder this solve was ("": the mission as asked, its first solve).
    rung: str = ""
    # Where the BLC planned it from (the mission start it was given: a measured one, or a
    # plan's expected end): base link x, y, yaw, z, roll, pitch [m, rad] and the six foot-sphere
    # centres in the world, (6, 3) as nested tuples [m]. Empty for a switch that failed.
    start: tuple = ()
    start_feet: tuple = ()


@dataclasses.dataclass(frozen=True)
class TopologySwitchRecord:
    """A topology switch the system made before a mission."""

    # [s]
    start_time: float
    from_topology: str
    to_topology: str
    # When the switch ends (the next mission's plan starts then). [s]
    end_time: float = math.nan
    # Where it puts the feet (foot-sphere centres in the world), (6, 3) as nested tuples. [m]
    end_feet: tuple = ()


@dataclasses.dataclass
class BlcLog:
    """Every solve the system made and every topology switch, in order."""

    solves: list[BlcSolveRecord] = dataclasses.field(default_factory=list)
    switches: list[TopologySwitchRecord] = dataclasses.field(default_factory=list)
    # Indices into ``solves`` of the failed solves that were followed by a retry of the mission
    # (the next rung of the ladder).
    retried: list[int] = dataclasses.field(default_factory=list)

    @property
    def failures(self) -> list[BlcSolveRecord]:
        """The failed solves no retry followed: one per mission that could not be planned."""
        retried = set(self.retried)
        return [s for i, s in enumerate(self.solves) if not s.success and i not in retried]

    @property
    def solve_time_s(self) -> float:
        return float(sum(s.solve_time for s in self.solves))


class TrajectoryOptimizationBLC(LeafSystem):
    """Solves the BLC per mission from the measured state (paper 000, section II-A).

    .. pydrake_system::

        name: TrajectoryOptimizationBLC
        input_ports:
        - state
        - target
        - topology
        - heightmap
        output_ports:
        - plan
        - solution
        - contact_schedule
        - desired_contact
        - failed_missions
        - robot_topology

    ``target`` is (x, y, yaw) of the base link; ``topology`` a topology name (abstract str);
    ``heightmap`` a HeightMap (abstract). ``plan`` is the BlcPlan the InverseKinematicsTracker
    follows (None before the first successful solve), ``solution`` the latest BlcSolution
    (failed ones too), ``contact_schedule`` its ContactSchedule and ``desired_contact`` (6) the
    planned contact of each foot now (1 in contact). ``failed_missions`` (1) counts the missions
    no solve (nor retry) could plan and ``robot_topology`` (abstract str) is the topology the
    robot is in or is switching to: a route source that reacts to failures reads them.

    Everything the updates and outputs read is Context state (the mission asked for, the plan,
    the plan solved ahead, the solution, the robot's topology, the failed missions), so a cloned
    or reset Context replays the same plans. Two things stay on ``self``, neither read by an
    update: ``log`` (BlcLog), a record the system writes and never reads back, kept on the
    system so that a caller reads it after the run without the Context (a second run of the
    same diagram appends to it: walk() builds a new diagram per run); and ``_planners``, the
    mission planner built for a heightmap, a cache that depends on the heightmap and the
    constructor's arguments only.

    Args:
        params: QingzhuiParams of the robot.
        timing: MissionTiming (duration of a mission from its length).
        blc_params: BlcParameters of the solver; None: defaults.
        check_period: how often the inputs are compared with the last mission. [s]
        settle_time: the plan solved at initialization starts this much later (the robot
            settles onto the ground first; later plans start when they are solved). [s]
        initial_topology: the topology the robot stands in at the start (None: the first
            mission's). A mission in another topology than the robot's is preceded by a
            TopologySwitchPlan (qz_drake.systems.topology_switch) from the standing robot;
            the BLC then solves the mission from the switch's expected end.
        mission_retries: how often a mission whose solve failed is solved again, each time
            one tripod cycle longer (a different problem: other footholds and timing). 0 (the
            capability trials' BLC, whose labels are first solves) or more (CapPlanner's
            walks: the robot stands while the BLC solves, so a retry costs wall time only).
        ladder: the rungs a mission whose first solve failed is solved on, in order, until one
            plans (qz_drake.systems.blc_plan.parse_ladder: "cycles+N", "split", "split+N", "short"; a
            sequence or a comma-separated string); None: ``mission_retries``'s. Deterministic:
            each rung is a solve (two for a split) with the BLC's iteration limit.
        ladder_budget: wall time a mission's solves may take before no further rung is tried
            (the log says so); it binds only when solves run into their time limits. [s]
    """

    def __init__(self, *, params=DEFAULT_PARAMS, timing: MissionTiming | None = None, blc_params=None,
                 check_period: float = 0.05, settle_time: float = 0.0,
                 initial_topology: str | None = None, mission_retries: int = 0,
                 ladder=None, ladder_budget: float = 120.0):
        super().__init__()
        if isinstance(mission_retries, bool) or not isinstance(mission_retries, int) or mission_retries < 0:
            raise bad_value("mission_retries", mission_retries, "must be a whole number >= 0", ConfigError)
        if ladder is not None and mission_retries:
            raise bad_value("mission_retries", mission_retries, "give a ladder or mission retries, not both",
                            ConfigError)
        self._ladder = retry_ladder(mission_retries) if ladder is None else parse_ladder(ladder, "ladder")
        if isinstance(ladder_budget, bool) or not (isinstance(ladder_budget, (int, float)) and ladder_budget > 0):
            raise bad_value("ladder_budget", ladder_budget, "must be a positive number of seconds", ConfigError)
        self._ladder_budget = float(ladder_budget)
        if not check_period > 0:
            raise bad_value("check_period", check_period, "must be positive", ConfigError)
        if not settle_time >= 0:
            raise bad_value("settle_time", settle_time, "must be non-negative", ConfigError)
        self._settle_time = float(settle_time)
        self._params = params
        self._timing = timing or MissionTiming()
        self._blc_params = blc_params
        self.log = BlcLog()
        self._state = self.DeclareVectorInputPort("state", STATE_SIZE)
        self._target = self.DeclareVectorInputPort("target", 3)
        self._topology = self.DeclareAbstractInputPort("topology", AbstractValue.Make("nominal"))
        self._heightmap = self.DeclareAbstractInputPort("heightmap", AbstractValue.Make(object()))
        # (target, topology) of the last mission asked for; the current plan; the latest solution.
        self._mission = self.DeclareAbstractState(AbstractValue.Make(None))
        self._plan = self.DeclareAbstractState(AbstractValue.Make(None))
        # A plan solved ahead, waiting for the current one to end (None: none).
        self._next = self.DeclareAbstractState(AbstractValue.Make(None))
        self._solution = self.DeclareAbstractState(AbstractValue.Make(None))
        # The topology the robot is in (or will be in when the current plan ends).
        self._robot_topology = self.DeclareAbstractState(AbstractValue.Make(initial_topology))
        # Missions no solve could plan, so far.
        self._failed_missions = self.DeclareAbstractState(AbstractValue.Make(0))
        # Outputs depend on the state alone (no direct feedthrough: the loop through the
        # station and the route sequencer is not algebraic).
        state_only = {self.all_state_ticket()}
        self.DeclareAbstractOutputPort("plan", lambda: AbstractValue.Make(None), self._calc_plan,
                                       prerequisites_of_calc={self.all_state_ticket(),
                                                              self.time_ticket()})
        self.DeclareAbstractOutputPort("solution", lambda: AbstractValue.Make(None),
                                       self._calc_solution, prerequisites_of_calc=state_only)
        self.DeclareAbstractOutputPort("contact_schedule", lambda: AbstractValue.Make(None),
                                       self._calc_schedule, prerequisites_of_calc=state_only)
        self.DeclareVectorOutputPort(
            "failed_missions", 1,
            lambda context, output: output.SetAtIndex(
                0, context.get_abstract_state(self._failed_missions).get_value()),
            prerequisites_of_calc=state_only)
        self.DeclareAbstractOutputPort(
            "robot_topology", lambda: AbstractValue.Make(""),
            lambda context, output: output.set_value(
                context.get_abstract_state(self._robot_topology).get_value() or ""),
            prerequisites_of_calc=state_only)
        self.DeclareVectorOutputPort("desired_contact", BasicVector(NUM_LEGS), self._calc_contact,
                                     prerequisites_of_calc={self.all_state_ticket(),
                                                            self.time_ticket()})
        self.DeclareInitializationUnrestrictedUpdateEvent(self._initialize)
        self.DeclarePeriodicUnrestrictedUpdateEvent(check_period, 0.0, self._update)
        self._planners = {}

    # -- solving ------------------------------------------------------------------------------
    def _planner(self, heightmap):
        from qz_drake.systems.blc_plan import blc_mission_planner

        key = id(heightmap)
        if key not in self._planners:
            self._planners = {key: blc_mission_planner(heightmap, self._params, self._timing,
                                                       blc_params=self._blc_params)}
        return self._planners[key]

    def _initialize(self, context, state):
        self._update(context, state, delay=self._settle_time)

    def _current_plan(self, context):
        """The plan in force now: a plan solved ahead once its start time has come."""
        ahead = context.get_abstract_state(self._next).get_value()
        if ahead is not None and context.get_time() >= ahead.start_time:
            return ahead
        return context.get_abstract_state(self._plan).get_value()

    def _update(self, context, state, delay: float = 0.0):
        current = self._current_plan(context)
        if current is not context.get_abstract_state(self._plan).get_value():
            state.get_mutable_abstract_state(self._plan).set_value(current)
            state.get_mutable_abstract_state(self._next).set_value(None)
        target = tuple(float(v) for v in self._target.Eval(context))
        topology = self._topology.Eval(context)
        mission = (target, topology)
        if mission == context.get_abstract_state(self._mission).get_value():
            return
        state.get_mutable_abstract_state(self._mission).set_value(mission)
        if topology not in TOPOLOGY_NAMES:
            raise bad_value("topology", topology, f"expected one of {', '.join(TOPOLOGY_NAMES)}",
                            ConfigError)
        if not all(math.isfinite(v) for v in target):
            raise bad_value("target", list(target), "must be finite", ConfigError)
        t = context.get_time()
        ahead = current is not None and t < current.end_time
        robot_topology = context.get_abstract_state(self._robot_topology).get_value() or topology
        if topology != robot_topology and ahead:
            # A switch starts from a standing robot: ask again once the current plan ended.
            state.get_mutable_abstract_state(self._mission).set_value(None)
            return
        if ahead:
            start = expected_end(current)
        else:
            start = measured_start(self._state.Eval(context), t, self._params)
            start.time = t + delay
        heightmap = self._heightmap.Eval(context)
        state.get_mutable_abstract_state(self._robot_topology).set_value(topology)
        if topology != robot_topology:
            from qz_drake.robot.topology import get_topology
            from qz_drake.systems.topology_switch import plan_topology_switch

            try:
                switch = plan_topology_switch(heightmap=heightmap, start=start,
                                            from_topology=get_topology(robot_topology, self._params),
                                            to_topology=get_topology(topology, self._params),
                                            start_time=start.time, params=self._params)
            except ConfigError as e:
                state.get_mutable_abstract_state(self._robot_topology).set_value(robot_topology)
                self._count_failure(context, state)
                self.log.solves.append(BlcSolveRecord(
                    start_time=start.time, target=target, topology=topology, success=False, solve_time=0.0,
                    reason=f"topology switch {robot_topology} -> {topology}: {e}", iterations=0))
                return
            state.get_mutable_abstract_state(self._plan).set_value(switch)
            state.get_mutable_abstract_state(self._next).set_value(None)
            current, ahead = switch, True
            start = expected_end(switch)
            self.log.switches.append(TopologySwitchRecord(
                switch.start_time, robot_topology, topology, end_time=float(switch.end_time),
                end_feet=tuple(map(tuple, np.asarray(start.feet_W, dtype=float).tolist()))))
        planner = self._planner(heightmap)
        first_reason, spent = "", 0.0
        base_z = math.nan if start.base_z is None else float(start.base_z)
        where = (*(float(v) for v in start.xy_yaw), base_z, *(float(v) for v in start.roll_pitch))
        feet = tuple(map(tuple, np.asarray(start.feet_W, dtype=float).tolist()))
        for k, rung in enumerate(("",) + self._ladder):
            clock = time.perf_counter()
            plan, reason = planner(start, target, topology, start.time, rung=rung)
            solve_time = time.perf_counter() - clock
            spent += solve_time
            solution = planner.last_solution
            last = plan is not None or k == len(self._ladder) or spent >= self._ladder_budget
            if k == 0:
                first_reason = reason
            elif reason and last:
                # A mission no rung could plan is refused with its first solve's reason.
                reason = f"{first_reason}; no rung of the ladder planned it (last: {rung}: {reason})"
                if k < len(self._ladder):
                    reason += f"; the ladder's budget of {self._ladder_budget:g} s was spent"
            elif reason:
                reason = f"rung {rung}: {reason}"
            self.log.solves.append(BlcSolveRecord(
                start_time=start.time, target=target, topology=topology, success=plan is not None,
                solve_time=solve_time, reason=reason, iterations=planner.last_iterations, rung=rung,
                start=where, start_feet=feet))
            if last:
                break
            self.log.retried.append(len(self.log.solves) - 1)
        state.get_mutable_abstract_state(self._solution).set_value(solution)
        if plan is not None:
            state.get_mutable_abstract_state(self._next if ahead else self._plan).set_value(plan)
        else:
            self._count_failure(context, state)

    def _count_failure(self, context, state):
        count = context.get_abstract_state(self._failed_missions).get_value()
        state.get_mutable_abstract_state(self._failed_missions).set_value(count + 1)

    # -- outputs -----------------------------------------------------------------------------
    def _calc_plan(self, context, output):
        output.set_value(self._current_plan(context))

    def _calc_solution(self, context, output):
        output.set_value(context.get_abstract_state(self._solution).get_value())

    def _calc_schedule(self, context, output):
        solution = context.get_abstract_state(self._solution).get_value()
        output.set_value(None if solution is None else solution.contact_schedule)

    def _calc_contact(self, context, output):
        plan = self._current_plan(context)
        contact = np.ones(NUM_LEGS) if plan is None else plan.contact(context.get_time())
        output.SetFromVector(np.asarray(contact, dtype=float))
