"""The station of the planning process: the walk's diagram as in the lockstep simulation, with a
servo in another process closing the loop (qz_drake.hardware.servo has the whole picture).

PlanningLcmStation has the controller ports of the LCM station (``state``,
``joint_torque_measured``, ``imu``, ``foot_contact`` out, decoded from the robot's statuses as
the servo's interface decodes them; ``trunk_contact`` NaN: a robot does not report it) and
one more input, ``plan``: each new plan's references go to the servo as a table
(qz_reference) the moment the plan appears. Its ``joint_torque`` input (and the position-mode
inputs) are taken and not used: the servo runs the joint PD at the robot's rate on the same
references, so the walk's diagram is built as in the lockstep simulation and its tracker and
PD are never asked for a command here.

ServoClockPacer keeps the simulation no further than ``HardwareConfig.plan_lead`` ahead of the
servo's plan clock and tells the servo how far it has got (qz_planner); a thread sends the same
heartbeat while the simulation is busy (a BLC solve), so that only a process that exits or
hangs falls silent. The walk stops (``halted``) when the servo has latched a safe stop or gone
silent.

ServoProcess starts ``qz servo`` for a planning process: ``qz simulate --station lcm --lcm-url
URL`` runs it around the walk.
"""

from __future__ import annotations

import bisect
import dataclasses
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.lcm import DrakeLcm
from pydrake.systems.framework import BasicVector, Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.lcm import LcmInterfaceSystem
from pydrake.systems.primitives import ConstantVectorSource

from qz_drake.config import Scenario, save_scenario
from qz_drake.errors import QzError
from qz_drake.hardware.codec import decode, encoded_key, joint_limits, status_problem
from qz_drake.hardware.config import HardwareConfig, validate_hardware_config
from qz_drake.hardware.interface import (_CONTACT, _IMU, _TAU, PoseTrack, decoded_status, initial_held,
                                         scenario_station_info, updated_pose_track)
from qz_drake.hardware.qz_lcm import qz_planner, qz_servo, qz_status
from qz_drake.hardware.references import encode_table, plan_references, table_chunks
from qz_drake.hardware.servo import REFERENCE_PERIOD
from qz_drake.robot.params import NUM_JOINTS
from qz_drake.state_layout import STATE_SIZE

# The pacer's period: how often the planning process checks the servo's plan clock and tells
# it how far it has got. [s]
PACER_PERIOD = 0.01
# The heartbeat thread's period (wall clock). [s]
PLANNER_HEARTBEAT_PERIOD = 0.02
# The servo is taken as gone after this long without a qz_servo message (wall clock). [s]
SERVO_TIMEOUT = 2.0
# How long the planning process waits for the servo's report after the walk. [s]
REPORT_WAIT = 5.0


class TimeSeries:
    """Values keyed by a non-decreasing key (a time), kept for ``span`` of the key: the newest at
    or before a key, by bisection."""

    def __init__(self, span: float):
        self._span = span
        self.keys: list[float] = []
        self.values: list = []

    def append(self, key: float, value) -> None:
        self.keys.append(key)
        self.values.append(value)
        if key - self.keys[0] > 2 * self._span:  # prune now and then, not at every append
            drop = bisect.bisect_left(self.keys, key - self._span)
            del self.keys[:drop], self.values[:drop]

    def at(self, key: float):
        """The value of the newest key at or before ``key``; None if there is none."""
        found = self.entry(key)
        return None if found is None else found[1]

    def entry(self, key: float):
        """(key, value) of the newest key at or before ``key``; None if there is none."""
        i = bisect.bisect_right(self.keys, key)
        return (self.keys[i - 1], self.values[i - 1]) if i else None


# How much of the robot's statuses and the servo's clock the planning process keeps: how far
# its simulation may fall behind the servo's plan clock and still read the status of its time. [s]
HISTORY_SPAN = 60.0


