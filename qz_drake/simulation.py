"""Runs a scenario: station + controller + loggers, then metrics, plots and a meshcat recording.

The standing controller (until walking lands) is the joint PD of paper 000 Eq. 7 holding the
topology's standing pose, with each foot's share of the body weight fed forward.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np
from pydrake.geometry import Meshcat
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput

from qz_drake.config import Scenario
from qz_drake.scene import GRAVITY
from qz_drake.station import make_station
from qz_drake.systems.joint_pd import JointPdController
from qz_drake.systems.state_layout import BASE_POS, JOINT_Q, base_rpy, tilt_deg
from qz_drake.viz.recording import RECORDING_FPS, recording_meshcat

# Samples per second of the logged signals. [Hz]
LOG_RATE = 100.0


@dataclasses.dataclass
class SimulationResult:
    """Logged signals and metrics of one run."""

    metrics: dict
    times: np.ndarray
    states: np.ndarray  # (N, 49)
    foot_contact: np.ndarray  # (N, 6)
    trunk_contact: np.ndarray  # (N,)
    files: dict


def _log_station(builder, station):
    """Loggers of the station's state, foot contacts and trunk contact at LOG_RATE."""
    period = 1.0 / LOG_RATE
    return tuple(LogVectorOutput(station.GetOutputPort(name), builder, period)
                 for name in ("state", "foot_contact", "trunk_contact"))


def _standing_controller(builder, station, info, scenario: Scenario):
    controller = builder.AddSystem(JointPdController(kp=scenario.controller.kp, kd=scenario.controller.kd,
                                                     params=info.params))
    q_des = info.initial_state[JOINT_Q]
    desired = builder.AddSystem(ConstantVectorSource(np.concatenate([q_des, np.zeros(18)])))
    weight = info.params.total_mass * GRAVITY / 6.0
    feedforward = builder.AddSystem(ConstantVectorSource(np.tile([0.0, 0.0, weight], 6)))
    builder.Connect(station.GetOutputPort("state"), controller.GetInputPort("state"))
    builder.Connect(desired.get_output_port(), controller.GetInputPort("desired_state"))
    builder.Connect(feedforward.get_output_port(), controller.GetInputPort("foot_force_feedforward"))
    builder.Connect(controller.GetOutputPort("joint_torque"), station.GetInputPort("joint_torque"))
    return controller


def add_tracking_controller(builder, station, info, plan=None, *, kp: float, kd: float,
                            plan_port=None, position_mode: bool = False):
    """Wires a plan -> InverseKinematicsTracker -> JointPdController (Eq. 7) -> station; returns
    (tracker, controller).

    The plan is either a fixed BodyFeetTrajectory (``plan``, held in a constant source) or an
    output port that provides one (``plan_port``, e.g. the MissionSequencer's). In position
    mode the tracker's q_des goes to the station's ``joint_position_command`` (the drives' PD
    tracks it) and the controller adds only the compensation and force feedforward.
    """
    from pydrake.common.value import AbstractValue
    from pydrake.systems.primitives import ConstantValueSource

    from qz_drake.systems.ik_tracker import InverseKinematicsTracker

    if plan_port is None:
        plan_port = builder.AddSystem(ConstantValueSource(AbstractValue.Make(plan))).get_output_port()
    tracker = builder.AddSystem(InverseKinematicsTracker(topology=info.topology, params=info.params))
    controller = builder.AddSystem(JointPdController(kp=0.0 if position_mode else kp,
                                                     kd=0.0 if position_mode else kd, params=info.params))
    builder.Connect(plan_port, tracker.GetInputPort("trajectory"))
    if position_mode:
        builder.Connect(tracker.GetOutputPort("position_command"), station.GetInputPort("joint_position_command"))
    builder.Connect(station.GetOutputPort("state"), controller.GetInputPort("state"))
    builder.Connect(tracker.GetOutputPort("desired_state"), controller.GetInputPort("desired_state"))
    builder.Connect(tracker.GetOutputPort("foot_force_feedforward"),
                    controller.GetInputPort("foot_force_feedforward"))
    builder.Connect(controller.GetOutputPort("joint_torque"), station.GetInputPort("joint_torque"))
    return tracker, controller


