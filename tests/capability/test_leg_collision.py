"""Leg links collide with the terrain, and the bend direction decides whether they do (paper
000 Fig. 2): the shank of a knee bent out lies on a step's edge that a knee bent in clears."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from qz_drake.config import RobotConfig, Scenario, TerrainConfig
from qz_drake.simulation import _standing_controller
from qz_drake.station import make_station


def _leg_link_force_standing(topology: str) -> np.ndarray:
    # A 0.2 m step 5 cm in front of MF's nominal foothold (x = 0.75 m).
    scenario = Scenario(terrain=TerrainConfig(kind="step", params={"height": 0.2, "start_x": 0.8}),
                        robot=RobotConfig(topology=topology))
    builder = DiagramBuilder()
    station, info = make_station(scenario)
    station = builder.AddSystem(station)
    _standing_controller(builder, station, info, scenario)
    log = LogVectorOutput(station.GetOutputPort("leg_link_force"), builder, 0.01)
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(0.3)
    return log.FindLog(simulator.get_context()).data().max(axis=1)


def test_bent_out_shank_touches_a_step_edge_that_bent_in_clears():
    nominal = _leg_link_force_standing("nominal")  # MF's knee out
    bent_in = _leg_link_force_standing("front_bend")  # MF's knee in
    assert nominal[0] > 50.0, nominal  # MF's shank on the edge
    assert np.all(nominal[1:] == 0.0)
    assert np.all(bent_in == 0.0), bent_in


def test_standing_on_flat_ground_has_no_leg_link_contact():
    scenario = Scenario(robot=RobotConfig(topology="split_up"))
    builder = DiagramBuilder()
    station, info = make_station(scenario)
    station = builder.AddSystem(station)
    _standing_controller(builder, station, info, scenario)
    logs = [LogVectorOutput(station.GetOutputPort(n), builder, 0.01) for n in ("leg_link_force", "self_contact")]
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(0.5)
    for log in logs:
        assert log.FindLog(simulator.get_context()).data().max() == pytest.approx(0.0)
