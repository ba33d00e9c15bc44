"""Execution of a searched static gait in Drake (paper 003, section 4: the quadruped walks).

The states of :func:`~qz_drake.planning.static_gait.search_gait` become references the way the
search reasoned about them (section 3.2): before each swing the body moves, feet standing, from
the previous pose to the state's pose (Table 2's adjustment); then the swing foot follows its
box path (Table 1): straight up to ``swing_height`` above the higher end point, across, straight
down. Each segment is timed by a smoothstep, so the references stop at the box's corners.
Leg IK (:mod:`qz_drake.robot.quadruped`) turns body pose and feet into 12 joint angles, sampled
and joined by a shape-preserving cubic; its derivative is the velocity reference. The plant's
own joint PD (Drake's implicit PD actuators, so stiff gains are stable at millisecond steps)
tracks them on a MultibodyPlant holding the heightmap terrain.

A walk succeeds when the body ends within ``position_tolerance`` of the last state's body
position, never tilts past ``max_tilt_deg`` and the body never touches the terrain.
"""

import dataclasses
import math
import time
from pathlib import Path

import numpy as np

from qz_drake.errors import bad_value
from qz_drake.planning.static_gait import LEGS, GaitSearchResult, _rotation

DISCRETE_APPROXIMATIONS = ("sap", "lagged", "similar")


@dataclasses.dataclass
class StaticGaitSimConfig:
    # Body adjustment before each swing, feet standing (Table 2). [s]
    shift_duration: float = 0.5
    # Swing along the box path (Table 1). [s]
    swing_duration: float = 0.6
    # Standing still before the first shift and after the last swing. [s]
    settle_duration: float = 0.3
    hold_duration: float = 0.5
    # Spacing of the IK samples of the joint references. [s]
    sample_period: float = 0.01
    # Plant time step. [s]
    time_step: float = 0.001
    # Drake's discrete contact solver; the PD actuators need one other than TAMSI.
    discrete_contact_approximation: str = "lagged"
    # Joint PD gains of every joint. [N*m/rad], [N*m*s/rad]
    kp: float = 60.0
    kd: float = 1.0
    # Ground material of the terrain (qz_drake.terrain.materials).
    material: str = "concrete"
    # Success: final body xy within this of the last state's body xy. [m]
    position_tolerance: float = 0.03
    # Success: the body never tilts more than this. [deg]
    max_tilt_deg: float = 20.0
    # How often tilt and body contact are checked. [s]
    monitor_period: float = 0.01


@dataclasses.dataclass
class GaitReference:
    """Body and feet references sampled in time (world frame)."""

    # Sample times (N,). [s]
    times: np.ndarray
    # Body centre (N, 3) and roll-pitch-yaw (N, 3). [m], [rad]
    p_WB: np.ndarray
    rpy: np.ndarray
    # Foot centres (N, 4, 3) in LEGS order (soles + foot radius). [m]
    feet: np.ndarray
    # Start time of each state's shift and swing phases (len(states), 2). [s]
    phase_starts: np.ndarray


@dataclasses.dataclass
class StaticGaitWalk:
    """A simulated walk of a searched gait: metrics and logs."""

    metrics: dict
    # Logged at monitor_period: times (M,), body position (M, 3), tilt (M,) and foot centres
    # (M, 4, 3). [s], [m], [deg], [m]
    times: np.ndarray
    p_WB: np.ndarray
    tilt_deg: np.ndarray
    feet: np.ndarray
    reference: GaitReference
    config: StaticGaitSimConfig
    recording: Path | None = None


def _check_config(config: StaticGaitSimConfig) -> None:
    for name in ("shift_duration", "swing_duration", "sample_period", "time_step", "kp", "kd",
                 "position_tolerance", "max_tilt_deg", "monitor_period"):
        value = getattr(config, name)
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise bad_value(f"simulation.{name}", value, "must be a finite positive number")
    for name in ("settle_duration", "hold_duration"):
        value = getattr(config, name)
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
            raise bad_value(f"simulation.{name}", value, "must be >= 0")
    if config.discrete_contact_approximation not in DISCRETE_APPROXIMATIONS:
        raise bad_value("simulation.discrete_contact_approximation", config.discrete_contact_approximation,
                        f"expected one of {', '.join(DISCRETE_APPROXIMATIONS)} (the PD actuators need it)")


def _smoothstep(s: np.ndarray) -> np.ndarray:
    s = np.clip(s, 0.0, 1.0)
    return s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)  # zero velocity and acceleration at the ends


