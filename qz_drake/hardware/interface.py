"""QingzhuiHardwareInterface: the station's ports over LCM (paper 000 II-C: the same BLC and
tracking run in simulation and on the robot).

``make_station(scenario, meshcat, backend="lcm", lcm_url=...)`` returns this Diagram in place
of the MultibodyPlant station, with the same ports: ``joint_torque`` (and
``joint_position_command`` in position mode) in; ``state``, ``joint_torque_measured``, ``imu``,
``foot_contact`` out. Inside, Drake's LcmSubscriberSystem / LcmPublisherSystem on a DrakeLcm
and two small LeafSystems: StatusReceiver (decoder, watchdog, base-state estimator) and
CommandSender (encoder, safe stop).

The base state. A robot does not measure its base pose; the ``state`` port is assembled from
the IMU (orientation, angular velocity, at the control rate: what the joint PD's gravity
compensation needs, fresh) and the localisation's qz_pose topic (base position and velocity
in the map, extrapolated by its velocity to the status time). On Qingzhui that topic is the
LiDAR odometry the paper localises with (LeGO-LOAM) or a mocap system; the simulated driver
publishes the simulator's ground truth. Leg odometry was the alternative and was not chosen:
the feet are rolling spheres that carry the body a centimetre per step (see the IK tracker's
roll compensation), so its position drifts by decimetres over a route, while the missions are
planned in the map frame the localisation provides.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.lcm import DrakeLcm
from pydrake.systems.framework import BasicVector, Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.lcm import LcmInterfaceSystem, LcmPublisherSystem, LcmSubscriberSystem

from qz_drake.config import Scenario
from qz_drake.hardware.codec import (EncodedMessageSerializer, decode, joint_limits, message_key, pose_problem,
                                     status_problem)
from qz_drake.hardware.config import HardwareConfig, validate_hardware_config
from qz_drake.hardware.pacer import StatusPacer
from qz_drake.hardware.qz_lcm import qz_command, qz_pose, qz_status
from qz_drake.hardware.watchdog import (LinkState, WatchdogLimits, declare_message_intake, latch_watchdog,
                                       reset_watchdog, step_watchdog)
from qz_drake.robot.params import DEFAULT_PARAMS, NUM_JOINTS, NUM_LEGS, QingzhuiParams
from qz_drake.robot.topology import get_topology
from qz_drake.scene import StationInfo, crop_to_region, default_region, make_heightmap, standing_state
from qz_drake.state_layout import (BASE_ANGVEL, BASE_POS, BASE_QUAT, BASE_VEL, IMU_SIZE,
                                           JOINT_Q, JOINT_V, STATE_SIZE)

# Offsets within a control period (see qz_drake.hardware.config): the interface decodes at
# half a period and publishes its command at three quarters.
RECEIVE_PHASE = 0.5
COMMAND_PHASE = 0.75

# The held measurement vector of StatusReceiver: state, measured torque, IMU, contacts,
# driver's safe-stop flag.
_TAU = slice(STATE_SIZE, STATE_SIZE + NUM_JOINTS)
_IMU = slice(_TAU.stop, _TAU.stop + IMU_SIZE)
_CONTACT = slice(_IMU.stop, _IMU.stop + NUM_LEGS)
_DRIVER_STOP = _CONTACT.stop
_HELD_SIZE = _DRIVER_STOP + 1


@dataclasses.dataclass(frozen=True)
class PoseTrack:
    """The newest accepted qz_pose and the pose topic's counters."""

    last_key: tuple[int, int] = (0, 0)
    have_pose: bool = False
    utime: int = 0
    position: tuple[float, ...] = (0.0, 0.0, 0.0)
    velocity: tuple[float, ...] = (0.0, 0.0, 0.0)
    received: int = 0
    rejected: int = 0
    # Statuses decoded with no pose yet, or one older than max_pose_extrapolation.
    stale: int = 0

    def __deepcopy__(self, memo):  # immutable: Drake's state copies may share it
        return self


