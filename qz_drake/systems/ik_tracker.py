"""Trajectory tracking by inverse kinematics (paper 000, section II-B).

A body-and-feet trajectory (the BLC's solution, or any object with the same sampling methods)
becomes joint references: at time t each foot's planned world position is expressed in the
planned body frame and solved by leg IK in the topology's bend direction,
q_des = Invk(p_i, r, theta); the joint rate is the difference quotient of Eq. 7,
v_des = (q(t + dt) - q(t)) / dt. The stance feet's planned ground reaction forces are passed
on as feedforward, so that JointPdController (Eq. 7 with gravity and Coriolis compensation)
only corrects errors. The position-command output carries q_des for a station in position
mode (as the paper drives the real robot).
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RollPitchYaw
from pydrake.systems.framework import BasicVector, LeafSystem

from qz_drake.robot import kinematics
from qz_drake.robot.params import DEFAULT_PARAMS, NUM_JOINTS, NUM_LEGS, QingzhuiParams
from qz_drake.robot.topology import Topology


class BodyFeetTrajectory(Protocol):
    """What the tracker needs of a plan; times are simulation times. [s]"""

    start_time: float
    end_time: float

    def base_position(self, t: float) -> np.ndarray: ...  # (3,) world [m]

    def base_rpy(self, t: float) -> np.ndarray: ...  # (3,) roll, pitch, yaw [rad]

    def foot_positions(self, t: float) -> np.ndarray: ...  # (6, 3) foot-sphere centres, world [m]

    def foot_forces(self, t: float) -> np.ndarray: ...  # (6, 3) ground reaction forces, world [N]

    def contact(self, t: float) -> np.ndarray: ...  # (6,) bool

    # Optional: when the stance of `leg` in force at t began (None if it swings); enables
    # the rolling compensation of joint_reference.
    # def stance_start(self, leg: int, t: float) -> float | None: ...


def _rotation_vectors(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) of rotation matrices (..., 3, 3) (angles below pi)."""
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos)
    vee = 0.5 * np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    scale = np.where(angle > 1e-8, angle / np.maximum(np.sin(angle), 1e-12), 1.0)
    return vee * scale[..., None]


def _clamp(t, low, high) -> float:
    """float(np.clip(t, low, high)) for scalars, without numpy's array machinery."""
    return float(min(max(float(t), float(low)), float(high)))


def _leg_ik(trajectory, t, topology, params):
    R_WB = RollPitchYaw(trajectory.base_rpy(t)).ToRotationMatrix().matrix()
    p_BF = (trajectory.foot_positions(t) - trajectory.base_position(t)) @ R_WB
    q, ok = kinematics.all_legs_inverse_kinematics(p_BF, topology.bends, params)
    return q, ok, R_WB, p_BF


