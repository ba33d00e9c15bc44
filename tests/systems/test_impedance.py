"""Spherical leg impedance (paper 002 Eq. 9-19): translators by hand and by virtual work, and
Qingzhui standing on its six impedance-controlled legs."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from qz_drake.config import Scenario
from qz_drake.robot import kinematics
from qz_drake.station import GRAVITY, make_station
from qz_drake.systems import impedance as imp


def test_spherical_coordinates_by_hand():
    # Straight down: l = |p|, no forward angle, no abduction.
    np.testing.assert_allclose(imp.cartesian_to_spherical([0.0, 0.5, 0.0]), [0.5, 0.0, 0.0])
    # 45 deg forward in the leg plane, abducted 30 deg.
    s = np.array([0.6, np.pi / 4, np.pi / 6])
    p = imp.spherical_to_cartesian(s)
    np.testing.assert_allclose(p, [0.6 * np.sqrt(0.5), 0.6 * np.sqrt(0.5) * np.cos(np.pi / 6),
                                   0.6 * np.sqrt(0.5) * np.sin(np.pi / 6)])
    np.testing.assert_allclose(imp.cartesian_to_spherical(p), s)
    # phi is the abduction joint j0 itself.
    q = np.array([0.3, 0.5, 1.4])
    p_L = kinematics.foot_position_leg_frame(kinematics.urdf_to_motor(q))
    assert imp.cartesian_to_spherical(p_L)[2] == pytest.approx(0.3)


def test_translators_preserve_velocity_and_work():
    rng = np.random.default_rng(0)
    s = np.column_stack([rng.uniform(0.3, 0.7, 20), rng.uniform(-0.8, 0.8, 20), rng.uniform(-0.5, 0.5, 20)])
    J = imp.spherical_jacobian(s)
    eps = 1e-7
    for k in range(3):
        d = np.zeros(3)
        d[k] = eps
        fd = (imp.spherical_to_cartesian(s + d) - imp.spherical_to_cartesian(s - d)) / (2 * eps)
        np.testing.assert_allclose(J[:, :, k], fd, atol=1e-7)
    v, f = rng.normal(size=(20, 3)), rng.normal(size=(20, 3))
    s_dot = imp.velocity_to_spherical(s, v)
    np.testing.assert_allclose((J @ s_dot[..., None])[..., 0], v, atol=1e-10)
    # A spherical generalized force does the same work as the Cartesian force.
    np.testing.assert_allclose(np.sum(imp.force_to_spherical(s, f) * s_dot, -1), np.sum(f * v, -1), atol=1e-10)


def test_joint_torques_do_the_work_of_the_spherical_force():
    rng = np.random.default_rng(1)
    for leg in range(6):
        q = np.array([0.1, 0.5, 1.4]) + rng.normal(0, 0.1, 3)
        q_dot, f_s = rng.normal(size=3), rng.normal(size=3)
        tau = imp.spherical_force_to_joint_torque(leg, q, f_s)
        J_q = kinematics.leg_jacobian_urdf(q)
        s = imp.cartesian_to_spherical(kinematics.foot_position_leg_frame(kinematics.urdf_to_motor(q)))
        s_dot = imp.velocity_to_spherical(s, J_q @ q_dot)
        assert tau @ q_dot == pytest.approx(f_s @ s_dot, abs=1e-9)


def test_stiffness_pulls_the_foot_back_along_the_leg():
    controller = imp.SphericalImpedance()
    q = np.array([0.0, 0.5, 1.5])
    p = kinematics.foot_position_leg_frame(kinematics.urdf_to_motor(q))
    s = imp.cartesian_to_spherical(p)
    target = imp.spherical_to_cartesian(s - np.array([0.02, 0.0, 0.0]))  # 2 cm shorter leg
    tau = controller.leg_torques(q, np.zeros(3), target, np.zeros(3), np.zeros(3), 9000.0, True)
    # The drives' force on the foot: -K * 0.02 m along l (shortening), nothing else.
    J_q = kinematics.leg_jacobian_urdf(q)
    f_L = np.linalg.solve(J_q.T, tau)
    np.testing.assert_allclose(imp.force_to_spherical(s, f_L), [-180.0, 0.0, 0.0], atol=1e-8)


def test_qingzhui_stands_on_impedance_legs():
    scenario = Scenario()
    builder = DiagramBuilder()
    diagram, info = make_station(scenario)
    station = builder.AddSystem(diagram)
    controller = builder.AddSystem(imp.SphericalImpedance())
    q0 = info.initial_state[7:25].reshape(6, 3)
    p_d = np.array([kinematics.foot_position_leg_frame(kinematics.urdf_to_motor(q)) for q in q0])
    weight = info.params.total_mass * GRAVITY / 6
    f_ref = np.tile([0.0, weight, 0.0], 6)  # each leg pushes its foot down (+y in L)
    sources = {"desired_foot_position": p_d.reshape(-1), "desired_foot_velocity": np.zeros(18),
               "reference_force": f_ref, "stiffness": np.full(6, 9000.0), "mode": np.ones(6)}
    for name, value in sources.items():
        src = builder.AddSystem(ConstantVectorSource(value))
        builder.Connect(src.get_output_port(), controller.GetInputPort(name))
    builder.Connect(station.GetOutputPort("state"), controller.GetInputPort("state"))
    builder.Connect(controller.GetOutputPort("joint_torque"), station.GetInputPort("joint_torque"))
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(3.0)
    x = station.GetOutputPort("state").Eval(station.GetMyContextFromRoot(simulator.get_context()))
    # Compliant legs: the body settles within 2 cm of nominal (the legs' own weight is not
    # compensated), level, all feet down.
    assert abs(x[6] - info.initial_state[6]) < 0.02
    assert abs(x[1]) < 0.01 and abs(x[2]) < 0.01
    np.testing.assert_array_equal(
        station.GetOutputPort("foot_contact").Eval(station.GetMyContextFromRoot(simulator.get_context())), np.ones(6))


def test_six_legs_at_once_equal_one_at_a_time():
    rng = np.random.default_rng(3)
    controller = imp.SphericalImpedance()
    q = np.array([0.0, 0.5, 1.5]) + rng.normal(0, 0.1, (6, 3))
    v, v_d, f_ref = rng.normal(0, 0.5, (6, 3)), rng.normal(0, 0.3, (6, 3)), rng.normal(0, 80, (6, 3))
    p_d = kinematics.foot_position_leg_frame(kinematics.urdf_to_motor(q)) + rng.normal(0, 0.02, (6, 3))
    stiffness = np.array([7000.0, 9000.0, 11000.0, 7000.0, 9000.0, 11000.0])
    stance = np.array([True, False, True, True, False, False])
    together = controller.leg_torques(q, v, p_d, v_d, f_ref, stiffness, stance)
    for i in range(6):
        alone = controller.leg_torques(q[i], v[i], p_d[i], v_d[i], f_ref[i], stiffness[i], stance[i])
        np.testing.assert_allclose(together[i], alone, rtol=1e-12, atol=1e-9)
    # Swing legs ignore the stance stiffness; stance legs do not.
    other = controller.leg_torques(q, v, p_d, v_d, f_ref, stiffness * 2, stance)
    np.testing.assert_allclose(other[~stance], together[~stance], atol=1e-12)
    assert np.all(np.abs(other[stance] - together[stance]).max(axis=1) > 1e-3)
