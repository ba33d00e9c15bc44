"""Leg kinematics of Qingzhui (paper 002, Eq. 1-6), vectorised over batches.

Two joint coordinates appear:

* motor angles m = (m0, m1, m2), the paper's j: m2 is the shank's *absolute* angle, set through
  the parallelogram;
* URDF joint angles q = (q0, q1, q2) of the serial chain in ``models/qingzhui.urdf``:
  q0 = m0, q1 = m1, q2 = m2 - m1.

Every function takes arrays whose last axis holds the three joints (or the xyz of a point) and
any number of leading batch axes. Positions of a foot are the centre of its sphere, in the base
frame B unless the name says leg frame L. Bend direction ``+1`` ("out") puts the knee radially
outside the hip-foot line, ``-1`` ("in") inside it, towards the trunk.
"""

from __future__ import annotations

import functools

import numpy as np

from qz_drake.errors import KinematicsError, bad_value
from qz_drake.robot.params import DEFAULT_PARAMS, NUM_LEGS, QingzhuiParams, leg_index

BEND_OUT = 1
BEND_IN = -1

# m = _T q and q = _T_INV m.
_T = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 1.0]])
_T_INV = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 1.0]])


def bend_sign(bend: int | str) -> int:
    """Normalises a bend direction given as +1/-1 or 'out'/'in'."""
    if isinstance(bend, str) and bend.lower() in ("out", "outside"):
        return BEND_OUT
    if isinstance(bend, str) and bend.lower() in ("in", "inside"):
        return BEND_IN
    if not isinstance(bend, (str, bool)) and bend in (BEND_OUT, BEND_IN):
        return int(bend)
    raise bad_value("bend", bend, "expected 'out' (+1) or 'in' (-1)", KinematicsError)


def motor_to_urdf(m: np.ndarray) -> np.ndarray:
    """Motor angles (..., 3) -> URDF joint angles (..., 3)."""
    return np.asarray(m, dtype=float) @ _T_INV.T


def urdf_to_motor(q: np.ndarray) -> np.ndarray:
    """URDF joint angles (..., 3) -> motor angles (..., 3)."""
    return np.asarray(q, dtype=float) @ _T.T


def motor_to_urdf_torque(tau_m: np.ndarray) -> np.ndarray:
    """Motor torques (..., 3) -> the equivalent URDF joint torques (power balance: T^T tau_m)."""
    return np.asarray(tau_m, dtype=float) @ _T


def urdf_to_motor_torque(tau_q: np.ndarray) -> np.ndarray:
    """URDF joint torques (..., 3) -> motor torques (..., 3)."""
    return np.asarray(tau_q, dtype=float) @ _T_INV


def foot_position_leg_frame(m: np.ndarray, params: QingzhuiParams = DEFAULT_PARAMS) -> np.ndarray:
    """Paper 002 Eq. 1-3: foot centre in the leg frame L from motor angles (..., 3)."""
    m = np.asarray(m, dtype=float)
    l1, l2 = params.thigh_length, params.shank_length
    m0, m1, m2 = m[..., 0], m[..., 1], m[..., 2]
    reach = l1 * np.sin(m1) + l2 * np.sin(m2)
    return np.stack([l1 * np.cos(m1) + l2 * np.cos(m2), reach * np.cos(m0), reach * np.sin(m0)],
                    axis=-1)


def leg_jacobian_motor(m: np.ndarray, params: QingzhuiParams = DEFAULT_PARAMS) -> np.ndarray:
    """Paper 002 Eq. 5: d p_L / d m, shape (..., 3, 3), columns ordered m0, m1, m2."""
    m = np.asarray(m, dtype=float)
    l1, l2 = params.thigh_length, params.shank_length
    s0, c0 = np.sin(m[..., 0]), np.cos(m[..., 0])
    s1, c1 = np.sin(m[..., 1]), np.cos(m[..., 1])
    s2, c2 = np.sin(m[..., 2]), np.cos(m[..., 2])
    reach = l1 * s1 + l2 * s2
    # Filled in place: nested np.stack costs more than the arithmetic at six legs a step.
    J = np.zeros(m.shape[:-1] + (3, 3))
    J[..., 0, 1], J[..., 0, 2] = -l1 * s1, -l2 * s2
    J[..., 1, 0], J[..., 1, 1], J[..., 1, 2] = -reach * s0, l1 * c1 * c0, l2 * c2 * c0
    J[..., 2, 0], J[..., 2, 1], J[..., 2, 2] = reach * c0, l1 * c1 * s0, l2 * c2 * s0
    return J


