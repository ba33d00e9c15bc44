"""The simulated station: ports, sensors, and Qingzhui standing in every topology."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from qz_drake.config import Scenario, SimulationConfig, TerrainConfig
from qz_drake.robot.topology import TOPOLOGY_NAMES
from qz_drake.simulation import _standing_controller, simulate
from qz_drake.station import make_station
from qz_drake.state_layout import IMU_SIZE, STATE_SIZE
from qz_drake.viz.recording import recording_summary


def test_station_exports_the_design_ports():
    diagram, info = make_station(Scenario())
    assert diagram.GetInputPort("joint_torque").size() == 18
    sizes = {"state": STATE_SIZE, "joint_torque_measured": 18, "imu": IMU_SIZE, "foot_contact": 6}
    for name, size in sizes.items():
        assert diagram.GetOutputPort(name).size() == size
    assert info.contact_representation == "boxes"


def test_sensors_read_a_standing_robot():
    """Standing under joint PD for 1 s: the IMU sees +g and no rotation, the torque port
    echoes the controller's torques, and all feet are in contact."""
    builder = DiagramBuilder()
    scenario = Scenario()
    diagram, info = make_station(scenario)
    station = builder.AddSystem(diagram)
    controller = _standing_controller(builder, station, info, scenario)
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(1.0)
    root = simulator.get_context()
    context = station.GetMyContextFromRoot(root)
    tau = controller.GetOutputPort("joint_torque").Eval(controller.GetMyContextFromRoot(root))
    # The plant samples its outputs once per step: the measurement lags by one 2 ms step.
    np.testing.assert_allclose(station.GetOutputPort("joint_torque_measured").Eval(context), tau, atol=0.1)
    # The middle legs carry weight: their thigh torques are far from zero.
    assert abs(tau[1]) > 10.0
    imu = station.GetOutputPort("imu").Eval(context)
    np.testing.assert_allclose(np.abs(imu[0:4]), [1, 0, 0, 0], atol=1e-2)
    np.testing.assert_allclose(imu[4:7], 0.0, atol=0.05)
    np.testing.assert_allclose(imu[7:10], [0, 0, 9.81], atol=0.3)
    np.testing.assert_array_equal(station.GetOutputPort("foot_contact").Eval(context), np.ones(6))
    assert station.GetOutputPort("trunk_contact").Eval(context)[0] == 0.0


@pytest.mark.parametrize("topology", TOPOLOGY_NAMES)
def test_holds_each_topology_standing_on_flat_ground(topology):
    scenario = Scenario(simulation=SimulationConfig(duration=5.0))
    scenario.robot.topology = topology
    result = simulate(scenario)
    m = result.metrics
    assert m["success"], m
    assert m["max_base_height_error_m"] < 0.02
    assert m["trunk_terrain_contacts"] == 0
    assert np.all(result.foot_contact[-1] == 1.0)


@pytest.mark.parametrize("topology", ["nominal", "front_bend"])
def test_holds_standing_on_the_grid_map_terrain(topology, tmp_path):
    scenario = Scenario(terrain=TerrainConfig(kind="grid_map", contact="mesh"),
                        simulation=SimulationConfig(duration=5.0))
    scenario.robot.topology = topology
    result = simulate(scenario, out_dir=tmp_path)
    m = result.metrics
    assert m["terrain_contact"] == "mesh"
    assert m["success"], m
    assert m["max_base_height_error_m"] < 0.02
    summary = recording_summary(tmp_path / "recording.html")
    assert summary["has_animation"], summary
    assert (tmp_path / "metrics.json").is_file() and (tmp_path / "base_and_contacts.png").is_file()


@pytest.mark.parametrize("topology", ["hind_bend", "hind_1_bend", "front_1_bend", "split_up"])
def test_holds_other_topologies_on_the_grid_map_terrain(topology):
    scenario = Scenario(terrain=TerrainConfig(kind="grid_map", contact="mesh"),
                        simulation=SimulationConfig(duration=5.0))
    scenario.robot.topology = topology
    assert simulate(scenario).metrics["success"]


def test_position_mode_holds_a_commanded_pose():
    """Position mode (the paper's real-robot interface): the drives' PD holds the standing pose
    from a joint position command and zero rates, and the same state/sensor ports are there."""
    from pydrake.systems.primitives import ConstantVectorSource

    scenario = Scenario()
    scenario.station.control_mode = "position"
    builder = DiagramBuilder()
    diagram, info = make_station(scenario)
    assert diagram.GetInputPort("joint_position_command").size() == 18
    assert diagram.GetInputPort("joint_velocity_command").size() == 18
    station = builder.AddSystem(diagram)
    command = builder.AddSystem(ConstantVectorSource(info.initial_state[7:25]))
    zero = builder.AddSystem(ConstantVectorSource(np.zeros(18)))
    builder.Connect(command.get_output_port(), station.GetInputPort("joint_position_command"))
    builder.Connect(zero.get_output_port(), station.GetInputPort("joint_torque"))
    builder.Connect(zero.get_output_port(), station.GetInputPort("joint_velocity_command"))
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(3.0)
    context = station.GetMyContextFromRoot(simulator.get_context())
    x = station.GetOutputPort("state").Eval(context)
    assert abs(x[6] - info.initial_state[6]) < 0.02
    # The drives do work: the measured torques carry the body's weight.
    assert np.abs(station.GetOutputPort("joint_torque_measured").Eval(context)).max() > 10.0