class ServoLink:
    """The planning process's end of the link to its servo: the servo's newest qz_servo, the
    plan time announced to it, the heartbeat thread and the servo's final report.

    Args:
        lcm: the planning process's LCM (its diagram pumps it).
        config: protocol settings (channels).
        heartbeat_lcm: an LCM the heartbeat thread publishes on (a second connection: the
            diagram's is used from the main thread only); None: no thread (a lockstep
            ``memq://`` test, where the pacer's own heartbeats are all there is).
    """

    def __init__(self, *, lcm: DrakeLcm, config: HardwareConfig, heartbeat_lcm: DrakeLcm | None):
        self.lcm = lcm
        self.config = config
        self.servo: qz_servo | None = None
        self.servo_wall = math.nan
        # The servo's clock: plan time -> the newest robot status it had taken in (utime).
        self.status_utime_at_plan_time = TimeSeries(HISTORY_SPAN)
        self.report: dict | None = None
        self._plan_time = -math.inf
        self._finished = False
        self._sequence = 0
        self._lock = threading.Lock()
        lcm.Subscribe(config.channels.servo, self._on_servo)
        self._stop = threading.Event()
        self._thread = None
        if heartbeat_lcm is not None:
            self._heartbeat_lcm = heartbeat_lcm
            self._thread = threading.Thread(target=self._beat, name="qz-planner-heartbeat", daemon=True)
            self._thread.start()

    def _on_servo(self, data: bytes) -> None:
        m = qz_servo.decode(data)
        self.servo, self.servo_wall = m, time.monotonic()
        if m.status_utime:
            self.status_utime_at_plan_time.append(m.plan_time, m.status_utime)
        if m.report:
            self.report = json.loads(m.report)

    def _message(self) -> bytes:
        with self._lock:
            self._sequence += 1
            m = qz_planner()
            m.utime, m.sequence = int(time.monotonic() * 1e6), self._sequence
            m.plan_time, m.finished = self._plan_time, self._finished
        return m.encode()

    def _beat(self) -> None:
        while not self._stop.wait(PLANNER_HEARTBEAT_PERIOD):
            self._heartbeat_lcm.Publish(self.config.channels.planner, self._message())

    def announce(self, plan_time: float) -> None:
        """Every event of the planning process's simulation before ``plan_time`` is handled."""
        with self._lock:
            self._plan_time = max(self._plan_time, plan_time)
        self.lcm.Publish(self.config.channels.planner, self._message())

    def pump(self, timeout: float) -> None:
        self.lcm.HandleSubscriptions(max(1, min(50, math.ceil(timeout * 1e3))))

    def servo_problem(self) -> str:
        """Why the walk cannot go on (a safe stop on the servo, a servo gone silent); ""."""
        if self.servo is not None and self.servo.safe_stop:
            return f"the servo latched a safe stop: {self.servo.reason}"
        if self.servo is not None and time.monotonic() - self.servo_wall > SERVO_TIMEOUT:
            return f"the servo has been silent for {time.monotonic() - self.servo_wall:.1f} s"
        return ""

    def finish(self) -> dict | None:
        """Tells the servo the walk is over and waits for its report (None if none came)."""
        with self._lock:
            self._finished = True
        deadline = time.monotonic() + REPORT_WAIT
        while self.report is None and time.monotonic() < deadline:
            self.lcm.Publish(self.config.channels.planner, self._message())
            self.pump(0.05)
        self.close()
        return self.report

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)


@dataclasses.dataclass(frozen=True)
class PacerRecord:
    """What the ServoClockPacer saw; immutable (a Drake abstract state)."""

    # Why the walk stopped ("" while it goes on).
    halted: str = ""
    # Wall time spent waiting for the servo's plan clock. [s]
    waited: float = 0.0

    def __deepcopy__(self, memo):
        return self


class ServoClockPacer(LeafSystem):
    """Keeps the planning process's simulation within ``config.plan_lead`` of the servo's plan clock.

    .. pydrake_system::

        name: ServoClockPacer

    Every PACER_PERIOD it announces how far the simulation has got (every event before the
    previous pacer time is handled) and waits, pumping the LCM, until the servo's plan time
    has come within the lead. It stops waiting, and records why, when the servo latched a safe
    stop or fell silent.
    """

    def __init__(self, *, link: ServoLink):
        super().__init__()
        self._link = link
        self._record = self.DeclareAbstractState(AbstractValue.Make(PacerRecord()))
        self.DeclarePeriodicUnrestrictedUpdateEvent(PACER_PERIOD, 0.0, self._wait)

    def record(self, context) -> PacerRecord:
        return context.get_abstract_state(self._record).get_value()

    def _wait(self, context, state):
        record: PacerRecord = context.get_abstract_state(self._record).get_value()
        if record.halted:
            return
        t = context.get_time()
        link = self._link
        link.announce(t - PACER_PERIOD)
        start = time.monotonic()
        lead = link.config.plan_lead
        while not link.servo_problem() and (link.servo is None or link.servo.plan_time < t - lead - 1e-9):
            link.pump(0.01)
            if link.servo is None and time.monotonic() - start > SERVO_TIMEOUT:
                break
        problem = link.servo_problem() or ("" if link.servo is not None else
                                           f"no servo answered within {SERVO_TIMEOUT} s")
        state.get_mutable_abstract_state(self._record).set_value(
            PacerRecord(halted=problem, waited=record.waited + time.monotonic() - start))


