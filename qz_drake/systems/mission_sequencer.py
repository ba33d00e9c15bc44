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
