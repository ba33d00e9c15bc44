"""The station: Qingzhui's MultibodyPlant on a terrain, behind the ports of DESIGN.md.

``make_station(scenario, meshcat)`` returns a Diagram with

* input ``joint_torque`` (18, leg-major URDF joint order, [N*m]); in position mode
  (``scenario.station.control_mode``) also ``joint_position_command`` (18, [rad]), held by the
  drives' PD (the plant's implicit PD actuators), with ``joint_torque`` as feedforward;
* outputs ``state`` (49, see qz_drake.systems.state_layout), ``joint_torque_measured`` (18),
  ``imu`` (10: orientation quaternion, gyro, accelerometer), ``foot_contact`` (6, 1.0 = in
  contact);
* simulation-only outputs for monitors and metrics (never for controllers):
  ``trunk_contact`` (1), ``foot_normal_force`` (6), ``leg_link_force`` (6: terrain on each
  leg's thigh and shank [N]), ``self_contact`` (1: largest force between two legs [N]),
  ``contact_results``, ``body_poses``.

The build is a straight line: plant -> terrain -> robot -> contact properties -> finalize ->
sensors -> visualizer. Controllers are added by the caller (see qz_drake.simulation).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from pydrake.geometry import (CollisionFilterDeclaration, GeometrySet, Meshcat,
                              MeshcatVisualizer, MeshcatVisualizerParams, Role, RoleAssign)
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.multibody.tree import PdControllerGains
from pydrake.systems.primitives import MatrixGain
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.sensors import Accelerometer, Gyroscope

from qz_drake.config import Scenario, TerrainConfig
from qz_drake.errors import ConfigError, QzError, bad_value
from qz_drake.robot import kinematics
from qz_drake.robot.model import JointOrder, add_qingzhui
from qz_drake.robot.params import DEFAULT_PARAMS, LEG_NAMES, NUM_LEGS, QingzhuiParams
from qz_drake.robot.topology import Topology, get_topology
from qz_drake.systems.sensors import FootContactSensor, ImuAssembler
from qz_drake.systems.state_layout import make_state
from qz_drake.terrain.drake_geometry import add_heightmap_to_plant, make_robot_proximity_properties

GRAVITY = 9.81


def make_heightmap(config: TerrainConfig, seed: int = 0):
    """The HeightMap a scenario's terrain section describes."""
    from qz_drake.terrain import HeightMap, grid_map_terrain, make_terrain

    if config.kind == "file":
        path = Path(config.file)
        if not path.is_file():
            raise bad_value("scenario.terrain.file", config.file,
                            "no such file (a relative path is relative to the scenario file's folder)")
        scale = {"resolution", "min_height", "max_height"}
        for key in config.params:
            if key not in scale:
                raise bad_value(f"scenario.terrain.params.{key}", config.params[key],
                                f"unknown parameter of a heightmap file (valid: {', '.join(sorted(scale))})")
        if path.suffix.lower() in HeightMap.IMAGE_SUFFIXES:
            for key in ("resolution", "max_height"):
                if key not in config.params:
                    raise bad_value(f"scenario.terrain.params.{key}", None,
                                    f"required with a picture file ({path.name}): its cell size and the "
                                    f"height of a full-scale pixel, e.g. params: {{resolution: 0.05, "
                                    f"min_height: 0.0, max_height: 0.4}}")
            return HeightMap.load(path, **config.params)
        if config.params:
            key = sorted(config.params)[0]
            raise bad_value(f"scenario.terrain.params.{key}", config.params[key],
                            f"a {path.suffix} file carries its own scale; give params only with an image")
        return HeightMap.load(path)
    if config.kind == "grid_map":
        allowed = {"resolution", "min_height", "max_height"}
        for key in config.params:
            if key not in allowed:
                raise bad_value(f"scenario.terrain.params.{key}", config.params[key],
                                f"unknown grid_map parameter (valid: {', '.join(sorted(allowed))})")
        return grid_map_terrain(**config.params)
    # A seed among the generator's parameters (--terrain-param seed=4711) takes the place of `seed`.
    params = dict(config.params)
    return make_terrain(config.kind, seed=params.pop("seed", seed), **params)