class ReferencePublisher(LeafSystem):
    """Sends each new plan's references to the servo (qz_reference), as the tracker would hold them.

    .. pydrake_system::

        name: ReferencePublisher
        input_ports:
        - plan

    Checked every reference period: a plan object it has not sent yet (None, or the input left
    unconnected as a standing run leaves it: nothing) is solved into a table
    (references.plan_references) and published at once, a second of rows to a message.

    Args:
        link: the servo link (its LCM and channels).
        topology: the tracker's topology (a plan may carry its own).
        params: robot parameters.
    """

    def __init__(self, *, link: ServoLink, topology, params):
        super().__init__()
        self._link = link
        self._topology = topology
        self._params = params
        self._plan = self.DeclareAbstractInputPort("plan", AbstractValue.Make(object()))
        # (the last plan sent, tables sent)
        self._sent = self.DeclareAbstractState(AbstractValue.Make((None, 0)))
        self.DeclarePeriodicUnrestrictedUpdateEvent(REFERENCE_PERIOD, 0.0, self._send)
        self.DeclareInitializationUnrestrictedUpdateEvent(self._send)

    def tables_sent(self, context) -> int:
        return context.get_abstract_state(self._sent).get_value()[1]

    def _send(self, context, state):
        if not self._plan.HasValue(context):  # a standing run: the servo holds the standing pose
            return
        plan = self._plan.Eval(context)
        last, count = context.get_abstract_state(self._sent).get_value()
        if plan is None or plan is last:
            return
        table = plan_references(plan, topology=self._topology, params=self._params, rate=1.0 / REFERENCE_PERIOD)
        for chunk in table_chunks(table):
            count += 1
            data = encode_table(chunk, sequence=count, utime=int(time.monotonic() * 1e6))
            self._link.lcm.Publish(self._link.config.channels.reference, data)
        state.get_mutable_abstract_state(self._sent).set_value((plan, count))


class StatusListener(LeafSystem):
    """The station's outputs: the robot's status at the simulation's time on the servo's plan
    clock, decoded as the servo's interface decodes it (without a watchdog: this process
    commands nothing).

    .. pydrake_system::

        name: StatusListener
        output_ports:
        - state
        - joint_torque_measured
        - imu
        - foot_contact
        - state_plan_time

    Once a period it takes the status the servo had taken in when its plan clock read this
    time (qz_servo maps the two clocks), and the newest pose before it. The simulation may
    fall behind the servo (a BLC solve): it then reads the statuses of its own time, kept for
    HISTORY_SPAN, so that its log and verdict compare the plan and the robot at one time, not
    a plan with where the robot has since walked. It is ahead of the servo most of the time
    (up to ``plan_lead``), and then holds the newest status, which is the robot at an earlier
    plan time: ``state_plan_time`` says which (NaN before the first status), and the walk
    compares the state with the plan at that time (simulation.judge_walk_run). Statuses and
    poses arrive through ``link``'s LCM subscriptions (every one kept, where Drake's
    LcmSubscriberSystem keeps the newest).

    Args:
        link: the servo link (the LCM, the servo's clock).
        params: robot parameters (joint limits: a malformed status is not used).
        prior_state: the state before the first status.
    """

    def __init__(self, *, link: ServoLink, params, prior_state: np.ndarray):
        super().__init__()
        config = link.config
        self._link = link
        self._max_extrapolation = config.max_pose_extrapolation
        self._margin = config.joint_limit_margin
        self._lower, self._upper = joint_limits(params)
        self._statuses = TimeSeries(HISTORY_SPAN * 1e6)
        self._poses = TimeSeries(HISTORY_SPAN * 1e6)
        link.lcm.Subscribe(config.channels.status, lambda data: self._keep(self._statuses, data))
        link.lcm.Subscribe(config.channels.pose, lambda data: self._keep(self._poses, data))
        self._held = self.DeclareDiscreteState(initial_held(prior_state))
        # (the status used last: its utime; statuses used, statuses rejected)
        self._seen = self.DeclareAbstractState(AbstractValue.Make((0, 0, 0)))
        # The servo's plan time at which the held status was taken in.
        self._plan_time = self.DeclareDiscreteState(np.array([np.nan]))
        self.DeclarePeriodicUnrestrictedUpdateEvent(config.control_period, 0.0, self._update)
        for name, part in (("state", slice(0, STATE_SIZE)), ("joint_torque_measured", _TAU), ("imu", _IMU),
                           ("foot_contact", _CONTACT)):
            self.DeclareVectorOutputPort(name, part.stop - part.start, self._output(part),
                                         {self.discrete_state_ticket(self._held)})
        self.DeclareVectorOutputPort(
            "state_plan_time", 1,
            lambda context, output: output.SetFromVector(context.get_discrete_state(self._plan_time).get_value()),
            {self.discrete_state_ticket(self._plan_time)})

    def _keep(self, series: TimeSeries, data: bytes) -> None:
        utime = encoded_key(data)[0]
        if not series.keys or utime >= series.keys[-1]:  # a robot's clock only moves on
            series.append(utime, data)

    def _output(self, part: slice):
        def calc(context, output: BasicVector):
            output.SetFromVector(context.get_discrete_state(self._held).get_value()[part])
        return calc

    def counts(self, context) -> tuple[int, int]:
        """(statuses used, statuses rejected)."""
        return context.get_abstract_state(self._seen).get_value()[1:]

    def _update(self, context, state):
        last, used, rejected = context.get_abstract_state(self._seen).get_value()
        mapped = self._link.status_utime_at_plan_time.entry(context.get_time() + 1e-9)
        data = None if mapped is None else self._statuses.at(mapped[1])
        if data is None:
            return
        m, problem = decode(qz_status, data)
        if m is None or m.utime == last:
            return
        problem = problem or status_problem(m, self._lower, self._upper, self._margin)
        if problem:
            rejected += 1
        else:
            used += 1
            pose = self._poses.at(m.utime)
            track = updated_pose_track(PoseTrack(), pose) if pose is not None else PoseTrack()
            held = context.get_discrete_state(self._held).get_value().copy()
            state.get_mutable_discrete_state(self._held).set_value(
                decoded_status(held, m, track, self._max_extrapolation))
            state.get_mutable_discrete_state(self._plan_time).set_value([mapped[0]])
        state.get_mutable_abstract_state(self._seen).set_value((m.utime, used, rejected))


