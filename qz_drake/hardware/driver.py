"""The simulated robot driver: the simulation station behind the LCM protocol.

What a user runs (``qz robot-sim SCENARIO --lcm-url URL``) to try a controller against the
hardware interface before the real robot, and what the tests run in the same diagram as the
interface over ``memq://``. Its cycle is the one the real driver must have (README, "The
hardware interface"): at each control tick apply the newest command (torques clamped to the
actuator limits, positions to the joint limits), step, then publish the status measured after
the tick; a stale or malformed command latches a safe stop.

Safe stop: hold the joint angles measured when the stop began, with a PD of moderate gains
(torque mode; position mode: the drives' own PD). Damping alone was not chosen: it lets the
60 kg trunk sink onto the ground at whatever speed the legs give way, ending in trunk contact,
whereas any three feet on the ground of a tripod gait stand statically, so holding keeps the
robot up, sinking only by the hold's compliance, and it can resume walking from there.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Callable

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.lcm import DrakeLcm
from pydrake.systems.framework import BasicVector, Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.lcm import LcmInterfaceSystem, LcmSubscriberSystem

from qz_drake.config import Scenario
from qz_drake.hardware.codec import EncodedMessageSerializer, command_problem, decode, joint_limits, message_key
from qz_drake.hardware.config import HardwareConfig, validate_hardware_config
from qz_drake.hardware.qz_lcm import qz_command, qz_pose, qz_status
from qz_drake.hardware.watchdog import (LinkState, WatchdogLimits, declare_message_intake, reset_watchdog,
                                       step_watchdog)
from qz_drake.robot.params import NUM_JOINTS, NUM_LEGS, QingzhuiParams
from qz_drake.sim_station import make_sim_station
from qz_drake.state_layout import BASE_POS, BASE_QUAT, BASE_VEL, IMU_SIZE, JOINT_Q, JOINT_V, STATE_SIZE

# The driver publishes its status a sixteenth of a period after its tick, and takes the newest
# command a sixteenth of a period before the tick (see qz_drake.hardware.config): a Drake
# plant's step and another system's update at the same time see each other's old values, so
# the command is latched first and the tick applies it. Between the two, 7/8 of a period is
# the command's budget, what a robot's driver, whose tick takes microseconds, leaves a servo in
# another process. (This simulated driver's own step takes most of a period at real time on a
# 2-core machine, so its statuses leave late whatever the phase: a servo answering in 0.8 ms
# through the relay still had 70-100 % of its commands applied a period late.)
STATUS_PHASE = 0.0625
COMMAND_PHASE = 0.9375


@dataclasses.dataclass(frozen=True)
class DriverCommandState:
    """What CommandReceiver applies: the newest accepted command, or a hold."""

    link: LinkState = LinkState()
    # Applied joint torques (torque mode) or feedforward (position mode), (18,) never written
    # to after construction. [N*m]
    torque: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(NUM_JOINTS))
    # Applied joint position and velocity commands (position mode). [rad], [rad/s]
    position: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(NUM_JOINTS))
    velocity: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(NUM_JOINTS))
    # The newest accepted command asked for a safe stop.
    commanded_stop: bool = False
    # Holding the joint angles ``hold`` (safe stop, or waiting for the first command).
    holding: bool = True
    hold: tuple[float, ...] | None = None
    clamped_commands: int = 0
    clamped_torques: int = 0
    clamped_positions: int = 0
    # Control periods from the measurement an accepted command answers (its status_sequence) to
    # the tick that applies it: 1 in the lockstep diagram; summed over ``answered`` commands,
    # and the most. Over a network it says whether the controller keeps up.
    answered: int = 0
    loop_delay_sum: int = 0
    loop_delay_max: int = 0

    def __deepcopy__(self, memo):  # immutable: Drake's state copies may share it
        return self


class CommandReceiver(LeafSystem):
    """Applies qz_command to the station: clamps, watchdog, safe stop.

    .. pydrake_system::

        name: CommandReceiver
        input_ports:
        - lcm_command
        - state
        output_ports:
        - joint_torque
        - joint_position_command (position mode)
        - joint_velocity_command (position mode)
        - safe_stop

    Before each control tick the newest command is checked (mode, sizes, finite values) and passed
    through the watchdog; an accepted command is applied with its torques clamped to
    +-``effort_limit`` and its positions to the joint limits (each clamped command counted) and
    held until the next. A stale or malformed command, a sequence or clock jump latches a safe
    stop until ``reset_safe_stop``; a MODE_SAFE_STOP command holds while it is commanded.
    ``state`` is the station's, for the hold's PD.

    Args:
        config: protocol settings (period, timeout, safe-stop gains).
        params: the robot's parameters (effort and joint limits).
        position_mode: the station takes joint position commands.
    """

    def __init__(self, *, config: HardwareConfig, params: QingzhuiParams, position_mode: bool):
        super().__init__()
        self._config = config
        self._position_mode = position_mode
        self._effort = params.effort_limit
        self._lower, self._upper = joint_limits(params)
        self._limits = WatchdogLimits(timeout=config.command_timeout,
                                      clock_tolerance=config.clock_tolerance, message="command")
        # The encoded message (bytes, see EncodedMessageSerializer).
        self._command = self.DeclareAbstractInputPort("lcm_command", AbstractValue.Make(b""))
        self._state = self.DeclareVectorInputPort("state", STATE_SIZE)
        self._applied = self.DeclareAbstractState(AbstractValue.Make(DriverCommandState()))
        self.DeclarePeriodicUnrestrictedUpdateEvent(config.control_period, COMMAND_PHASE * config.control_period,
                                                    self._update)
        declare_message_intake(self, config.control_period, COMMAND_PHASE)
        self.DeclareVectorOutputPort("joint_torque", NUM_JOINTS, self._calc_torque)
        if position_mode:
            self.DeclareVectorOutputPort("joint_position_command", NUM_JOINTS, self._calc_position,
                                         prerequisites_of_calc={self.abstract_state_ticket(self._applied)})
            self.DeclareVectorOutputPort("joint_velocity_command", NUM_JOINTS, self._calc_velocity,
                                         prerequisites_of_calc={self.abstract_state_ticket(self._applied)})
        self.DeclareVectorOutputPort("safe_stop", 1, self._calc_safe_stop,
                                     prerequisites_of_calc={self.abstract_state_ticket(self._applied)})

    def applied(self, context) -> DriverCommandState:
        return context.get_abstract_state(self._applied).get_value()

    def reset(self, context) -> None:
        """Unlatches the driver's safe stop (operator action on the robot); ``context`` is this
        system's."""
        value = context.get_mutable_abstract_state(self._applied)
        s = value.get_value()
        value.set_value(dataclasses.replace(s, link=reset_watchdog(s.link)))

    def _update(self, context, state):
        s: DriverCommandState = context.get_abstract_state(self._applied).get_value()
        data = self._command.Eval(context)
        m, problem = decode(qz_command, data)
        key = message_key(m, problem, data)
        if m is not None and key != s.link.last_key:
            problem = command_problem(m, self._position_mode)
        link, accepted = step_watchdog(s.link, key, problem, context.get_time(), self._limits)
        fields = {"link": link}
        commanded_stop = s.commanded_stop
        if accepted:
            commanded_stop = fields["commanded_stop"] = m.mode == qz_command.MODE_SAFE_STOP
            if not commanded_stop:
                fields.update(self._accept(s, m))
                # The status published after tick k carries sequence k + 1; this command is
                # applied at the next tick.
                tick = int(round(context.get_time() / self._config.control_period - COMMAND_PHASE))
                delay = tick + 2 - m.status_sequence
                fields.update(answered=s.answered + 1, loop_delay_sum=s.loop_delay_sum + delay,
                              loop_delay_max=max(s.loop_delay_max, delay))
        hold = link.latched or not link.armed or commanded_stop
        if hold and (not s.holding or s.hold is None):  # (waiting for the first command: no hold yet)
            fields.update(holding=True, hold=tuple(self._state.Eval(context)[JOINT_Q]))
        elif not hold and s.holding:
            fields.update(holding=False, hold=None)
        state.get_mutable_abstract_state(self._applied).set_value(dataclasses.replace(s, **fields))

    def _accept(self, s: DriverCommandState, m: qz_command) -> dict:
        """The fields of an accepted command: clamped torques and positions, clamp counts."""
        tau = np.asarray(m.joint_torque, dtype=float)
        clamped_tau = np.clip(tau, -self._effort, self._effort)
        n_tau = int(np.count_nonzero(clamped_tau != tau))
        q = np.asarray(m.joint_position, dtype=float)
        n_q = 0
        if self._position_mode:
            clamped_q = np.clip(q, self._lower, self._upper)
            n_q = int(np.count_nonzero(clamped_q != q))
            q = clamped_q
        v = np.asarray(m.joint_velocity, dtype=float) if self._position_mode else np.zeros(NUM_JOINTS)
        return dict(torque=clamped_tau, position=q, velocity=v, clamped_commands=s.clamped_commands + int(n_tau + n_q > 0),
                    clamped_torques=s.clamped_torques + n_tau, clamped_positions=s.clamped_positions + n_q)

    def _hold_target(self, context, s: DriverCommandState) -> np.ndarray:
        # Before the first tick's update the hold is the current measurement.
        return np.asarray(s.hold) if s.hold is not None else self._state.Eval(context)[JOINT_Q]

    def _calc_torque(self, context, output: BasicVector):
        s = self.applied(context)
        if not s.holding:
            output.SetFromVector(s.torque)
        elif self._position_mode:
            output.SetFromVector(np.zeros(NUM_JOINTS))
        else:
            x = self._state.Eval(context)
            tau = (self._config.safe_stop_kp * (self._hold_target(context, s) - x[JOINT_Q])
                   - self._config.safe_stop_kd * x[JOINT_V])
            output.SetFromVector(np.clip(tau, -self._effort, self._effort))

    def _calc_position(self, context, output: BasicVector):
        s = self.applied(context)
        output.SetFromVector(self._hold_target(context, s) if s.holding else s.position)

    def _calc_velocity(self, context, output: BasicVector):
        # A hold asks the drives for rest.
        s = self.applied(context)
        output.SetFromVector(np.zeros(NUM_JOINTS) if s.holding else s.velocity)

    def _calc_safe_stop(self, context, output: BasicVector):
        output.SetFromVector([float(self.applied(context).holding)])


