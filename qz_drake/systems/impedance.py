"""Leg impedance in spherical coordinates (paper 002, section 4.2, Eq. 9-20).

Each leg's foot is described in its leg frame L (x radially out along j0's axis, y down,
z = x cross y) by spherical coordinates s = (l, theta, phi): the leg length, the
forward/backward angle in the leg plane and the abduction angle,

    p_L = l (sin theta, cos theta cos phi, cos theta sin phi),   phi = j0.

The translators of Eq. 9-11 map a designed position, velocity and reference force from
Cartesian to spherical coordinates (a force becomes the generalized force [f_l, t_theta,
t_phi] = J_s^T f that does the same work). The impedance law of Eq. 18 makes the foot behave
as a mass-damper-spring about the designed motion; we drop the inertia term (M_d = 0: the
foot's acceleration is not measured) and write it as the generalized force the drives put on
the foot,

    f_leg = f_ref - K (s - s_d) - B (s_dot - s_d_dot),

whose joint torques follow by virtual work (Eq. 19): tau = J_q^T J_s^-T f_leg, with J_q the
foot Jacobian in L. In simulation the torques are applied directly; on the robot the torque
PID of Eq. 20 closes the loop on the joint torque sensors and belongs in the hardware
interface, below the station's ``joint_torque`` port.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector, LeafSystem

from qz_drake.robot import kinematics
from qz_drake.robot.params import DEFAULT_PARAMS, NUM_JOINTS, NUM_LEGS, QingzhuiParams
from qz_drake.state_layout import JOINT_Q, JOINT_V, STATE_SIZE

SWING, STANCE = 0, 1


def cartesian_to_spherical(p_L: np.ndarray) -> np.ndarray:
    """Eq. 9: (..., 3) foot positions in L -> (l, theta, phi)."""
    p = np.asarray(p_L, dtype=float)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    planar = np.hypot(y, z)
    return np.stack([np.sqrt(x * x + planar * planar), np.arctan2(x, planar), np.arctan2(z, y)], axis=-1)


def spherical_to_cartesian(s: np.ndarray) -> np.ndarray:
    s = np.asarray(s, dtype=float)
    l, th, ph = s[..., 0], s[..., 1], s[..., 2]
    return np.stack([l * np.sin(th), l * np.cos(th) * np.cos(ph), l * np.cos(th) * np.sin(ph)], axis=-1)


def spherical_jacobian(s: np.ndarray) -> np.ndarray:
    """J_s = d p_L / d s, shape (..., 3, 3), columns l, theta, phi."""
    s = np.asarray(s, dtype=float)
    l, th, ph = s[..., 0], s[..., 1], s[..., 2]
    st, ct, sp, cp = np.sin(th), np.cos(th), np.sin(ph), np.cos(ph)
    # Filled in place: nested np.stack costs more than the arithmetic at six legs a step.
    J = np.zeros(s.shape[:-1] + (3, 3))
    J[..., 0, 0], J[..., 0, 1] = st, l * ct
    J[..., 1, 0], J[..., 1, 1], J[..., 1, 2] = ct * cp, -l * st * cp, -l * ct * sp
    J[..., 2, 0], J[..., 2, 1], J[..., 2, 2] = ct * sp, -l * st * sp, l * ct * cp
    return J


def velocity_to_spherical(s: np.ndarray, v_L: np.ndarray) -> np.ndarray:
    """Eq. 10: Cartesian foot velocity in L -> s_dot = J_s^-1 v."""
    return np.linalg.solve(spherical_jacobian(s), np.asarray(v_L, dtype=float)[..., None])[..., 0]


def force_to_spherical(s: np.ndarray, f_L: np.ndarray) -> np.ndarray:
    """Eq. 11: a Cartesian force on the foot in L -> [f_l, t_theta, t_phi] = J_s^T f."""
    J = spherical_jacobian(s)
    return (np.swapaxes(J, -1, -2) @ np.asarray(f_L, dtype=float)[..., None])[..., 0]


def spherical_force_to_joint_torque(leg: int, q_leg: np.ndarray, f_s: np.ndarray,
                                    params: QingzhuiParams = DEFAULT_PARAMS) -> np.ndarray:
    """Eq. 19: joint torques (URDF coordinates) that apply the generalized force f_s to the foot:
    tau = J_q^T J_s^-T f_s (J_q the foot Jacobian in L)."""
    p_L = kinematics.foot_position_leg_frame(kinematics.urdf_to_motor(q_leg), params)
    s = cartesian_to_spherical(p_L)
    J_q = kinematics.leg_jacobian_urdf(q_leg, params)
    f_L = np.linalg.solve(np.swapaxes(spherical_jacobian(s), -1, -2), np.asarray(f_s, dtype=float)[..., None])
    return (np.swapaxes(J_q, -1, -2) @ f_L)[..., 0]


class SphericalImpedance(LeafSystem):
    """Per-leg spherical impedance (Eq. 9-19) for all six legs.

    .. pydrake_system::

        name: SphericalImpedance
        input_ports:
        - state
        - desired_foot_position
        - desired_foot_velocity
        - reference_force
        - stiffness
        - mode
        output_ports:
        - joint_torque

    Desired foot positions and velocities (18) and reference forces (18, the force the leg
    should apply to its foot, e.g. weight support from the body stabiliser) are in each leg's
    frame L, three per leg in LEG_NAMES order. ``stiffness`` (6) is each leg's stance stiffness
    along l [N/m] (paper: 9 kN/m default, 7 kN/m on concrete, 11 kN/m on foam); ``mode`` (6)
    is 0 for swing ("swing" mode, used in LDS) and 1 for stance (WAS, THS, LTS).

    Args:
        swing_stiffness: (l, theta, phi) stiffness in swing. [N/m, N*m/rad, N*m/rad]
        swing_damping: (l, theta, phi) damping in swing. [N*s/m, N*m*s/rad, N*m*s/rad]
        stance_angular_stiffness: (theta, phi) stiffness in stance. [N*m/rad]
        stance_damping: (l, theta, phi) damping in stance (paper's Fig. 13: 200 N*s/m along l).
        params: robot parameters.
    """

    def __init__(self, *, swing_stiffness=(2000.0, 300.0, 300.0), swing_damping=(60.0, 10.0, 10.0),
                 stance_angular_stiffness=(800.0, 800.0), stance_damping=(200.0, 30.0, 30.0),
                 params: QingzhuiParams = DEFAULT_PARAMS):
        super().__init__()
        self._params = params
        self._swing_k = np.asarray(swing_stiffness, dtype=float)
        self._swing_b = np.asarray(swing_damping, dtype=float)
        self._stance_k_angular = np.asarray(stance_angular_stiffness, dtype=float)
        self._stance_b = np.asarray(stance_damping, dtype=float)
        self._state = self.DeclareVectorInputPort("state", STATE_SIZE)
        self._p_d = self.DeclareVectorInputPort("desired_foot_position", 3 * NUM_LEGS)
        self._v_d = self.DeclareVectorInputPort("desired_foot_velocity", 3 * NUM_LEGS)
        self._f_ref = self.DeclareVectorInputPort("reference_force", 3 * NUM_LEGS)
        self._stiffness = self.DeclareVectorInputPort("stiffness", NUM_LEGS)
        self._mode = self.DeclareVectorInputPort("mode", NUM_LEGS)
        self.DeclareVectorOutputPort("joint_torque", NUM_JOINTS, self._calc_torque)

    def leg_torques(self, q, v, p_d, v_d, f_ref, stiffness, stance) -> np.ndarray:
        """The impedance torques (URDF coordinates) of legs given as (..., 3) joint angles,
        joint velocities, designed foot positions and velocities and reference forces in L,
        with (...) stance stiffnesses and stance flags; all legs at once."""
        q, v, p_d, v_d, f_ref = (np.asarray(a, dtype=float) for a in (q, v, p_d, v_d, f_ref))
        stance = np.asarray(stance, dtype=bool)[..., None]
        J_q = kinematics.leg_jacobian_urdf(q, self._params)
        s = cartesian_to_spherical(kinematics.foot_position_leg_frame(kinematics.urdf_to_motor(q), self._params))
        s_d = cartesian_to_spherical(p_d)
        J_s = spherical_jacobian(s)
        s_dot = np.linalg.solve(J_s, (J_q @ v[..., None]))[..., 0]
        s_d_dot = velocity_to_spherical(s_d, v_d)
        k_stance = np.concatenate([np.asarray(stiffness, dtype=float)[..., None],
                                   np.broadcast_to(self._stance_k_angular, s.shape[:-1] + (2,))], axis=-1)
        k = np.where(stance, k_stance, self._swing_k)
        b = np.where(stance, self._stance_b, self._swing_b)
        error = s - s_d
        error[..., 1:] = np.arctan2(np.sin(error[..., 1:]), np.cos(error[..., 1:]))
        J_sT = np.swapaxes(J_s, -1, -2)
        f_leg = (J_sT @ f_ref[..., None])[..., 0] - k * error - b * (s_dot - s_d_dot)
        f_L = np.linalg.solve(J_sT, f_leg[..., None])
        return (np.swapaxes(J_q, -1, -2) @ f_L)[..., 0]

    def _calc_torque(self, context, output: BasicVector):
        x = self._state.Eval(context)
        q, v = x[JOINT_Q].reshape(6, 3), x[JOINT_V].reshape(6, 3)
        p_d = self._p_d.Eval(context).reshape(6, 3)
        v_d = self._v_d.Eval(context).reshape(6, 3)
        f_ref = self._f_ref.Eval(context).reshape(6, 3)
        stiffness = self._stiffness.Eval(context)
        mode = self._mode.Eval(context)
        tau = self.leg_torques(q, v, p_d, v_d, f_ref, stiffness, mode >= 0.5).reshape(-1)
        output.SetFromVector(np.clip(tau, -self._params.effort_limit, self._params.effort_limit))
