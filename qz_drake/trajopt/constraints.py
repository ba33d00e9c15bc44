"""Constraints of the BLC (paper 000 Eq. 1-5), vectorised over their sample times, each with an
analytic sparse Jacobian (TOWR's ``TimeDiscretizationConstraint`` pattern).

Each quantity a constraint reads (body angles and their rates, CoM, foot positions, forces) is a
spline sampled as ``LinearSamples``, i.e. ``q[k, d] = sum_j W[k, j, d] x[I[k, j, d]]``. A
constraint computes its values g and the partials ``dg/dq``; the chain rule through the constant
weights W gives the Jacobian entries in a fixed sparsity pattern (built once, from W's structural
zeros), so the solver gets an exact sparse Jacobian without AutoDiff.

Units: forces in body weights (f / (m g)); the dynamics residuals are divided by m g, so they are
in body weights (linear) and metres (angular); kinematics and terrain residuals are in metres.

Linear parts are not here: the linear-momentum half of Eq. 2 (``linear_dynamics_matrix``) and
the body-acceleration continuity are sparse linear equalities, which Drake hands to Ipopt
without evaluating Python.
"""

from __future__ import annotations

import abc
import copy

import numpy as np
import scipy.sparse as sp

from qz_drake.trajopt.splines import LinearSamples

INF = np.inf


# -- rotations -------------------------------------------------------------------------------
def rotation_from_rpy(rpy) -> np.ndarray:
    """R_WB (n, 3, 3) of roll-pitch-yaw angles (n, 3), R = Rz(yaw) Ry(pitch) Rx(roll) as in
    Drake's RollPitchYaw. Works on float and AutoDiffXd object arrays."""
    r, p, y = rpy[:, 0], rpy[:, 1], rpy[:, 2]
    cr, sr, cp, sp_, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    rows = [
        [cy * cp, cy * sp_ * sr - sy * cr, cy * sp_ * cr + sy * sr],
        [sy * cp, sy * sp_ * sr + cy * cr, sy * sp_ * cr - cy * sr],
        [-sp_, cp * sr, cp * cr],
    ]
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def rotation_derivatives(rpy: np.ndarray) -> np.ndarray:
    """dR/d(roll, pitch, yaw), (n, 3, 3, 3) with the angle last."""
    R = rotation_from_rpy(rpy)
    r, p, y = rpy[:, 0], rpy[:, 1], rpy[:, 2]
    n = len(rpy)
    ex, ey, ez = skew(np.eye(3))
    # dR/droll = R [ex]x ; dR/dpitch = Rz Ry [ey]x Rx ; dR/dyaw = [ez]x R.
    d_roll = R @ ex
    Rz = np.zeros((n, 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = (
        np.cos(y), -np.sin(y), np.sin(y), np.cos(y), 1.0)
    Rx = np.zeros((n, 3, 3))
    Rx[:, 0, 0], Rx[:, 1, 1], Rx[:, 1, 2], Rx[:, 2, 1], Rx[:, 2, 2] = (
        1.0, np.cos(r), -np.sin(r), np.sin(r), np.cos(r))
    Ry = np.zeros((n, 3, 3))
    Ry[:, 0, 0], Ry[:, 0, 2], Ry[:, 1, 1], Ry[:, 2, 0], Ry[:, 2, 2] = (
        np.cos(p), np.sin(p), 1.0, -np.sin(p), np.cos(p))
    d_pitch = Rz @ Ry @ ey @ Rx
    d_yaw = ez @ R
    return np.stack([d_roll, d_pitch, d_yaw], axis=-1)


def skew(v) -> np.ndarray:
    """[v]x, (..., 3, 3), with [v]x w = v x w."""
    v = np.asarray(v)
    z = np.zeros(v.shape[:-1], dtype=v.dtype)
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1),
                     np.stack([-y, x, z], -1)], -2)