def simulate(scenario: Scenario, *, duration: float | None = None, meshcat: Meshcat | None = None,
             out_dir: str | Path | None = None, station_factory=make_station,
             realtime_rate: float = 0.0, progress=None) -> SimulationResult:
    """Simulates a scenario; writes recording.html, metrics.json and plots to out_dir if given.

    ``station_factory(scenario, meshcat, mesh_dir=...) -> (diagram, info)`` builds the station
    (make_station; qz_drake.hardware.loopback: over LCM). ``realtime_rate`` paces the simulator
    (0: as fast as possible; 1 against a robot driver in another process). ``progress(sim_time,
    end_time, missions)`` hears how far the run is while it runs (a walk: every half second
    simulated; a standing run: at most every PROGRESS_PERIOD of wall time) and once when the
    simulation has ended (end_time then its final time; missions None for a standing run)."""
    if scenario.controller.kind == "walk":
        return walk(scenario, meshcat=meshcat, out_dir=out_dir, max_duration=duration,
                    station_factory=station_factory, realtime_rate=realtime_rate, progress=progress)
    builder = DiagramBuilder()
    out = Path(out_dir) if out_dir is not None else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        if meshcat is None:
            meshcat = recording_meshcat()
    station_diagram, info = station_factory(scenario, meshcat, mesh_dir=None if out is None else out / "terrain_mesh")
    station = builder.AddSystem(station_diagram)
    _standing_controller(builder, station, info, scenario)
    state_log, contact_log, trunk_log = _log_station(builder, station)
    leg_log = _optional_log(builder, station, "leg_link_force")
    diagram = builder.Build()

    simulator = Simulator(diagram)
    simulator.set_target_realtime_rate(realtime_rate)
    simulator.Initialize()
    duration = scenario.simulation.duration if duration is None else duration
    if meshcat is not None:
        meshcat.StartRecording(frames_per_second=RECORDING_FPS)
    if progress is not None:
        _monitor_progress(simulator, duration, progress)
    wall_start = time.perf_counter()
    simulator.AdvanceTo(duration)
    wall = time.perf_counter() - wall_start
    if progress is not None:
        progress(duration, duration, None)
    context = simulator.get_context()
    files = {}
    if meshcat is not None:
        meshcat.StopRecording()
    times = state_log.FindLog(context).sample_times()
    states = state_log.FindLog(context).data().T
    contacts = contact_log.FindLog(context).data().T
    trunk = trunk_log.FindLog(context).data()[0]
    metrics = standing_metrics(scenario, info, times, states, trunk,
                               leg_link_force=None if leg_log is None else leg_log.FindLog(context).data().T)
    _add_station_metrics(metrics, station_diagram, context)
    metrics.update(sim_time_s=float(duration), wall_time_s=wall,
                   realtime_factor=float(duration / wall) if wall > 0 else float("inf"),
                   terrain_contact=info.contact_representation)
    if out is not None:
        from qz_drake.viz.plots import plot_standing
        from qz_drake.viz.recording import save_recording

        files["recording"] = str(save_recording(meshcat, out / "recording.html", follow_robot=True))
        files["plot"] = str(plot_standing(times, states, contacts, info, out / "base_and_contacts.png"))
        (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
        files["metrics"] = str(out / "metrics.json")
    return SimulationResult(metrics=metrics, times=times, states=states, foot_contact=contacts,
                            trunk_contact=trunk, files=files)


# Wall time between two progress reports of a running simulation. [s]
PROGRESS_PERIOD = 0.25


def _monitor_progress(simulator, end_time: float, progress) -> None:
    """Reports the simulated time from a Simulator monitor: it runs after each step and only
    reads the time, so the run advances in the same steps as without it (one AdvanceTo)."""
    from pydrake.systems.framework import EventStatus

    last = [-PROGRESS_PERIOD]

    def monitor(context):
        now = time.perf_counter()
        if now - last[0] >= PROGRESS_PERIOD:
            last[0] = now
            progress(context.get_time(), end_time, None)
        return EventStatus.DidNothing()

    simulator.set_monitor(monitor)


def _add_station_metrics(metrics: dict, station, root_context) -> None:
    """Adds a station's own counters (the LCM station's watchdogs), if it reports any. A failed
    run during which the station latched a safe stop says so first: the robot stopped there,
    and the rest of the reason (a missed target) is only what followed."""
    report = getattr(station, "station_metrics", None)
    metrics.update(report(root_context) if report is not None else {})
    if metrics.get("safe_stop") and not metrics["success"]:
        metrics["reason"] = f"safe stop {metrics['safe_stop']}; {metrics['reason']}"
        if "reasons" in metrics:
            metrics["reasons"] = ["safe_stop", *metrics["reasons"]]


def _optional_log(builder, station, name: str):
    """A logger of a simulation-only station output (leg-link forces), or None when the station
    does not observe it (the LCM hardware interface)."""
    if not station.HasOutputPort(name):
        return None
    return LogVectorOutput(station.GetOutputPort(name), builder, 1.0 / LOG_RATE)


def standing_metrics(scenario: Scenario, info, times, states, trunk, leg_link_force=None) -> dict:
    """Success of a standing run: base height within tolerance of nominal, no trunk or leg-link
    contact, small tilt. The first 0.5 s (settling into the ground) is not judged for height."""
    z0 = info.initial_state[BASE_POS][2]
    settled = times >= min(0.5, times[-1])
    height_error = np.abs(states[settled, 6] - z0)
    tilts = np.array([tilt_deg(x) for x in states])
    xy_drift = np.linalg.norm(states[-1, 4:6] - info.initial_state[4:6])
    crit = scenario.success
    max_height_error = float(height_error.max())
    trunk_contacts = int(np.count_nonzero(trunk > 0.5))
    fell = bool(tilts.max() > crit.max_tilt_deg)
    legs = np.zeros((len(times), 6)) if leg_link_force is None else np.asarray(leg_link_force)
    leg_contacts = int(np.count_nonzero((legs > crit.leg_contact_force).any(axis=1)))
    success = (max_height_error <= crit.max_base_height_error and trunk_contacts == 0 and not fell
               and leg_contacts == 0)
    reason = "" if success else (
        "fell" if fell else "trunk touched the terrain" if trunk_contacts else
        "a leg link touched the terrain" if leg_contacts else
        f"base height error {max_height_error:.3f} m > {crit.max_base_height_error} m")
    return {
        "scenario": scenario.name,
        "success": bool(success),
        "reason": reason,
        "topology": scenario.robot.topology,
        "max_base_height_error_m": max_height_error,
        "final_base_height_m": float(states[-1, 6]),
        "nominal_base_height_m": float(z0),
        "max_tilt_deg": float(tilts.max()),
        "final_rpy_rad": base_rpy(states[-1]).tolist(),
        "xy_drift_m": float(xy_drift),
        "trunk_terrain_contacts": trunk_contacts,
        "leg_terrain_contacts": leg_contacts,
        "max_leg_link_force_n": float(legs.max()) if legs.size else 0.0,
    }


# Turning rate a mission allows for. [rad/s]
_TURN_RATE = 0.4
# Shortest mission. [s]
_MIN_MISSION_DURATION = 1.2
# A tilt beyond this ends the run as a fall. [deg]
_FALL_TILT_DEG = 60.0
# Standing time before the first mission starts: the robot settles onto the ground. [s]
SETTLE_TIME = 0.5


def _tripod_planner(heightmap, params, control):
    from qz_drake.robot.topology import get_topology
    from qz_drake.systems.reference_gait import TripodGaitPlan

    def plan(start, target, topology, start_time):
        x0, y0, yaw0 = start.xy_yaw
        dist = float(np.hypot(target[0] - x0, target[1] - y0))
        dyaw = abs(np.arctan2(np.sin(target[2] - yaw0), np.cos(target[2] - yaw0)))
        duration = max(dist / control.speed, dyaw / _TURN_RATE, _MIN_MISSION_DURATION)
        return TripodGaitPlan(heightmap=heightmap, topology=get_topology(topology, params),
                              start_xy_yaw=start.xy_yaw, goal_xy_yaw=tuple(target), start_time=start_time,
                              duration=duration, phase_duration=control.phase_duration, params=params,
                              start_feet_W=start.feet_W), ""
    return plan


def walk(scenario: Scenario, *, meshcat: Meshcat | None = None, out_dir: str | Path | None = None,
         max_duration: float | None = None, heightmap=None, stop_on_failure: bool = False,
         blc_params=None, station_factory=make_station, realtime_rate: float = 0.0,
         mission_retries: int | None = None, progress=None) -> SimulationResult:
    """Walks a scenario's route: missions planned from the measured state, IK + joint PD.

    ``heightmap`` replaces the map of the scenario's terrain section (see make_station). With
    ``stop_on_failure`` the run ends as soon as a contact or tracking check of the verdict has
    failed (capability trials: the rest of the walk cannot change the label). ``blc_params``
    are the BLC's BlcParameters (None: the defaults; for CapPlanner, the capability trials'
    iteration budget). ``mission_retries``: how often the BLC system solves a mission that
    failed to plan again, one tripod cycle longer each time (None: CAPPLANNER_MISSION_RETRIES
    for CapPlanner, 0 otherwise). ``station_factory``, ``realtime_rate`` and ``progress`` as in
    simulate(); ``progress`` hears the missions planned so far."""
    from qz_drake.systems.mission_sequencer import split_route

    out = Path(out_dir) if out_dir is not None else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        meshcat = meshcat or recording_meshcat()
    control = scenario.controller
    builder = DiagramBuilder()
    extra = {} if heightmap is None else {"heightmap": heightmap}
    station_diagram, info = station_factory(scenario, meshcat, mesh_dir=None if out is None else out / "terrain_mesh",
                                            **extra)
    station = builder.AddSystem(station_diagram)
    x0 = info.initial_state
    targets = split_route(tuple(x0[4:6]), [(w.x, w.y, w.yaw, w.topology) for w in control.route],
                          control.mission_length)
    # Wall time counts from the first mission's planning, so the real-time factor includes it.
    wall_start = time.perf_counter()
    if control.planner == "blc":
        missions = _BlcMissions(builder, station, info, targets, control, blc_params,
                                mission_retries=mission_retries or 0)
    elif control.planner == "capplanner":
        if blc_params is None:
            # The BLC the capability model learned: the trials' deterministic budget (30 Ipopt
            # iterations, not 5 s of wall time, which a loaded machine spends in fewer), so that
            # a walk plans what the model predicts, whatever else the machine runs.
            from qz_drake.capability.trials import TrialConfig, trial_blc_parameters

            blc_params = trial_blc_parameters(TrialConfig())
        source = _capability_planner(scenario, info)
        if source.log.unreachable:
            return _unplanned(scenario, out, None, reason=f"goal unreachable: {source.log.unreachable}",
                              code="unreachable", extra=source.counts())
        missions = _BlcMissions(builder, station, info, targets, control, blc_params, route_source=source,
                                mission_retries=CAPPLANNER_MISSION_RETRIES if mission_retries is None
                                else mission_retries)
        if meshcat is not None:  # the guidance path in the recording, replaced at each replan
            from qz_drake.viz.guidance_path import add_guidance_visualizer

            add_guidance_visualizer(builder, source.GetOutputPort("guidance"), meshcat, info.heightmap)
    else:
        missions = _PlannerMissions(builder, station, info, targets, control, scenario.robot.initial_yaw)
        if missions.first_failure:
            return _unplanned(scenario, out, missions)
    tracker, _ = add_tracking_controller(builder, station, info, kp=control.kp, kd=control.kd,
                                         plan_port=missions.plan_port,
                                         position_mode=scenario.station.control_mode == "position")
    state_log, contact_log, trunk_log = _log_station(builder, station)
    desired_log = LogVectorOutput(tracker.GetOutputPort("desired_state"), builder, 1.0 / LOG_RATE)
    leg_log, self_log = (_optional_log(builder, station, name) for name in ("leg_link_force", "self_contact"))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.set_target_realtime_rate(realtime_rate)
    simulator.Initialize()
    if missions.first_failure:
        return _unplanned(scenario, out, missions)
    limit = scenario.simulation.duration if max_duration is None else max_duration
    if meshcat is not None:
        meshcat.StartRecording(frames_per_second=RECORDING_FPS)
    context = simulator.get_context()
    station_context = station.GetMyContextFromRoot(context)
    fell = False
    stopped = False
    crit = scenario.success
    while context.get_time() < limit:
        simulator.AdvanceTo(min(limit, context.get_time() + 0.5))
        x = station.GetOutputPort("state").Eval(station_context)
        if tilt_deg(x) > _FALL_TILT_DEG:
            fell = True
            break
        if stop_on_failure and (
                np.any(trunk_log.FindLog(context).data() > 0.5)
                or (leg_log is not None and np.any(leg_log.FindLog(context).data() > crit.leg_contact_force))
                or (self_log is not None and np.any(self_log.FindLog(context).data() > crit.leg_contact_force))
                or np.degrees(np.max(np.abs(state_log.FindLog(context).data()[JOINT_Q]
                                            - desired_log.FindLog(context).data()[:18]), initial=0.0))
                > crit.max_joint_error_deg):
            stopped = True
            break
        if missions.done and missions.log.plans and \
                context.get_time() >= missions.log.plans[-1].end_time + 0.5:
            break
        if progress is not None:
            progress(context.get_time(), _expected_end(missions, targets, limit), len(missions.log.plans))
    wall = time.perf_counter() - wall_start
    if progress is not None:
        progress(context.get_time(), context.get_time(), len(missions.log.plans))
    if meshcat is not None:
        meshcat.StopRecording()
    times = state_log.FindLog(context).sample_times()
    states = state_log.FindLog(context).data().T
    contacts = contact_log.FindLog(context).data().T
    trunk = trunk_log.FindLog(context).data()[0]
    desired = desired_log.FindLog(context).data().T
    links = (None if leg_log is None else leg_log.FindLog(context).data().T,
             None if self_log is None else self_log.FindLog(context).data()[0])
    if control.planner == "capplanner":  # the goal's heading is the planner's to choose
        targets = targets[:-1] + [(targets[-1][0], targets[-1][1], None, targets[-1][3])]
    metrics = walking_metrics(scenario, info, missions.log, targets, times, states, contacts, trunk, desired,
                              fell=fell, timed_out=not stopped and (not missions.done or context.get_time() >= limit),
                              leg_link_force=links[0], self_force=links[1])
    sim_time = float(context.get_time())
    counts = missions.counts()
    metrics.update(sim_time_s=sim_time, wall_time_s=wall, realtime_factor=sim_time / wall if wall > 0 else 0.0,
                   realtime_factor_excluding_planning=sim_time / max(wall - counts["blc_solve_time_s"], 1e-9),
                   terrain_contact=info.contact_representation, planner=control.planner, **counts)
    if counts.get("unreachable"):
        _gave_up(metrics, counts["unreachable"], counts.get("tlc_recoveries", 0))
    _add_station_metrics(metrics, station_diagram, context)
    files = {}
    if out is not None:
        from qz_drake.viz.plots import plot_walk
        from qz_drake.viz.recording import save_recording

        files["recording"] = str(save_recording(meshcat, out / "recording.html", follow_robot=True))
        files.update(plot_walk(times, states, contacts, desired, missions.log, info, out))
        if control.planner == "capplanner" and missions.targets.first_plan is not None:
            from qz_drake.capability.plots import plot_plan

            files["plan"] = str(plot_plan(info.heightmap, missions.targets.first_plan, out / "plan.png",
                                          title=f"{scenario.name}: CapPlanner's plan from the start and the walk",
                                          walked_xy=states[:, 4:6]))
        (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
        files["metrics"] = str(out / "metrics.json")
    return SimulationResult(metrics=metrics, times=times, states=states, foot_contact=contacts,
                            trunk_contact=trunk, files=files)


def _expected_end(missions, targets, limit: float) -> float:
    """When the walk should end, for the progress display only: after the last planned
    mission, the missions still ahead (CapPlanner: the rest of its latest replan; a fixed
    route: the rest of the route), each as long as the mean so far; at most the limit."""
    log = missions.log
    if not log.plans:
        return limit
    replans = getattr(log, "replans", None)
    if missions.done:
        ahead = 0
    elif replans:  # (time, start, missions planned, predicted success): the first is under way
        ahead = replans[-1][2] - 1 + len(log.targets) - len(log.plans)
    else:
        ahead = len(targets) - len(log.plans)
    mean = (log.plans[-1].end_time - log.plans[0].start_time) / len(log.plans)
    # The walk stops half a second after its last plan has ended (the loop above).
    return min(limit, log.plans[-1].end_time + max(ahead, 0) * mean + 0.5)


class _PlannerMissions:
    """Missions planned by a callable (the kinematic tripod plan) inside a MissionSequencer."""

    def __init__(self, builder, station, info, targets, control, initial_yaw: float):
        from qz_drake.robot.kinematics import all_foot_positions
        from qz_drake.systems.mission_sequencer import MissionSequencer, MissionStart

        self.planner = _tripod_planner(info.heightmap, info.params, control)
        x0 = info.initial_state
        feet0 = all_foot_positions(x0[7:25], info.params) + x0[4:7]
        # The first mission starts after 0.5 s of standing (the robot settles on the ground).
        first, reason = self.planner(MissionStart(SETTLE_TIME, (x0[4], x0[5], initial_yaw), feet0, float(x0[6])),
                                     targets[0][:3], targets[0][3], SETTLE_TIME)
        self.first_failure = "" if first is not None else reason
        if first is None:
            return
        self.sequencer = builder.AddSystem(MissionSequencer(targets=targets, planner=self.planner,
                                                            first_plan=first, params=info.params))
        builder.Connect(station.GetOutputPort("state"), self.sequencer.GetInputPort("state"))
        self.plan_port = self.sequencer.GetOutputPort("plan")

    @property
    def log(self):
        return self.sequencer.log

    @property
    def done(self) -> bool:
        return self.sequencer.done

    def counts(self) -> dict:
        return {"blc_solves": 0, "blc_failures": 0, "blc_retries": 0, "blc_solve_time_s": 0.0, "blc_iterations": 0,
                "topology_changes": 0}


class _BlcMissions:
    """Missions solved by the TrajectoryOptimizationBLC system in the diagram, fed by a route
    source: the fixed route's MissionTargetSequencer (each local target once the previous plan
    has ended) or CapPlanner's CapabilityVIPlanner (``route_source``). Both have a ``plan``
    input, ``target`` and ``topology`` outputs, a MissionLog ``log`` and ``done``; the wiring
    is the same."""

    def __init__(self, builder, station, info, targets, control, blc_params=None, route_source=None,
                 mission_retries: int = 0):
        from pydrake.common.value import AbstractValue
        from pydrake.systems.primitives import ConstantValueSource

        from qz_drake.systems.blc import MissionTiming, TrajectoryOptimizationBLC
        from qz_drake.systems.mission_sequencer import MissionTargetSequencer

        self.blc = builder.AddSystem(TrajectoryOptimizationBLC(
            params=info.params, timing=MissionTiming(control.speed, control.phase_duration),
            settle_time=SETTLE_TIME, blc_params=blc_params, initial_topology=info.topology.name,
            mission_retries=mission_retries))
        self.blc.set_name("blc")
        self.targets = builder.AddSystem(route_source or MissionTargetSequencer(targets=targets,
                                                                                plan_ahead=control.plan_ahead))
        heightmap = builder.AddSystem(ConstantValueSource(AbstractValue.Make(info.heightmap)))
        builder.Connect(station.GetOutputPort("state"), self.blc.GetInputPort("state"))
        builder.Connect(self.targets.GetOutputPort("target"), self.blc.GetInputPort("target"))
        builder.Connect(self.targets.GetOutputPort("topology"), self.blc.GetInputPort("topology"))
        builder.Connect(heightmap.get_output_port(), self.blc.GetInputPort("heightmap"))
        builder.Connect(self.blc.GetOutputPort("plan"), self.targets.GetInputPort("plan"))
        if self.targets.HasInputPort("state"):
            builder.Connect(station.GetOutputPort("state"), self.targets.GetInputPort("state"))
        # A route source that goes round missions the BLC could not plan (CapPlanner's TLC).
        self.recovers = self.targets.HasInputPort("failed_missions")
        if self.recovers:
            for name in ("failed_missions", "robot_topology"):
                builder.Connect(self.blc.GetOutputPort(name), self.targets.GetInputPort(name))
        self.plan_port = self.blc.GetOutputPort("plan")

    @property
    def first_failure(self) -> str:
        solves = self.blc.log.solves
        if not solves:
            return ""
        # The first mission's solves (a retry repeats its target and topology).
        first = [s for s in solves if s[1:3] == solves[0][1:3]]
        return "" if any(s[3] for s in first) else first[-1][5]

    @property
    def log(self):
        log = self.targets.log
        failures = self.blc.log.failures
        if self.recovers:  # the ones the route source went round are not the walk's failures
            failures = failures[len(log.recoveries):]
        # Failures as (mission index, reason): the index of the target the BLC was given.
        log.failures = [(len(log.plans), s[5]) for s in failures]
        return log

    @property
    def done(self) -> bool:
        if self.recovers:  # it says when it is done, or gives up (unreachable)
            return self.targets.done
        return bool(self.log.failures) or self.targets.done

    def counts(self) -> dict:
        log = self.blc.log
        counts = getattr(self.targets, "counts", dict)()
        return {**counts, "blc_solves": len(log.solves), "blc_failures": len(log.failures),
                "blc_retries": len(log.retried),
                "blc_solve_time_s": log.solve_time_s,
                "blc_iterations": int(sum(s[6] for s in log.solves)),
                "topology_changes": len(log.switches)}


def _gave_up(metrics: dict, why: str, recoveries: int = 0) -> None:
    """A failed walk whose route source gave up on the way (CapPlanner: no route left round
    ``recoveries`` missions the BLC could not plan) says so: ``unreachable`` first when the
    walk otherwise only missed its target (that is why it did), after the other reasons when
    something worse happened first; the message gains ``why``."""
    if metrics["success"]:
        return
    reasons = list(metrics["reasons"])
    if set(reasons) <= {"missed_target"}:
        reasons.insert(0, "unreachable")
    elif "unreachable" not in reasons:
        reasons.append("unreachable")
    metrics["reasons"] = reasons
    after = f" after going round {recoveries} missions the BLC could not plan" if recoveries else ""
    metrics["reason"] = f"{metrics['reason']}; CapPlanner gave up{after}: {why}"


def _unplanned(scenario, out, missions, *, reason: str | None = None, code: str | None = None,
               extra: dict | None = None) -> SimulationResult:
    """The result of a walk that never started: its first mission could not be planned (or,
    with CapPlanner, no route reaches the goal)."""
    from qz_drake.verdict import blc_failure_code

    reason = reason or f"mission 0 could not be planned: {missions.first_failure}"
    metrics = {"scenario": scenario.name, "success": False, "reason": reason,
               "reasons": [code or blc_failure_code(missions.first_failure)],
               "missions": 0, "planner": scenario.controller.planner,
               **(missions.counts() if missions is not None else {}), **(extra or {})}
    if out is not None:
        (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return SimulationResult(metrics=metrics, times=np.zeros(0), states=np.zeros((0, 49)),
                            foot_contact=np.zeros((0, 6)), trunk_contact=np.zeros(0), files={})


# CapPlanner's walks solve a mission that failed to plan again, up to this often, each time one
# tripod cycle longer (TrajectoryOptimizationBLC's mission_retries). A long_range walk ended at
# its third mission on the BLC's dense check (a stance foot 2 mm outside its kinematic box at
# one 100 Hz sample); 46 of the first 5800 capability trials failed the same way, by 2-6 mm or
# a residual of 0.05-0.08 body weights. The robot stands while the BLC solves, so a retry costs
# wall time only. The capability trials keep 0: their labels are the BLC's first solves, so
# the learned success rates are, if anything, cautious for a walk that retries.
CAPPLANNER_MISSION_RETRIES = 2


def mdp_config(overrides: dict, topologies):
    """CapPlanner's MDP settings: the defaults, ``overrides`` (controller.capability_mdp) by
    name, the topologies the model knows."""
    import dataclasses

    from qz_drake.errors import bad_value
    from qz_drake.planning.capability_mdp import CapabilityMdpConfig

    numbers = [f.name for f in dataclasses.fields(CapabilityMdpConfig) if f.type in ("float", float)]
    for key in overrides:
        if key not in numbers:
            raise bad_value(f"scenario.controller.capability_mdp.{key}", overrides[key],
                            f"not a setting of the MDP (valid: {', '.join(numbers)})")
    return CapabilityMdpConfig(topologies=list(topologies), **{k: float(v) for k, v in overrides.items()}).check()


def _capability_planner(scenario, info):
    """CapPlanner's top-level controller for a walking scenario: the capability model of
    ``controller.capability_model`` (empty: the shipped one), the goal at the route's last
    waypoint, planned over the station's heightmap from the robot's start."""
    from qz_drake.capability.model import CapabilityModel
    from qz_drake.planning.capability_planner import CapabilityVIPlanner
    from qz_drake.systems.state_layout import base_rpy

    from qz_drake.capability.patches import KINDS
    from qz_drake.errors import bad_value
    from qz_drake.robot.topology import TOPOLOGY_NAMES

    from qz_drake.scene import check_standable

    control = scenario.controller
    model = CapabilityModel.load(control.capability_model or None)
    # The topologies the model knows all three moves of.
    topologies = [t for t in TOPOLOGY_NAMES if all(model.has_network(t, k) for k in KINDS)]
    if info.topology.name not in topologies:
        raise bad_value("scenario.robot.topology", info.topology.name,
                        f"the capability model has no networks for it (it has {', '.join(topologies) or 'none'})")
    x0 = info.initial_state
    goal = control.route[-1]
    check_standable(info.heightmap, (goal.x, goal.y), info.topology.name,
                    f"scenario.controller.route[{len(control.route) - 1}]")
    return CapabilityVIPlanner(model=model, heightmap=info.heightmap, goal=(goal.x, goal.y),
                               start=(float(x0[4]), float(x0[5]), float(base_rpy(x0)[2])),
                               initial_topology=info.topology.name, plan_ahead=control.plan_ahead,
                               mdp_config=mdp_config(control.capability_mdp, topologies))


def _planned_base(plans, times):
    """The planned base position at each time (the plan in force then), NaN before the first."""
    out = np.full((len(times), 3), np.nan)
    for plan in plans:
        for k, t in enumerate(times):
            if plan.start_time <= t:
                out[k] = plan.base_position(min(t, plan.end_time))
    return out


def feet_in_world(states, params) -> np.ndarray:
    """Foot-sphere centres (N, 6, 3) in the world from logged station states."""
    from qz_drake.robot.kinematics import all_foot_positions
    from qz_drake.systems.state_layout import base_pose

    return np.array([all_foot_positions(x[7:25], params) @ base_pose(x).rotation().matrix().T
                     + x[4:7] for x in states]).reshape(len(states), 6, 3)


def walking_metrics(scenario, info, log, targets, times, states, contacts, trunk, desired, *, fell: bool,
                    timed_out: bool, leg_link_force=None, self_force=None) -> dict:
    """A walk's metrics and its strict verdict (qz_drake.verdict): success, the reason codes
    and messages, final errors, tilt, contacts, slip, tracking, solves."""
    from qz_drake.verdict import judge_walk

    planned = _planned_base(log.plans, times)
    valid = ~np.isnan(planned[:, 0])
    tracking = float(np.sqrt(np.mean(np.sum((states[valid, 4:7] - planned[valid]) ** 2, axis=1)))) \
        if valid.any() else 0.0
    joint_rms = float(np.sqrt(np.mean((states[:, JOINT_Q] - desired[:, :18]) ** 2)))
    n = len(times)
    verdict = judge_walk(
        scenario.success, goal_xy_yaw=targets[-1][:3], times=times, states=states,
        desired_q=desired, feet_W=feet_in_world(states, info.params), contacts=contacts,
        trunk=trunk, leg_link_force=np.zeros((n, 6)) if leg_link_force is None else leg_link_force,
        self_force=np.zeros(n) if self_force is None else self_force,
        blc_failures=[f"mission {i}: {r}" for i, r in log.failures], fell=fell, timed_out=timed_out)
    return {
        "scenario": scenario.name,
        "success": verdict.success,
        "reason": verdict.message,
        "reasons": verdict.reasons,
        **verdict.measures,
        "tracking_rms_m": tracking,
        "joint_tracking_rms_rad": joint_rms,
        "missions": len(log.plans),
        "planner_failures": len(log.failures),
        # False when the station cannot see leg-link contacts (the LCM hardware interface): the
        # verdict then has not checked them.
        "leg_contact_observed": leg_link_force is not None,
    }
