"""The servo: the joint PD answering every robot status from references a planner sent ahead.

On the robot the control loop must answer each status within a period, whatever the planners
do: a BLC solve takes 0.1-2 s, and a process that solves it cannot also answer statuses (a
walk at real time ended in a safe stop 4.9 s in, the status clock 0.4 s behind). So the stack
runs in two processes:

* the **servo** (this module, ``qz servo``): QingzhuiHardwareInterface, Eq. 7's joint PD and a
  ReferencePlayer that reads the tracker's references from tables (qz_reference); nothing in it
  takes longer than a period;
* the **planning process** (``qz simulate --station lcm`` at a network URL): the route source,
  the BLC and the tracker in the same diagram as in the lockstep simulation, with a station
  that sends each plan's references to the servo (``planning_station.PlanningLcmStation``).

The plan clock. The planning process's simulated time is the plan time; the servo reads its
references at a plan time tau that runs with the robot's clock while references reach
further, and stands still when they do not and the planning process has not yet handled
every event up to tau + h (it announces how far it has, in qz_planner): a mission that is not
planned by the time the current one ends holds the current plan's end stance (the robot
stands, as paper 000's robot does while its BLC solves), and the hold is counted ("late
holds"). The planning process runs its simulation no further than a small lead ahead of tau
(qz_servo), so the plan time and the robot's time differ only by the stances held.

A planner that falls silent (no heartbeat for ``HardwareConfig.planner_timeout``; a process
that exits) latches the interface's safe stop with that reason: the robot holds its joints.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import signal
import time

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.lcm import DrakeLcm
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import BasicVector, DiagramBuilder, LeafSystem

from qz_drake.config import Scenario
from qz_drake.hardware.codec import encoded_key
from qz_drake.hardware.config import HardwareConfig, validate_hardware_config
from qz_drake.hardware.interface import COMMAND_PHASE, RECEIVE_PHASE, make_hardware_interface
from qz_drake.hardware.qz_lcm import qz_planner, qz_servo
from qz_drake.hardware.references import (CONTACT, DESIRED_STATE, FORCES, Q_DES, V_DES, ReferenceTable,
                                          decode_table, standing_row)
from qz_drake.hardware.scheduling import SteadyCollector
from qz_drake.robot.params import NUM_LEGS
from qz_drake.scene import GRAVITY
from qz_drake.state_layout import JOINT_Q
from qz_drake.systems.joint_pd import add_joint_pd

# The player moves its plan clock between the interface's status read (RECEIVE_PHASE) and its
# command (COMMAND_PHASE), so that a command reads the references of its own period.
PLAYER_PHASE = 0.5 * (RECEIVE_PHASE + COMMAND_PHASE)
# The player tells the planning process its state (qz_servo) after the command is out, every
# REPORT_PERIODS control periods (100 Hz at 500 Hz).
REPORT_PHASE = 0.5 * (COMMAND_PHASE + 1.0)
REPORT_PERIODS = 5
# The references' update period the tables carry (the IK tracker's 200 Hz). [s]
REFERENCE_PERIOD = 0.005


@dataclasses.dataclass(frozen=True)
class PlayerState:
    """What the ReferencePlayer knows; immutable (a Drake abstract state)."""

    table: ReferenceTable
    # The plan time the references are read at. [s]
    plan_time: float = 0.0
    # How far the planning process has handled its events (its heartbeat). [s]
    planner_time: float = -math.inf
    # The newest heartbeat's key (utime, sequence) and when it came (servo time). [s]
    heartbeat_key: tuple[int, int] = (0, 0)
    heartbeat_time: float = -math.inf
    finished: bool = False
    tables: int = 0
    holding: bool = False
    # The servo time the current hold began at. [s]
    hold_start: float = math.nan
    late_holds: int = 0
    late_hold_time: float = 0.0
    longest_late_hold: float = 0.0
    # Why the planner cannot be followed ("" while it can; the interface's latch records when).
    fault: str = ""
    # The safe stop latched on the servo's interface, whatever latched it ("" while none).
    safe_stop: str = ""
    # The newest robot status taken in when the plan clock last moved (its utime). [us]
    status_utime: int = 0

    def __deepcopy__(self, memo):
        return self

    def counters(self, t: float) -> dict:
        """The counters at servo time t (a hold still going on counted to t)."""
        ongoing = t - self.hold_start if self.holding else 0.0
        return {"plan_time_s": self.plan_time, "reference_end_s": self.table.end_time, "tables": self.tables,
                "late_holds": self.late_holds, "late_hold_time_s": self.late_hold_time + ongoing,
                "longest_late_hold_s": max(self.longest_late_hold, ongoing), "holding": self.holding,
                "planner_finished": self.finished, "planner_fault": self.fault}


class ReferencePlayer(LeafSystem):
    """The IK tracker's outputs, read from the tables a planning process sends (qz_reference).

    .. pydrake_system::

        name: ReferencePlayer
        output_ports:
        - desired_state
        - foot_force_feedforward
        - position_command
        - velocity_command
        - contact_plan

    The ports are the InverseKinematicsTracker's, so the joint PD is wired to it as to the
    tracker. Once a period (between the interface's status read and its command) the player
    takes in the tables and the planner's heartbeat that came, moves its plan clock (module
    doc) and holds the row in force. Before any table it holds ``standing``. It publishes its
    state (qz_servo) every REPORT_PERIODS periods, after the command. Tables and heartbeats arrive through ``lcm`` subscriptions
    (every table is kept: a table replaces the rows from its start on, so none may be lost, and
    Drake's LcmSubscriberSystem keeps only the newest message).

    Args:
        lcm: the servo's LCM (the interface's, pumped by its diagram).
        config: protocol settings (period, channels, planner_timeout).
        standing: the reference row held before the first table (references.standing_row).
    """

    def __init__(self, *, lcm: DrakeLcm, config: HardwareConfig, standing: np.ndarray):
        super().__init__()
        self._lcm = lcm
        self._config = config
        self._period = config.control_period
        self._inbox: list[bytes] = []
        self._heartbeat = [b""]
        self._status_utime = [0]
        lcm.Subscribe(config.channels.reference, self._inbox.append)
        lcm.Subscribe(config.channels.planner, self._keep_heartbeat)
        lcm.Subscribe(config.channels.status, self._keep_status_time)
        first = ReferenceTable(start_time=0.0, period=REFERENCE_PERIOD, rows=np.asarray(standing, float)[None])
        self._state = self.DeclareAbstractState(AbstractValue.Make(PlayerState(table=first)))
        self._row = self.DeclareDiscreteState(np.asarray(standing, dtype=float))
        self.DeclarePeriodicUnrestrictedUpdateEvent(self._period, PLAYER_PHASE * self._period, self._update)
        self.DeclareInitializationDiscreteUpdateEvent(self._initial_row)
        # After the period's command has gone (COMMAND_PHASE): the planning process waits for
        # this message, the robot for the command. Every REPORT_PERIODS periods: the planning
        # process looks at the plan clock every 10 ms, and each message is work for the relay.
        self.DeclarePeriodicPublishEvent(REPORT_PERIODS * self._period, REPORT_PHASE * self._period, self._publish)
        held = {self.discrete_state_ticket(self._row)}
        for name, part in (("desired_state", DESIRED_STATE), ("foot_force_feedforward", FORCES),
                           ("position_command", Q_DES), ("velocity_command", V_DES), ("contact_plan", CONTACT)):
            self.DeclareVectorOutputPort(name, part.stop - part.start, self._held(part), held)

    def _keep_heartbeat(self, data: bytes) -> None:
        self._heartbeat[0] = data

    def _keep_status_time(self, data: bytes) -> None:
        self._status_utime[0] = encoded_key(data)[0]

    def _held(self, part: slice):
        def calc(context, output: BasicVector):
            output.SetFromVector(context.get_discrete_state(self._row).get_value()[part])
        return calc

    def _initial_row(self, context, discrete_state):
        state: PlayerState = context.get_abstract_state(self._state).get_value()
        discrete_state.set_value(self._row, state.table.row_at(state.plan_time))

    def player_state(self, context) -> PlayerState:
        return context.get_abstract_state(self._state).get_value()

    def _take_in(self, s: PlayerState, t: float) -> PlayerState:
        inbox, self._inbox[:] = list(self._inbox), []
        for data in inbox:
            try:
                _, table = decode_table(data)
            except ValueError as e:
                return dataclasses.replace(s, fault=s.fault or f"malformed reference table: {e}")
            s = dataclasses.replace(s, table=s.table.merged(table), tables=s.tables + 1)
        data = self._heartbeat[0]
        if data:
            try:
                m = qz_planner.decode(data)
            except ValueError as e:
                return dataclasses.replace(s, fault=s.fault or f"malformed planner heartbeat: {e}")
            if (m.utime, m.sequence) != s.heartbeat_key:
                s = dataclasses.replace(s, heartbeat_key=(m.utime, m.sequence), heartbeat_time=t,
                                        planner_time=max(s.planner_time, m.plan_time),
                                        finished=s.finished or bool(m.finished))
        return s

    def _update(self, context, state):
        t = context.get_time()
        s = self._take_in(context.get_abstract_state(self._state).get_value(), t)
        silence = t - s.heartbeat_time
        if (not s.fault and not s.finished and math.isfinite(s.heartbeat_time)
                and silence > self._config.planner_timeout):
            s = dataclasses.replace(s, fault=f"planner silent for {silence:.3f} s (timeout "
                                             f"{self._config.planner_timeout} s): its process stopped or hung")
        step = self._period
        reach = max(s.table.end_time, s.planner_time)
        if s.plan_time + step <= reach + 1e-9:
            if s.holding:
                held = t - s.hold_start
                s = dataclasses.replace(s, holding=False, late_hold_time=s.late_hold_time + held,
                                        longest_late_hold=max(s.longest_late_hold, held))
            s = dataclasses.replace(s, plan_time=s.plan_time + step)
        else:
            # Up to the last row, and no further: the robot stands on it.
            s = dataclasses.replace(s, plan_time=max(s.plan_time, reach))
            if not s.holding and math.isfinite(s.planner_time) and not s.finished:
                # The planning process is behind the robot.
                s = dataclasses.replace(s, holding=True, hold_start=t, late_holds=s.late_holds + 1)
        s = dataclasses.replace(s, status_utime=self._status_utime[0])
        if s.table.start_time < s.plan_time - 1.0:  # rows long past are no longer needed
            s = dataclasses.replace(s, table=s.table.after(s.plan_time))
        state.get_mutable_abstract_state(self._state).set_value(s)
        state.get_mutable_discrete_state(self._row).set_value(s.table.row_at(s.plan_time))

    def _publish(self, context):
        self._lcm.Publish(self._config.channels.servo, self.status_message(context).encode())

    def status_message(self, context, *, report: str = "") -> qz_servo:
        """qz_servo of the player's state; the last one carries the servo's ``report``."""
        s: PlayerState = context.get_abstract_state(self._state).get_value()
        t = context.get_time()
        m = qz_servo()
        # One a report period; the last one (the report) one more.
        m.utime = int(round(t * 1e6))
        m.sequence = int(round((t / self._period - REPORT_PHASE) / REPORT_PERIODS)) + 1 + bool(report)
        m.status_utime, m.plan_time, m.reference_end, m.holding = s.status_utime, s.plan_time, s.table.end_time, s.holding
        m.late_holds, m.late_hold_time, m.longest_late_hold = s.late_holds, s.late_hold_time, s.longest_late_hold
        m.safe_stop, m.reason, m.report = bool(s.safe_stop), s.safe_stop, report
        return m

    def note_safe_stop(self, context, reason: str) -> None:
        """Records the safe stop latched on the servo's interface (``context`` is this system's),
        so that its messages tell the planning process."""
        state = context.get_mutable_abstract_state(self._state)
        state.set_value(dataclasses.replace(state.get_value(), safe_stop=reason))


class LatencyRecorder:
    """Status -> command latency as the servo's process sees it: from the moment a status is
    taken in (its LCM subscription's callback, as the interface's pacer pumps) to the publish of
    the command that answers it (the interface's command hook), and the wall time between two
    commands. Statuses are matched by sequence number, read from the encoded message."""

    def __init__(self, lcm: DrakeLcm, channel: str):
        self._arrivals: dict[int, float] = {}
        self.latencies: list[float] = []
        self.gaps: list[float] = []
        self.longest_status_gap = 0.0
        self._last_status = math.inf  # (no gap before the first)
        self._last_command = math.nan
        lcm.Subscribe(channel, self._on_status)

    def _on_status(self, data: bytes) -> None:
        sequence = encoded_key(data)[1]
        now = time.monotonic()
        self.longest_status_gap = max(self.longest_status_gap, now - self._last_status)
        self._last_status = now
        self._arrivals[sequence] = now
        if len(self._arrivals) > 64:  # only the newest few can still be answered
            for key in sorted(self._arrivals)[:-32]:
                del self._arrivals[key]

    def on_command(self, m):
        now = time.monotonic()
        arrival = self._arrivals.get(m.status_sequence)
        if arrival is not None and m.mode != m.MODE_SAFE_STOP:
            self.latencies.append(now - arrival)
            del self._arrivals[m.status_sequence]  # a repeated command answers no new status
        if math.isfinite(self._last_command):
            self.gaps.append(now - self._last_command)
        self._last_command = now
        return m

    def summary(self) -> dict:
        """Median, 99th percentile and largest latency, and the longest time between two
        commands, all in wall-clock ms."""
        if not self.latencies:
            return {"commands_answering_a_status": 0}
        ms = np.asarray(self.latencies) * 1e3
        return {"commands_answering_a_status": int(ms.size), "latency_median_ms": float(np.median(ms)),
                "latency_p99_ms": float(np.percentile(ms, 99)), "latency_max_ms": float(ms.max()),
                "longest_command_gap_ms": float(max(self.gaps, default=0.0) * 1e3),
                "longest_status_gap_ms": self.longest_status_gap * 1e3}


class Servo:
    """The servo's diagram: QingzhuiHardwareInterface, ReferencePlayer and the joint PD (Eq. 7,
    or in position mode the drives' PD on the player's q_des / v_des and the compensation here),
    wired as the lockstep walk wires the tracker, the PD and the station.

    Args:
        scenario: the walk's scenario (gains, control mode, the standing start).
        lcm: the LCM the robot driver and the planning process are on.
        config: protocol settings.
        with_driver: the simulated robot driver in the same diagram, on an in-process
            ``memq://`` LCM (the lockstep servo, as ``qz simulate --station lcm`` runs the
            interface and the driver): tests, and a planner in the same process.
    """

    def __init__(self, *, scenario: Scenario, lcm: DrakeLcm, config: HardwareConfig | None = None,
                 with_driver: bool = False):
        self.config = validate_hardware_config(config or HardwareConfig())
        builder = DiagramBuilder()
        self.latency = LatencyRecorder(lcm, self.config.channels.status)
        self.collector = SteadyCollector()
        self.driver = None
        if with_driver:
            from qz_drake.hardware.driver import QingzhuiRobotDriver

            self.driver = builder.AddSystem(QingzhuiRobotDriver(scenario=scenario, lcm=lcm, config=self.config))
        interface, info = make_hardware_interface(scenario, lcm=lcm, config=self.config,
                                                  command_filter=self.latency.on_command)
        self.interface = builder.AddSystem(interface)
        weight = info.params.total_mass * GRAVITY / NUM_LEGS
        self.player = builder.AddSystem(ReferencePlayer(
            lcm=lcm, config=self.config, standing=standing_row(info.initial_state[JOINT_Q], weight)))
        self.player.set_name("reference_player")
        control = scenario.controller
        add_joint_pd(builder, self.interface, self.player, params=info.params, kp=control.kp, kd=control.kd,
                     position_mode=scenario.station.control_mode == "position", update_period=REFERENCE_PERIOD)
        self.diagram = builder.Build()
        # Not paced to a clock of its own: against a driver in another process the interface
        # waits for each status (StatusPacer) and then runs to its command at once, so that a
        # command leaves as soon as it can (paced to real time, the simulator slept until the
        # command's phase of its own schedule: the robot took 39 % of the commands a period
        # late); in the lockstep diagram it runs as fast as it can.
        self.simulator = Simulator(self.diagram)
        self.lcm = lcm

    @property
    def context(self):
        return self.simulator.get_context()

    def player_state(self) -> PlayerState:
        return self.player.player_state(self.player.GetMyContextFromRoot(self.context))

    def _sync_safe_stop(self, parent_pid: int | None) -> None:
        """Latches the interface on a planner fault (or a parent planning process gone), and
        tells the player about a latched safe stop, whichever end latched it."""
        root = self.context
        fault = self.player_state().fault
        if not fault and parent_pid is not None and os.getppid() != parent_pid:
            fault = f"planner process {parent_pid} exited"
        link = self.interface.watchdog(root)
        if fault and not link.latched:
            self.interface.latch_safe_stop(root, fault)
            link = self.interface.watchdog(root)
        if link.latched and not self.player_state().safe_stop:
            self.player.note_safe_stop(self.player.GetMyMutableContextFromRoot(root), link.reason)

    def run(self, *, parent_pid: int | None = None, linger: float = 0.2, ready=None,
            stop_requested=lambda: False) -> dict:
        """Serves the robot until the planner has finished (then ``linger`` seconds more of
        standing), a safe stop has latched (then ``linger`` of holding it), or
        ``stop_requested()``; returns the report (also published on qz_servo). ``ready()`` is
        called once the diagram is up."""
        self.simulator.Initialize()
        self.collector.start()  # what the setup made is never walked again (SteadyCollector)
        try:
            if ready is not None:
                ready()
            end = math.inf
            while not stop_requested():
                t = self.context.get_time()
                self.simulator.AdvanceTo(t + 0.01)
                self._sync_safe_stop(parent_pid)
                s = self.player_state()
                if math.isinf(end) and (s.finished or self.interface.watchdog(self.context).latched):
                    end = self.context.get_time() + linger
                    self.finish()  # the planning process waits for the report; the robot stands on
                if self.context.get_time() >= end:
                    break
            return self.finish()
        finally:
            self.collector.stop()

    def report(self) -> dict:
        root = self.context
        link = self.interface.watchdog(root)
        return {"servo": {**self.player_state().counters(root.get_time()), "time_s": root.get_time(),
                          **self.latency.summary(), **self.collector.summary()},
                "interface": self.interface.counters(root),
                "safe_stop": (f"at {link.latched_time:.3f} s on the servo: {link.reason}" if link.latched else "")}

    def finish(self) -> dict:
        """Publishes the report as the servo's last message and returns it."""
        report = self.report()
        player_context = self.player.GetMyContextFromRoot(self.context)
        message = self.player.status_message(player_context, report=json.dumps(report))
        self.lcm.Publish(self.config.channels.servo, message.encode())
        return report


def serve(scenario: Scenario, *, lcm_url: str, config: HardwareConfig | None = None,
          parent_pid: int | None = None, ready=None) -> dict:
    """``qz servo``: connects, serves until the planner finishes, SIGTERM or a safe stop; the report."""
    from qz_drake.hardware.relay import connect_lcm

    stop = [False]

    def on_term(signum, frame):
        stop[0] = True

    previous = signal.signal(signal.SIGTERM, on_term)
    try:
        servo = Servo(scenario=scenario, lcm=connect_lcm(lcm_url, "--lcm-url"), config=config)
        return servo.run(parent_pid=parent_pid, ready=ready, stop_requested=lambda: stop[0])
    finally:
        signal.signal(signal.SIGTERM, previous)