def euler_rate_matrix(rpy) -> tuple:
    """E with omega_B = E(roll, pitch) d(rpy)/dt, and its partials E_r, E_p, E_rr, E_rp, E_pp,
    each (n, 3, 3). Works on float arrays (the partials) and object arrays (E alone)."""
    r, p = rpy[:, 0], rpy[:, 1]
    cr, sr, cp, sp_ = np.cos(r), np.sin(r), np.cos(p), np.sin(p)
    zero, one = 0 * cr, 0 * cr + 1

    def mat(rows):
        return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)

    E = mat([[one, zero, -sp_], [zero, cr, sr * cp], [zero, -sr, cr * cp]])
    if rpy.dtype == object:
        return (E,)
    E_r = mat([[zero, zero, zero], [zero, -sr, cr * cp], [zero, -cr, -sr * cp]])
    E_p = mat([[zero, zero, -cp], [zero, zero, -sr * sp_], [zero, zero, -cr * sp_]])
    E_rr = mat([[zero, zero, zero], [zero, -cr, -sr * cp], [zero, sr, -cr * cp]])
    E_rp = mat([[zero, zero, zero], [zero, zero, -cr * sp_], [zero, zero, sr * sp_]])
    E_pp = mat([[zero, zero, sp_], [zero, zero, -sr * cp], [zero, zero, -cr * cp]])
    return E, E_r, E_p, E_rr, E_rp, E_pp


def _matvec(M, v):
    """Batched M @ v for (..., 3, 3) and (..., 3), object-array friendly."""
    return (M * v[..., None, :]).sum(axis=-1)


def _mat_t_vec(M, v):
    """Batched M^T @ v."""
    return (M * v[..., :, None]).sum(axis=-2)


# -- the common machinery --------------------------------------------------------------------
class _Block:
    """Rows (M, A) of a constraint that depend on one sampled quantity (M, K, D)."""

    def __init__(self, rows: np.ndarray, samples: LinearSamples):
        W, I = samples.weights, samples.index
        M, A = rows.shape
        K, D = W.shape[1], W.shape[2]
        self.weights = W
        shape = (M, A, K, D)
        mask = np.broadcast_to((W != 0)[:, None, :, :], shape)
        self.select = np.flatnonzero(mask)
        self.rows = np.broadcast_to(rows[:, :, None, None], shape).ravel()[self.select]
        self.cols = np.broadcast_to(I[:, None, :, :], shape).ravel()[self.select]

    def values(self, partials: np.ndarray) -> np.ndarray:
        """Jacobian entries from dg/dq (M, A, D)."""
        return (partials[:, :, None, :] * self.weights[:, None, :, :]).ravel()[self.select]


class SampledConstraint(abc.ABC):
    """lower <= g(x) <= upper, g vectorised over samples, with a fixed sparse Jacobian pattern.

    Subclasses set ``name``, ``lower``, ``upper``, call ``_set_blocks`` and implement
    ``_compute(x, with_partials) -> (g, [dg/dq per block] or None)``.
    """

    name = "constraint"
    # Rows per sample: Drake bindings take whole samples.
    rows_per_sample = 1
    # Explicit row ranges for Drake bindings (e.g. one per leg); None: chunks of samples.
    segments: list[tuple[int, int]] | None = None

    def binding_ranges(self, samples_per_binding: int) -> list[tuple[int, int]]:
        """Row ranges [start, stop) of the Drake bindings this constraint is split into."""
        if self.segments is not None:
            return list(self.segments)
        step = max(1, int(samples_per_binding)) * self.rows_per_sample
        m = self.num_constraints
        return [(a, min(a + step, m)) for a in range(0, m, step)]

    def _set_blocks(self, blocks: list[_Block]) -> None:
        self._blocks = blocks
        self.rows = np.concatenate([b.rows for b in blocks])
        self.cols = np.concatenate([b.cols for b in blocks])
        # (start, stop) -> the Drake binding's columns and sparsity, and the rows' order by row
        # (formulation.add_constraint_rows), shared by the copies ``on`` makes: they have the
        # same rows and columns.
        self.binding_structure: dict = {}

    def on(self, **data) -> "SampledConstraint":
        """This constraint for other data (e.g. ``terrain=``, ``field=``): a shallow copy that
        shares its samples, bounds and Jacobian pattern, which depend on the contact schedule
        only (formulation.py builds them once per schedule). Names that are not attributes of
        the constraint raise AttributeError."""
        for name in data:
            if name not in self.__dict__:
                raise AttributeError(f"{type(self).__name__} has no data {name!r}")
        if all(self.__dict__[name] is value for name, value in data.items()):
            return self
        clone = copy.copy(self)
        clone.__dict__.update(data)
        return clone

    @property
    def num_constraints(self) -> int:
        return len(self.lower)

    @abc.abstractmethod
    def _compute(self, x, with_partials: bool):
        """(g, [dg/dq per block] or None)."""

    def evaluate(self, x) -> np.ndarray:
        """g(x), (m,). x is the full decision vector (floats, or AutoDiffXd where supported)."""
        return self._compute(x, False)[0]

    def evaluate_with_jacobian(self, x) -> tuple[np.ndarray, np.ndarray]:
        """g(x) and the Jacobian entries at (self.rows, self.cols) (duplicates add up)."""
        g, partials = self._compute(x, True)
        return g, np.concatenate([b.values(p) for b, p in zip(self._blocks, partials)])

    def jacobian(self, x, num_vars: int) -> sp.csr_matrix:
        _, values = self.evaluate_with_jacobian(x)
        return sp.csr_matrix((values, (self.rows, self.cols)), shape=(self.num_constraints, num_vars))

    def violation(self, x) -> np.ndarray:
        """Per-row amount by which g(x) leaves [lower, upper] (0 inside)."""
        g = self.evaluate(x)
        return np.maximum(0.0, np.maximum(self.lower - g, g - self.upper))


