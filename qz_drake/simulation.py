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

from qz_drake.config import Scenario, check_simulated_time
from qz_drake.scene import GRAVITY
from qz_drake.station import make_station
from qz_drake.systems.joint_pd import JointPdController, add_joint_pd
from qz_drake.state_layout import BASE_POS, BASE_XY, BASE_Z, JOINT_Q, base_pose, base_rpy, tilt_deg
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
    mode the tracker's q_des and v_des go to the station's ``joint_position_command`` and
    ``joint_velocity_command`` (the drives' PD tracks them: Eq. 7's PD in the drives) and the
    controller adds only the compensation and force feedforward, at the tracker's rate.
    """
    from pydrake.common.value import AbstractValue
    from pydrake.systems.primitives import ConstantValueSource

    from qz_drake.systems.ik_tracker import InverseKinematicsTracker

    if plan_port is None:
        plan_port = builder.AddSystem(ConstantValueSource(AbstractValue.Make(plan))).get_output_port()
    tracker = builder.AddSystem(InverseKinematicsTracker(topology=info.topology, params=info.params))
    controller = add_joint_pd(builder, station, tracker, params=info.params, kp=kp, kd=kd,
                              position_mode=position_mode, update_period=tracker.update_period)
    builder.Connect(plan_port, tracker.GetInputPort("trajectory"))
    return tracker, controller


def simulate(scenario: Scenario, *, duration: float | None = None, meshcat: Meshcat | None = None,
             out_dir: str | Path | None = None, station_factory=make_station,
             realtime_rate: float = 0.0, progress=None, route_source=None) -> SimulationResult:
    """Simulates a scenario; writes recording.html, metrics.json and plots to out_dir if given.

    ``station_factory(scenario, meshcat, mesh_dir=...) -> (diagram, info)`` builds the station
    (make_station; qz_drake.hardware.loopback: over LCM). ``realtime_rate`` paces the simulator
    (0: as fast as possible; 1 against a robot driver in another process). ``progress(sim_time,
    end_time, missions)`` hears how far the run is while it runs (a walk: every half second
    simulated; a standing run: at most every PROGRESS_PERIOD of wall time) and once when the
    simulation has ended (end_time then its final time; missions None for a standing run).
    ``route_source``: a walk's, as in walk()."""
    if duration is not None:
        # Drake's AdvanceTo would stop the interpreter on a negative or NaN end time.
        check_simulated_time("duration", duration)
    if scenario.controller.kind == "walk":
        return walk(scenario, meshcat=meshcat, out_dir=out_dir, max_duration=duration,
                    station_factory=station_factory, realtime_rate=realtime_rate, progress=progress,
                    route_source=route_source)
    builder = DiagramBuilder()
    out = Path(out_dir) if out_dir is not None else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        if meshcat is None:
            meshcat = recording_meshcat()
    station_diagram, info = station_factory(scenario, meshcat)
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


def _desired_at_state_times(logs, context) -> np.ndarray:
    """The desired-state log (rows: the state, columns: samples) at the times the logged states
    show the robot at. In the lockstep simulation those are the samples' own times. A planning
    process's station (qz_drake.hardware.planning_station) runs ahead of the robot, up to the
    servo's plan lead, and shows the newest status, taken at an earlier plan time, which it
    logs as ``state_plan_time``: the plan is read there (linear between samples; NaN, before
    the first status: the sample's own), so that the tracking error is the robot's, not the
    lead's (a swing joint at 300 deg/s is 15 deg from the plan 50 ms on)."""
    desired_log = logs["desired"].FindLog(context)
    if logs.get("state_plan_time") is None:
        return desired_log.data()
    return desired_at(desired_log.sample_times(), desired_log.data(),
                      logs["state_plan_time"].FindLog(context).data()[0])