class StatusReceiver(LeafSystem):
    """Decodes qz_status and qz_pose into the station's output vectors, with the watchdog.

    .. pydrake_system::

        name: StatusReceiver
        input_ports:
        - lcm_status
        - lcm_pose
        output_ports:
        - state
        - joint_torque_measured
        - imu
        - foot_contact
        - watchdog
        - driver_safe_stop

    Once per control period (at half a period) the newest status is checked (sizes, finite
    values, joint limits) and passed through the watchdog (freshness, sequence, driver clock;
    qz_drake.hardware.watchdog). An accepted status updates the held outputs; a rejected one
    leaves them as they were (it counts as stale) and latches a safe stop, as does every other
    fault. ``watchdog`` is the LinkState (abstract) for CommandSender; ``driver_safe_stop`` the
    driver's own flag from the status. Until the first status the outputs hold ``prior_state``
    (the scenario's expected standing state) and the commands are safe stops.

    Args:
        config: protocol settings (period, timeouts, limits).
        params: the robot's parameters (joint limits).
        prior_state: station state (49) to output before the first status.
    """

    def __init__(self, *, config: HardwareConfig, params: QingzhuiParams, prior_state: np.ndarray):
        super().__init__()
        self._config = config
        self._limits = WatchdogLimits(timeout=config.status_timeout,
                                      clock_tolerance=config.clock_tolerance, message="status")
        self._lower, self._upper = joint_limits(params)
        # Encoded messages (bytes, see EncodedMessageSerializer).
        self._status = self.DeclareAbstractInputPort("lcm_status", AbstractValue.Make(b""))
        self._pose = self.DeclareAbstractInputPort("lcm_pose", AbstractValue.Make(b""))
        self._held = self.DeclareDiscreteState(initial_held(prior_state))
        self._link = self.DeclareAbstractState(AbstractValue.Make(LinkState()))
        self._pose_track = self.DeclareAbstractState(AbstractValue.Make(PoseTrack()))
        period = config.control_period
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, RECEIVE_PHASE * period, self._update)
        declare_message_intake(self, period, RECEIVE_PHASE)
        for name, part in (("state", slice(0, STATE_SIZE)), ("joint_torque_measured", _TAU),
                           ("imu", _IMU), ("foot_contact", _CONTACT)):
            self.DeclareVectorOutputPort(name, part.stop - part.start, self._held_output(part),
                                         prerequisites_of_calc={self.discrete_state_ticket(self._held)})
        self.DeclareAbstractOutputPort("watchdog", lambda: AbstractValue.Make(LinkState()), self._calc_watchdog,
                                       prerequisites_of_calc={self.abstract_state_ticket(self._link)})
        self.DeclareVectorOutputPort("driver_safe_stop", 1, self._held_output(slice(_DRIVER_STOP, _HELD_SIZE)),
                                     prerequisites_of_calc={self.discrete_state_ticket(self._held)})

    def _held_output(self, part: slice):
        def calc(context, output: BasicVector):
            output.SetFromVector(context.get_discrete_state(self._held).get_value()[part])
        return calc

    def _calc_watchdog(self, context, output):
        output.set_value(context.get_abstract_state(self._link).get_value())

    def link_state(self, context) -> LinkState:
        return context.get_abstract_state(self._link).get_value()

    def pose_track(self, context) -> PoseTrack:
        return context.get_abstract_state(self._pose_track).get_value()

    def reset(self, context) -> None:
        """Unlatches the safe stop (operator action); ``context`` is this system's."""
        state = context.get_mutable_abstract_state(self._link)
        state.set_value(reset_watchdog(state.get_value()))

    def latch(self, context, reason: str) -> None:
        """Latches the safe stop with ``reason`` (``context`` is this system's)."""
        state = context.get_mutable_abstract_state(self._link)
        state.set_value(latch_watchdog(state.get_value(), reason, context.get_time()))

    def _update(self, context, state):
        t = context.get_time()
        track = self._update_pose(context, context.get_abstract_state(self._pose_track).get_value())
        state.get_mutable_abstract_state(self._pose_track).set_value(track)
        link = context.get_abstract_state(self._link).get_value()
        data = self._status.Eval(context)
        m, problem = decode(qz_status, data)
        key = message_key(m, problem, data)
        if m is not None and key != link.last_key:
            problem = status_problem(m, self._lower, self._upper, self._config.joint_limit_margin)
        link, accepted = step_watchdog(link, key, problem, t, self._limits)
        state.get_mutable_abstract_state(self._link).set_value(link)
        if accepted:
            state.get_mutable_discrete_state(self._held).set_value(self._decode(m, track, context))
            if not track.have_pose or (m.utime - track.utime) * 1e-6 > self._config.max_pose_extrapolation:
                state.get_mutable_abstract_state(self._pose_track).set_value(
                    dataclasses.replace(track, stale=track.stale + 1))

    def _update_pose(self, context, track: PoseTrack) -> PoseTrack:
        return updated_pose_track(track, self._pose.Eval(context))

    def _decode(self, m: qz_status, track: PoseTrack, context) -> np.ndarray:
        held = context.get_discrete_state(self._held).get_value().copy()
        return decoded_status(held, m, track, self._config.max_pose_extrapolation)