class PublishTiming:
    """The wall clock of the statuses a driver published: the longest time between two, and at
    what simulated time it ended. A diagnosis of a driver in another process (a controller's
    safe stop for statuses that stopped coming: did this driver stop sending them, or did they
    stop on the way?), kept outside the diagram's state: it is not the simulation's."""

    def __init__(self):
        self.count = 0
        self.last_wall = self.last_cpu = math.nan
        self.longest_gap = self.longest_gap_cpu = 0.0
        self.longest_gap_time = math.nan

    def published(self, t: float) -> None:
        now, cpu = time.monotonic(), time.thread_time()
        if self.count and now - self.last_wall > self.longest_gap:
            self.longest_gap, self.longest_gap_time = now - self.last_wall, t
            self.longest_gap_cpu = cpu - self.last_cpu
        self.count += 1
        self.last_wall, self.last_cpu = now, cpu

    def summary(self) -> dict:
        """The longest gap, when it ended (simulated time), and the CPU time this thread spent
        in it: about the gap, the driver computed for it (a long step); much less, it waited
        for a core."""
        return {"statuses_published": self.count, "longest_publish_gap_ms": round(self.longest_gap * 1e3, 3),
                "longest_publish_gap_cpu_ms": round(self.longest_gap_cpu * 1e3, 3),
                "longest_publish_gap_at_s": None if math.isnan(self.longest_gap_time) else self.longest_gap_time}


