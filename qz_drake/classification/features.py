"""Measurement and stance features for terrain classification (paper 002, section 3, Eq. 6-8).

Measurement, from the station's ports only (never the simulator's contact forces):

* the foot force of each leg from its measured joint torques through the leg Jacobian (Eq. 6,
  ``qz_drake.robot.kinematics.foot_force_from_torque``), in the base frame; the classifier
  uses its component along the base z axis (the paper's "force along the y axis", the
  direction of gravity in its figures);
* pitch and roll from the IMU's orientation;
* the foot's velocity relative to the body (J q_dot), whose mean speed over a stance measures
  the robot's forward speed.

Features (Eq. 7-8), per leg per stance: the stance force split into three sub-windows, each
max, min, mean, median and standard deviation (15), then the mean pitch, mean roll and mean
foot speed: 18 in all. A stance too short to split into three windows of
``MIN_SAMPLES_PER_WINDOW`` samples gives no feature vector; the caller counts it.
"""

from __future__ import annotations

import numpy as np

from qz_drake.robot import kinematics
from qz_drake.robot.params import DEFAULT_PARAMS, NUM_LEGS, QingzhuiParams

NUM_FEATURES = 18
# Fewest samples in each of the three sub-windows (a standard deviation needs a few). [-]
MIN_SAMPLES_PER_WINDOW = 3
FEATURE_NAMES: tuple[str, ...] = tuple(
    f"force_w{w}_{stat}" for w in (1, 2, 3) for stat in ("max", "min", "mean", "median", "std")
) + ("mean_pitch", "mean_roll", "mean_foot_speed")
# Samples a stance buffer holds (at 2 ms, 1.2 s: four times the default support time).
MAX_STANCE_SAMPLES = 600
# Signals sampled per leg while it supports: vertical foot force, pitch, roll, foot speed.
SAMPLE_SIZE = 4


def _batched_foot_jacobians(q: np.ndarray, params: QingzhuiParams) -> np.ndarray:
    """d p_BF / d q of all six legs, (6, 3, 3), from the 18 URDF angles."""
    return kinematics.all_leg_rotations(params) @ kinematics.leg_jacobian_urdf(np.asarray(q).reshape(NUM_LEGS, 3),
                                                                                 params)


def foot_forces(q: np.ndarray, tau: np.ndarray, params: QingzhuiParams = DEFAULT_PARAMS) -> np.ndarray:
    """Eq. 6 for all legs: ground reaction force on each foot in the base frame, (6, 3), from the
    18 joint angles and the 18 measured joint torques (static balance, legs' weight neglected)."""
    J = _batched_foot_jacobians(np.asarray(q, dtype=float), params)
    tau = np.asarray(tau, dtype=float).reshape(NUM_LEGS, 3)
    return -np.linalg.solve(np.swapaxes(J, -1, -2), tau[..., None])[..., 0]


def foot_velocities(q: np.ndarray, v: np.ndarray, params: QingzhuiParams = DEFAULT_PARAMS) -> np.ndarray:
    """Each foot's velocity relative to the body, in the base frame, (6, 3)."""
    J = _batched_foot_jacobians(np.asarray(q, dtype=float), params)
    return (J @ np.asarray(v, dtype=float).reshape(NUM_LEGS, 3, 1))[..., 0]


def pitch_roll(imu: np.ndarray) -> tuple[float, float]:
    """Pitch and roll (ZYX convention) from the IMU's orientation quaternion w x y z. [rad]"""
    w, x, y, z = np.asarray(imu[:4], dtype=float) / np.linalg.norm(imu[:4])
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    return float(pitch), float(roll)


def measure(q: np.ndarray, v: np.ndarray, tau: np.ndarray, imu: np.ndarray,
            params: QingzhuiParams = DEFAULT_PARAMS) -> np.ndarray:
    """One sample per leg, (6, SAMPLE_SIZE): [vertical foot force in the base frame (N), pitch,
    roll (rad), foot speed relative to the body (m/s)]."""
    force = foot_forces(q, tau, params)
    speed = np.linalg.norm(foot_velocities(q, v, params), axis=1)
    pitch, roll = pitch_roll(imu)
    out = np.empty((NUM_LEGS, SAMPLE_SIZE))
    out[:, 0] = force[:, 2]
    out[:, 1] = pitch
    out[:, 2] = roll
    out[:, 3] = speed
    return out


def stance_features(samples: np.ndarray) -> np.ndarray | None:
    """Eq. 7-8: the 18 features of one stance from its samples (n, SAMPLE_SIZE); None when the
    stance is too short for three windows of MIN_SAMPLES_PER_WINDOW samples."""
    samples = np.asarray(samples, dtype=float)
    if samples.ndim != 2 or samples.shape[1] != SAMPLE_SIZE:
        raise ValueError(f"stance samples must have shape (n, {SAMPLE_SIZE}), got {samples.shape}")
    if len(samples) < 3 * MIN_SAMPLES_PER_WINDOW:
        return None
    out = np.empty(NUM_FEATURES)
    for w, window in enumerate(np.array_split(samples[:, 0], 3)):
        out[5 * w:5 * w + 5] = (window.max(), window.min(), window.mean(), np.median(window), window.std())
    out[15:18] = samples[:, 1:4].mean(axis=0)
    return out