def _box_path(start: np.ndarray, end: np.ndarray, top: float, s: np.ndarray) -> np.ndarray:
    """Points of the swing box path (Table 1) at phases s in [0, 1]: up, across, down, each
    segment timed in proportion to its length and eased by a smoothstep."""
    corners = np.array([start, [start[0], start[1], top], [end[0], end[1], top], end])
    lengths = np.linalg.norm(np.diff(corners, axis=0), axis=1)
    # A segment of zero length still gets a little time so the corners stay distinct.
    durations = np.maximum(lengths, 1e-3)
    bounds = np.concatenate([[0.0], np.cumsum(durations) / durations.sum()])
    segment = np.clip(np.searchsorted(bounds, s, side="right") - 1, 0, 2)
    local = _smoothstep((s - bounds[segment]) / (bounds[segment + 1] - bounds[segment]))
    return corners[segment] + local[:, None] * (corners[segment + 1] - corners[segment])


def foot_centre_heights(heightmap, xy, radius: float) -> np.ndarray:
    """Height of a foot sphere's centre resting on the map at xy (..., 2): the highest point
    where the sphere touches one of the cells, each a square column as the simulated terrain
    has them (a foot near an edge rests on the edge, not on the cell under its centre). [m]"""
    xy = np.asarray(xy, dtype=float)
    res = heightmap.resolution
    H, W = heightmap.heights.shape
    reach = int(math.ceil(radius / res)) + 1
    cols = np.rint((xy[..., 0] - heightmap.origin[0]) / res).astype(int)
    rows = np.rint((xy[..., 1] - heightmap.origin[1]) / res).astype(int)
    best = np.full(xy.shape[:-1], -np.inf)
    for dr in range(-reach, reach + 1):
        for dc in range(-reach, reach + 1):
            r, c = np.clip(rows + dr, 0, H - 1), np.clip(cols + dc, 0, W - 1)
            # Distance from the point to the cell's square.
            gx = np.abs(xy[..., 0] - (heightmap.origin[0] + c * res)) - res / 2
            gy = np.abs(xy[..., 1] - (heightmap.origin[1] + r * res)) - res / 2
            d2 = np.maximum(gx, 0.0) ** 2 + np.maximum(gy, 0.0) ** 2
            z = heightmap.heights[r, c] + np.sqrt(np.maximum(radius * radius - d2, 0.0))
            best = np.where(d2 < radius * radius, np.maximum(best, z), best)
    return best


def gait_reference(heightmap, result: GaitSearchResult, config: StaticGaitSimConfig | None = None, *,
                   foot_radius: float = 0.012) -> GaitReference:
    """Samples body pose and foot centres through the states of ``result``: settle, then per
    state a body shift and a swing, then a hold. Footholds are the states' (x, y); the foot
    centre rests where a sphere of ``foot_radius`` touches ``heightmap`` there."""
    config = config or StaticGaitSimConfig()
    _check_config(config)
    if result.start_feet is None:
        raise bad_value("result", "GaitSearchResult", "has no start pose (made by an older search_gait)")

    def rest(xy):
        xy = np.asarray(xy, dtype=float)[..., :2]
        return np.concatenate([xy, foot_centre_heights(heightmap, xy, foot_radius)[..., None]], axis=-1)

    feet = rest(result.start_feet)
    p, rpy = np.asarray(result.start_p_WB, dtype=float), np.asarray(result.start_rpy, dtype=float)
    swing_height = result.config.swing_height
    dt = config.sample_period

    chunks_t, chunks_p, chunks_rpy, chunks_feet, starts = [], [], [], [], []
    t0 = 0.0

    def add(duration: float, body_p, body_rpy, feet_traj):
        nonlocal t0
        n = max(2, int(math.ceil(duration / dt)) + 1)
        s = np.linspace(0.0, 1.0, n)
        chunks_t.append(t0 + s * duration)
        chunks_p.append(body_p(s))
        chunks_rpy.append(body_rpy(s))
        chunks_feet.append(feet_traj(s))
        t0 += duration

    def still(pos, ang, f):
        return (lambda s: np.repeat(pos[None], len(s), 0), lambda s: np.repeat(ang[None], len(s), 0),
                lambda s: np.repeat(f[None], len(s), 0))

    if config.settle_duration > 0:
        add(config.settle_duration, *still(p, rpy, feet))
    for state in result.states:
        i = LEGS.index(state.leg)
        p_new, rpy_new = np.asarray(state.p_WB, float), np.asarray(state.rpy, float)
        shift_start = t0
        add(config.shift_duration,
            lambda s, a=p, b=p_new: a + _smoothstep(s)[:, None] * (b - a),
            lambda s, a=rpy, b=rpy_new: a + _smoothstep(s)[:, None] * (b - a),
            lambda s, f=feet: np.repeat(f[None], len(s), 0))
        target = rest(state.feet[i])
        top = max(feet[i, 2], target[2]) + swing_height

        def swing_feet(s, f=feet, i=i, a=feet[i], b=target, top=top):
            out = np.repeat(f[None], len(s), 0)
            out[:, i] = _box_path(a, b, top, s)
            return out

        swing_start = t0
        add(config.swing_duration, lambda s, a=p_new: np.repeat(a[None], len(s), 0),
            lambda s, a=rpy_new: np.repeat(a[None], len(s), 0), swing_feet)
        starts.append((shift_start, swing_start))
        feet = feet.copy()
        feet[i] = target
        p, rpy = p_new, rpy_new
    if config.hold_duration > 0:
        add(config.hold_duration, *still(p, rpy, feet))

    # Chunks share their end points; keep one of each.
    times = np.concatenate([c if k == 0 else c[1:] for k, c in enumerate(chunks_t)])

    def join(chunks):
        return np.concatenate([c if k == 0 else c[1:] for k, c in enumerate(chunks)])

    return GaitReference(times, join(chunks_p), join(chunks_rpy), join(chunks_feet),
                         np.array(starts).reshape(-1, 2))


