"""Measurement (Eq. 6), pitch / roll and the 18 stance features (Eq. 7-8)."""

import numpy as np
import pytest
from pydrake.math import RollPitchYaw

from qz_drake.classification import features as feat
from qz_drake.robot import kinematics
from qz_drake.station import standing_state
from qz_drake.robot.topology import get_topology
from qz_drake.terrain import make_terrain


def _standing_q():
    x = standing_state(make_terrain("flat"), get_topology("nominal"))
    return x[7:25]


def test_foot_forces_invert_the_jacobian_transpose():
    q = _standing_q() + np.random.default_rng(0).normal(0, 0.05, 18)
    F = np.random.default_rng(1).normal(0, 100, (6, 3))
    tau = np.concatenate([-kinematics.foot_jacobian(i, q[3 * i:3 * i + 3]).T @ F[i] for i in range(6)])
    np.testing.assert_allclose(feat.foot_forces(q, tau), F, atol=1e-8)
    for i in range(6):
        np.testing.assert_allclose(feat.foot_forces(q, tau)[i],
                                   kinematics.foot_force_from_torque(i, q[3 * i:3 * i + 3], tau[3 * i:3 * i + 3]))


def test_foot_velocity_is_the_jacobian_times_joint_rates():
    q, v = _standing_q(), np.random.default_rng(2).normal(0, 1, 18)
    h = 1e-7
    p0 = kinematics.all_foot_positions(q)
    p1 = kinematics.all_foot_positions(q + h * v)
    np.testing.assert_allclose(feat.foot_velocities(q, v), (p1 - p0) / h, atol=1e-5)


def test_pitch_and_roll_from_the_imu_quaternion():
    imu = np.zeros(10)
    imu[:4] = RollPitchYaw(0.1, -0.2, 0.7).ToQuaternion().wxyz()
    pitch, roll = feat.pitch_roll(imu)
    assert pitch == pytest.approx(-0.2) and roll == pytest.approx(0.1)


def test_features_by_hand():
    samples = np.zeros((9, feat.SAMPLE_SIZE))
    samples[:, 0] = [1, 2, 3, 4, 5, 6, 7, 8, 9]
    samples[:, 1] = 0.1
    samples[:, 2] = -0.2
    samples[:, 3] = np.linspace(0.2, 0.4, 9)
    f = feat.stance_features(samples)
    assert f.shape == (18,) and len(feat.FEATURE_NAMES) == 18
    std = np.sqrt(2.0 / 3.0)
    np.testing.assert_allclose(f[:15], [3, 1, 2, 2, std, 6, 4, 5, 5, std, 9, 7, 8, 8, std])
    np.testing.assert_allclose(f[15:], [0.1, -0.2, 0.3])
    # Unequal windows split as evenly as possible: 10 samples -> 4, 3, 3.
    samples10 = np.zeros((10, feat.SAMPLE_SIZE))
    samples10[:, 0] = np.arange(10)
    assert feat.stance_features(samples10)[0] == 3 and feat.stance_features(samples10)[5] == 6


def test_a_stance_too_short_for_three_windows_gives_no_features():
    assert feat.stance_features(np.ones((3 * feat.MIN_SAMPLES_PER_WINDOW - 1, feat.SAMPLE_SIZE))) is None
    assert feat.stance_features(np.ones((0, feat.SAMPLE_SIZE))) is None
    with pytest.raises(ValueError, match="shape"):
        feat.stance_features(np.ones((12, 3)))