def desired_at(times: np.ndarray, desired: np.ndarray, at: np.ndarray) -> np.ndarray:
    """``desired`` (rows: the state, columns: the samples at ``times``) read at the times
    ``at`` (one per sample), linear between samples, held beyond them; a NaN in ``at`` reads
    the sample's own column."""
    times, desired, at = np.asarray(times, dtype=float), np.asarray(desired, dtype=float), np.asarray(at, dtype=float)
    n = min(len(at), len(times))
    if n == 0:
        return desired.copy()
    when = np.where(np.isfinite(at[:n]), at[:n], times[:n])
    aligned = desired.copy()
    aligned[:, :n] = np.stack([np.interp(when, times, row) for row in desired])
    return aligned


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
    height_error = np.abs(states[settled, BASE_Z] - z0)
    tilts = np.array([tilt_deg(x) for x in states])
    xy_drift = np.linalg.norm(states[-1, BASE_XY] - info.initial_state[BASE_XY])
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
        "final_base_height_m": float(states[-1, BASE_Z]),
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
                              duration=duration, phase_duration=control.timing.phase_duration, params=params,
                              start_feet_W=start.feet_W), ""
    return plan


class FixedRoute:
    """A walk's route source: the scenario's route split into missions, each local target handed
    to the BLC system once the previous plan has ended (MissionTargetSequencer).

    walk() receives its route source from whoever calls it, so that nothing here depends on the
    planners above (CapPlanner's is qz_drake.planning.capplanner_route.CapPlannerRoute). A
    route source says what the walk's BLC system needs of it:

    * ``make(scenario, info, targets)``: the system that feeds the BLC, with a ``plan`` input,
      ``target`` and ``topology`` outputs, a MissionLog ``log`` and ``done`` (and, to go round
      missions the BLC could not plan, ``failed_missions`` and ``robot_topology`` inputs);
    * ``unreachable(system)``: why it found no route (empty: it did; the walk then never starts);
    * ``blc_parameters()``: the BLC's parameters when the caller gives none (None: the defaults);
    * ``mission_retries``: how often the BLC solves a failed mission again when the caller does
      not say, and ``blc_ladder``: the BLC ladder's rungs instead (None: the retries');
    * ``chooses_goal_heading``: whether the goal's heading is the route source's to choose (not
      judged);
    * ``name``: who plans the route, in messages (e.g. "CapPlanner gave up ...");
    * ``add_visuals(builder, system, meshcat, info)`` and ``plots(system, scenario, info, states,
      out) -> files``: what it adds to the recording and the walk's figures.
    """

    mission_retries = 0
    blc_ladder = None
    chooses_goal_heading = False
    # Who plans the route, in messages.
    name = "the fixed route"

    def blc_parameters(self):
        return None

    def make(self, scenario, info, targets, blc_params=None):
        """The walk's route source system; ``blc_params`` are the BLC's (what its missions will
        end in: BlcParameters.terminal_stance), None the defaults."""
        from qz_drake.systems.mission_sequencer import MissionTargetSequencer

        return MissionTargetSequencer(targets=targets, plan_ahead=scenario.controller.plan_ahead)

    def unreachable(self, source) -> str:
        return ""

    def add_visuals(self, builder, source, meshcat, info) -> None:
        pass

    def plots(self, source, scenario, info, states, out) -> dict:
        return {}


@dataclasses.dataclass
class BuiltWalk:
    """A walk's diagram, built and not yet run (build_walk)."""

    diagram: object
    station: object
    info: object
    # The local targets (x, y, yaw, topology) of the scenario's route.
    targets: list
    # _BlcMissions or _PlannerMissions: the missions' log, counts and ``done``.
    missions: object
    route_source: FixedRoute | None
    # Loggers of the station's state, foot contacts, trunk contact, the tracker's desired
    # state and, where the station observes them, leg-link and self-contact forces.
    logs: dict
    # perf_counter() when the first mission's planning began: the real-time factor includes it.
    wall_start: float


@dataclasses.dataclass
class WalkNotStarted:
    """A walk that never started: its first mission could not be planned, or the route source
    found no route to the goal."""

    reason: str
    code: str
    counts: dict


@dataclasses.dataclass
class WalkRun:
    """What a walk's simulation ended with (run_walk)."""

    # The simulator owns the context that holds the logs.
    simulator: Simulator
    fell: bool
    # Ended early by ``stop_on_failure``.
    stopped: bool
    limit: float
    # Wall time from the first mission's planning to the end. [s]
    wall: float

    @property
    def context(self):
        return self.simulator.get_context()