class StatusPublisher(LeafSystem):
    """Publishes the station's measurements as qz_status (and the true base pose as qz_pose).

    .. pydrake_system::

        name: StatusPublisher
        input_ports:
        - state
        - joint_torque_measured
        - imu
        - foot_contact
        - safe_stop

    One status per control period, a quarter period after the driver's tick; ``sequence``
    counts the ticks from 1, ``utime`` is the simulated clock. It publishes directly (not via
    an LcmPublisherSystem) so that a tick can go without a status, as on a robot whose driver
    misses a cycle: ``status_filter`` (tests) may alter a message or drop it (return None).

    Args:
        lcm: the LCM instance.
        config: protocol settings (channels, periods).
        status_filter, pose_filter: hooks that may alter (fault tests) or observe (benchmarks)
            each message before it is published: message -> message, or None to drop it.
    """

    def __init__(self, *, lcm: DrakeLcm, config: HardwareConfig,
                 status_filter: Callable[[qz_status], qz_status | None] | None = None,
                 pose_filter: Callable[[qz_pose], qz_pose | None] | None = None):
        super().__init__()
        self._lcm = lcm
        self._config = config
        self._status_filter = status_filter
        self._pose_filter = pose_filter
        self.timing = PublishTiming()
        self._state = self.DeclareVectorInputPort("state", STATE_SIZE)
        self._tau = self.DeclareVectorInputPort("joint_torque_measured", NUM_JOINTS)
        self._imu = self.DeclareVectorInputPort("imu", IMU_SIZE)
        self._contact = self.DeclareVectorInputPort("foot_contact", NUM_LEGS)
        self._safe_stop = self.DeclareVectorInputPort("safe_stop", 1)
        period = config.control_period
        self.DeclarePeriodicPublishEvent(period, STATUS_PHASE * period, self._publish_status)
        self.DeclarePeriodicPublishEvent(config.pose_period, STATUS_PHASE * period, self._publish_pose)

    def _publish_status(self, context):
        t = context.get_time()
        x = self._state.Eval(context)
        imu = self._imu.Eval(context)
        m = qz_status()
        m.utime = int(round(t * 1e6))
        m.sequence = int(round(t / self._config.control_period - STATUS_PHASE)) + 1
        m.safe_stop = int(self._safe_stop.Eval(context)[0] > 0.5)
        m.num_joints = NUM_JOINTS
        m.joint_position = x[JOINT_Q].tolist()
        m.joint_velocity = x[JOINT_V].tolist()
        m.joint_torque = self._tau.Eval(context).tolist()
        m.orientation = imu[0:4].tolist()
        m.angular_velocity = imu[4:7].tolist()
        m.linear_acceleration = imu[7:10].tolist()
        m.num_feet = NUM_LEGS
        m.foot_contact = [bool(c > 0.5) for c in self._contact.Eval(context)]
        if self._status_filter is not None:
            m = self._status_filter(m)
        if m is not None:
            self._lcm.Publish(self._config.channels.status, m.encode())
            self.timing.published(t)

    def _publish_pose(self, context):
        t = context.get_time()
        x = self._state.Eval(context)
        m = qz_pose()
        m.utime = int(round(t * 1e6))
        m.sequence = int(round((t - STATUS_PHASE * self._config.control_period) / self._config.pose_period)) + 1
        m.position = x[BASE_POS].tolist()
        m.orientation = x[BASE_QUAT].tolist()
        m.linear_velocity = x[BASE_VEL].tolist()
        if self._pose_filter is not None:
            m = self._pose_filter(m)
        if m is not None:
            self._lcm.Publish(self._config.channels.pose, m.encode())


