"""Leg kinematics against Drake's MultibodyPlant of models/qingzhui.urdf, and by hand."""

import math

import numpy as np
import pytest
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import JacobianWrtVariable

from qz_drake.errors import KinematicsError
from qz_drake.robot import kinematics as kin
from qz_drake.robot.model import JointOrder, add_qingzhui
from qz_drake.robot.params import DEFAULT_PARAMS, LEG_NAMES


@pytest.fixture(scope="module")
def plant_setup():
    plant = MultibodyPlant(0.0)
    instance = add_qingzhui(plant)
    plant.Finalize()
    return plant, instance, plant.CreateDefaultContext(), JointOrder(plant, instance)


def _random_leg_angles(rng, n):
    lower, upper = DEFAULT_PARAMS.joint_limits()
    return rng.uniform(lower, upper, size=(n, 3))


def test_leg_frame_position_matches_paper_equations_by_hand():
    l1, l2 = DEFAULT_PARAMS.thigh_length, DEFAULT_PARAMS.shank_length
    # Thigh horizontal out, shank straight down, leg plane tilted 90 deg: foot along L's z.
    p = kin.foot_position_leg_frame(np.array([math.pi / 2, 0.0, math.pi / 2]))
    np.testing.assert_allclose(p, [l1, 0.0, l2], atol=1e-12)
    # Both links horizontal: foot straight out along x.
    np.testing.assert_allclose(kin.foot_position_leg_frame(np.zeros(3)), [l1 + l2, 0, 0], atol=1e-12)


def test_foot_position_and_jacobian_match_drake(plant_setup):
    plant, instance, context, order = plant_setup
    rng = np.random.default_rng(0)
    q_plant = plant.GetPositions(context)
    base = plant.GetBodyByName("base", instance).body_frame()
    for _ in range(5):
        q_legs = _random_leg_angles(rng, 6)
        q_plant[order.q_index] = q_legs.reshape(-1)
        plant.SetPositions(context, q_plant)
        for i, leg in enumerate(LEG_NAMES):
            foot = plant.GetFrameByName(f"{leg}_foot", instance)
            p_drake = plant.CalcPointsPositions(context, foot, np.zeros(3), base)[:, 0]
            np.testing.assert_allclose(kin.foot_position(i, q_legs[i]), p_drake, atol=1e-9)
            J_drake = plant.CalcJacobianTranslationalVelocity(
                context, JacobianWrtVariable.kV, foot, np.zeros(3), base, base)
            J_leg = J_drake[:, order.v_index[3 * i:3 * i + 3]]
            np.testing.assert_allclose(kin.foot_jacobian(leg, q_legs[i]), J_leg, atol=1e-9)


def test_batched_calls_match_single_calls():
    rng = np.random.default_rng(1)
    q = _random_leg_angles(rng, 7).reshape(7, 3)
    batch = kin.foot_position("RB", q)
    assert batch.shape == (7, 3)
    for k in range(7):
        np.testing.assert_allclose(batch[k], kin.foot_position(2, q[k]), atol=1e-14)
    q18 = rng.uniform(-0.5, 0.5, size=(4, 18))
    feet = kin.all_foot_positions(q18)
    assert feet.shape == (4, 6, 3)
    np.testing.assert_allclose(feet[2, 4], kin.foot_position(4, q18[2, 12:15]), atol=1e-14)


@pytest.mark.parametrize("bend", ["out", "in"])
def test_inverse_kinematics_round_trip(bend):
    rng = np.random.default_rng(2)
    for i in range(6):
        target = DEFAULT_PARAMS.nominal_foothold(i) + rng.uniform(-0.12, 0.12, size=(50, 3))
        q, ok = kin.leg_inverse_kinematics(i, target, bend)
        assert ok.all()
        np.testing.assert_allclose(kin.foot_position(i, q), target, atol=1e-10)
        # The knee points the requested way: relative knee angle q2 > 0 is "out".
        assert np.all(np.sign(q[:, 2]) == kin.bend_sign(bend))


def test_inverse_kinematics_signals_unreachable_points():
    far = DEFAULT_PARAMS.hip_position(0) + np.array([0.0, 0.0, -1.5])
    above = DEFAULT_PARAMS.hip_position(0) + np.array([0.2, 0.0, 0.3])
    q, ok = kin.leg_inverse_kinematics(0, np.stack([far, above, DEFAULT_PARAMS.nominal_foothold(0)]),
                                       "out")
    assert ok.tolist() == [False, False, True]
    with pytest.raises(KinematicsError, match="leg 0"):
        kin.solve_leg_inverse_kinematics(0, far, "out")
    with pytest.raises(KinematicsError, match="bend"):
        kin.leg_inverse_kinematics(0, far, "sideways")
    with pytest.raises(KinematicsError, match="leg = 'XX'"):
        kin.foot_position("XX", np.zeros(3))