def walk(scenario: Scenario, *, meshcat: Meshcat | None = None, out_dir: str | Path | None = None,
         max_duration: float | None = None, heightmap=None, stop_on_failure: bool = False,
         blc_params=None, station_factory=make_station, realtime_rate: float = 0.0,
         mission_retries: int | None = None, progress=None, route_source: FixedRoute | None = None,
         on_judged=None, blc_ladder=None) -> SimulationResult:
    """Walks a scenario's route: missions planned from the measured state, IK + joint PD; builds
    (build_walk), runs (run_walk), judges (judge_walk_run) and writes its files.

    ``route_source`` feeds the BLC its local targets (planner "blc": FixedRoute when None;
    "capplanner": qz_drake.planning.capplanner_route.CapPlannerRoute, which the caller must
    pass). ``heightmap`` replaces the map of the scenario's terrain section (see make_station).
    With ``stop_on_failure`` the run ends as soon as a contact or tracking check of the verdict
    has failed (capability trials: the rest of the walk cannot change the label). ``blc_params``
    are the BLC's BlcParameters (None: the route source's). ``mission_retries``: how often the
    BLC system solves a mission that failed to plan again, one tripod cycle longer each time
    (None: the route source's). ``blc_ladder``: the rungs a refused mission is solved on instead
    (TrajectoryOptimizationBLC's ``ladder``; None: the route source's, or the retries').
    ``station_factory``, ``realtime_rate`` and ``progress`` as in
    simulate(); ``progress`` hears the missions planned so far. ``on_judged(built, run, result)``
    is called once the walk is judged, before its files are written (to read the missions'
    logs: qz_drake.capability.walk_missions); a walk that never started does not call it."""
    out = Path(out_dir) if out_dir is not None else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        meshcat = meshcat or recording_meshcat()
    built = build_walk(scenario, route_source=route_source, meshcat=meshcat, heightmap=heightmap,
                       blc_params=blc_params, station_factory=station_factory, mission_retries=mission_retries,
                       blc_ladder=blc_ladder)
    if isinstance(built, WalkNotStarted):
        return _unplanned(scenario, out, built)
    run = run_walk(built, scenario, max_duration=max_duration, stop_on_failure=stop_on_failure,
                   realtime_rate=realtime_rate, meshcat=meshcat, progress=progress)
    if isinstance(run, WalkNotStarted):
        return _unplanned(scenario, out, run)
    result = judge_walk_run(scenario, built, run)
    if on_judged is not None:
        on_judged(built, run, result)
    if out is not None:
        from qz_drake.viz.plots import plot_walk
        from qz_drake.viz.recording import save_recording

        files = result.files
        files["recording"] = str(save_recording(meshcat, out / "recording.html", follow_robot=True))
        desired = _desired_at_state_times(built.logs, run.context).T
        files.update(plot_walk(result.times, result.states, result.foot_contact, desired, built.missions.log,
                               built.info, out))
        if built.route_source is not None:
            files.update(built.route_source.plots(built.missions.targets, scenario, built.info, result.states, out))
        (out / "metrics.json").write_text(json.dumps(result.metrics, indent=2))
        files["metrics"] = str(out / "metrics.json")
    return result


