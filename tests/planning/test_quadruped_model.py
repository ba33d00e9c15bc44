"""The quadruped of paper 003: committed URDF, Drake FK against the analytic legs, IK round trip."""

import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import MultibodyPlant

from qz_drake.errors import KinematicsError
from qz_drake.planning.static_gait import LEGS, QuadrupedGeometry
from qz_drake.robot.quadruped import (DEFAULT_QUADRUPED, QUADRUPED_URDF, add_quadruped, body_ik, joint_names,
                                      leg_fk, leg_ik, make_quadruped_urdf)


def test_committed_urdf_is_generated():
    assert QUADRUPED_URDF.read_text() == make_quadruped_urdf(DEFAULT_QUADRUPED), (
        "models/quadruped.urdf is stale: run scripts/make_quadruped_urdf.py")


@pytest.fixture(scope="module")
def plant():
    plant = MultibodyPlant(0.0)
    instance = add_quadruped(plant)
    plant.Finalize()
    return plant, instance


def test_mass_and_joints(plant):
    plant, instance = plant
    assert plant.num_actuators() == 12 and plant.num_positions() == 7 + 12
    mass = sum(plant.get_body(i).default_mass() for i in plant.GetBodyIndices(instance))
    assert mass == pytest.approx(DEFAULT_QUADRUPED.total_mass) and mass == pytest.approx(2.8)
    lower, upper = DEFAULT_QUADRUPED.joint_limits()
    for name in joint_names():
        joint = plant.GetJointByName(name, instance)
        j = int(name[-1])
        assert joint.position_lower_limits()[0] == pytest.approx(lower[j])
        assert joint.position_upper_limits()[0] == pytest.approx(upper[j])


def test_drake_fk_matches_the_analytic_legs(plant):
    plant, instance = plant
    context = plant.CreateDefaultContext()
    rng = np.random.default_rng(0)
    lower, upper = DEFAULT_QUADRUPED.joint_limits()
    X_WB = RigidTransform(RollPitchYaw(0.1, -0.2, 0.7), [0.3, -0.1, 0.2])
    plant.SetFreeBodyPose(context, plant.GetBodyByName("base", instance), X_WB)
    for _ in range(5):
        q = rng.uniform(lower, upper, size=(4, 3))
        for i, leg in enumerate(LEGS):
            for j in range(3):
                plant.GetJointByName(f"{leg}_j{j}", instance).set_angle(context, q[i, j])
        for i, leg in enumerate(LEGS):
            foot = plant.GetFrameByName(f"{leg}_foot", instance)
            p_WF = plant.CalcPointsPositions(context, foot, np.zeros(3), plant.world_frame())[:, 0]
            assert X_WB.inverse() @ p_WF == pytest.approx(leg_fk(leg, q[i]), abs=1e-12)


def test_hand_checked_pose():
    g = QuadrupedGeometry()
    # Straight leg hanging down: the foot is shoulder-outwards of the hip, thigh + shank below.
    assert leg_fk("RB", [0, 0, 0]) == pytest.approx([-g.half_length, -g.half_width - g.shoulder, -0.17])
    # Positive abduction swings a right foot outwards (-y), a left foot outwards (+y).
    assert leg_fk("RF", [0.3, 0, 0])[1] < leg_fk("RF", [0, 0, 0])[1]
    assert leg_fk("LF", [0.3, 0, 0])[1] > leg_fk("LF", [0, 0, 0])[1]
    # Positive hip swings the thigh backwards; the knee-backwards branch keeps q2 <= 0.
    assert leg_fk("LF", [0, 0.3, 0])[0] < g.half_length


def test_ik_round_trip_and_reachable_workspace():
    """IK inverts FK on the knee-backwards branch; every point the gait search calls reachable has
    an IK solution inside the URDF's joint limits."""
    g = QuadrupedGeometry()
    lower, upper = DEFAULT_QUADRUPED.joint_limits()
    rng = np.random.default_rng(1)
    for leg in LEGS:
        q = rng.uniform(lower, [upper[0], upper[1], -0.05], size=(200, 3))
        p = leg_fk(leg, q)
        # The IK's branch: foot below the hip in the leg plane.
        keep = g.thigh * np.cos(q[:, 1]) + g.shank * np.cos(q[:, 1] + q[:, 2]) > 1e-3
        assert leg_ik(leg, p[keep]) == pytest.approx(q[keep], abs=1e-9)
        points = g.hip_B(leg) + rng.uniform([-0.15, -0.15, -0.17], [0.15, 0.15, 0.0], size=(3000, 3))
        reachable = np.array([g.reachable(leg, p) for p in points])
        assert reachable.sum() > 100
        q = leg_ik(leg, points[reachable])
        assert np.all(q >= lower - 1e-9) and np.all(q <= upper + 1e-9)
        assert leg_fk(leg, q) == pytest.approx(points[reachable], abs=1e-9)


def test_body_ik_places_the_feet():
    g = QuadrupedGeometry()
    R_WB = RollPitchYaw(0.05, -0.1, 0.3).ToRotationMatrix().matrix()
    p_WB = np.array([0.2, 0.1, 0.14])
    feet_B = np.array([[*g.default_foothold_B(leg), -0.11] for leg in LEGS])
    feet_W = feet_B @ R_WB.T + p_WB
    q = body_ik(p_WB, R_WB, feet_W).reshape(4, 3)
    for i, leg in enumerate(LEGS):
        assert leg_fk(leg, q[i]) == pytest.approx(feet_B[i], abs=1e-12)


def test_out_of_reach_names_the_leg():
    with pytest.raises(KinematicsError, match="LB foot"):
        leg_ik("LB", [-0.1, 0.075, -0.5])
    assert np.isnan(leg_ik("LB", [[-0.1, 0.075, -0.5]], strict=False)).all()
    with pytest.raises(KinematicsError, match="leg"):
        leg_fk("XX", [0, 0, 0])