def _stack_legs(samples: list[LinearSamples]) -> LinearSamples:
    return LinearSamples.concatenate(samples)


# -- Eq. 2, angular part ---------------------------------------------------------------------
class AngularDynamicsConstraint(SampledConstraint):
    """Euler's equation of the single rigid body in the body frame, divided by m g:

        (I w' + w x I w) / (m g) - R^T sum_i (p_i - r) x f_i / (m g) = 0,

    with w = E(rpy) rpy' the body angular velocity and w' = E rpy'' + E' rpy'. Forces are
    variables in body weights, so the last term is R^T sum_i (p_i - r) x F_i.
    """

    name = "dynamics"
    rows_per_sample = 3

    def __init__(self, variables, times, inertia_over_weight: np.ndarray, scales=None):
        """``scales``: per sample, the index of its phase's time scale rho (free phase
        durations, timing.py; times are then nominal and rates are divided by rho)."""
        v = variables
        self.times = t = np.atleast_1d(np.asarray(times, dtype=float))
        n, L = len(t), v.num_legs
        self.scales = None if scales is None else _scale_samples(scales)
        self.inertia = np.asarray(inertia_over_weight, dtype=float)
        self.lower = np.zeros(3 * n)
        self.upper = np.zeros(3 * n)
        self.rpy = [v.base_rpy.sample(t, order) for order in (0, 1, 2)]
        self.com = v.base_position.sample(t, 0)
        feet, forces = [], []
        for leg in range(L):
            f = v.foot_force[leg].sample(t, 0)
            active = np.any(f.weights != 0, axis=(1, 2))
            p = v.foot_position[leg].sample(t, 0)
            p.weights = p.weights * active[:, None, None]  # no force: the foot drops out
            feet.append(p)
            forces.append(f)
        self.num_legs = L
        self.feet = _stack_legs(feet)
        self.forces = _stack_legs(forces)
        rows = np.arange(3 * n).reshape(n, 3)
        leg_rows = np.tile(rows, (L, 1))
        blocks = [_Block(rows, self.rpy[0]), _Block(rows, self.rpy[1]),
                  _Block(rows, self.rpy[2]), _Block(rows, self.com),
                  _Block(leg_rows, self.feet), _Block(leg_rows, self.forces)]
        if self.scales is not None:
            blocks.append(_Block(rows, self.scales))
        self._set_blocks(blocks)

    def _compute(self, x, with_partials):
        n, L = len(self.times), self.num_legs
        rpy, rate, acc = (s.value(x) for s in self.rpy)
        if self.scales is not None:
            rho = self.scales.value(x)  # (n, 1)
            rate, acc = rate / rho, acc / (rho * rho)
        r = self.com.value(x)
        p = self.feet.value(x).reshape(L, n, 3)
        F = self.forces.value(x).reshape(L, n, 3)
        I = self.inertia
        R = rotation_from_rpy(rpy)
        if rpy.dtype == object:  # AutoDiff (tests): E' from its closed form
            E = euler_rate_matrix(rpy)[0]
            cr, sr = np.cos(rpy[:, 0]), np.sin(rpy[:, 0])
            cp, sp_ = np.cos(rpy[:, 1]), np.sin(rpy[:, 1])
            dr, dp = rate[:, 0], rate[:, 1]
            zero = 0 * cr
            E_dot = np.stack([
                np.stack([zero, zero, -cp * dp], -1),
                np.stack([zero, -sr * dr, cr * cp * dr - sr * sp_ * dp], -1),
                np.stack([zero, -cr * dr, -sr * cp * dr - cr * sp_ * dp], -1)], -2)
        else:
            E, E_r, E_p, E_rr, E_rp, E_pp = euler_rate_matrix(rpy)
            E_dot = E_r * rate[:, 0, None, None] + E_p * rate[:, 1, None, None]
        w = _matvec(E, rate)
        lever = p - r[None]
        torque = np.cross(lever, F).sum(axis=0)  # (n, 3), world frame
        w_dot = _matvec(E, acc) + _matvec(E_dot, rate)
        Iw = _matvec(I[None], w)
        Iw_dot = _matvec(I[None], w_dot)
        g = Iw_dot + np.cross(w, Iw) - _mat_t_vec(R, torque)
        g = g.reshape(-1)
        if not with_partials:
            return g, None
        # d/d acc
        IE = I[None] @ E
        d_acc = IE
        # d/d rate: I (E_dot + [E_r rate, E_p rate, 0]) + ([w]x I - [I w]x) E
        C = skew(w) @ I[None] - skew(Iw)
        extra = np.zeros((n, 3, 3))
        extra[:, :, 0] = _matvec(E_r, rate)
        extra[:, :, 1] = _matvec(E_p, rate)
        d_rate = I[None] @ (E_dot + extra) + C @ E
        # d/d rpy
        dR = rotation_derivatives(rpy)
        d_rpy = np.zeros((n, 3, 3))
        for j, (E_j, E_jr, E_jp) in enumerate(((E_r, E_rr, E_rp), (E_p, E_rp, E_pp))):
            dw_dot = _matvec(E_j, acc) + _matvec(E_jr * rate[:, 0, None, None]
                                                 + E_jp * rate[:, 1, None, None], rate)
            dw = _matvec(E_j, rate)
            d_rpy[:, :, j] = _matvec(np.broadcast_to(I, (n, 3, 3)), dw_dot) + _matvec(C, dw)
        for j in range(3):
            d_rpy[:, :, j] -= _mat_t_vec(dR[..., j], torque)
        # d/d r, p_i, F_i
        Rt = np.swapaxes(R, 1, 2)
        skew_F = skew(F)  # (L, n, 3, 3)
        d_com = -Rt @ skew_F.sum(axis=0)
        d_feet = (Rt[None] @ skew_F).reshape(L * n, 3, 3)
        d_forces = -(Rt[None] @ skew(lever)).reshape(L * n, 3, 3)
        if self.scales is None:
            return g, [d_rpy, d_rate, d_acc, d_com, d_feet, d_forces]
        # Rates and accelerations in real time are rate / rho and acc / rho^2 of the sampled
        # (nominal-time) ones: chain rule through both, and their derivative in rho.
        d_rho = -(_matvec(d_rate, rate) + 2.0 * _matvec(d_acc, acc)) / rho
        return g, [d_rpy, d_rate / rho[:, :, None], d_acc / (rho * rho)[:, :, None], d_com,
                   d_feet, d_forces, d_rho[:, :, None]]


