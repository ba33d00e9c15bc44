"""JointPdController (paper 000 Eq. 7): at every read, or held at a period beside drives that
run the PD themselves."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, Integrator

from qz_drake.errors import QzError
from qz_drake.scene import standing_state
from qz_drake.systems.joint_pd import JointPdController


def _controller_on_a_moving_state(update_period):
    """The controller reading a state whose joint velocities integrate into its positions."""
    from qz_drake.config import TerrainConfig
    from qz_drake.robot.params import DEFAULT_PARAMS
    from qz_drake.robot.topology import get_topology
    from qz_drake.station import make_heightmap

    x0 = standing_state(make_heightmap(TerrainConfig(kind="flat")), get_topology("nominal", DEFAULT_PARAMS),
                        (0.0, 0.0), 0.0, DEFAULT_PARAMS)
    builder = DiagramBuilder()
    rates = np.zeros(len(x0))
    rates[7:25] = 0.5  # the joint angles drift at 0.5 rad/s
    drift = builder.AddSystem(ConstantVectorSource(rates))
    state = builder.AddSystem(Integrator(len(x0)))
    builder.Connect(drift.get_output_port(), state.get_input_port())
    controller = builder.AddSystem(JointPdController(kp=100.0, kd=0.0, update_period=update_period))
    desired = builder.AddSystem(ConstantVectorSource(np.concatenate([x0[7:25], np.zeros(18)])))
    builder.Connect(state.get_output_port(), controller.GetInputPort("state"))
    builder.Connect(desired.get_output_port(), controller.GetInputPort("desired_state"))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    state.set_integral_value(state.GetMyMutableContextFromRoot(simulator.get_mutable_context()), x0)
    simulator.Initialize()
    return simulator, controller


def test_a_held_torque_changes_only_at_its_period_and_matches_the_torque_read_then():
    simulator, held = _controller_on_a_moving_state(0.005)
    port = held.GetOutputPort("joint_torque")
    context = held.GetMyContextFromRoot(simulator.get_context())
    start = port.Eval(context).copy()
    np.testing.assert_allclose(start, _read_at(0.0), atol=1e-9)  # the initialization's update
    simulator.AdvanceTo(0.004)
    np.testing.assert_array_equal(port.Eval(context), start)  # the joints moved, the torque is held
    simulator.AdvanceTo(0.006)
    updated = port.Eval(context)
    assert np.abs(updated - start).max() > 0.1  # updated at 5 ms: kp * 0.5 rad/s * 5 ms = 0.25
    np.testing.assert_allclose(updated, _read_at(0.005), atol=1e-9)


def _read_at(t):
    simulator, live = _controller_on_a_moving_state(None)
    simulator.AdvanceTo(t)
    return live.GetOutputPort("joint_torque").Eval(live.GetMyContextFromRoot(simulator.get_context())).copy()


@pytest.mark.parametrize("period", [0.0, -1.0, float("nan")])
def test_a_bad_update_period_is_refused_by_name(period):
    with pytest.raises(QzError, match="update_period"):
        JointPdController(kp=0.0, kd=0.0, update_period=period)
