"""Trotting runs on ground materials: station + TrottingController + SphericalImpedance +
TerrainClassifier, with the signals the experiments of paper 002 look at.

``simulate_trot`` is the one place such a diagram is built, for the dataset collection, the
classifier's training runs and the adaptive-locomotion experiments.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput

from qz_drake.classification import features as feat
from qz_drake.config import Scenario
from qz_drake.errors import bad_value
from qz_drake.robot.kinematics import all_foot_positions
from qz_drake.robot.params import NUM_LEGS
from qz_drake.station import make_station
from qz_drake.state_layout import BASE_POS, JOINT_Q, base_pose, tilt_deg
from qz_drake.classification.terrain_classifier import DEFAULT_STIFFNESS, TerrainClassifier
from qz_drake.systems.trotting import TrotConfig, add_trotting_controller

# Logging period of body signals (the vibration experiments look at these). [s]
LOG_PERIOD = 0.004
# Logging period of the classifier's stance outputs: shorter than any stance. [s]
STANCE_LOG_PERIOD = 0.02
# A tilt beyond this ends a run as a fall. [deg]
FALL_TILT_DEG = 45.0
# Ground ahead of and behind the robot's travel. [m]
_MARGIN = 2.0


def trot_scenario(material: str = "concrete", *, distance: float = 6.0, payload_kg: float = 5.0,
                  mixed_patch_length: float = 0.0, mixed_patch_width: float = math.inf, seed: int = 0) -> Scenario:
    """A flat floor of one material for ``distance`` metres of trotting; with a positive
    ``mixed_patch_length`` [m] a floor of concrete, wood and foam stripes instead (the
    material_floor generator; a finite ``mixed_patch_width`` [m] cuts the stripes into patches
    along y; ``material`` is then the default of the robot's contact properties)."""
    from qz_drake.terrain import get_material

    get_material(material)  # an unknown name is an error naming it
    if not (math.isfinite(distance) and distance > 0):
        raise bad_value("distance", distance, "must be a positive number of metres")
    scenario = Scenario(name=f"trot_{'mixed' if mixed_patch_length > 0 else material}", random_seed=seed)
    size_x = distance + 2 * _MARGIN
    if mixed_patch_length > 0:
        scenario.terrain.kind = "material_floor"
        scenario.terrain.params = {"patch_length": float(mixed_patch_length), "size_x": size_x, "size_y": 3.0}
        if math.isfinite(mixed_patch_width):
            scenario.terrain.params["patch_width"] = float(mixed_patch_width)
    else:
        scenario.terrain.kind = "flat"
        scenario.terrain.params = {"size_x": size_x, "size_y": 3.0}
    scenario.terrain.material = material
    scenario.terrain.contact = "boxes"
    scenario.terrain.region = [-_MARGIN, distance + _MARGIN, -1.5, 1.5]
    scenario.robot.payload_kg = payload_kg
    return scenario


@dataclasses.dataclass
class TrotRun:
    """Logged signals of one trotting run."""

    times: np.ndarray  # (N,) at LOG_PERIOD
    states: np.ndarray  # (N, 49)
    imu: np.ndarray  # (N, 10)
    gait_state: np.ndarray  # (N, 6)
    stiffness: np.ndarray  # (N, 6) stance stiffness the impedance applied [N/m]
    terrain_label: np.ndarray  # (N, 6) confirmed labels (-1 unknown)
    ground_truth: np.ndarray  # (N, 6) index of the material under each foot (-1 off the map)
    classes: tuple[str, ...]
    # One row per finished stance with features: time seen, leg, features (18), commanded
    # speed, ground truth and the online prediction (-1 without models).
    stance_time: np.ndarray
    stance_leg: np.ndarray
    stance_features: np.ndarray
    stance_speed: np.ndarray
    stance_truth: np.ndarray
    stance_prediction: np.ndarray
    skipped_stances: np.ndarray  # (6,)
    fell: bool
    wall_time_s: float

    def vertical_acceleration(self) -> np.ndarray:
        """The IMU's specific force along world z minus g (paper's "acceleration along y",
        the direction of gravity). [m/s^2]"""
        out = np.empty(len(self.times))
        for k, x in enumerate(self.states):
            out[k] = (base_pose(x).rotation().matrix() @ self.imu[k, 7:10])[2] - 9.81
        return out


def speed_schedule(duration: float, speed_range=(0.0, 0.6), hold: float = 2.0, seed: int = 0):
    """Random piecewise-constant forward speeds: a new one from ``speed_range`` every ``hold`` s."""
    rng = np.random.default_rng(seed)
    times = np.arange(0.0, duration + hold, hold)
    return times, rng.uniform(speed_range[0], speed_range[1], len(times))


def simulate_trot(scenario: Scenario, *, duration: float, speed=0.3, trot_config: TrotConfig | None = None,
                  models=None, adaptive: bool = False, stiffness=DEFAULT_STIFFNESS,
                  stiffness_by_material: dict | None = None, meshcat=None) -> TrotRun:
    """Trots a scenario for ``duration`` s.

    ``speed`` is a forward speed [m/s] or a schedule (times, speeds) held piecewise constant.
    With ``models`` the TerrainClassifier labels every stance; with ``adaptive`` its stiffness
    output (``stiffness_by_material``, default the paper's presets) drives the impedance,
    otherwise every leg keeps ``stiffness`` [N/m] (one value, or one per leg).
    """
    from pydrake.trajectories import PiecewisePolynomial
    from pydrake.systems.primitives import TrajectorySource

    if not (math.isfinite(duration) and duration > 0):
        raise bad_value("duration", duration, "must be a positive number of seconds")
    if adaptive and models is None:
        raise bad_value("adaptive", adaptive, "adaptive stiffness needs trained models")
    builder = DiagramBuilder()
    station_diagram, info = make_station(scenario, meshcat)
    station = builder.AddSystem(station_diagram)
    if np.isscalar(speed):
        if not (math.isfinite(speed) and 0 <= speed <= 1.0):
            raise bad_value("speed", speed, "must be within [0, 1] m/s")
        velocity_port = builder.AddSystem(ConstantVectorSource([float(speed), 0.0, 0.0])).get_output_port()
        schedule = (np.array([0.0]), np.array([float(speed)]))
    else:
        times, speeds = (np.asarray(a, dtype=float) for a in speed)
        values = np.vstack([speeds, np.zeros_like(speeds), np.zeros_like(speeds)])
        velocity_port = builder.AddSystem(TrajectorySource(PiecewisePolynomial.ZeroOrderHold(
            np.append(times, times[-1] + 1.0), np.hstack([values, values[:, -1:]])))).get_output_port()
        schedule = (times, speeds)
    config = trot_config or TrotConfig()
    classifier = builder.AddSystem(TerrainClassifier(models=models, period=config.control_period,
                                                     stiffness_by_material=stiffness_by_material,
                                                     params=info.params))
    classifier.set_name("terrain_classifier")
    trot, _ = add_trotting_controller(builder, station, info, config=config, velocity_port=velocity_port,
                                      stiffness_port=classifier.GetOutputPort("stiffness") if adaptive else None,
                                      stance_stiffness=stiffness)
    for name in ("state", "joint_torque_measured", "imu"):
        builder.Connect(station.GetOutputPort(name), classifier.GetInputPort(name))
    builder.Connect(trot.GetOutputPort("gait_state"), classifier.GetInputPort("gait_state"))
    logs = {name: LogVectorOutput(port, builder, LOG_PERIOD) for name, port in (
        ("state", station.GetOutputPort("state")), ("imu", station.GetOutputPort("imu")),
        ("gait", trot.GetOutputPort("gait_state")), ("stiffness", classifier.GetOutputPort("stiffness")),
        ("label", classifier.GetOutputPort("terrain_label")))}
    stance_logs = {name: LogVectorOutput(classifier.GetOutputPort(name), builder, STANCE_LOG_PERIOD)
                   for name in ("stance_features", "stance_count", "skipped_stances", "prediction")}
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.Initialize()
    context = simulator.get_context()
    station_context = station.GetMyContextFromRoot(context)
    wall = time.perf_counter()
    fell = False
    while context.get_time() < duration - 1e-9:
        simulator.AdvanceTo(min(duration, context.get_time() + 0.5))
        if tilt_deg(station.GetOutputPort("state").Eval(station_context)) > FALL_TILT_DEG:
            fell = True
            break
    wall = time.perf_counter() - wall
    data = {name: log.FindLog(context).data().T for name, log in logs.items()}
    times = logs["state"].FindLog(context).sample_times()
    classes = classifier.classes
    heightmap = info.heightmap
    truth = _ground_truth(heightmap, data["state"], classes, scenario.terrain.material, info.params)
    stance = _stances(stance_logs, context, data["state"], times, truth, schedule)
    skipped = stance_logs["skipped_stances"].FindLog(context).data()[:, -1].astype(int)
    # The stiffness the impedance applied: the classifier's command only when adaptive.
    applied = data["stiffness"] if adaptive else np.broadcast_to(
        np.asarray(stiffness, dtype=float), data["stiffness"].shape).copy()
    return TrotRun(times=times, states=data["state"], imu=data["imu"], gait_state=data["gait"],
                   stiffness=applied, terrain_label=data["label"], ground_truth=truth, classes=classes,
                   skipped_stances=skipped, fell=fell, wall_time_s=wall, **stance)


def _ground_truth(heightmap, states, classes, default_material, params) -> np.ndarray:
    """Index into classes of the material under each foot at every logged sample."""
    feet = np.empty((len(states), NUM_LEGS, 2))
    for k, x in enumerate(states):
        R = base_pose(x).rotation().matrix()
        feet[k] = (all_foot_positions(x[JOINT_Q], params) @ R.T + x[BASE_POS])[:, :2]
    if heightmap.materials is None:
        index = classes.index(default_material) if default_material in classes else -1
        return np.full((len(states), NUM_LEGS), index)
    names = heightmap.material_at(feet[..., 0].ravel(), feet[..., 1].ravel())
    lookup = {c: i for i, c in enumerate(classes)}
    return np.array([lookup.get(str(n), -1) for n in names]).reshape(len(states), NUM_LEGS)


def _stances(stance_logs, context, states, times, truth, schedule) -> dict:
    """One row per finished stance, from the changes of the classifier's stance counter."""
    log_times = stance_logs["stance_count"].FindLog(context).sample_times()
    counts = stance_logs["stance_count"].FindLog(context).data().T
    feats = stance_logs["stance_features"].FindLog(context).data().T.reshape(len(log_times), NUM_LEGS, -1)
    predictions = stance_logs["prediction"].FindLog(context).data().T
    rows = {"time": [], "leg": [], "features": [], "speed": [], "truth": [], "prediction": []}
    previous = np.zeros(NUM_LEGS)
    for k, t in enumerate(log_times):
        for leg in np.flatnonzero(counts[k] > previous):
            # Ground truth: the material under the foot just before it lifted (the latest
            # logged sample at or before the stance end seen here).
            j = max(0, int(np.searchsorted(times, t - STANCE_LOG_PERIOD)) - 1)
            rows["time"].append(t)
            rows["leg"].append(leg)
            rows["features"].append(feats[k, leg])
            rows["speed"].append(schedule[1][max(0, int(np.searchsorted(schedule[0], t, side="right")) - 1)])
            rows["truth"].append(truth[j, leg])
            rows["prediction"].append(predictions[k, leg])
        previous = counts[k]
    return {"stance_time": np.asarray(rows["time"], dtype=float),
            "stance_leg": np.asarray(rows["leg"], dtype=int),
            "stance_features": np.asarray(rows["features"], dtype=float).reshape(-1, feat.NUM_FEATURES),
            "stance_speed": np.asarray(rows["speed"], dtype=float),
            "stance_truth": np.asarray(rows["truth"], dtype=int),
            "stance_prediction": np.asarray(rows["prediction"], dtype=int)}