def _scale_samples(scale_index) -> LinearSamples:
    """The time scale rho of each sample as LinearSamples (n, 1, 1)."""
    idx = np.asarray(scale_index, dtype=np.int64).reshape(-1, 1, 1)
    return LinearSamples(np.ones(idx.shape), idx)


class ScaledLinearDynamicsConstraint(SampledConstraint):
    """The linear-momentum half of Eq. 2 with free phase durations (timing.py), divided by
    m g: r''_tau / (g rho^2) - sum_i F_i + e_z = 0 at nominal sample times, rho the scale of the
    sample's phase. (With fixed durations it is the linear equality of
    ``linear_dynamics_matrix``.)"""

    name = "dynamics/linear"
    rows_per_sample = 3

    def __init__(self, variables, times, gravity: float, scales):
        v = variables
        self.times = t = np.atleast_1d(np.asarray(times, dtype=float))
        n, L = len(t), v.num_legs
        self.gravity = float(gravity)
        self.num_legs = L
        self.lower = np.zeros(3 * n)
        self.upper = np.zeros(3 * n)
        self.acc = v.base_position.sample(t, 2)
        self.forces = _stack_legs([v.foot_force[leg].sample(t, 0) for leg in range(L)])
        self.scales = _scale_samples(scales)
        rows = np.arange(3 * n).reshape(n, 3)
        self._set_blocks([_Block(rows, self.acc), _Block(np.tile(rows, (L, 1)), self.forces),
                          _Block(rows, self.scales)])

    def _compute(self, x, with_partials):
        n, L = len(self.times), self.num_legs
        acc = self.acc.value(x)
        F = self.forces.value(x).reshape(L, n, 3)
        rho = self.scales.value(x)  # (n, 1)
        scale = 1.0 / (self.gravity * rho * rho)
        g = acc * scale - F.sum(axis=0) + np.array([0.0, 0.0, 1.0])
        g = g.reshape(-1)
        if not with_partials:
            return g, None
        eye = np.eye(3)
        d_acc = eye[None] * scale[:, :, None]
        d_forces = -np.broadcast_to(eye, (L * n, 3, 3))
        d_rho = (-2.0 * acc * scale / rho)[:, :, None]
        return g, [d_acc, d_forces, d_rho]