def build_walk(scenario: Scenario, *, route_source: FixedRoute | None = None, meshcat: Meshcat | None = None,
               mesh_dir: Path | None = None, heightmap=None, blc_params=None, station_factory=make_station,
               mission_retries: int | None = None, blc_ladder=None) -> BuiltWalk | WalkNotStarted:
    """The walk's diagram: station, missions (the tripod plan, or the BLC system fed by the
    route source), IK tracker and joint PD, loggers. Arguments as in walk()."""
    from qz_drake.errors import bad_value
    from qz_drake.systems.mission_sequencer import split_route

    control = scenario.controller
    if control.planner == "tripod" and route_source is not None:
        raise bad_value("scenario.controller.planner", control.planner,
                        "the kinematic tripod plan has no route source (a route source feeds the BLC)")
    if control.planner == "capplanner" and route_source is None:
        raise bad_value("scenario.controller.planner", control.planner,
                        "needs CapPlanner's route source: walk(..., route_source=qz_drake.planning."
                        "capplanner_route.route_source_for(scenario)), as `qz simulate` does")
    if control.planner == "blc" and route_source is None:
        route_source = FixedRoute()
    builder = DiagramBuilder()
    extra = {} if heightmap is None else {"heightmap": heightmap}
    station_diagram, info = station_factory(scenario, meshcat, mesh_dir=mesh_dir, **extra)
    station = builder.AddSystem(station_diagram)
    x0 = info.initial_state
    targets = split_route(tuple(x0[BASE_XY]), [(w.x, w.y, w.yaw, w.topology) for w in control.route],
                          control.mission_length)
    # Wall time counts from the first mission's planning, so the real-time factor includes it.
    wall_start = time.perf_counter()
    if route_source is not None:
        blc_params = route_source.blc_parameters() if blc_params is None else blc_params
        ladder = getattr(route_source, "blc_ladder", None) if blc_ladder is None else blc_ladder
        retries = route_source.mission_retries if mission_retries is None else mission_retries
        if ladder is not None and mission_retries is None:
            retries = 0  # the ladder replaces the route source's retries
        source = route_source.make(scenario, info, targets, blc_params=blc_params)
        unreachable = route_source.unreachable(source)
        if unreachable:
            return WalkNotStarted(f"goal unreachable: {unreachable}", "unreachable", source.counts())
        missions = _BlcMissions(builder, station, info, source, control, blc_params, mission_retries=retries,
                                ladder=ladder)
        if meshcat is not None:
            route_source.add_visuals(builder, source, meshcat, info)
    else:
        missions = _PlannerMissions(builder, station, info, targets, control, scenario.robot.initial_yaw)
        if missions.first_failure:
            return _not_started(missions)
    tracker, _ = add_tracking_controller(builder, station, info, kp=control.kp, kd=control.kd,
                                         plan_port=missions.plan_port,
                                         position_mode=scenario.station.control_mode == "position")
    if station.HasInputPort("plan"):  # a planning process's station sends each plan to its servo
        builder.Connect(missions.plan_port, station.GetInputPort("plan"))
    logs = dict(zip(("state", "contact", "trunk"), _log_station(builder, station)))
    logs["desired"] = LogVectorOutput(tracker.GetOutputPort("desired_state"), builder, 1.0 / LOG_RATE)
    logs["leg"], logs["self"] = (_optional_log(builder, station, name) for name in ("leg_link_force", "self_contact"))
    logs["state_plan_time"] = _optional_log(builder, station, "state_plan_time")
    return BuiltWalk(diagram=builder.Build(), station=station, info=info, targets=targets, missions=missions,
                     route_source=route_source, logs=logs, wall_start=wall_start)


def run_walk(built: BuiltWalk, scenario: Scenario, *, max_duration: float | None = None,
             stop_on_failure: bool = False, realtime_rate: float = 0.0, meshcat: Meshcat | None = None,
             progress=None) -> WalkRun | WalkNotStarted:
    """Simulates a built walk until its missions are done (and the robot has stood half a
    second after the last), it falls, ``stop_on_failure`` sees a failed check, or the time
    limit (``max_duration``, None: the scenario's duration) is reached."""
    missions, logs, station = built.missions, built.logs, built.station
    simulator = Simulator(built.diagram)
    simulator.set_target_realtime_rate(realtime_rate)
    simulator.Initialize()
    if missions.first_failure:
        return _not_started(missions)
    limit = scenario.simulation.duration if max_duration is None else max_duration
    if meshcat is not None:
        meshcat.StartRecording(frames_per_second=RECORDING_FPS)
    context = simulator.get_context()
    station_context = station.GetMyContextFromRoot(context)
    fell = False
    stopped = False
    crit = scenario.success

    def data(name):
        return logs[name].FindLog(context).data()

    while context.get_time() < limit:
        simulator.AdvanceTo(min(limit, context.get_time() + 0.5))
        x = station.GetOutputPort("state").Eval(station_context)
        if tilt_deg(x) > _FALL_TILT_DEG:
            fell = True
            break
        if stop_on_failure and (
                np.any(data("trunk") > 0.5)
                or (logs["leg"] is not None and np.any(data("leg") > crit.leg_contact_force))
                or (logs["self"] is not None and np.any(data("self") > crit.leg_contact_force))
                or np.degrees(np.max(np.abs(data("state")[JOINT_Q] - _desired_at_state_times(logs, context)[:18]),
                                     initial=0.0))
                > crit.max_joint_error_deg):
            stopped = True
            break
        if missions.done and missions.log.plans and \
                context.get_time() >= missions.log.plans[-1].end_time + 0.5:
            break
        halted = getattr(station, "halted", None)  # a station whose robot stopped (the servo's safe stop)
        if halted is not None and halted(context):
            stopped = True
            break
        if progress is not None:
            progress(context.get_time(), _expected_end(missions, built.targets, limit), len(missions.log.plans))
    wall = time.perf_counter() - built.wall_start
    if progress is not None:
        progress(context.get_time(), context.get_time(), len(missions.log.plans))
    if meshcat is not None:
        meshcat.StopRecording()
    return WalkRun(simulator=simulator, fell=fell, stopped=stopped, limit=limit, wall=wall)