class _Unused(LeafSystem):
    """Takes an input nothing here reads (the servo computes the commands)."""

    def __init__(self, name: str, size: int):
        super().__init__()
        self.DeclareVectorInputPort(name, size)


class PlanningLcmStation(Diagram):
    """The planning process's station (module doc).

    .. pydrake_system::

        name: PlanningLcmStation
        input_ports:
        - joint_torque (not used: the servo commands)
        - joint_position_command (position mode; not used)
        - joint_velocity_command (position mode; not used)
        - plan
        output_ports:
        - state
        - joint_torque_measured
        - imu
        - foot_contact
        - trunk_contact
        - state_plan_time

    ``state_plan_time`` is the plan time the ``state`` shows the robot at (StatusListener).

    Args:
        scenario: the walk's scenario.
        lcm: the LCM of the robot and the servo.
        config: protocol settings.
        heartbeat_lcm: a second connection for the heartbeat thread (None: no thread).
    """

    def __init__(self, *, scenario: Scenario, lcm: DrakeLcm, config: HardwareConfig | None = None,
                 heartbeat_lcm: DrakeLcm | None = None):
        super().__init__()
        config = validate_hardware_config(config or HardwareConfig())
        self.info = scenario_station_info(scenario)
        self.link = ServoLink(lcm=lcm, config=config, heartbeat_lcm=heartbeat_lcm)
        builder = DiagramBuilder()
        builder.AddSystem(LcmInterfaceSystem(lcm))
        self._listener = builder.AddSystem(StatusListener(link=self.link, params=self.info.params,
                                                          prior_state=self.info.initial_state))
        self._pacer = builder.AddSystem(ServoClockPacer(link=self.link))
        self._publisher = builder.AddSystem(ReferencePublisher(link=self.link, topology=self.info.topology,
                                                               params=self.info.params))
        inputs = ["joint_torque"]
        if scenario.station.control_mode == "position":
            inputs += ["joint_position_command", "joint_velocity_command"]
        for name in inputs:
            builder.ExportInput(builder.AddSystem(_Unused(name, NUM_JOINTS)).get_input_port(), name)
        builder.ExportInput(self._publisher.GetInputPort("plan"), "plan")
        for name in ("state", "joint_torque_measured", "imu", "foot_contact"):
            builder.ExportOutput(self._listener.GetOutputPort(name), name)
        builder.ExportOutput(self._listener.GetOutputPort("state_plan_time"), "state_plan_time")
        unknown = builder.AddSystem(ConstantVectorSource(np.array([np.nan])))
        builder.ExportOutput(unknown.get_output_port(), "trunk_contact")
        builder.BuildInto(self)
        self.set_name("station")

    def halted(self, root_context) -> str:
        """Why the walk cannot go on ("" while it can): the servo's safe stop or silence."""
        return self._pacer.record(self._pacer.GetMyContextFromRoot(root_context)).halted

    def station_metrics(self, root_context) -> dict:
        """Ends the link (the servo reports and stops) and returns the servo's counters: its
        interface's watchdog (``lcm_interface``), its plan clock and late holds (``servo``),
        the safe stop; and this process's own (``planner``)."""
        report = self.link.finish()
        pacer = self._pacer.record(self._pacer.GetMyContextFromRoot(root_context))
        used, rejected = self._listener.counts(self._listener.GetMyContextFromRoot(root_context))
        planner = {"statuses_used": used, "statuses_rejected": rejected, "waited_for_servo_s": pacer.waited,
                   "tables_sent": self._publisher.tables_sent(self._publisher.GetMyContextFromRoot(root_context))}
        if report is None:
            stop = pacer.halted or "the servo sent no report"
            return {"servo": None, "planner": planner, "trunk_contact_observed": False, "safe_stop": stop}
        stop = report["safe_stop"]
        if not stop and report["interface"]["driver_safe_stop"]:
            stop = "reported by the robot driver (its own report says why)"
        return {"lcm_interface": report["interface"], "servo": report["servo"], "planner": planner,
                "trunk_contact_observed": False, "safe_stop": stop}