class PhaseContinuityConstraint(SampledConstraint):
    """The body's velocity (order 1) or acceleration (order 2) continuous across the global
    phase boundaries of free phase durations (timing.py): there the body node has a rate per
    side, each in its own phase's nominal time, so
    (q_left / rho_left^k - q_right / rho_right^k) h^k = 0, h the body node spacing (rows O(1)
    in the node values, as ``acceleration_continuity_matrix``'s)."""

    rows_per_sample = 3

    def __init__(self, spline, times, order: int, left_scales, right_scales, spacing: float,
                 name: str):
        self.name = name
        self.times = t = np.atleast_1d(np.asarray(times, dtype=float))
        n = len(t)
        self.order = int(order)
        self.h = float(spacing) ** self.order
        self.lower = np.zeros(3 * n)
        self.upper = np.zeros(3 * n)
        self.left = spline.sample(t, self.order, side="left")
        self.right = spline.sample(t, self.order, side="right")
        self.rho_left = _scale_samples(left_scales)
        self.rho_right = _scale_samples(right_scales)
        rows = np.arange(3 * n).reshape(n, 3)
        self._set_blocks([_Block(rows, self.left), _Block(rows, self.right),
                          _Block(rows, self.rho_left), _Block(rows, self.rho_right)])

    def _compute(self, x, with_partials):
        k, h = self.order, self.h
        ql, qr = self.left.value(x), self.right.value(x)
        rl, rr = self.rho_left.value(x), self.rho_right.value(x)
        g = (h * (ql / rl ** k - qr / rr ** k)).reshape(-1)
        if not with_partials:
            return g, None
        eye = np.eye(3)
        return g, [eye[None] * (h / rl ** k)[:, :, None], -eye[None] * (h / rr ** k)[:, :, None],
                   (-k * h * ql / rl ** (k + 1))[:, :, None],
                   (k * h * qr / rr ** (k + 1))[:, :, None]]


def linear_dynamics_matrix(variables, times, gravity: float):
    """(A, b) of the linear-momentum half of Eq. 2 divided by m g: r''/g - sum_i F_i = -e_z
    at each sample time, rows ordered (sample, axis); A is sparse over the full vector."""
    v = variables
    t = np.atleast_1d(np.asarray(times, dtype=float))
    A = v.base_position.sample(t, 2).sparse(v.num_vars) / gravity
    for leg in range(v.num_legs):
        A = A - v.foot_force[leg].sample(t, 0).sparse(v.num_vars)
    b = np.tile([0.0, 0.0, -1.0], len(t))
    return sp.csr_matrix(A), b


