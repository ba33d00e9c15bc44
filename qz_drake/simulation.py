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
from qz_drake.station import GRAVITY, make_station
from qz_drake.systems.joint_pd import JointPdController
from qz_drake.systems.state_layout import BASE_POS, JOINT_Q, base_rpy, tilt_deg

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


def add_tracking_controller(builder, station, info, plan, *, kp: float, kd: float):
    """Wires plan -> InverseKinematicsTracker -> JointPdController (Eq. 7) -> station; returns
    (tracker, controller). ``plan`` is a BodyFeetTrajectory held in a constant source."""
    from pydrake.common.value import AbstractValue
    from pydrake.systems.primitives import ConstantValueSource

    from qz_drake.systems.ik_tracker import InverseKinematicsTracker

    source = builder.AddSystem(ConstantValueSource(AbstractValue.Make(plan)))
    tracker = builder.AddSystem(InverseKinematicsTracker(topology=info.topology, params=info.params))
    controller = builder.AddSystem(JointPdController(kp=kp, kd=kd, params=info.params))
    builder.Connect(source.get_output_port(), tracker.GetInputPort("trajectory"))
    builder.Connect(station.GetOutputPort("state"), controller.GetInputPort("state"))
    builder.Connect(tracker.GetOutputPort("desired_state"), controller.GetInputPort("desired_state"))
    builder.Connect(tracker.GetOutputPort("foot_force_feedforward"),
                    controller.GetInputPort("foot_force_feedforward"))
    builder.Connect(controller.GetOutputPort("joint_torque"), station.GetInputPort("joint_torque"))
    return tracker, controller


def simulate(scenario: Scenario, *, duration: float | None = None, meshcat: Meshcat | None = None,
             out_dir: str | Path | None = None) -> SimulationResult:
    """Simulates a scenario; writes recording.html, metrics.json and plots to out_dir if given."""
    builder = DiagramBuilder()
    out = Path(out_dir) if out_dir is not None else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        if meshcat is None:
            meshcat = Meshcat()
    station_diagram, info = make_station(scenario, meshcat, mesh_dir=None if out is None else out / "terrain_mesh")
    station = builder.AddSystem(station_diagram)
    _standing_controller(builder, station, info, scenario)
    period = 1.0 / LOG_RATE
    state_log = LogVectorOutput(station.GetOutputPort("state"), builder, period)
    contact_log = LogVectorOutput(station.GetOutputPort("foot_contact"), builder, period)
    trunk_log = LogVectorOutput(station.GetOutputPort("trunk_contact"), builder, period)
    diagram = builder.Build()

    simulator = Simulator(diagram)
    simulator.Initialize()
    duration = scenario.simulation.duration if duration is None else duration
    if meshcat is not None:
        meshcat.StartRecording()
    wall_start = time.perf_counter()
    simulator.AdvanceTo(duration)
    wall = time.perf_counter() - wall_start
    context = simulator.get_context()
    files = {}
    if meshcat is not None:
        meshcat.StopRecording()
    times = state_log.FindLog(context).sample_times()
    states = state_log.FindLog(context).data().T
    contacts = contact_log.FindLog(context).data().T
    trunk = trunk_log.FindLog(context).data()[0]
    metrics = standing_metrics(scenario, info, times, states, trunk)
    metrics.update(sim_time_s=float(duration), wall_time_s=wall,
                   realtime_factor=float(duration / wall) if wall > 0 else float("inf"),
                   terrain_contact=info.contact_representation)
    if out is not None:
        from qz_drake.viz.plots import plot_standing
        from qz_drake.viz.recording import save_recording

        files["recording"] = str(save_recording(meshcat, out / "recording.html"))
        files["plot"] = str(plot_standing(times, states, contacts, info, out / "base_and_contacts.png"))
        (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
        files["metrics"] = str(out / "metrics.json")
    return SimulationResult(metrics=metrics, times=times, states=states, foot_contact=contacts,
                            trunk_contact=trunk, files=files)


def standing_metrics(scenario: Scenario, info, times, states, trunk) -> dict:
    """Success of a standing run: base height within tolerance of nominal, no trunk contact,
    small tilt. The first 0.5 s (settling into the ground) is not judged for height."""
    z0 = info.initial_state[BASE_POS][2]
    settled = times >= min(0.5, times[-1])
    height_error = np.abs(states[settled, 6] - z0)
    tilts = np.array([tilt_deg(x) for x in states])
    xy_drift = np.linalg.norm(states[-1, 4:6] - info.initial_state[4:6])
    crit = scenario.success
    max_height_error = float(height_error.max())
    trunk_contacts = int(np.count_nonzero(trunk > 0.5))
    fell = bool(tilts.max() > crit.max_tilt_deg)
    success = (max_height_error <= crit.max_base_height_error and trunk_contacts == 0 and not fell)
    reason = "" if success else (
        "fell" if fell else "trunk touched the terrain" if trunk_contacts else
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
    }