def joint_reference(trajectory: BodyFeetTrajectory, t: float, topology: Topology,
                    params: QingzhuiParams = DEFAULT_PARAMS, *,
                    roll_compensation: bool = True,
                    cache: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """q_des (18) by leg IK at time t (clamped to the plan), and a reachability mask (6,).

    A stance foot is a sphere welded to its shank: as the shank turns, the sphere rolls and its
    centre moves by dphi x (r n) (no slip), which would carry the body ahead of the plan by a
    centimetre per step. With ``roll_compensation`` (and a plan that reports stance_start) the
    IK target of a stance foot is shifted by the roll predicted from the planned shank rotation
    since touchdown, so the rolling lands the body where it was planned. ``cache`` (a dict the
    caller keeps per plan) saves the touchdown IK between calls.
    """
    t = _clamp(t, trajectory.start_time, trajectory.end_time)
    q, ok, R_WB, p_BF = _leg_ik(trajectory, t, topology, params)
    if roll_compensation and hasattr(trajectory, "stance_start"):
        legs, R_BS_td, R_WB_td = [], [], []
        for i in range(NUM_LEGS):
            td = trajectory.stance_start(i, t)
            if td is None or td >= t or not ok[i]:
                continue
            key = (id(trajectory), td)
            if cache is not None and key in cache:
                q_at, ok_at, R_at, shanks_at = cache[key]
            else:
                q_at, ok_at, R_at, _ = _leg_ik(trajectory, td, topology, params)
                shanks_at = {}  # leg -> its shank's orientation at touchdown, filled as asked
                if cache is not None:
                    cache[key] = (q_at, ok_at, R_at, shanks_at)
            if ok_at[i]:
                legs.append(i)
                if i not in shanks_at:
                    shanks_at[i] = kinematics.shank_rotation(i, q_at[i], params)
                R_BS_td.append(shanks_at[i])
                R_WB_td.append(R_at)
        if legs:
            legs = np.array(legs)
            R_BS_now = kinematics.all_shank_rotations(q.reshape(-1), params)[legs]
            R_BS_td = np.stack(R_BS_td)
            R_rel = (R_WB @ R_BS_now) @ np.swapaxes(np.stack(R_WB_td) @ R_BS_td, -1, -2)
            dphi = _rotation_vectors(R_rel)
            shift_W = np.cross(dphi, [0.0, 0.0, params.foot_radius])
            targets = p_BF.copy()
            targets[legs] += shift_W @ R_WB  # R_WB^T shift, row-wise
            q_shifted, ok_shifted = kinematics.all_legs_inverse_kinematics(targets, topology.bends, params)
            q = np.where(ok_shifted[:, None], q_shifted, q)
    return q.reshape(-1), ok


# The most updates the tracker solves at once when a plan arrives (10 s at 200 Hz, ~0.1 s).
SOLVE_AHEAD = 2000


def joint_references(trajectory: BodyFeetTrajectory, times, topology: Topology,
                     params: QingzhuiParams = DEFAULT_PARAMS, *,
                     roll_compensation: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """:func:`joint_reference` at many times at once: q_des (n, 18) and the reachability masks
    (n, 6). The plan is read time by time as there; the leg IK, the touchdown IK and the
    rolling compensation run once over all the times (the tracker solves a mission's
    references this way when the plan arrives: 0.5 ms of numpy per reference, one by one)."""
    times = np.asarray(times, dtype=float).reshape(-1)
    n = times.size
    if not n:
        return np.zeros((0, 3 * NUM_LEGS)), np.zeros((0, NUM_LEGS), bool)
    ts = [_clamp(t, trajectory.start_time, trajectory.end_time) for t in times]
    q, ok, R_WB, p_BF = _leg_ik_many(trajectory, ts, topology, params)
    if roll_compensation and hasattr(trajectory, "stance_start"):
        # (time, leg) pairs of stance feet past their touchdown, and each touchdown's IK once.
        pairs, touchdowns = [], {}
        for k, t in enumerate(ts):
            for i in range(NUM_LEGS):
                td = trajectory.stance_start(i, t)
                if td is None or td >= t or not ok[k, i]:
                    continue
                pairs.append((k, i, touchdowns.setdefault(td, len(touchdowns))))
        if pairs:
            q_td, ok_td, R_td, _ = _leg_ik_many(trajectory, list(touchdowns), topology, params)
            pairs = np.array(pairs)
            pairs = pairs[ok_td[pairs[:, 2], pairs[:, 1]]]
        if len(pairs):
            k, i, d = pairs[:, 0], pairs[:, 1], pairs[:, 2]
            R_BS_now = kinematics.all_shank_rotations(q.reshape(n, -1), params)[k, i]
            R_BS_td = kinematics.all_shank_rotations(q_td.reshape(len(R_td), -1), params)[d, i]
            R_rel = (R_WB[k] @ R_BS_now) @ np.swapaxes(R_td[d] @ R_BS_td, -1, -2)
            dphi = _rotation_vectors(R_rel)
            shift_W = np.cross(dphi, [0.0, 0.0, params.foot_radius])
            targets = p_BF.copy()
            # R_WB^T shift, row-wise, one time's legs at a time: the (legs, 3) @ (3, 3) product
            # joint_reference takes (einsum over all pairs rounds differently in the last bit).
            bounds = np.flatnonzero(np.diff(k)) + 1
            for rows in np.split(np.arange(len(k)), bounds):
                targets[k[rows[0]], i[rows]] += shift_W[rows] @ R_WB[k[rows[0]]]
            shifted = np.unique(k)
            q_s, ok_s = kinematics.all_legs_inverse_kinematics(targets[shifted], topology.bends, params)
            q[shifted] = np.where(ok_s[..., None], q_s, q[shifted])
    return q.reshape(n, -1), ok


def _leg_ik_many(trajectory, times, topology, params):
    """_leg_ik at several times (the plan read time by time, the IK once over all of them):
    q (n, 6, 3), ok (n, 6), R_WB (n, 3, 3), p_BF (n, 6, 3)."""
    R_WB = np.stack([RollPitchYaw(trajectory.base_rpy(t)).ToRotationMatrix().matrix() for t in times])
    if hasattr(trajectory, "foot_positions_many"):  # a plan that reads many times at once (the same numbers)
        feet, base = trajectory.foot_positions_many(times), trajectory.base_positions_many(times)
        p_BF = np.stack([(feet[k] - base[k]) @ R for k, R in enumerate(R_WB)])
    else:
        p_BF = np.stack([(trajectory.foot_positions(t) - trajectory.base_position(t)) @ R
                         for t, R in zip(times, R_WB)])
    q, ok = kinematics.all_legs_inverse_kinematics(p_BF, topology.bends, params)
    return q, ok, R_WB, p_BF


class InverseKinematicsTracker(LeafSystem):
    """Joint references and force feedforward from a body-and-feet trajectory.

    .. pydrake_system::

        name: InverseKinematicsTracker
        input_ports:
        - trajectory
        output_ports:
        - desired_state
        - foot_force_feedforward
        - position_command
        - velocity_command
        - contact_plan

    ``trajectory`` is an abstract input holding a BodyFeetTrajectory (or None: keep the
    references held so far; a planner must provide a plan at initialization). ``desired_state`` is q_des (18) then v_des (18) for JointPdController;
    ``foot_force_feedforward`` the planned stance forces (18, world); ``position_command``
    q_des alone and ``velocity_command`` v_des alone (the station's position-mode inputs);
    ``contact_plan`` the planned contact flags (6).

    The references are updated at ``rate`` (the paper's controllers exchange them at 200 Hz)
    and held in between; the joint PD runs at every plant step.

    A reference is a function of the plan and the time only, so when a plan arrives the
    references of all its updates are solved at once (:func:`joint_references`, the numbers
    of solving them one by one: 12x less time for a mission's 600), and an update reads its
    own: the leg IK leaves the control path except at a plan's first update. Plans that change
    topology or joints along the way (``topology_at``, ``joint_override``) are solved update by
    update.

    Args:
        topology: the body topology (knee bend per leg) the IK uses.
        params: robot parameters.
        rate: reference update rate. [Hz]
    """

    def __init__(self, *, topology: Topology, params: QingzhuiParams = DEFAULT_PARAMS,
                 rate: float = 200.0):
        super().__init__()
        self._topology = topology
        self._params = params
        # The Delta T of Eq. 7: one update period.
        self._dt = 1.0 / rate
        # Touchdown IK per (plan, touchdown time), for the rolling compensation.
        self._touchdown_cache: dict = {}
        # The reference at t + dt of the last update (plan, time, q): the next update's q(t).
        # Eq. 7's difference quotient needs q at t and t + dt; updates come every dt, so each
        # IK is solved once instead of twice (measured: half of a trial's simulation time).
        self._ahead: tuple | None = None
        # A plan's references solved at once when it arrives: (plan, {time: q}).
        self._solved: tuple | None = None
        self._trajectory = self.DeclareAbstractInputPort("trajectory", AbstractValue.Make(object()))
        # Held references: q_des (18), v_des (18), forces (18), contact (6).
        self._held = self.DeclareDiscreteState(2 * NUM_JOINTS + 3 * NUM_LEGS + NUM_LEGS)
        self.DeclarePeriodicDiscreteUpdateEvent(self._dt, 0.0, self._update)
        self.DeclareInitializationDiscreteUpdateEvent(self._update)
        n = NUM_JOINTS
        # The outputs read the held references only: recomputed when they change, not at every
        # plant step.
        held = {self.discrete_state_ticket(self._held)}
        self.DeclareVectorOutputPort("desired_state", 2 * n, self._output(0, 2 * n), held)
        self.DeclareVectorOutputPort("foot_force_feedforward", 3 * NUM_LEGS, self._output(2 * n, 3 * n), held)
        self.DeclareVectorOutputPort("position_command", n, self._output(0, n), held)
        self.DeclareVectorOutputPort("velocity_command", n, self._output(n, 2 * n), held)
        self.DeclareVectorOutputPort("contact_plan", NUM_LEGS, self._output(3 * n, 3 * n + NUM_LEGS), held)

    @property
    def update_period(self) -> float:
        """The references' update period (1 / rate). [s]"""
        return self._dt

    def _output(self, start: int, stop: int):
        def calc(context, output: BasicVector):
            output.SetFromVector(context.get_discrete_state(self._held).get_value()[start:stop])
        return calc

    def _reference(self, plan, t: float) -> np.ndarray:
        # A plan may carry its own topology (missions can change it), per leg and time while
        # the robot switches topology (topology_at), and joint-space references for legs it
        # moves in joint space (joint_override, NaN elsewhere); else the tracker's topology.
        tc = _clamp(t, plan.start_time, plan.end_time)
        if hasattr(plan, "topology_at"):
            topology = plan.topology_at(tc)
        else:
            topology = getattr(plan, "topology", None) or self._topology
        q, _ = joint_reference(plan, t, topology, self._params, cache=self._touchdown_cache)
        if hasattr(plan, "joint_override"):
            override = plan.joint_override(tc)
            q = np.where(np.isnan(override), q, override)
        return q

    def _solve_plan(self, plan, t: float) -> None:
        """Every reference the updates from t to the plan's end will ask for, at once: q(t)
        and q(t_k + dt) for the update times t_k = k dt (Drake's periodic event times), the
        very floats the updates compute."""
        self._solved = None
        if hasattr(plan, "topology_at") or hasattr(plan, "joint_override"):
            return
        k = round(t / self._dt)
        left = (plan.end_time - t) / self._dt
        # At most SOLVE_AHEAD updates at a time (a long plan is solved a window at a time).
        count = (SOLVE_AHEAD if not math.isfinite(left) else min(SOLVE_AHEAD, max(0, math.ceil(left)))) + 2
        times = [t] + [(k + j) * self._dt + self._dt for j in range(count)]
        topology = getattr(plan, "topology", None) or self._topology
        q, _ = joint_references(plan, times, topology, self._params)
        self._solved = (plan, dict(zip(times, q)))

    def _reference_at(self, plan, t: float) -> np.ndarray:
        solved = self._solved
        if solved is not None and solved[0] is plan:
            q = solved[1].get(t)
            if q is not None:
                return q
        return self._reference(plan, t)

    def _update(self, context, discrete_state):
        plan: BodyFeetTrajectory = self._trajectory.Eval(context)
        if plan is None:  # no plan yet (a planner still failing): keep the held references
            return
        t = context.get_time()
        if len(self._touchdown_cache) > 64:
            self._touchdown_cache.clear()
        solved = self._solved
        if (solved is None or solved[0] is not plan
                or (t + self._dt not in solved[1] and t < plan.end_time)):  # a new plan or window
            self._solve_plan(plan, t)
        ahead = self._ahead
        if ahead is not None and ahead[0] is plan and abs(ahead[1] - t) <= 1e-9:
            q0 = ahead[2]
        else:
            q0 = self._reference_at(plan, t)
        q1 = self._reference_at(plan, t + self._dt)
        self._ahead = (plan, t + self._dt, q1)
        v = (q1 - q0) / self._dt if t + self._dt <= plan.end_time else np.zeros(NUM_JOINTS)
        tc = _clamp(t, plan.start_time, plan.end_time)
        contact = plan.contact(tc)
        forces = np.where(contact[:, None], plan.foot_forces(tc), 0.0)
        discrete_state.set_value(self._held, np.concatenate([q0, v, forces.reshape(-1), contact.astype(float)]))