def acceleration_continuity_matrix(variables, times=None):
    """Sparse A with A x = 0 iff the body's linear and angular accelerations are continuous at
    every interior node (TOWR's BaseAcc constraint), or at the given node times."""
    v = variables
    t = v.base_breaks[1:-1] if times is None else np.asarray(times, dtype=float)
    if len(t) == 0:
        return None
    parts = []
    for spline in (v.base_position, v.base_rpy):
        left = spline.sample(t, 2, side="left").sparse(v.num_vars)
        right = spline.sample(t, 2, side="right").sparse(v.num_vars)
        parts.append(left - right)
    # Scaled by the node spacing squared so that the rows are O(1) in the node values.
    h = float(np.min(np.diff(v.base_breaks)))
    return sp.csr_matrix(sp.vstack(parts) * h * h)


# -- Eq. 1 -----------------------------------------------------------------------------------
class KinematicsConstraint(SampledConstraint):
    """Each foot inside its box: |R^T (p_i - r) - p_nominal_i| <= b_i, per axis (Eq. 1)."""

    name = "kinematics"

    def __init__(self, variables, times, nominal_footholds: np.ndarray, box_half_sizes: np.ndarray):
        v = variables
        self.times = t = np.atleast_1d(np.asarray(times, dtype=float))
        n, L = len(t), v.num_legs
        self.num_legs = L
        self.rows_per_sample = 3 * L
        self.nominal = np.asarray(nominal_footholds, dtype=float)
        box = np.asarray(box_half_sizes, dtype=float)
        self.lower = np.tile(-box.reshape(-1), n)
        self.upper = np.tile(box.reshape(-1), n)
        self.rpy = v.base_rpy.sample(t, 0)
        self.com = v.base_position.sample(t, 0)
        self.feet = _stack_legs([v.foot_position[leg].sample(t, 0) for leg in range(L)])
        rows_all = np.arange(3 * L * n).reshape(n, 3 * L)
        leg_rows = rows_all.reshape(n, L, 3).transpose(1, 0, 2).reshape(L * n, 3)
        self._set_blocks([_Block(rows_all, self.rpy), _Block(rows_all, self.com),
                          _Block(leg_rows, self.feet)])

    def _compute(self, x, with_partials):
        n, L = len(self.times), self.num_legs
        rpy = self.rpy.value(x)
        r = self.com.value(x)
        p = self.feet.value(x).reshape(L, n, 3).transpose(1, 0, 2)  # (n, L, 3)
        R = rotation_from_rpy(rpy)
        d = p - r[:, None, :]
        # q[k, l, a] = sum_b R[k, b, a] d[k, l, b]
        q = (R[:, None, :, :] * d[:, :, :, None]).sum(axis=2) - self.nominal[None]
        g = q.reshape(-1)
        if not with_partials:
            return g, None
        dR = rotation_derivatives(rpy)  # (n, 3, 3, 3)
        d_rpy = np.einsum("kbaj,klb->klaj", dR, d).reshape(n, 3 * L, 3)
        Rt = np.swapaxes(R, 1, 2)
        d_com = -np.broadcast_to(Rt[:, None], (n, L, 3, 3)).reshape(n, 3 * L, 3)
        d_feet = np.broadcast_to(Rt[None], (L, n, 3, 3)).reshape(L * n, 3, 3)
        return g, [d_rpy, d_com, d_feet]


# -- Eq. 4 -----------------------------------------------------------------------------------
class TerrainConstraint(SampledConstraint):
    """Foot height above the terrain: lower <= p_z - h(p_x, p_y) - foot_radius <= upper at the
    given foot samples (stance footholds: = 0; swing samples: >= clearance)."""

    name = "terrain"

    def __init__(self, samples: LinearSamples, terrain, foot_radius: float, lower, upper,
                 name: str = "terrain"):
        self.name = name
        self.samples = samples
        self.terrain = terrain
        self.foot_radius = float(foot_radius)
        m = samples.num_samples
        self.lower = np.broadcast_to(np.asarray(lower, dtype=float), (m,)).copy()
        self.upper = np.broadcast_to(np.asarray(upper, dtype=float), (m,)).copy()
        self.segments = [(a, min(a + 32, m)) for a in range(0, m, 32)]
        self._set_blocks([_Block(np.arange(m)[:, None], samples)])

    def _compute(self, x, with_partials):
        p = self.samples.value(x)
        h, hx, hy, *_ = self.terrain.height_derivatives(p[:, 0], p[:, 1])
        g = p[:, 2] - h - self.foot_radius
        if not with_partials:
            return g, None
        d = np.stack([-hx, -hy, np.ones_like(hx)], axis=-1)[:, None, :]
        return g, [d]


