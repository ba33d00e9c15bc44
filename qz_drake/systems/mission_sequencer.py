"""Chains local missions along a route (paper 000, section III-B).

A route is a list of waypoints, each with a topology, split into missions no longer than
``mission_length``; when a mission's plan ends, the next one is planned from the *measured*
state (base pose and feet), so that tracking errors do not accumulate. Two ways to chain them:

* ``MissionSequencer`` calls a planner function ``plan(start, target, topology, start_time) ->
  (plan or None, reason)`` itself (the kinematic tripod plan);
* ``MissionTargetSequencer`` only hands out the local targets, to the TrajectoryOptimizationBLC
  system (``qz_drake.systems.blc``), which solves each one from the measured state: the BLC
  loop of paper 000 as systems in one diagram.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from qz_drake.robot.kinematics import all_foot_positions
from qz_drake.state_layout import BASE_XY, BASE_Z, JOINT_Q, STATE_SIZE, base_pose, base_rpy


@dataclasses.dataclass
class MissionStart:
    """Where a mission starts: measured, or expected at the end of the previous plan."""

    time: float
    xy_yaw: tuple[float, float, float]
    feet_W: np.ndarray  # (6, 3) measured foot-sphere centres
    base_z: float | None = None  # measured base height [m]; None: unknown
    roll_pitch: tuple[float, float] = (0.0, 0.0)  # measured base roll and pitch [rad]


def measured_start(x: np.ndarray, t: float, params) -> MissionStart:
    """The mission start seen in a station state: base xy, yaw and height, and the six feet in
    the world from leg kinematics."""
    X_WB = base_pose(x)
    feet_B = all_foot_positions(x[JOINT_Q], params)
    feet_W = feet_B @ X_WB.rotation().matrix().T + X_WB.translation()
    rpy = base_rpy(x)
    x_B, y_B = x[BASE_XY]
    return MissionStart(time=t, xy_yaw=(float(x_B), float(y_B), float(rpy[2])),
                        feet_W=feet_W, base_z=float(x[BASE_Z]), roll_pitch=(float(rpy[0]), float(rpy[1])))


@dataclasses.dataclass
class MissionLog:
    """What happened to each mission."""

    targets: list = dataclasses.field(default_factory=list)
    topologies: list = dataclasses.field(default_factory=list)
    start_times: list = dataclasses.field(default_factory=list)
    failures: list = dataclasses.field(default_factory=list)  # (index, reason)
    plans: list = dataclasses.field(default_factory=list)


def split_route(start_xy: tuple[float, float], route: list[tuple[float, float, float, str]],
                mission_length: float) -> list[tuple[float, float, float, str]]:
    """Local targets (x, y, yaw, topology) no further apart than mission_length along a route
    of waypoints (x, y, yaw, topology). Intermediate targets face along their segment."""
    targets = []
    px, py = start_xy
    for x, y, yaw, topology in route:
        dist = math.hypot(x - px, y - py)
        pieces = max(1, int(math.ceil(dist / mission_length - 1e-9)))
        heading = math.atan2(y - py, x - px) if dist > 1e-9 else yaw
        for k in range(1, pieces + 1):
            s = k / pieces
            targets.append((px + s * (x - px), py + s * (y - py), yaw if k == pieces else heading, topology))
        px, py = x, y
    return targets


class MissionSequencer(LeafSystem):
    """Gives the tracker its current plan, replanning from the measured state per mission.

    .. pydrake_system::

        name: MissionSequencer
        input_ports:
        - state
        output_ports:
        - plan

    Args:
        targets: local targets (x, y, yaw, topology), e.g. from :func:`split_route`.
        planner: ``planner(start: MissionStart, target, topology, start_time)`` returning
            ``(plan, reason)``; plan None means the mission failed (reason says why).
        first_plan: the plan of the first mission (made from the known initial state).
        check_period: how often the sequencer looks for a finished mission. [s]
    """

    def __init__(self, *, targets, planner: Callable, first_plan, params, check_period: float = 0.05):
        super().__init__()
        self._targets = list(targets)
        self._planner = planner
        self._params = params
        self.log = MissionLog()
        self._state = self.DeclareVectorInputPort("state", STATE_SIZE)
        self._index = self.DeclareAbstractState(AbstractValue.Make(0))
        self._plan = self.DeclareAbstractState(AbstractValue.Make(first_plan))
        self.DeclareAbstractOutputPort("plan", lambda: AbstractValue.Make(first_plan), self._calc_plan)
        self.DeclarePeriodicUnrestrictedUpdateEvent(check_period, 0.0, self._update)
        self.log.targets.append(self._targets[0])
        self.log.topologies.append(self._targets[0][3])
        self.log.start_times.append(first_plan.start_time)
        self.log.plans.append(first_plan)

    @property
    def done(self) -> bool:
        return len(self.log.plans) >= len(self._targets) or bool(self.log.failures)

    def _calc_plan(self, context, output):
        output.set_value(context.get_abstract_state(self._plan).get_value())

    def _update(self, context, state):
        index = context.get_abstract_state(self._index).get_value()
        plan = context.get_abstract_state(self._plan).get_value()
        t = context.get_time()
        if t < plan.end_time or index + 1 >= len(self._targets) or self.log.failures:
            return
        start = measured_start(self._state.Eval(context), t, self._params)
        target = self._targets[index + 1]
        new_plan, reason = self._planner(start, target[:3], target[3], t)
        self.log.targets.append(target)
        self.log.topologies.append(target[3])
        self.log.start_times.append(t)
        if new_plan is None:
            self.log.failures.append((index + 1, reason))
            return
        self.log.plans.append(new_plan)
        state.get_mutable_abstract_state(self._index).set_value(index + 1)
        state.get_mutable_abstract_state(self._plan).set_value(new_plan)


class MissionTargetSequencer(LeafSystem):
    """The route side of the BLC loop: gives TrajectoryOptimizationBLC its local target and
    topology, one mission after another; the next target goes out once the plan for the
    current one has ended (the BLC then solves it from the measured state).

    .. pydrake_system::

        name: MissionTargetSequencer
        input_ports:
        - plan
        output_ports:
        - target
        - topology

    ``log`` records the targets handed out, their start times and the plans received, in the
    MissionLog shape the walking metrics use (failures are the BLC's to report).

    Args:
        targets: local targets (x, y, yaw, topology), e.g. from :func:`split_route`.
        check_period: how often the plan is looked at. [s]
        plan_ahead: hand out the next target this long before the current plan ends (the BLC
            then solves it from the plan's expected end state while the robot walks); 0: when
            it has ended (solved from the measured state). [s]
    """

    def __init__(self, *, targets, check_period: float = 0.05, plan_ahead: float = 0.0):
        super().__init__()
        self._plan_ahead = float(plan_ahead)
        self._targets = list(targets)
        if not self._targets:
            raise ValueError("MissionTargetSequencer needs at least one target")
        self.log = MissionLog()
        self._plan = self.DeclareAbstractInputPort("plan", AbstractValue.Make(None))
        self._index = self.DeclareAbstractState(AbstractValue.Make(0))
        state_only = {self.all_state_ticket()}
        self.DeclareVectorOutputPort("target", 3, self._calc_target, prerequisites_of_calc=state_only)
        self.DeclareAbstractOutputPort("topology", lambda: AbstractValue.Make("nominal"),
                                       self._calc_topology, prerequisites_of_calc=state_only)
        self.DeclarePeriodicUnrestrictedUpdateEvent(check_period, 0.0, self._update)
        self._record(0, 0.0)

    @property
    def num_targets(self) -> int:
        return len(self._targets)

    @property
    def done(self) -> bool:
        """True once every target has its plan."""
        return len(self.log.plans) >= len(self._targets)

    def _record(self, index: int, t: float) -> None:
        self.log.targets.append(self._targets[index])
        self.log.topologies.append(self._targets[index][3])
        self.log.start_times.append(t)

    def _calc_target(self, context, output):
        index = context.get_abstract_state(self._index).get_value()
        output.SetFromVector(np.asarray(self._targets[index][:3], dtype=float))

    def _calc_topology(self, context, output):
        output.set_value(self._targets[context.get_abstract_state(self._index).get_value()][3])

    def _update(self, context, state):
        plan = self._plan.Eval(context)
        # Plans that are not missions (a topology switch before one) are not counted.
        if plan is None or not getattr(plan, "is_mission", True):
            return
        if not self.log.plans or self.log.plans[-1] is not plan:
            self.log.plans.append(plan)
        index = context.get_abstract_state(self._index).get_value()
        # The plan must be the current mission's (one plan per target) and (nearly) have ended.
        if len(self.log.plans) != index + 1 or context.get_time() < plan.end_time - self._plan_ahead:
            return
        if index + 1 < len(self._targets):
            state.get_mutable_abstract_state(self._index).set_value(index + 1)
            self._record(index + 1, context.get_time())


@dataclasses.dataclass
class RecoveryLog(MissionLog):
    """The missions handed out (MissionLog's fields) and how a route source went round the
    missions the BLC could not plan."""

    # (time, refused target (x, y, yaw, topology) or None, what was done, e.g. "split").
    recoveries: list = dataclasses.field(default_factory=list)
    # Why the goal is unreachable ("" while it is not).
    unreachable: str = ""


class MissionQueue(tuple):
    """A route's missions (a tuple) and the index of the current one, as a RecoveringSequencer
    holds them in its context: ``missions, index = queue``. Never changed in place (a new queue
    replaces it), so that Drake's copies of the context state share it instead of copying
    every mission at each check (a deep copy of the list was 3 % of a Fig. 9 walk)."""

    def __new__(cls, missions, index: int = 0):
        return super().__new__(cls, (tuple(missions), int(index)))

    def __deepcopy__(self, memo):
        return self


class RecoveringSequencer(LeafSystem):
    """The route side of the BLC loop for a route source that goes round the missions the BLC
    could not plan (CapPlanner's TLC, qz_drake.planning.capability_planner; the A* baseline's,
    qz_drake.experiments.astar_recovery): the ports, the bookkeeping and the standing robot
    are the same, what differs is how the next missions are found.

    Input ports ``state``, ``plan``, ``failed_missions`` and ``robot_topology``
    (TrajectoryOptimizationBLC's outputs of those names), output ports ``target`` (x, y, yaw)
    and ``topology``. A mission is anything with ``target`` (x, y, yaw) and ``topology``.

    A subclass calls :meth:`_start` with its first missions once it has them (after declaring
    any ports of its own it wants first) and implements
    ``_advance(context, state, plan, missions, index) -> missions or None`` (the current
    mission has ended: the missions from here on, the next one first; None: the last was
    handed out) and ``_go_round(context, state, failed, missions, index) -> (missions, what
    was done)`` (the BLC could not plan ``failed``: the missions that go round it; no
    missions: the goal is unreachable, with ``log.unreachable`` set).

    Context state: the missions of the latest plan with the index of the current one, and the
    mission held after the last refusal (the outputs hold it, so that the BLC system, which
    does not solve one mission twice, leaves the robot standing instead of being sent
    somewhere new). The count of failures already answered and ``log`` stay on ``self``: one
    sequencer serves one walk.

    Args:
        log: a RecoveryLog (or a subclass of it).
        max_recoveries: refused missions gone round; one more and the goal is unreachable.
        plan_ahead: hand out the next mission this long before the current plan ends. [s]
    """

    def __init__(self, *, log: RecoveryLog, max_recoveries: int, plan_ahead: float = 0.0):
        super().__init__()
        if isinstance(max_recoveries, bool) or not isinstance(max_recoveries, int) or max_recoveries < 0:
            from qz_drake.errors import ConfigError, bad_value

            raise bad_value("max_recoveries", max_recoveries, "must be a whole number >= 0", ConfigError)
        self.log = log
        self._max_recoveries = max_recoveries
        self._plan_ahead = float(plan_ahead)
        self._failures_seen = 0
        self._last_handed = False
        self._state = self.DeclareVectorInputPort("state", STATE_SIZE)
        self._plan = self.DeclareAbstractInputPort("plan", AbstractValue.Make(None))
        self._failed = self.DeclareVectorInputPort("failed_missions", 1)
        self._robot_topology = self.DeclareAbstractInputPort("robot_topology", AbstractValue.Make(""))

    def _start(self, missions: list, initial_topology: str, check_period: float) -> None:
        """Declares the state, the target and topology outputs and the update, with the first
        missions."""
        self._topology0 = initial_topology
        self._record(missions, 0, 0.0)
        self._missions = self.DeclareAbstractState(AbstractValue.Make(MissionQueue(missions)))
        self._held = self.DeclareAbstractState(AbstractValue.Make(None))
        state_only = {self.all_state_ticket()}
        self.DeclareVectorOutputPort("target", 3, self._calc_target, prerequisites_of_calc=state_only)
        self.DeclareAbstractOutputPort("topology", lambda: AbstractValue.Make("nominal"), self._calc_topology,
                                       prerequisites_of_calc=state_only)
        self.DeclarePeriodicUnrestrictedUpdateEvent(check_period, 0.0, self._update)

    def _record(self, missions, index, t) -> None:
        if index < len(missions):
            m = missions[index]
            self.log.targets.append((*m.target, m.topology))
            self.log.topologies.append(m.topology)
            self.log.start_times.append(t)

    @property
    def done(self) -> bool:
        """True once the last mission was handed out and its plan has ended, or the goal is
        unreachable."""
        return bool(self.log.unreachable) or self._last_handed

    def _update(self, context, state):
        if self._failed.HasValue(context):
            failed = int(round(self._failed.Eval(context)[0]))
            if failed > self._failures_seen:
                self._failures_seen = failed
                self._recover(context, state)
                return
        plan = self._plan.Eval(context)
        if plan is None or not getattr(plan, "is_mission", True):
            return
        if not self.log.plans or self.log.plans[-1] is not plan:
            self.log.plans.append(plan)
        missions, index = context.get_abstract_state(self._missions).get_value()
        if not missions or len(self.log.plans) != len(self.log.targets):
            return
        if context.get_time() < plan.end_time - self._plan_ahead:
            return
        new = self._advance(context, state, plan, missions, index)
        if not new:
            self._last_handed = True
            return
        state.get_mutable_abstract_state(self._missions).set_value(MissionQueue(new))
        self._record(new, 0, context.get_time())

    def _recover(self, context, state):
        missions, index = context.get_abstract_state(self._missions).get_value()
        failed = missions[index] if index < len(missions) else None
        target = None
        if len(self.log.targets) > len(self.log.plans):  # its plan never came: out of the log
            target = self.log.targets.pop()
            self.log.topologies.pop()
            self.log.start_times.pop()
        if failed is not None:
            state.get_mutable_abstract_state(self._held).set_value((tuple(failed.target), failed.topology))
        if failed is None or len(self.log.recoveries) >= self._max_recoveries:
            last = target if target is not None else (
                (*failed.target, failed.topology) if failed is not None else None)
            self.log.unreachable = (f"the BLC could not plan {len(self.log.recoveries) + 1} missions, the last "
                                    + ("unknown" if last is None else
                                       f"to (x, y, yaw) {[round(float(v), 2) for v in last[:3]]}"))
            state.get_mutable_abstract_state(self._missions).set_value(MissionQueue(()))
            return
        t = context.get_time()
        new, action = self._go_round(context, state, failed, missions, index)
        self.log.recoveries.append((t, None if target is None else tuple(target), action))
        state.get_mutable_abstract_state(self._missions).set_value(MissionQueue(new))
        if not new:
            self._last_handed = True
            return
        self._record(new, 0, t)

    def _calc_target(self, context, output):
        missions, index = context.get_abstract_state(self._missions).get_value()
        if index < len(missions):
            output.SetFromVector(np.asarray(missions[index].target, dtype=float))
            return
        held = context.get_abstract_state(self._held).get_value()
        if held is not None:  # no route left after a mission the BLC could not plan: stand
            output.SetFromVector(np.asarray(held[0], dtype=float))
            return
        x = self._state.Eval(context)  # unreachable from the start: hold the start
        output.SetFromVector([*x[BASE_XY], base_rpy(x)[2]])

    def _calc_topology(self, context, output):
        missions, index = context.get_abstract_state(self._missions).get_value()
        if index < len(missions):
            output.set_value(missions[index].topology)
            return
        held = context.get_abstract_state(self._held).get_value()
        output.set_value(self._topology0 if held is None else held[1])


def unwrapped_yaws(missions: list, yaw: float) -> list:
    """Copies of the missions (dataclasses with a ``target`` (x, y, yaw)) with each target's
    yaw the previous one's (the first: ``yaw``) plus the turn in between, so that no 2 pi jump
    reaches the BLC."""
    out, previous = [], yaw
    for m in missions:
        x, y, target_yaw = m.target
        previous = previous + math.remainder(target_yaw - previous, 2 * math.pi)
        out.append(dataclasses.replace(m, target=(x, y, previous)))
    return out
