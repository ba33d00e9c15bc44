"""The simulated station: Qingzhui's MultibodyPlant on a terrain, behind the ports of DESIGN.md.

``make_sim_station(scenario, meshcat)`` (make_station's "sim" backend) returns a Diagram with

* input ``joint_torque`` (18, leg-major URDF joint order, [N*m]); in position mode
  (``scenario.station.control_mode``) also ``joint_position_command`` (18, [rad]) and
  ``joint_velocity_command`` (18, [rad/s]), tracked by the drives' PD (the plant's implicit PD
  actuators), with ``joint_torque`` as feedforward;
* outputs ``state`` (49, see qz_drake.state_layout), ``joint_torque_measured`` (18),
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
from pydrake.math import RigidTransform
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.multibody.tree import PdControllerGains
from pydrake.systems.primitives import Multiplexer
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.sensors import Accelerometer, Gyroscope

from qz_drake.config import Scenario
from qz_drake.robot.model import JointOrder, add_qingzhui
from qz_drake.robot.params import DEFAULT_PARAMS, LEG_NAMES, NUM_JOINTS
from qz_drake.robot.topology import get_topology
from qz_drake.scene import StationInfo, crop_to_region, default_region, make_heightmap, standing_state
from qz_drake.systems.sensors import FootContactSensor, ImuAssembler
from qz_drake.terrain import get_material
from qz_drake.terrain.drake_geometry import add_heightmap_to_plant, make_robot_proximity_properties
from qz_drake.viz.recording import RECORDING_FPS

def set_robot_contact(plant, scene_graph, instance, *, hydroelastic: bool, material) -> None:
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


def make_sim_station(scenario: Scenario, meshcat: Meshcat | None = None, *,
                     mesh_dir: str | Path | None = None, heightmap=None) -> tuple[Diagram, StationInfo]:
    """Builds the MultibodyPlant station for a scenario; returns (diagram, info).

    ``heightmap`` replaces the scenario's terrain section's map (e.g. a capability scene held
    in memory); the section's contact, material and region still apply.
    """
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
    heightmap = crop_to_region(heightmap, region)
    representation = add_heightmap_to_plant(plant, heightmap, contact=scenario.terrain.contact,
                                            default_material=scenario.terrain.material,
                                            mesh_dir=mesh_dir)
    params = dataclasses.replace(DEFAULT_PARAMS, payload_mass=scenario.robot.payload_kg)
    instance = add_qingzhui(plant, params)
    material = get_material(scenario.terrain.material)
    set_robot_contact(plant, scene_graph, instance, hydroelastic=representation == "mesh",
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
        # Desired state [q_cmd, v_cmd]: the drives track positions and rates (Eq. 7's PD, solved
        # implicitly with the contact in the plant's step).
        to_state = builder.AddSystem(Multiplexer([NUM_JOINTS, NUM_JOINTS]))
        builder.Connect(to_state.get_output_port(0), plant.get_desired_state_input_port(instance))
        builder.ExportInput(to_state.get_input_port(0), "joint_position_command")
        builder.ExportInput(to_state.get_input_port(1), "joint_velocity_command")
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
        MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat,
                                       MeshcatVisualizerParams(role=Role.kIllustration,
                                                               publish_period=1.0 / RECORDING_FPS))
    diagram = builder.Build()
    diagram.set_name("station")
    return diagram, StationInfo(heightmap=heightmap, contact_representation=representation,
                                params=params, topology=topology, initial_state=x0)