def judge_walk_run(scenario: Scenario, built: BuiltWalk, run: WalkRun) -> SimulationResult:
    """The walk's logs, its metrics and its strict verdict (walking_metrics), the route
    source's and the station's counts; no files."""
    context, missions, info = run.context, built.missions, built.info
    logs = {name: None if log is None else log.FindLog(context) for name, log in built.logs.items()}
    times = logs["state"].sample_times()
    states = logs["state"].data().T
    contacts = logs["contact"].data().T
    trunk = logs["trunk"].data()[0]
    desired = _desired_at_state_times(built.logs, context).T
    links = (None if logs["leg"] is None else logs["leg"].data().T,
             None if logs["self"] is None else logs["self"].data()[0])
    targets = built.targets
    if built.route_source is not None and built.route_source.chooses_goal_heading:
        targets = targets[:-1] + [(targets[-1][0], targets[-1][1], None, targets[-1][3])]
    metrics = walking_metrics(scenario, info, missions.log, targets, times, states, contacts, trunk, desired,
                              fell=run.fell,
                              timed_out=not run.stopped and (not missions.done or context.get_time() >= run.limit),
                              leg_link_force=links[0], self_force=links[1])
    sim_time = float(context.get_time())
    counts = missions.counts()
    wall = run.wall
    metrics.update(sim_time_s=sim_time, wall_time_s=wall, realtime_factor=sim_time / wall if wall > 0 else 0.0,
                   realtime_factor_excluding_planning=sim_time / max(wall - counts["blc_solve_time_s"], 1e-9),
                   terrain_contact=info.contact_representation, planner=scenario.controller.planner, **counts)
    if counts.get("unreachable"):
        _gave_up(metrics, counts["unreachable"], counts.get("tlc_recoveries", 0),
                 getattr(built.route_source, "name", "the route source"))
    _add_station_metrics(metrics, built.station, context)
    return SimulationResult(metrics=metrics, times=times, states=states, foot_contact=contacts,
                            trunk_contact=trunk, files={})


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
        feet0 = all_foot_positions(x0[JOINT_Q], info.params) + x0[BASE_POS]
        x_start, y_start, z_start = x0[BASE_POS]
        # The first mission starts after 0.5 s of standing (the robot settles on the ground).
        first, reason = self.planner(MissionStart(SETTLE_TIME, (x_start, y_start, initial_yaw), feet0, float(z_start)),
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
    """Missions solved by the TrajectoryOptimizationBLC system in the diagram, fed by the system
    a route source made (``source``: the fixed route's MissionTargetSequencer, CapPlanner's
    CapabilityVIPlanner; see FixedRoute); the wiring is the same."""

    def __init__(self, builder, station, info, source, control, blc_params=None, mission_retries: int = 0,
                 ladder=None):
        from pydrake.common.value import AbstractValue
        from pydrake.systems.primitives import ConstantValueSource

        from qz_drake.systems.blc import TrajectoryOptimizationBLC

        self.blc = builder.AddSystem(TrajectoryOptimizationBLC(
            params=info.params, timing=control.timing,
            settle_time=SETTLE_TIME, blc_params=blc_params, initial_topology=info.topology.name,
            mission_retries=mission_retries, ladder=ladder))
        self.blc.set_name("blc")
        self.targets = builder.AddSystem(source)
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
        first = [s for s in solves if (s.target, s.topology) == (solves[0].target, solves[0].topology)]
        return "" if any(s.success for s in first) else first[-1].reason

    @property
    def log(self):
        log = self.targets.log
        failures = self.blc.log.failures
        if self.recovers:  # the ones the route source went round are not the walk's failures
            failures = failures[len(log.recoveries):]
        # Failures as (mission index, reason): the index of the target the BLC was given.
        log.failures = [(len(log.plans), s.reason) for s in failures]
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
                "blc_iterations": int(sum(s.iterations for s in log.solves)),
                "topology_changes": len(log.switches)}