def initial_held(prior_state: np.ndarray) -> np.ndarray:
    """A receiver's held vector before the first status: the expected state, a level IMU at
    rest, every foot down, no safe stop."""
    held = np.zeros(_HELD_SIZE)
    held[:STATE_SIZE] = prior_state
    held[_IMU] = [1, 0, 0, 0, 0, 0, 0, 0, 0, 9.81]
    held[_CONTACT] = 1.0
    return held


def updated_pose_track(track: PoseTrack, data: bytes) -> PoseTrack:
    """The pose track after the newest encoded qz_pose (``data``; b"" before the first)."""
    p, problem = decode(qz_pose, data)
    key = message_key(p, problem, data)
    if key == (0, 0) or key == track.last_key:
        return track
    if problem or pose_problem(p):
        return dataclasses.replace(track, last_key=key, received=track.received + 1,
                                   rejected=track.rejected + 1)
    return PoseTrack(last_key=key, have_pose=True, utime=key[0], position=tuple(p.position),
                     velocity=tuple(p.linear_velocity), received=track.received + 1,
                     rejected=track.rejected, stale=track.stale)


def decoded_status(held: np.ndarray, m: qz_status, track: PoseTrack, max_pose_extrapolation: float) -> np.ndarray:
    """``held`` (a StatusReceiver's held vector: state, measured torque, IMU, contacts, the
    driver's flag) updated in place from a checked status and the pose track; returns it."""
    # Plain floats where numpy's per-call overhead would dominate 3- and 4-vectors.
    w, qx, qy, qz = m.orientation
    norm = math.sqrt(w * w + qx * qx + qy * qy + qz * qz)
    w, qx, qy, qz = w / norm, qx / norm, qy / norm, qz / norm
    held[BASE_QUAT] = (w, qx, qy, qz)
    # R_WB of the unit quaternion, applied to the gyro's base-frame rate: w_WB in world.
    R_WB = np.array([[1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - w * qz), 2 * (qx * qz + w * qy)],
                     [2 * (qx * qy + w * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - w * qx)],
                     [2 * (qx * qz - w * qy), 2 * (qy * qz + w * qx), 1 - 2 * (qx * qx + qy * qy)]])
    held[BASE_ANGVEL] = R_WB @ m.angular_velocity
    held[JOINT_Q] = m.joint_position
    held[JOINT_V] = m.joint_velocity
    if track.have_pose:
        # The pose may be older than the status (a slower localisation): carry it forward.
        age = min(max((m.utime - track.utime) * 1e-6, 0.0), max_pose_extrapolation)
        held[BASE_POS] = [p + age * v for p, v in zip(track.position, track.velocity)]
        held[BASE_VEL] = track.velocity
    held[_TAU] = m.joint_torque
    held[_IMU.start:_IMU.start + 4] = held[BASE_QUAT]
    held[_IMU.start + 4:_IMU.stop] = m.angular_velocity + m.linear_acceleration
    held[_CONTACT] = m.foot_contact
    held[_DRIVER_STOP] = m.safe_stop
    return held


