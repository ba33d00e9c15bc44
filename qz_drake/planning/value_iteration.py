"""Value iteration (paper 000 section II-E.2, Eq. 9-10) in pymdptoolbox's convention.

``P`` has shape (A, S, S): ``P[a][s, s']`` is the probability of reaching s' from s with action
a; it is a dense array, or a sequence of A (S, S) scipy.sparse matrices for large maps (the
capability MDP has two next states per action). ``R`` is the reward: (S, A) expected
immediate rewards, (S,) a reward per state, or (A, S, S) per transition (dense or a sequence
of sparse matrices), reduced to (S, A) by r(s, a) = sum_s' P(s, a, s') R(s, a, s').

One iteration is Eq. 9 for every state at once, Q = r + gamma P V, V = max_a Q, as A
matrix-vector products. It stops when the largest change of V falls below
epsilon (1 - gamma) / (2 gamma): then the greedy policy of Eq. 10 is epsilon-optimal
(Puterman, Markov Decision Processes, Theorem 6.3.1); with gamma = 1 it stops at a change
below epsilon.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from qz_drake.errors import bad_value


@dataclasses.dataclass
class ValueIterationResult:
    """What value iteration found."""

    # (S,) utilities V(s) after the last iteration.
    V: np.ndarray
    # (S,) greedy action of Eq. 10 for V (the lowest index among ties).
    policy: np.ndarray
    # (S, A) Q(s, a) = r(s, a) + gamma sum_s' P(s, a, s') V(s').
    Q: np.ndarray
    # Iterations run.
    iterations: int
    # Largest |V_n+1(s) - V_n(s)| of the last iteration.
    max_change: float
    # Whether max_change fell below the stopping threshold before max_iter.
    converged: bool


def _is_sparse(m) -> bool:
    import scipy.sparse as sp

    return sp.issparse(m)


def _transitions(P) -> tuple[list, int, int]:
    """P as a list of A (S, S) matrices (dense rows or CSR), with A and S."""
    import scipy.sparse as sp

    if isinstance(P, np.ndarray) or not isinstance(P, (list, tuple)):
        P = np.asarray(P, dtype=float)
        if P.ndim != 3 or P.shape[1] != P.shape[2]:
            raise bad_value("P", f"array of shape {P.shape}", "expected (A, S, S)")
        matrices = list(P)
    else:
        matrices = [sp.csr_matrix(m, dtype=float) if _is_sparse(m) else np.asarray(m, dtype=float) for m in P]
    if not matrices:
        raise bad_value("P", "[]", "needs at least one action")
    S = matrices[0].shape[0]
    for a, m in enumerate(matrices):
        if m.shape != (S, S):
            raise bad_value(f"P[{a}]", f"matrix of shape {m.shape}", f"expected ({S}, {S}) like P[0]")
        values = m.data if _is_sparse(m) else m
        if values.size and (not np.isfinite(values).all() or values.min() < 0):
            raise bad_value(f"P[{a}]", "negative or non-finite entries", "probabilities must be in [0, 1]")
        rows = np.asarray(m.sum(axis=1)).reshape(-1)
        bad = np.nonzero(np.abs(rows - 1.0) > 1e-6)[0]
        if len(bad):
            raise bad_value(f"P[{a}] row {bad[0]}", float(rows[bad[0]]), "must sum to 1 (a stochastic matrix)")
    return matrices, len(matrices), S


def expected_rewards(P, R) -> np.ndarray:
    """R of any accepted shape as (S, A) expected immediate rewards."""
    matrices, A, S = _transitions(P)
    if isinstance(R, (list, tuple)) and R and (_is_sparse(R[0]) or np.ndim(R[0]) == 2):
        if len(R) != A:
            raise bad_value("R", f"{len(R)} matrices", f"expected one per action ({A})")
        columns = []
        for a, (p, r) in enumerate(zip(matrices, R)):
            if r.shape != (S, S):
                raise bad_value(f"R[{a}]", f"matrix of shape {r.shape}", f"expected ({S}, {S})")
            product = p.multiply(r) if _is_sparse(p) else (r.multiply(p) if _is_sparse(r) else p * np.asarray(r))
            columns.append(np.asarray(product.sum(axis=1)).reshape(-1))
        return np.column_stack(columns)
    R = np.asarray(R, dtype=float)
    if R.shape == (S,):
        return np.repeat(R[:, None], A, axis=1)
    if R.shape == (S, A):
        return R.copy()
    if R.shape == (A, S, S):
        return expected_rewards(matrices, list(R))
    raise bad_value("R", f"array of shape {R.shape}", f"expected ({S}, {A}), ({S},) or ({A}, {S}, {S})")


def bellman_q(matrices: list, r: np.ndarray, V: np.ndarray, discount: float) -> np.ndarray:
    """Q = r + gamma P V for every state and action, (S, A)."""
    return r + discount * np.column_stack([m @ V for m in matrices])


def value_iteration(P, R, discount: float, epsilon: float = 0.01, max_iter: int = 1000,
                    V0=None) -> ValueIterationResult:
    """Value iteration of Eq. 9 until epsilon-optimal, then the greedy policy of Eq. 10.

    Args:
        P: (A, S, S) transition probabilities, dense or a sequence of A scipy.sparse matrices.
        R: rewards, (S, A), (S,) or (A, S, S) (dense, or a sequence of sparse matrices).
        discount: gamma in (0, 1].
        epsilon: accuracy of the values the policy is greedy for (see the module docstring).
        max_iter: most iterations.
        V0: (S,) initial values; zeros by default.
    """
    matrices, A, S = _transitions(P)
    if not (0.0 < float(discount) <= 1.0):
        raise bad_value("discount", discount, "must be in (0, 1]")
    if not (float(epsilon) > 0.0):
        raise bad_value("epsilon", epsilon, "must be positive")
    if isinstance(max_iter, bool) or int(max_iter) != max_iter or max_iter < 1:
        raise bad_value("max_iter", max_iter, "must be a positive whole number")
    r = expected_rewards(matrices, R)
    if not np.isfinite(r).all():
        raise bad_value("R", "non-finite rewards", "rewards must be finite")
    gamma = float(discount)
    threshold = epsilon * (1.0 - gamma) / (2.0 * gamma) if gamma < 1.0 else float(epsilon)
    V = np.zeros(S) if V0 is None else np.array(V0, dtype=float).reshape(S)
    change, converged, iterations = np.inf, False, 0
    if all(_is_sparse(m) for m in matrices):
        # One (A S, S) matrix: one product per iteration instead of A (the same row sums, so
        # the same values; 2.4x faster on the 20 m capability MDP, where the A products' own
        # overhead dominated).
        import scipy.sparse as sp

        stacked, r_by_action = sp.vstack(matrices, format="csr"), np.ascontiguousarray(r.T)

        def backup(V):
            Q = (stacked @ V).reshape(A, S)
            Q *= gamma
            Q += r_by_action
            return Q.max(axis=0)
    else:
        def backup(V):
            return bellman_q(matrices, r, V, gamma).max(axis=1)
    for iterations in range(1, int(max_iter) + 1):
        V_next = backup(V)
        change = float(np.max(np.abs(V_next - V)))
        V = V_next
        if change < threshold:
            converged = True
            break
    Q = bellman_q(matrices, r, V, gamma)
    return ValueIterationResult(V=V, policy=np.argmax(Q, axis=1), Q=Q, iterations=iterations,
                                max_change=change, converged=converged)


def policy_values(P, R, discount: float, policy) -> np.ndarray:
    """Exact V of a fixed policy: the linear solve (I - gamma P_pi) V = r_pi (gamma < 1)."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    matrices, A, S = _transitions(P)
    r = expected_rewards(matrices, R)
    policy = np.asarray(policy, dtype=int).reshape(S)
    # Row s of P_pi is row s of P[policy[s]]: a sum of row-masked action matrices.
    P_pi = sum(sp.diags((policy == a).astype(float)) @ sp.csr_matrix(m) for a, m in enumerate(matrices))
    P_pi = sp.csc_matrix(P_pi)
    r_pi = r[np.arange(S), policy]
    return spla.spsolve(sp.identity(S, format="csc") - float(discount) * P_pi, r_pi)