def make_planning_lcm_station(scenario: Scenario, meshcat=None, *, mesh_dir=None, lcm_url: str,
                              config: HardwareConfig | None = None):
    """A make_station-compatible factory: (PlanningLcmStation, StationInfo) on ``lcm_url``, with
    a heartbeat thread on a second connection."""
    from qz_drake.hardware.relay import connect_lcm

    station = PlanningLcmStation(scenario=scenario, lcm=connect_lcm(lcm_url), config=config,
                                 heartbeat_lcm=connect_lcm(lcm_url))
    return station, station.info


class ServoProcess:
    """``qz servo`` in a child process for the duration of a ``with`` block.

    It starts the servo on the scenario and the URL, waits until it serves, and at the end
    waits for it to exit (it does once the planning station's station_metrics has told it the
    walk is over) or stops it. Its output goes to ``log`` (a file) if given.

    Args:
        scenario: the walk's scenario.
        lcm_url: the robot's LCM.
        config: protocol settings.
        startup_timeout: how long the servo may take to start. [s]
    """

    def __init__(self, scenario: Scenario, *, lcm_url: str, config: HardwareConfig | None = None,
                 startup_timeout: float = 60.0, log: Path | None = None):
        self._scenario = scenario
        self._url = lcm_url
        self._config = validate_hardware_config(config or HardwareConfig())
        self._timeout = startup_timeout
        self._log = log
        self.process: subprocess.Popen | None = None
        self.report: dict | None = None

    def __enter__(self) -> ServoProcess:
        from pydrake.common.yaml import yaml_dump_typed

        self._folder = tempfile.TemporaryDirectory(prefix="qz_servo_")
        folder = Path(self._folder.name)
        save_scenario(self._scenario, folder / "scenario.yaml")
        (folder / "hardware.yaml").write_text(yaml_dump_typed(self._config))
        command = [sys.executable, "-m", "qz_drake.cli", "servo", str(folder / "scenario.yaml"),
                   "--lcm-url", self._url, "--hardware", str(folder / "hardware.yaml"),
                   "--parent-pid", str(os.getpid())]
        stderr = open(self._log, "w") if self._log is not None else subprocess.DEVNULL
        self.process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=stderr, text=True)
        if stderr is not subprocess.DEVNULL:
            stderr.close()
        line = _read_line(self.process, self._timeout)
        if not line.startswith('{"servo": "serving"'):
            self._stop()
            raise QzError(f"--lcm-url = {self._url!r}: the servo process did not start ({line.strip() or 'no output'})")
        return self

    def __exit__(self, *exc) -> None:
        self._stop()
        self._folder.cleanup()

    def _stop(self) -> None:
        process = self.process
        if process is None or process.poll() is not None:
            return
        try:
            out, _ = process.communicate(timeout=REPORT_WAIT)
        except subprocess.TimeoutExpired:
            process.terminate()
            out, _ = process.communicate(timeout=10)
        lines = [ln for ln in (out or "").splitlines() if ln.startswith("{")]
        if lines:
            self.report = json.loads(lines[-1])


def _read_line(process: subprocess.Popen, timeout: float) -> str:
    """The child's first line of output, or "" after ``timeout`` seconds or its exit."""
    result = [""]
    reader = threading.Thread(target=lambda: result.__setitem__(0, process.stdout.readline()), daemon=True)
    reader.start()
    reader.join(timeout)
    return result[0]