def standing_state(heightmap, topology: Topology, xy=(0.0, 0.0), yaw: float = 0.0,
                   params: QingzhuiParams = DEFAULT_PARAMS, foot_offsets=None) -> np.ndarray:
    """A station state standing on the terrain: base level at the nominal height above the mean
    ground under the feet, each foot placed on the ground by leg IK (topology's bends).

    foot_offsets: (6, 2) moves of the feet from their nominal footholds in the base frame
    (the stance a previous mission may leave), or None. [m]"""
    R = RollPitchYaw(0.0, 0.0, yaw).ToRotationMatrix().matrix()
    p_B = topology.footholds_B.copy()
    if foot_offsets is not None and len(foot_offsets):
        offsets = np.asarray(foot_offsets, dtype=float)
        if offsets.shape != (NUM_LEGS, 2) or not np.all(np.isfinite(offsets)):
            raise bad_value("scenario.robot.initial_foot_offsets", np.asarray(foot_offsets).tolist(),
                            "expected six finite (dx, dy) pairs", ConfigError)
        p_B[:, :2] += offsets
    feet_xy = np.asarray(xy, dtype=float) + (p_B[:, :2] @ R[:2, :2].T)
    ground = heightmap.height(feet_xy[:, 0], feet_xy[:, 1])
    base_z = float(np.mean(ground)) + params.standing_height
    q = np.zeros((NUM_LEGS, 3))
    for i in range(NUM_LEGS):
        p_WF = np.array([feet_xy[i, 0], feet_xy[i, 1], ground[i] + params.foot_radius])
        p_BF = R.T @ (p_WF - np.array([xy[0], xy[1], base_z]))
        q[i], ok = kinematics.leg_inverse_kinematics(i, p_BF, topology.bends[i], params)
        if not ok:
            offset = ground[i] - float(np.mean(ground))
            raise bad_value("scenario.robot.initial_xy", [float(v) for v in xy],
                            f"the ground under leg {LEG_NAMES[i]} at ({feet_xy[i, 0]:.2f}, {feet_xy[i, 1]:.2f}) "
                            f"is {abs(offset):.2f} m {'above' if offset > 0 else 'below'} the mean under the "
                            f"six feet, out of the leg's reach for a standing pose", ConfigError)
    return make_state([xy[0], xy[1], base_z], [0.0, 0.0, yaw], q.reshape(-1))


def check_standable(heightmap, xy, topology: str, field: str) -> None:
    """Raises QzError naming ``field`` when the robot cannot stand at xy in the topology."""
    xmin, xmax, ymin, ymax = heightmap.bounds
    if not (xmin <= xy[0] <= xmax and ymin <= xy[1] <= ymax):
        raise bad_value(field, f"{xy[0]:g},{xy[1]:g}", f"off the map (x in [{xmin:g}, {xmax:g}], "
                                                      f"y in [{ymin:g}, {ymax:g}])")
    try:
        x0 = standing_state(heightmap, get_topology(topology), xy, 0.0)
    except QzError:
        raise bad_value(field, f"{xy[0]:g},{xy[1]:g}",
                        f"the robot cannot stand there in {topology} (a foot out of reach)") from None
    # The trunk must clear the ground under it (any heading: the disc the trunk sweeps).
    lx, ly, lz = DEFAULT_PARAMS.trunk_size
    radius = 0.5 * float(np.hypot(lx, ly))
    g = np.arange(-radius, radius + 1e-9, 0.05)
    gx, gy = np.meshgrid(g, g)
    inside = np.hypot(gx, gy) <= radius
    ground = heightmap.height(xy[0] + gx[inside], xy[1] + gy[inside])
    if float(ground.max()) > float(x0[6]) - 0.5 * lz - 0.02:
        raise bad_value(field, f"{xy[0]:g},{xy[1]:g}",
                        f"the robot cannot stand there in {topology}: ground {ground.max():.2f} m under "
                        f"the trunk (inside an obstacle?)")


# Half-width of the simulated terrain around a standing robot's start. [m]
STANDING_REGION_HALF_WIDTH = 2.0


def default_region(scenario: Scenario) -> list[float]:
    """The part of the map a scenario's controller can reach: the start and every waypoint of
    its route, with a margin of STANDING_REGION_HALF_WIDTH."""
    xs = [scenario.robot.initial_xy[0]] + [w.x for w in scenario.controller.route]
    ys = [scenario.robot.initial_xy[1]] + [w.y for w in scenario.controller.route]
    r = STANDING_REGION_HALF_WIDTH
    return [min(xs) - r, max(xs) + r, min(ys) - r, max(ys) + r]