class QingzhuiRobotDriver(Diagram):
    """The simulation station behind the LCM protocol (qz_status, qz_pose out; qz_command in).

    .. pydrake_system::

        name: QingzhuiRobotDriver
        output_ports:
        - true_state
        - foot_contact
        - trunk_contact
        - foot_normal_force
        - contact_results
        - body_poses
        - safe_stop

    The outputs are the simulation's truth for monitors and metrics; a controller sees the
    robot only through LCM.

    Args:
        scenario: the scenario (terrain, robot, control mode, plant step).
        lcm: the LCM instance; the diagram pumps it with an LcmInterfaceSystem.
        config: protocol settings; defaults if None.
        meshcat, mesh_dir: passed to make_station.
        status_filter, pose_filter: hooks on the published messages (see StatusPublisher).
    """

    def __init__(self, *, scenario: Scenario, lcm: DrakeLcm, config: HardwareConfig | None = None,
                 meshcat=None, mesh_dir=None, status_filter=None, pose_filter=None):
        super().__init__()
        config = validate_hardware_config(config or HardwareConfig())
        if abs(config.control_period - scenario.simulation.time_step) > 1e-12:
            from qz_drake.errors import bad_value

            raise bad_value("hardware.control_period", config.control_period,
                            f"the simulated driver ticks with the plant: use scenario.simulation.time_step "
                            f"({scenario.simulation.time_step} s)")
        self.config = config
        position_mode = scenario.station.control_mode == "position"
        builder = DiagramBuilder()
        station_diagram, self.info = make_sim_station(scenario, meshcat, mesh_dir=mesh_dir)
        station = builder.AddSystem(station_diagram)
        builder.AddSystem(LcmInterfaceSystem(lcm))
        subscriber = builder.AddSystem(LcmSubscriberSystem(config.channels.command,
                                                           EncodedMessageSerializer(qz_command), lcm))
        self._receiver = builder.AddSystem(CommandReceiver(config=config, params=self.info.params,
                                                           position_mode=position_mode))
        self._receiver.set_name("command_receiver")
        publisher = builder.AddSystem(StatusPublisher(lcm=lcm, config=config, status_filter=status_filter,
                                                      pose_filter=pose_filter))
        publisher.set_name("status_publisher")
        self._publisher = publisher
        builder.Connect(subscriber.get_output_port(), self._receiver.GetInputPort("lcm_command"))
        builder.Connect(station.GetOutputPort("state"), self._receiver.GetInputPort("state"))
        builder.Connect(self._receiver.GetOutputPort("joint_torque"), station.GetInputPort("joint_torque"))
        if position_mode:
            builder.Connect(self._receiver.GetOutputPort("joint_position_command"),
                            station.GetInputPort("joint_position_command"))
            builder.Connect(self._receiver.GetOutputPort("joint_velocity_command"),
                            station.GetInputPort("joint_velocity_command"))
        for name in ("state", "joint_torque_measured", "imu", "foot_contact"):
            builder.Connect(station.GetOutputPort(name), publisher.GetInputPort(name))
        builder.Connect(self._receiver.GetOutputPort("safe_stop"), publisher.GetInputPort("safe_stop"))
        builder.ExportOutput(station.GetOutputPort("state"), "true_state")
        for name in ("foot_contact", "trunk_contact", "foot_normal_force", "contact_results", "body_poses",
                     "joint_torque_measured"):
            builder.ExportOutput(station.GetOutputPort(name), name)
        builder.ExportOutput(self._receiver.GetOutputPort("safe_stop"), "safe_stop")
        builder.BuildInto(self)
        self.set_name("robot_driver")

    def command_state(self, root_context) -> DriverCommandState:
        return self._receiver.applied(self._receiver.GetMyContextFromRoot(root_context))

    def counters(self, root_context) -> dict:
        """The command link's watchdog counters and the clamp counts, for metrics."""
        s = self.command_state(root_context)
        return {**s.link.counters(), "safe_stop_latched": s.link.latched, "safe_stop_reason": s.link.reason,
                "safe_stop_time_s": s.link.latched_time if s.link.latched else None,
                "holding": s.holding, "clamped_commands": s.clamped_commands,
                "clamped_torques": s.clamped_torques, "clamped_positions": s.clamped_positions,
                "mean_loop_delay_periods": s.loop_delay_sum / s.answered if s.answered else None,
                "longest_loop_delay_periods": s.loop_delay_max, **self._publisher.timing.summary()}

    def reset_safe_stop(self, root_context) -> None:
        self._receiver.reset(self._receiver.GetMyMutableContextFromRoot(root_context))