def leg_jacobian_urdf(q_leg: np.ndarray, params: QingzhuiParams = DEFAULT_PARAMS) -> np.ndarray:
    """d p_L / d q (URDF angles) in the leg frame L, shape (..., 3, 3)."""
    return leg_jacobian_motor(urdf_to_motor(q_leg), params) @ _T


def foot_position(leg: int | str, q_leg: np.ndarray,
                  params: QingzhuiParams = DEFAULT_PARAMS) -> np.ndarray:
    """Foot-sphere centre in the base frame from one leg's URDF angles (..., 3) ordered j0, j1, j2."""
    i = leg_index(leg)
    p_L = foot_position_leg_frame(urdf_to_motor(q_leg), params)
    return p_L @ params.R_BL(i).T + params.hip_position(i)


def foot_jacobian(leg: int | str, q_leg: np.ndarray,
                  params: QingzhuiParams = DEFAULT_PARAMS) -> np.ndarray:
    """d p_BF / d q (URDF angles) in the base frame, shape (..., 3, 3)."""
    i = leg_index(leg)
    J_m = leg_jacobian_motor(urdf_to_motor(q_leg), params)
    return params.R_BL(i) @ J_m @ _T


def shank_rotation(leg: int | str, q_leg: np.ndarray, params: QingzhuiParams = DEFAULT_PARAMS) -> np.ndarray:
    """Orientation of the shank (and the foot welded to it) in the base frame, (..., 3, 3):
    R_BL Rx(m0) Rz(m2), since the parallelogram keeps the shank at the absolute angle m2."""
    i = leg_index(leg)
    return params.R_BL(i) @ _rx_rz(urdf_to_motor(q_leg))


def all_shank_rotations(q: np.ndarray, params: QingzhuiParams = DEFAULT_PARAMS) -> np.ndarray:
    """The six shanks' orientations in the base frame from 18 URDF angles, (..., 6, 3, 3)."""
    q = np.asarray(q, dtype=float)
    m = urdf_to_motor(q.reshape(q.shape[:-1] + (NUM_LEGS, 3)))
    return all_leg_rotations(params) @ _rx_rz(m)


def all_leg_rotations(params: QingzhuiParams = DEFAULT_PARAMS) -> np.ndarray:
    """R_BL of the six legs, (6, 3, 3)."""
    return _leg_constants(params)[1].copy()


@functools.lru_cache(maxsize=16)
def _leg_constants(params: QingzhuiParams):
    """(hips (6, 3), R_BL (6, 3, 3), joint lower (3,), upper (3,)) of a parameter set, computed
    once (the tracker's IK runs hundreds of times per simulated second); read-only arrays."""
    hips = np.array(params.hip_positions, dtype=float)
    R = np.stack([params.R_BL(i) for i in range(NUM_LEGS)])
    lower, upper = params.joint_limits()
    for a in (hips, R, lower, upper):
        a.flags.writeable = False
    return hips, R, lower, upper


def _rx_rz(m: np.ndarray) -> np.ndarray:
    """Rx(m0) Rz(m2) for motor angles (..., 3)."""
    c0, s0 = np.cos(m[..., 0]), np.sin(m[..., 0])
    c2, s2 = np.cos(m[..., 2]), np.sin(m[..., 2])
    out = np.zeros(m.shape[:-1] + (3, 3))
    # Rx(a) Rz(b) = [[cb, -sb, 0], [ca sb, ca cb, -sa], [sa sb, sa cb, ca]]
    out[..., 0, 0], out[..., 0, 1] = c2, -s2
    out[..., 1, 0], out[..., 1, 1], out[..., 1, 2] = c0 * s2, c0 * c2, -s0
    out[..., 2, 0], out[..., 2, 1], out[..., 2, 2] = s0 * s2, s0 * c2, c0
    return out


def all_foot_positions(q: np.ndarray, params: QingzhuiParams = DEFAULT_PARAMS) -> np.ndarray:
    """All six feet in the base frame from the 18 URDF angles (..., 18) -> (..., 6, 3)."""
    q = np.asarray(q, dtype=float)
    q = q.reshape(q.shape[:-1] + (NUM_LEGS, 3))
    p_L = foot_position_leg_frame(urdf_to_motor(q), params)
    return np.einsum("lij,...lj->...li", all_leg_rotations(params), p_L) + np.asarray(params.hip_positions)