def _crop_to(heightmap, region):
    xmin, xmax, ymin, ymax = heightmap.bounds
    if region[0] <= xmin and region[1] >= xmax and region[2] <= ymin and region[3] >= ymax:
        return heightmap
    try:
        return heightmap.crop(*region)
    except ConfigError:
        raise
    except Exception as e:
        raise bad_value("scenario.terrain.region", list(region), f"does not overlap the map ({e})") from None


@dataclasses.dataclass
class StationInfo:
    """What a caller of make_station may need to know about what was built."""

    heightmap: object
    contact_representation: str
    params: QingzhuiParams
    topology: Topology
    initial_state: np.ndarray


def _set_robot_contact(plant, scene_graph, instance, *, hydroelastic: bool, material) -> None:
    """Feet, leg links and trunk collide with the terrain with material-matched properties.

    A leg's own links, and every leg's links with the trunk, never collide: the joints and the
    drives between them make that impossible. Links of different legs may (two legs crossing is
    a real failure, reported on the ``self_contact`` output).
    """
    source = plant.get_source_id()
    trunk = list(plant.GetCollisionGeometriesForBody(plant.GetBodyByName("base", instance)))
    legs = {leg: [] for leg in LEG_NAMES}
    for b in plant.GetBodyIndices(instance):
        body = plant.get_body(b)
        for g in plant.GetCollisionGeometriesForBody(body):
            props = make_robot_proximity_properties(
                hydroelastic=hydroelastic, material=material,
                friction=material.static_friction)
            scene_graph.AssignRole(source, g, props, RoleAssign.kReplace)
            prefix = body.name().split("_")[0]
            if prefix in legs:
                legs[prefix].append(g)
    manager = scene_graph.collision_filter_manager()
    for geometries in legs.values():
        manager.Apply(CollisionFilterDeclaration().ExcludeWithin(GeometrySet(geometries + trunk)))