class CommandSender(LeafSystem):
    """Encodes the controller's joint commands as qz_command, or a safe stop.

    .. pydrake_system::

        name: CommandSender
        input_ports:
        - joint_torque
        - joint_position_command (position mode)
        - joint_velocity_command (position mode)
        - watchdog
        output_ports:
        - lcm_command

    While the watchdog is latched, or before the first status, the command is MODE_SAFE_STOP
    (the driver holds the joint angles it measures when the stop begins) and the controller's
    inputs are not evaluated. In a period without a new status (one lost or late, the link
    still within its time budget) the command computed from the last status is sent again:
    the controller's output against a measurement that stood still while its reference moved
    on let the robot sink 3.8 cm in a 21 ms outage during a tripod swing, the last command
    0.7 cm. ``joint_torque`` left unconnected is zero.

    Args:
        config: protocol settings (period).
        position_mode: send MODE_POSITION (joint_position_command and
            joint_velocity_command for the drives' PD, joint_torque as feedforward) instead of
            MODE_TORQUE.
        command_filter: a hook that may alter (fault tests) or observe (benchmarks)
            each command before it is published.
    """

    def __init__(self, *, config: HardwareConfig, position_mode: bool,
                 command_filter: Callable[[qz_command], qz_command] | None = None):
        super().__init__()
        self._period = config.control_period
        self._position_mode = position_mode
        self._filter = command_filter
        self._torque = self.DeclareVectorInputPort("joint_torque", NUM_JOINTS)
        self._position = (self.DeclareVectorInputPort("joint_position_command", NUM_JOINTS)
                          if position_mode else None)
        self._velocity = (self.DeclareVectorInputPort("joint_velocity_command", NUM_JOINTS)
                          if position_mode else None)
        self._watchdog = self.DeclareAbstractInputPort("watchdog", AbstractValue.Make(LinkState()))
        # The last command computed from a new status (encoded; b"" before the first).
        self._last_good = self.DeclareAbstractState(AbstractValue.Make(b""))
        self.DeclarePeriodicUnrestrictedUpdateEvent(self._period, COMMAND_PHASE * self._period, self._keep)
        # The encoded message (bytes, see EncodedMessageSerializer).
        self.DeclareAbstractOutputPort("lcm_command", lambda: AbstractValue.Make(b""), self._calc_command)

    def _new_status(self, link: LinkState, t: float) -> bool:
        """A status came since the last command (it is read half a period before a command)."""
        return link.armed and not link.latched and t - link.received_time < self._period

    def _fill_from_controller(self, m: qz_command, context) -> None:
        m.mode = qz_command.MODE_POSITION if self._position_mode else qz_command.MODE_TORQUE
        m.num_joints = NUM_JOINTS
        tau = self._torque.Eval(context) if self._torque.HasValue(context) else np.zeros(NUM_JOINTS)
        m.joint_torque = tau.tolist()
        m.joint_position = self._position.Eval(context).tolist() if self._position_mode else [0.0] * NUM_JOINTS
        m.joint_velocity = self._velocity.Eval(context).tolist() if self._position_mode else [0.0] * NUM_JOINTS

    def _keep(self, context, state):
        # After the period's command went out (a publish precedes the updates of its time).
        if self._new_status(self._watchdog.Eval(context), context.get_time()):
            m = qz_command()
            self._fill_from_controller(m, context)
            state.get_mutable_abstract_state(self._last_good).set_value(m.encode())

    def _calc_command(self, context, output):
        t = context.get_time()
        link: LinkState = self._watchdog.Eval(context)
        last_good = context.get_abstract_state(self._last_good).get_value()
        m = qz_command()
        if link.latched or not link.armed:
            m.mode = qz_command.MODE_SAFE_STOP
        elif self._new_status(link, t) or not last_good:
            self._fill_from_controller(m, context)
        else:
            m = qz_command.decode(last_good)
        m.utime = int(round(t * 1e6))
        m.sequence = int(round(t / self._period - COMMAND_PHASE)) + 1
        m.status_sequence = link.sequence
        if self._filter is not None:
            m = self._filter(m)
        output.set_value(m.encode())