# -- Eq. 5 -----------------------------------------------------------------------------------
def terrain_frame(terrain, x, y):
    """Unit normal n and tangents t1 (along x), t2 (along y) of the terrain, (m, 3) each, and
    their derivatives with respect to x and y, (m, 3, 2) each."""
    h, hx, hy, hxx, hxy, hyy = terrain.height_derivatives(x, y)
    one, zero = np.ones_like(hx), np.zeros_like(hx)
    raw = [np.stack([-hx, -hy, one], -1), np.stack([one, zero, hx], -1),
           np.stack([zero, one, hy], -1)]
    # d raw / d(x, y)
    draw = [np.stack([np.stack([-hxx, -hxy], -1), np.stack([-hxy, -hyy], -1),
                      np.stack([zero, zero], -1)], -2),
            np.stack([np.stack([zero, zero], -1), np.stack([zero, zero], -1),
                      np.stack([hxx, hxy], -1)], -2),
            np.stack([np.stack([zero, zero], -1), np.stack([zero, zero], -1),
                      np.stack([hxy, hyy], -1)], -2)]
    units, dunits = [], []
    for u, du in zip(raw, draw):
        norm = np.linalg.norm(u, axis=-1, keepdims=True)
        e = u / norm
        de = (du - e[:, :, None] * (e[:, :, None] * du).sum(axis=1, keepdims=True)) / norm[:, :, None]
        units.append(e)
        dunits.append(de)
    return units, dunits


class ForceConstraint(SampledConstraint):
    """Stance forces (Eq. 5) in the terrain's frame at the stance foothold: f_min <= F.n <= f_max
    and |F.t1|, |F.t2| <= mu F.n (a friction pyramid), forces in body weights."""

    name = "force"

    rows_per_sample = 5

    def __init__(self, forces: LinearSamples, footholds: LinearSamples, terrain, mu: float,
                 min_force, max_force, segments=None):
        self.forces = forces
        footholds = LinearSamples(footholds.weights * np.array([1.0, 1.0, 0.0]), footholds.index)
        self.footholds = footholds
        self.terrain = terrain
        self.mu = float(mu)
        m = forces.num_samples
        lower = np.zeros((m, 5)) - INF
        upper = np.zeros((m, 5))
        lower[:, 0] = min_force
        upper[:, 0] = max_force
        if segments is not None:  # sample ranges -> row ranges
            self.segments = [(5 * a, 5 * b) for a, b in segments]
        self.lower, self.upper = lower.reshape(-1), upper.reshape(-1)
        rows = np.arange(5 * m).reshape(m, 5)
        self._set_blocks([_Block(rows, forces), _Block(rows, footholds)])

    def _compute(self, x, with_partials):
        F = self.forces.value(x)
        p = self.footholds.value(x)
        (n, t1, t2), (dn, dt1, dt2) = terrain_frame(self.terrain, p[:, 0], p[:, 1])
        mu = self.mu
        dirs = np.stack([n, t1 - mu * n, -t1 - mu * n, t2 - mu * n, -t2 - mu * n], axis=1)
        g = (dirs * F[:, None, :]).sum(-1).reshape(-1)
        if not with_partials:
            return g, None
        ddirs = np.stack([dn, dt1 - mu * dn, -dt1 - mu * dn, dt2 - mu * dn, -dt2 - mu * dn],
                         axis=1)  # (m, 5, 3, 2)
        d_p = np.zeros((len(F), 5, 3))
        d_p[:, :, :2] = (ddirs * F[:, None, :, None]).sum(axis=2)
        return g, [dirs, d_p]