def make_station(scenario: Scenario, meshcat: Meshcat | None = None, *,
                 mesh_dir: str | Path | None = None, heightmap=None, backend: str = "sim",
                 lcm_url: str = "memq://", hardware=None) -> tuple[Diagram, StationInfo]:
    """Builds the station for a scenario; returns (diagram, info).

    ``backend="sim"``: the MultibodyPlant station below; ``heightmap`` then replaces the
    scenario's terrain section's map (e.g. a capability scene held in memory); the section's
    contact, material and region still apply. ``backend="lcm"``: the
    QingzhuiHardwareInterface (qz_drake.hardware) with the same controller ports, talking LCM
    on ``lcm_url`` to a robot driver (the robot, or ``qz robot-sim``), with ``hardware`` (a
    qz_drake.hardware.config.HardwareConfig) as its protocol settings.
    """
    if backend == "lcm":
        from qz_drake.hardware.interface import make_hardware_interface

        if heightmap is not None:
            raise bad_value("heightmap", "a HeightMap", "replaces the simulated terrain: backend 'sim' only")
        return make_hardware_interface(scenario, meshcat, lcm_url=lcm_url, config=hardware)
    if backend != "sim":
        raise bad_value("backend", backend, "expected sim or lcm")
    from qz_drake.terrain import get_material

    builder = DiagramBuilder()
    sim = scenario.simulation
    plant, scene_graph = AddMultibodyPlant(
        MultibodyPlantConfig(time_step=sim.time_step,
                             discrete_contact_approximation=sim.discrete_contact_approximation,
                             contact_model="hydroelastic_with_fallback"), builder)
    plant.set_name("plant")
    if heightmap is None:
        heightmap = make_heightmap(scenario.terrain, scenario.random_seed)
    region = scenario.terrain.region or default_region(scenario)
    heightmap = _crop_to(heightmap, region)
    representation = add_heightmap_to_plant(plant, heightmap, contact=scenario.terrain.contact,
                                            default_material=scenario.terrain.material,
                                            mesh_dir=mesh_dir)
    params = dataclasses.replace(DEFAULT_PARAMS, payload_mass=scenario.robot.payload_kg)
    instance = add_qingzhui(plant, params)
    material = get_material(scenario.terrain.material)
    _set_robot_contact(plant, scene_graph, instance, hydroelastic=representation == "mesh",
                       material=material)
    position_mode = scenario.station.control_mode == "position"
    if position_mode:
        # (Per-instance actuator lists exist only after Finalize: filter all actuators.)
        for index in plant.GetJointActuatorIndices():
            actuator = plant.get_mutable_joint_actuator(index)
            if actuator.model_instance() == instance:
                actuator.set_controller_gains(
                    PdControllerGains(p=scenario.station.position_kp, d=scenario.station.position_kd))
    plant.Finalize()

    order = JointOrder(plant, instance)
    if not (np.array_equal(order.q_index, np.arange(7, 25)) and np.array_equal(order.u_index, np.arange(18))):
        raise RuntimeError("the plant's joint ordering differs from the station's state layout")
    topology = get_topology(scenario.robot.topology, params)
    x0 = standing_state(heightmap, topology, scenario.robot.initial_xy, scenario.robot.initial_yaw, params,
                        foot_offsets=scenario.robot.initial_foot_offsets or None)
    plant.SetDefaultPositions(x0[:25])

    base = plant.GetBodyByName("base", instance)
    gravity = plant.gravity_field().gravity_vector()
    gyro = builder.AddSystem(Gyroscope(base, RigidTransform()))
    accel = builder.AddSystem(Accelerometer(base, RigidTransform(), gravity))
    builder.Connect(plant.get_body_poses_output_port(), gyro.get_body_poses_input_port())
    builder.Connect(plant.get_body_spatial_velocities_output_port(), gyro.get_body_velocities_input_port())
    builder.Connect(plant.get_body_poses_output_port(), accel.get_body_poses_input_port())
    builder.Connect(plant.get_body_spatial_velocities_output_port(), accel.get_body_velocities_input_port())
    builder.Connect(plant.get_body_spatial_accelerations_output_port(),
                    accel.get_body_accelerations_input_port())
    imu = builder.AddSystem(ImuAssembler(plant=plant, base_body_index=base.index()))
    builder.Connect(plant.get_body_poses_output_port(), imu.GetInputPort("body_poses"))
    builder.Connect(gyro.get_measurement_output_port(), imu.GetInputPort("angular_velocity"))
    builder.Connect(accel.get_measurement_output_port(), imu.GetInputPort("acceleration"))
    contact = builder.AddSystem(FootContactSensor(plant=plant, instance=instance))
    builder.Connect(plant.get_contact_results_output_port(), contact.GetInputPort("contact_results"))

    builder.ExportInput(plant.get_actuation_input_port(instance), "joint_torque")
    if position_mode:
        # Desired state [q_cmd, 0]: the drives hold positions; rates are left to their damping.
        to_state = builder.AddSystem(MatrixGain(np.vstack([np.eye(18), np.zeros((18, 18))])))
        builder.Connect(to_state.get_output_port(), plant.get_desired_state_input_port(instance))
        builder.ExportInput(to_state.get_input_port(), "joint_position_command")
    builder.ExportOutput(plant.get_state_output_port(instance), "state")
    builder.ExportOutput(plant.get_net_actuation_output_port(instance), "joint_torque_measured")
    builder.ExportOutput(imu.GetOutputPort("imu"), "imu")
    builder.ExportOutput(contact.GetOutputPort("foot_contact"), "foot_contact")
    builder.ExportOutput(contact.GetOutputPort("trunk_contact"), "trunk_contact")
    builder.ExportOutput(contact.GetOutputPort("foot_normal_force"), "foot_normal_force")
    builder.ExportOutput(contact.GetOutputPort("leg_link_force"), "leg_link_force")
    builder.ExportOutput(contact.GetOutputPort("self_contact"), "self_contact")
    builder.ExportOutput(plant.get_contact_results_output_port(), "contact_results")
    builder.ExportOutput(plant.get_body_poses_output_port(), "body_poses")

    if meshcat is not None:
        from qz_drake.viz.recording import RECORDING_FPS

        MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat,
                                       MeshcatVisualizerParams(role=Role.kIllustration,
                                                               publish_period=1.0 / RECORDING_FPS))
    diagram = builder.Build()
    diagram.set_name("station")
    return diagram, StationInfo(heightmap=heightmap, contact_representation=representation,
                                params=params, topology=topology, initial_state=x0)