class QingzhuiHardwareInterface(Diagram):
    """The station over LCM: the ports of qz_drake.station, talking to a robot driver.

    .. pydrake_system::

        name: QingzhuiHardwareInterface
        input_ports:
        - joint_torque
        - joint_position_command (position mode)
        output_ports:
        - state
        - joint_torque_measured
        - imu
        - foot_contact

    Exactly the simulation station's controller ports; the watchdog's state and counters are
    read with ``watchdog`` and ``counters``, and ``reset_safe_stop`` unlatches.

    Args:
        scenario: the scenario (control mode; the expected start state before the first status).
        lcm: the LCM instance (DrakeLcm(url)); the diagram pumps it with an LcmInterfaceSystem.
        config: protocol settings; defaults if None.
        params: the robot's parameters (joint limits).
        prior_state: the state to output before the first status.
        command_filter: a hook that may alter (fault tests) or observe (benchmarks)
            each command before it is published.
        pace_on_status: wait for each status before reading it (StatusPacer): for a driver
            in another process; not in the lockstep memq:// diagram.
    """

    def __init__(self, *, scenario: Scenario, lcm: DrakeLcm, config: HardwareConfig | None = None,
                 params: QingzhuiParams, prior_state: np.ndarray,
                 command_filter: Callable[[qz_command], qz_command] | None = None, pace_on_status: bool = False):
        super().__init__()
        config = validate_hardware_config(config or HardwareConfig())
        self.config = config
        position_mode = scenario.station.control_mode == "position"
        builder = DiagramBuilder()
        builder.AddSystem(LcmInterfaceSystem(lcm))
        status = builder.AddSystem(LcmSubscriberSystem(config.channels.status,
                                                       EncodedMessageSerializer(qz_status), lcm))
        pose = builder.AddSystem(LcmSubscriberSystem(config.channels.pose, EncodedMessageSerializer(qz_pose), lcm))
        self._receiver = builder.AddSystem(StatusReceiver(config=config, params=params, prior_state=prior_state))
        self._receiver.set_name("status_receiver")
        sender = builder.AddSystem(CommandSender(config=config, position_mode=position_mode,
                                                 command_filter=command_filter))
        sender.set_name("command_sender")
        publisher = builder.AddSystem(LcmPublisherSystem(
            channel=config.channels.command, serializer=EncodedMessageSerializer(qz_command), lcm=lcm,
            publish_period=config.control_period, publish_offset=COMMAND_PHASE * config.control_period))
        if pace_on_status:
            pacer = builder.AddSystem(StatusPacer(lcm=lcm, subscriber=status, period=config.control_period,
                                                  read_phase=RECEIVE_PHASE))
            pacer.set_name("status_pacer")
            builder.Connect(self._receiver.GetOutputPort("watchdog"), pacer.GetInputPort("watchdog"))
        builder.Connect(status.get_output_port(), self._receiver.GetInputPort("lcm_status"))
        builder.Connect(pose.get_output_port(), self._receiver.GetInputPort("lcm_pose"))
        builder.Connect(self._receiver.GetOutputPort("watchdog"), sender.GetInputPort("watchdog"))
        builder.Connect(sender.GetOutputPort("lcm_command"), publisher.get_input_port())
        builder.ExportInput(sender.GetInputPort("joint_torque"), "joint_torque")
        if position_mode:
            builder.ExportInput(sender.GetInputPort("joint_position_command"), "joint_position_command")
            builder.ExportInput(sender.GetInputPort("joint_velocity_command"), "joint_velocity_command")
        for name in ("state", "joint_torque_measured", "imu", "foot_contact"):
            builder.ExportOutput(self._receiver.GetOutputPort(name), name)
        builder.BuildInto(self)
        self.set_name("lcm_station")

    def watchdog(self, root_context) -> LinkState:
        """The status link's watchdog state (latch, reason, counters)."""
        return self._receiver.link_state(self._receiver.GetMyContextFromRoot(root_context))

    def counters(self, root_context) -> dict:
        """Watchdog counters of the status link and the pose topic's, for metrics."""
        context = self._receiver.GetMyContextFromRoot(root_context)
        link = self._receiver.link_state(context)
        track = self._receiver.pose_track(context)
        driver_stop = self._receiver.GetOutputPort("driver_safe_stop").Eval(context)[0] > 0.5
        return {**link.counters(), "safe_stop_latched": link.latched, "safe_stop_reason": link.reason,
                "driver_safe_stop": bool(driver_stop),
                "safe_stop_time_s": link.latched_time if link.latched else None,
                "pose_received": track.received, "pose_rejected": track.rejected, "pose_stale": track.stale}

    def reset_safe_stop(self, root_context) -> None:
        """Unlatches the safe stop (operator action); the next valid status re-arms."""
        self._receiver.reset(self._receiver.GetMyMutableContextFromRoot(root_context))

    def latch_safe_stop(self, root_context, reason: str) -> None:
        """Latches the safe stop for a cause outside the link (the servo's planner gone): the
        commands are safe stops from the next period on, until ``reset_safe_stop``."""
        self._receiver.latch(self._receiver.GetMyMutableContextFromRoot(root_context), reason)