def leg_inverse_kinematics(leg: int | str, p_BF: np.ndarray, bend: int | str,
                           params: QingzhuiParams = DEFAULT_PARAMS, *,
                           check_limits: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """URDF joint angles that put a foot at p_BF (..., 3) with the given knee bend.

    Returns ``(q, reachable)``: q (..., 3) and a boolean mask (...,). Points out of reach (too
    far, too close, above the hip, or needing angles outside the joint limits when
    ``check_limits``) are marked False and their q is the closest configuration on the
    workspace boundary, so a caller can still show where the leg would point. Use
    :func:`solve_leg_inverse_kinematics` for an error instead.
    """
    i = leg_index(leg)
    sign = bend_sign(bend)
    l1, l2 = params.thigh_length, params.shank_length
    p_L = (np.asarray(p_BF, dtype=float) - params.hip_position(i)) @ params.R_BL(i)
    x, y, z = p_L[..., 0], p_L[..., 1], p_L[..., 2]
    m0 = np.arctan2(z, y)
    planar = np.hypot(y, z)
    dist = np.hypot(x, planar)
    alpha = np.arctan2(planar, x)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_beta = (l1 * l1 + dist * dist - l2 * l2) / (2.0 * l1 * dist)
    reachable = (dist <= l1 + l2) & (dist >= abs(l1 - l2)) & (dist > 1e-9) & (y > 0.0)
    beta = np.arccos(np.clip(np.nan_to_num(cos_beta, nan=1.0), -1.0, 1.0))
    m1 = alpha - sign * beta
    m2 = np.arctan2(planar - l1 * np.sin(m1), x - l1 * np.cos(m1))
    q = motor_to_urdf(np.stack([m0, m1, m2], axis=-1))
    if check_limits:
        lower, upper = params.joint_limits()
        reachable &= np.all((q >= lower - 1e-9) & (q <= upper + 1e-9), axis=-1)
    return q, reachable


def all_legs_inverse_kinematics(p_BF: np.ndarray, bends, params: QingzhuiParams = DEFAULT_PARAMS
                                ) -> tuple[np.ndarray, np.ndarray]:
    """Leg IK for all six feet at once: p_BF (..., 6, 3), bends (6,) -> q (..., 6, 3), ok (..., 6).

    The same solution as :func:`leg_inverse_kinematics` leg by leg, vectorised across legs
    (the tracker calls it hundreds of times per simulated second)."""
    hips, R, lower, upper = _leg_constants(params)
    signs = np.array([bend_sign(b) for b in bends], dtype=float)
    l1, l2 = params.thigh_length, params.shank_length
    p_L = np.einsum("...li,lij->...lj", np.asarray(p_BF, dtype=float) - hips, R)
    x, y, z = p_L[..., 0], p_L[..., 1], p_L[..., 2]
    planar = np.hypot(y, z)
    dist = np.hypot(x, planar)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_beta = (l1 * l1 + dist * dist - l2 * l2) / (2.0 * l1 * dist)
    ok = (dist <= l1 + l2) & (dist >= abs(l1 - l2)) & (dist > 1e-9) & (y > 0.0)
    beta = np.arccos(np.clip(np.where(np.isfinite(cos_beta), cos_beta, 1.0), -1.0, 1.0))
    m1 = np.arctan2(planar, x) - signs * beta
    m2 = np.arctan2(planar - l1 * np.sin(m1), x - l1 * np.cos(m1))
    q = np.stack([np.arctan2(z, y), m1, m2 - m1], axis=-1)
    ok &= np.all((q >= lower - 1e-9) & (q <= upper + 1e-9), axis=-1)
    return q, ok


def solve_leg_inverse_kinematics(leg: int | str, p_BF: np.ndarray, bend: int | str,
                                 params: QingzhuiParams = DEFAULT_PARAMS) -> np.ndarray:
    """Like :func:`leg_inverse_kinematics` but raises KinematicsError naming the first
    unreachable point."""
    q, ok = leg_inverse_kinematics(leg, p_BF, bend, params)
    if not np.all(ok):
        bad = np.asarray(p_BF, dtype=float).reshape(-1, 3)[~np.asarray(ok).reshape(-1)][0]
        raise bad_value(f"foot position of leg {leg}", tuple(np.round(bad, 4)),
                        "out of the leg's reach (or joint limits) for this bend", KinematicsError)
    return q


def foot_force_from_torque(leg: int | str, q_leg: np.ndarray, tau_leg: np.ndarray,
                           params: QingzhuiParams = DEFAULT_PARAMS) -> np.ndarray:
    """Paper 002 Eq. 6: the ground reaction force on a foot, in the base frame.

    tau_leg are the actuator torques (URDF coordinates) that hold the leg in static balance
    against the contact force F: tau + J^T F = 0, so F = -(J^T)^-1 tau. Leg weight and
    inertia are neglected, as in the paper (80 % of the leg's mass sits at the hip axis).
    Batched over leading axes. Near a singular leg (fully stretched) the result is unreliable.
    """
    J = foot_jacobian(leg, q_leg, params)
    tau = np.asarray(tau_leg, dtype=float)
    return -np.linalg.solve(np.swapaxes(J, -1, -2), tau[..., None])[..., 0]
