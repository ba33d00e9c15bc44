"""Cubic Hermite splines that are linear in the decision variables (TOWR's SplineHolder).

Every trajectory of the BLC (body position and Euler angles, each foot's position and force) is a
cubic Hermite spline whose node values and node derivatives are fixed linear combinations of
decision variables (usually one variable with coefficient 1; a swing foot's mid node in x, y is
the mean of its two footholds; a force node next to a swing is zero). Sampling a spline at many
times is therefore a sparse linear map from the decision vector, built once from the times and
evaluated with one vectorised gather: ``y[k, d] = sum_j weights[k, j, d] * x[index[k, j, d]]``.
Its derivative with respect to ``x[index[k, j, d]]`` is ``weights[k, j, d]``, which is what every
constraint's analytic Jacobian is built from.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp


def hermite_basis(tau: np.ndarray, order: int = 0) -> np.ndarray:
    """The four cubic Hermite basis functions (h00, h10, h01, h11) at tau in [0, 1], or their
    ``order``-th derivative with respect to tau; shape (n, 4)."""
    t = np.asarray(tau, dtype=float)
    t2, t3 = t * t, t * t * t
    if order == 0:
        cols = (2 * t3 - 3 * t2 + 1, t3 - 2 * t2 + t, -2 * t3 + 3 * t2, t3 - t2)
    elif order == 1:
        cols = (6 * t2 - 6 * t, 3 * t2 - 4 * t + 1, -6 * t2 + 6 * t, 3 * t2 - 2 * t)
    elif order == 2:
        cols = (12 * t - 6, 6 * t - 4, -12 * t + 6, 6 * t - 2)
    else:
        raise ValueError(f"order {order} not supported")
    return np.stack(np.broadcast_arrays(*cols), axis=-1)


@dataclasses.dataclass
class LinearSamples:
    """Samples of a trajectory that is linear in the decision vector x.

    ``value(x)[k, d] = sum_j weights[k, j, d] * x[index[k, j, d]]``; entries with a zero weight
    are structural zeros (their index is arbitrary but valid).
    """

    weights: np.ndarray  # (n, K, D)
    index: np.ndarray  # (n, K, D) int

    @property
    def num_samples(self) -> int:
        return self.weights.shape[0]

    def value(self, x) -> np.ndarray:
        """(n, D); x may be a float or an AutoDiffXd object array."""
        return (self.weights * np.asarray(x)[self.index]).sum(axis=1)

    def sparse(self, num_vars: int) -> sp.csr_matrix:
        """The map as a sparse ((n * D), num_vars) matrix, rows ordered (k, d)."""
        n, K, D = self.weights.shape
        rows = np.broadcast_to((np.arange(n)[:, None] * D + np.arange(D)[None, :])[:, None, :],
                               (n, K, D))
        mask = self.weights != 0
        return sp.csr_matrix((self.weights[mask], (rows[mask], self.index[mask])),
                             shape=(n * D, num_vars))

    def take(self, rows) -> "LinearSamples":
        return LinearSamples(self.weights[rows], self.index[rows])

    def compact(self) -> "LinearSamples":
        """Drops the j columns that are zero for every sample (cheaper gathers)."""
        keep = np.any(self.weights != 0, axis=(0, 2))
        if not keep.any():
            keep[0] = True
        return LinearSamples(self.weights[:, keep], self.index[:, keep])

    @staticmethod
    def concatenate(parts: list["LinearSamples"]) -> "LinearSamples":
        K = max(p.weights.shape[1] for p in parts)

        def pad(a, fill):
            return np.pad(a, ((0, 0), (0, K - a.shape[1]), (0, 0)), constant_values=fill)

        return LinearSamples(np.concatenate([pad(p.weights, 0.0) for p in parts]),
                             np.concatenate([pad(p.index, 0) for p in parts]))


@dataclasses.dataclass
class NodeSpline:
    """A D-dimensional cubic Hermite spline through nodes at ``breaks``.

    Node n's value in dimension d is ``sum_q value_coef[n, q, d] * x[value_index[n, q, d]]``
    and likewise its time derivative; a coefficient of 0 marks an unused term.
    """

    breaks: np.ndarray  # (N,)
    value_index: np.ndarray  # (N, Q, D) int
    value_coef: np.ndarray  # (N, Q, D)
    deriv_index: np.ndarray  # (N, Q, D) int
    deriv_coef: np.ndarray  # (N, Q, D)

    @property
    def dim(self) -> int:
        return self.value_index.shape[2]

    @staticmethod
    def from_variables(breaks, value_index: np.ndarray, deriv_index: np.ndarray) -> "NodeSpline":
        """Nodes that are plain variables; an index of -1 makes that entry zero."""
        vi = np.asarray(value_index)[:, None, :]
        di = np.asarray(deriv_index)[:, None, :]
        return NodeSpline(np.asarray(breaks, dtype=float), np.maximum(vi, 0), (vi >= 0) * 1.0,
                          np.maximum(di, 0), (di >= 0) * 1.0)

    def segments(self, t: np.ndarray, side: str = "right") -> tuple[np.ndarray, np.ndarray]:
        """Segment of each time (closed-open, or open-closed with side='left') and its tau."""
        b = self.breaks
        seg = np.searchsorted(b, t, side=side) - 1
        if side == "left":
            seg = np.where(t <= b[0], 0, seg)
        seg = np.clip(seg, 0, len(b) - 2)
        # Zero-length segments (a repeated break: a jump) are never selected, except when
        # clipping at the ends, where tau is then 0.
        h = b[seg + 1] - b[seg]
        tau = np.divide(t - b[seg], h, out=np.zeros_like(t), where=h > 0)
        return seg, tau

    def sample(self, t, order: int = 0, side: str = "right") -> LinearSamples:
        """The ``order``-th time derivative at times t as LinearSamples (n, 4Q, D)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        seg, tau = self.segments(t, side)
        h = self.breaks[seg + 1] - self.breaks[seg]
        h = np.where(h > 0, h, 1.0)
        basis = hermite_basis(tau, order) / h[:, None] ** order
        basis[:, 1] *= h
        basis[:, 3] *= h
        # (n, 4 corners, Q, D): value/derivative coefficients of the two bounding nodes.
        coef = np.stack([self.value_coef[seg], self.deriv_coef[seg],
                         self.value_coef[seg + 1], self.deriv_coef[seg + 1]], axis=1)
        index = np.stack([self.value_index[seg], self.deriv_index[seg],
                          self.value_index[seg + 1], self.deriv_index[seg + 1]], axis=1)
        weights = basis[:, :, None, None] * coef
        n, _, Q, D = weights.shape
        return LinearSamples(weights.reshape(n, 4 * Q, D), index.reshape(n, 4 * Q, D)).compact()

    def bernstein_points(self, segments) -> LinearSamples:
        """The four Bezier control points of each given segment, (4 n, 2Q, D), rows ordered
        (segment, point): for a cubic Hermite piece of length h with end values p0, p1 and
        rates m0, m1 they are p0, p0 + h m0 / 3, p1 - h m1 / 3, p1. The piece lies in their
        convex hull, so a convex constraint met at the four points holds along the whole piece
        (used for the force cone: forces push and stay in the friction pyramid between
        samples, not only at them)."""
        seg = np.asarray(segments, dtype=np.int64).reshape(-1)
        h = self.breaks[seg + 1] - self.breaks[seg]
        n, Q, D = len(seg), self.value_index.shape[1], self.dim
        zero_i = np.zeros((n, Q, D), dtype=np.int64)
        zero_c = np.zeros((n, Q, D))
        vi0, vc0 = self.value_index[seg], self.value_coef[seg]
        vi1, vc1 = self.value_index[seg + 1], self.value_coef[seg + 1]
        di0, dc0 = self.deriv_index[seg], self.deriv_coef[seg]
        di1, dc1 = self.deriv_index[seg + 1], self.deriv_coef[seg + 1]
        k = (h / 3.0)[:, None, None]
        points = [(np.concatenate([vi0, zero_i], 1), np.concatenate([vc0, zero_c], 1)),
                  (np.concatenate([vi0, di0], 1), np.concatenate([vc0, k * dc0], 1)),
                  (np.concatenate([vi1, di1], 1), np.concatenate([vc1, -k * dc1], 1)),
                  (np.concatenate([vi1, zero_i], 1), np.concatenate([vc1, zero_c], 1))]
        index = np.stack([p[0] for p in points], axis=1).reshape(4 * n, 2 * Q, D)
        weights = np.stack([p[1] for p in points], axis=1).reshape(4 * n, 2 * Q, D)
        return LinearSamples(weights, index).compact()

    def node_values(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, D) node values and derivatives at the decision vector x."""
        x = np.asarray(x, dtype=float)
        values = (self.value_coef * x[self.value_index]).sum(axis=1)
        derivs = (self.deriv_coef * x[self.deriv_index]).sum(axis=1)
        return values, derivs

    def to_piecewise_polynomial(self, x: np.ndarray, scale: float = 1.0):
        """The spline at x (times ``scale``) as a Drake PiecewisePolynomial: the same cubic
        Hermite pieces, discontinuous where a break time repeats."""
        from pydrake.trajectories import PiecewisePolynomial

        values, derivs = self.node_values(x)
        values, derivs = scale * values, scale * derivs
        cuts = np.flatnonzero(np.diff(self.breaks) <= 0) + 1
        pp = None
        for lo, hi in zip(np.concatenate([[0], cuts]), np.concatenate([cuts, [len(self.breaks)]])):
            piece = PiecewisePolynomial.CubicHermite(self.breaks[lo:hi], values[lo:hi].T,
                                                     derivs[lo:hi].T)
            if pp is None:
                pp = piece
            else:
                pp.ConcatenateInTime(piece)
        return pp

    def evaluate(self, x: np.ndarray, t, order: int = 0) -> np.ndarray:
        """(n, D) values of the ``order``-th derivative at times t."""
        return self.sample(t, order).value(np.asarray(x, dtype=float))


def swing_profile(u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """s(u) = 3u^2 - 2u^3 and its first two derivatives: the horizontal progress of a swing
    (the cubic with zero end velocities that a two-piece Hermite swing reproduces)."""
    u = np.asarray(u, dtype=float)
    return 3 * u * u - 2 * u ** 3, 6 * u - 6 * u * u, 6 - 12 * u