def joint_references(reference: GaitReference, geometry=None) -> np.ndarray:
    """IK of every reference sample: (N, 12) joint angles, NaN rows where a leg cannot reach."""
    from qz_drake.robot.quadruped import body_ik

    q = np.empty((len(reference.times), 12))
    for k in range(len(reference.times)):
        q[k] = body_ik(reference.p_WB[k], _rotation(reference.rpy[k]), reference.feet[k], geometry, strict=False)
    return q


def simulate_static_gait(heightmap, result: GaitSearchResult, config: StaticGaitSimConfig | None = None, *,
                         meshcat=None, recording_path: str | Path | None = None, params=None,
                         progress: bool = False) -> StaticGaitWalk:
    """Walks the gait of ``result`` on ``heightmap`` in a Drake simulation.

    Args:
        heightmap: the terrain the gait was searched on (qz_drake.terrain.HeightMap).
        result: a search_gait result; its states are walked even when the search stopped early.
        config: timing, gains and success thresholds.
        meshcat: when given, the walk is recorded; with ``recording_path`` the recording is saved
            as static HTML there.
        params: QuadrupedParams of the simulated robot (default: the URDF's).
        progress: show a progress bar of simulated time.
    """
    from pydrake.geometry import MeshcatVisualizer, MeshcatVisualizerParams, Role
    from pydrake.math import RigidTransform, RollPitchYaw
    from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
    from pydrake.multibody.tree import PdControllerGains
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import TrajectorySource
    from pydrake.trajectories import PiecewisePolynomial

    from qz_drake.robot.quadruped import DEFAULT_QUADRUPED, add_quadruped, joint_names
    from qz_drake.sim_station import set_robot_contact
    from qz_drake.terrain import get_material
    from qz_drake.terrain.drake_geometry import add_heightmap_to_plant

    config = config or StaticGaitSimConfig()
    params = params or DEFAULT_QUADRUPED
    _check_config(config)
    material = get_material(config.material)
    reference = gait_reference(heightmap, result, config, foot_radius=params.foot_radius)
    q_ref = joint_references(reference, params.geometry)
    bad = ~np.isfinite(q_ref).all(axis=1)
    metrics: dict = {"states": len(result.states), "search_success": bool(result.success),
                     "search_reason": result.reason, "duration_s": float(reference.times[-1])}
    if bad.any():
        t_bad = float(reference.times[np.argmax(bad)])
        metrics.update(success=False, reason=f"reference out of the legs' reach at t = {t_bad:.2f} s")
        return StaticGaitWalk(metrics, np.zeros(0), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 4, 3)),
                              reference, config)

    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(
        MultibodyPlantConfig(time_step=config.time_step,
                             discrete_contact_approximation=config.discrete_contact_approximation,
                             contact_model="hydroelastic_with_fallback"), builder)
    representation = add_heightmap_to_plant(plant, heightmap, default_material=material.name)
    instance = add_quadruped(plant, params)
    set_robot_contact(plant, scene_graph, instance, hydroelastic=representation == "mesh", material=material)
    for index in plant.GetJointActuatorIndices():  # per-instance lists exist only after Finalize
        actuator = plant.get_mutable_joint_actuator(index)
        if actuator.model_instance() == instance:
            actuator.set_controller_gains(PdControllerGains(p=config.kp, d=config.kd))
    plant.Finalize()

    # The desired-state port is ordered by actuator; the references by joint_names().
    names = joint_names()
    actuated = [plant.get_joint_actuator(a).joint().name() for a in plant.GetJointActuatorIndices(instance)]
    order = np.array([names.index(n) for n in actuated])
    q_traj = PiecewisePolynomial.CubicShapePreserving(reference.times, q_ref[:, order].T,
                                                      zero_end_point_derivatives=True)
    source = builder.AddSystem(TrajectorySource(q_traj, output_derivative_order=1))
    builder.Connect(source.get_output_port(), plant.get_desired_state_input_port(instance))
    if meshcat is not None:
        MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat,
                                       MeshcatVisualizerParams(role=Role.kIllustration))
    diagram = builder.Build()

    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    plant_context = plant.GetMyMutableContextFromRoot(context)
    base = plant.GetBodyByName("base", instance)
    plant.SetFreeBodyPose(plant_context, base, RigidTransform(RollPitchYaw(reference.rpy[0]), reference.p_WB[0]))
    for name, angle in zip(names, q_ref[0]):
        plant.GetJointByName(name, instance).set_angle(plant_context, float(angle))
    body_geometries = set(plant.GetCollisionGeometriesForBody(base))

    if meshcat is not None:
        meshcat.StartRecording()
    wall_start = time.perf_counter()
    duration = float(reference.times[-1])
    n = int(math.floor(duration / config.monitor_period + 1e-9)) + 1
    log_t, log_p, log_tilt, log_feet = np.zeros(n), np.zeros((n, 3)), np.zeros(n), np.zeros((n, 4, 3))
    foot_frames = [plant.GetFrameByName(f"{leg}_foot", instance) for leg in LEGS]
    body_contact_time = None
    ticks = range(n)
    if progress:
        from rich.console import Console
        from rich.progress import track

        ticks = track(ticks, description="static gait walk", console=Console(stderr=True), transient=True)
    for k in ticks:
        t = min(k * config.monitor_period, duration)
        simulator.AdvanceTo(t)
        X_WB = plant.EvalBodyPoseInWorld(plant_context, base)
        R = X_WB.rotation().matrix()
        log_t[k], log_p[k] = t, X_WB.translation()
        log_tilt[k] = math.degrees(math.acos(float(np.clip(R[2, 2], -1.0, 1.0))))
        for i, frame in enumerate(foot_frames):
            log_feet[k, i] = plant.CalcPointsPositions(plant_context, frame, np.zeros(3), plant.world_frame())[:, 0]
        if body_contact_time is None and _body_touches(plant, plant_context, base, body_geometries):
            body_contact_time = t
    wall = time.perf_counter() - wall_start
    if meshcat is not None:
        meshcat.StopRecording()

    final = np.asarray(result.states[-1].p_WB if result.states else result.start_p_WB, dtype=float)
    final_error = float(np.linalg.norm(log_p[-1, :2] - final[:2]))
    max_tilt = float(log_tilt.max())
    fell = max_tilt > config.max_tilt_deg
    reasons = []
    if final_error > config.position_tolerance:
        reasons.append(f"final body xy error {final_error:.3f} m > {config.position_tolerance:g} m")
    if fell:
        reasons.append(f"tilt {max_tilt:.1f} deg > {config.max_tilt_deg:g} deg")
    if body_contact_time is not None:
        reasons.append(f"body touched the terrain at t = {body_contact_time:.2f} s")
    tracking = np.linalg.norm(log_p - np.column_stack(
        [np.interp(log_t, reference.times, reference.p_WB[:, j]) for j in range(3)]), axis=1)
    metrics.update(
        success=not reasons,
        reason="; ".join(reasons) or "reached the last state's body position",
        final_error_m=final_error,
        max_tilt_deg=max_tilt,
        fell=bool(fell),
        body_terrain_contact=body_contact_time is not None,
        body_tracking_rms_m=float(np.sqrt(np.mean(tracking**2))),
        body_tracking_max_m=float(tracking.max()),
        wall_time_s=wall,
        realtime_factor=duration / wall if wall > 0 else math.inf,
        contact_representation=representation,
    )
    recording = None
    if meshcat is not None and recording_path is not None:
        from qz_drake.viz.recording import save_recording

        recording = save_recording(meshcat, recording_path)
    return StaticGaitWalk(metrics, log_t, log_p, log_tilt, log_feet, reference, config, recording)


def _body_touches(plant, plant_context, base, body_geometries) -> bool:
    """Whether the body's collision box is in contact with anything (point or hydroelastic)."""
    contacts = plant.get_contact_results_output_port().Eval(plant_context)
    index = base.index()
    for k in range(contacts.num_point_pair_contacts()):
        info = contacts.point_pair_contact_info(k)
        if index in (info.bodyA_index(), info.bodyB_index()):
            return True
    for k in range(contacts.num_hydroelastic_contacts()):
        surface = contacts.hydroelastic_contact_info(k).contact_surface()
        if surface.id_M() in body_geometries or surface.id_N() in body_geometries:
            return True
    return False