def _gave_up(metrics: dict, why: str, recoveries: int = 0, planner: str = "CapPlanner") -> None:
    """A failed walk whose route source gave up on the way (no route left round
    ``recoveries`` missions the BLC could not plan) says so: ``unreachable`` first when the
    walk otherwise only missed its target (that is why it did), after the other reasons when
    something worse happened first; the message gains ``why``, with the ``planner`` that gave
    up (the route source's ``name``)."""
    if metrics["success"]:
        return
    reasons = list(metrics["reasons"])
    if set(reasons) <= {"missed_target"}:
        reasons.insert(0, "unreachable")
    elif "unreachable" not in reasons:
        reasons.append("unreachable")
    metrics["reasons"] = reasons
    after = f" after going round {recoveries} missions the BLC could not plan" if recoveries else ""
    metrics["reason"] = f"{metrics['reason']}; {planner} gave up{after}: {why}"


def _not_started(missions) -> WalkNotStarted:
    """A walk whose first mission could not be planned."""
    from qz_drake.verdict import blc_failure_code

    return WalkNotStarted(f"mission 0 could not be planned: {missions.first_failure}",
                          blc_failure_code(missions.first_failure), missions.counts())


def _unplanned(scenario, out, not_started: WalkNotStarted) -> SimulationResult:
    """The result of a walk that never started."""
    metrics = {"scenario": scenario.name, "success": False, "reason": not_started.reason,
               "reasons": [not_started.code], "missions": 0, "planner": scenario.controller.planner,
               **not_started.counts}
    if out is not None:
        (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return SimulationResult(metrics=metrics, times=np.zeros(0), states=np.zeros((0, 49)),
                            foot_contact=np.zeros((0, 6)), trunk_contact=np.zeros(0), files={})


def _planned_base(plans, times):
    """The planned base position at each time (the plan in force then: the last of ``plans``
    started by then), NaN before the first; each time's position computed once."""
    out = np.full((len(times), 3), np.nan)
    owner = np.full(len(times), -1)
    for i, plan in enumerate(plans):
        owner[np.asarray(times) >= plan.start_time] = i
    for k in np.flatnonzero(owner >= 0):
        plan = plans[owner[k]]
        out[k] = plan.base_position(min(times[k], plan.end_time))
    return out


def feet_in_world(states, params) -> np.ndarray:
    """Foot-sphere centres (N, 6, 3) in the world from logged station states."""
    from qz_drake.robot.kinematics import all_foot_positions

    return np.array([all_foot_positions(x[JOINT_Q], params) @ base_pose(x).rotation().matrix().T
                     + x[BASE_POS] for x in states]).reshape(len(states), 6, 3)


def walking_metrics(scenario, info, log, targets, times, states, contacts, trunk, desired, *, fell: bool,
                    timed_out: bool, leg_link_force=None, self_force=None) -> dict:
    """A walk's metrics and its strict verdict (qz_drake.verdict): success, the reason codes
    and messages, final errors, tilt, contacts, slip, tracking, solves."""
    from qz_drake.verdict import judge_walk

    planned = _planned_base(log.plans, times)
    valid = ~np.isnan(planned[:, 0])
    tracking = float(np.sqrt(np.mean(np.sum((states[valid, BASE_POS] - planned[valid]) ** 2, axis=1)))) \
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
        # Whether the verdict has checked the leg links' contacts (leg_terrain_contacts, the
        # samples with a leg link on the terrain): False where the station cannot see them (the
        # LCM hardware interface).
        "leg_contacts_checked": leg_link_force is not None,
    }