def scenario_station_info(scenario: Scenario) -> StationInfo:
    """What make_station's StationInfo holds, known from the scenario alone (no plant): the
    cropped map, the robot's parameters, the topology, the expected standing start."""
    heightmap = make_heightmap(scenario.terrain, scenario.random_seed)
    heightmap = crop_to_region(heightmap, scenario.terrain.region or default_region(scenario))
    params = dataclasses.replace(DEFAULT_PARAMS, payload_mass=scenario.robot.payload_kg)
    topology = get_topology(scenario.robot.topology, params)
    x0 = standing_state(heightmap, topology, scenario.robot.initial_xy, scenario.robot.initial_yaw, params)
    return StationInfo(heightmap=heightmap, contact_representation="lcm", params=params, topology=topology,
                       initial_state=x0)


def make_hardware_interface(scenario: Scenario, meshcat=None, *, lcm_url: str = "memq://",
                            lcm: DrakeLcm | None = None, config: HardwareConfig | None = None,
                            command_filter=None):
    """make_station's "lcm" backend: (QingzhuiHardwareInterface, StationInfo).

    The StationInfo holds what a controller knows before it runs: the scenario's map, robot
    parameters, topology and the expected standing start (``contact_representation`` is
    "lcm"). ``meshcat`` is unused (the robot is not drawn from here). On any LCM but the
    in-process ``memq://`` the interface keeps time with the driver's statuses (StatusPacer).
    """
    info = scenario_station_info(scenario)
    lcm = lcm if lcm is not None else DrakeLcm(lcm_url)
    interface = QingzhuiHardwareInterface(scenario=scenario, lcm=lcm, config=config, params=info.params,
                                          prior_state=info.initial_state, command_filter=command_filter,
                                          pace_on_status=not lcm.get_lcm_url().startswith("memq://"))
    interface.lcm = lcm
    return interface, info