def test_motor_urdf_conversions_preserve_power():
    rng = np.random.default_rng(3)
    q = rng.normal(size=(10, 3))
    np.testing.assert_allclose(kin.motor_to_urdf(kin.urdf_to_motor(q)), q, atol=1e-14)
    q_dot, tau_m = rng.normal(size=(10, 3)), rng.normal(size=(10, 3))
    m_dot = kin.urdf_to_motor(q_dot)
    tau_q = kin.motor_to_urdf_torque(tau_m)
    np.testing.assert_allclose(np.sum(tau_m * m_dot, -1), np.sum(tau_q * q_dot, -1), atol=1e-12)
    np.testing.assert_allclose(kin.urdf_to_motor_torque(tau_q), tau_m, atol=1e-12)


def test_foot_force_from_torque_inverts_the_static_balance(plant_setup):
    plant, instance, context, order = plant_setup
    base = plant.GetBodyByName("base", instance).body_frame()
    rng = np.random.default_rng(4)
    q_plant = plant.GetPositions(context)
    for i, leg in enumerate(LEG_NAMES):
        q_leg, ok = kin.leg_inverse_kinematics(i, DEFAULT_PARAMS.nominal_foothold(i), "out")
        assert ok
        q_plant[order.q_index[3 * i:3 * i + 3]] = q_leg
        plant.SetPositions(context, q_plant)
        foot = plant.GetFrameByName(f"{leg}_foot", instance)
        J = plant.CalcJacobianTranslationalVelocity(
            context, JacobianWrtVariable.kV, foot, np.zeros(3), base, base)[:, order.v_index[3 * i:3 * i + 3]]
        force = np.array([rng.normal(0, 30), rng.normal(0, 30), 200.0])
        tau_holding = -J.T @ force  # actuator torques that balance the ground force
        np.testing.assert_allclose(kin.foot_force_from_torque(leg, q_leg, tau_holding), force,
                                   atol=1e-8)
        # Motor torques give the same force (Eq. 6 with the paper's own joint coordinates).
        tau_m = kin.urdf_to_motor_torque(tau_holding)
        J_m = DEFAULT_PARAMS.R_BL(i) @ kin.leg_jacobian_motor(kin.urdf_to_motor(q_leg))
        np.testing.assert_allclose(-np.linalg.solve(J_m.T, tau_m), force, atol=1e-8)


def test_shank_rotation_matches_drake(plant_setup):
    plant, instance, context, order = plant_setup
    rng = np.random.default_rng(5)
    q_plant = plant.GetPositions(context)
    q_legs = _random_leg_angles(rng, 6)
    q_plant[order.q_index] = q_legs.reshape(-1)
    plant.SetPositions(context, q_plant)
    base = plant.GetBodyByName("base", instance).body_frame()
    for i, leg in enumerate(LEG_NAMES):
        shank = plant.GetFrameByName(f"{leg}_shank", instance)
        R = shank.CalcPose(context, base).rotation().matrix()
        np.testing.assert_allclose(kin.shank_rotation(i, q_legs[i]), R, atol=1e-9)


@pytest.mark.parametrize("bends", [(1,) * 6, (-1, 1, -1, 1, -1, 1)])
def test_all_legs_inverse_kinematics_matches_per_leg(bends):
    rng = np.random.default_rng(6)
    targets = np.array([DEFAULT_PARAMS.nominal_foothold(i) for i in range(6)]) + rng.uniform(-0.1, 0.1, (5, 6, 3))
    targets[0, 2] = [0.0, 0.0, 2.0]  # one unreachable point
    q, ok = kin.all_legs_inverse_kinematics(targets, bends)
    for i in range(6):
        q_i, ok_i = kin.leg_inverse_kinematics(i, targets[:, i], bends[i])
        np.testing.assert_array_equal(ok[:, i], ok_i)
        np.testing.assert_allclose(q[ok[:, i], i], q_i[ok_i], atol=1e-12)
    assert not ok[0, 2]


def test_all_shank_rotations_match_per_leg():
    q = np.random.default_rng(7).uniform(-1, 1, 18)
    R = kin.all_shank_rotations(q)
    for i in range(6):
        np.testing.assert_allclose(R[i], kin.shank_rotation(i, q[3 * i:3 * i + 3]), atol=1e-14)
