"""Value iteration (paper 000 Eq. 9-10) against hand-solved MDPs and exact policy evaluation."""

import itertools

import numpy as np
import pytest
import scipy.sparse as sp

from qz_drake.errors import QzError
from qz_drake.planning.value_iteration import expected_rewards, policy_values, value_iteration


def forest(S=3, r1=4.0, r2=2.0, p=0.1):
    """pymdptoolbox's forest example: action 0 wait, 1 cut; fire with probability p."""
    P = np.zeros((2, S, S))
    P[0, :, 0] = p
    P[0, np.arange(S - 1), np.arange(1, S)] = 1 - p
    P[0, S - 1, S - 1] = 1 - p
    P[1, :, 0] = 1.0
    R = np.zeros((S, 2))
    R[S - 1, 0] = r1
    R[1:, 1] = 1.0
    R[S - 1, 1] = r2
    return P, R


def brute_force(P, R, gamma):
    """Best policy by evaluating every deterministic policy exactly."""
    A, S = P.shape[0], P.shape[1]
    best = None
    for policy in itertools.product(range(A), repeat=S):
        V = policy_values(P, R, gamma, policy)
        if best is None or np.all(V >= best[1] - 1e-12) and np.any(V > best[1] + 1e-12):
            best = (np.array(policy), V)
    return best


def test_two_state_mdp_by_hand():
    # State 0: action 0 stays (reward 1), action 1 moves to 1 (reward 0); state 1 absorbing, reward 2.
    P = np.array([[[1, 0], [0, 1]], [[0, 1], [0, 1]]], float)
    R = np.array([[1.0, 0.0], [2.0, 2.0]])
    gamma = 0.9
    result = value_iteration(P, R, gamma, epsilon=1e-8)
    # V(1) = 2 / (1 - gamma) = 20; V(0) = max(1 + 0.9 V(0), 0.9 * 20) = 18 (moving is better).
    assert result.converged and result.V == pytest.approx([18.0, 20.0], abs=1e-6)
    assert result.policy[0] == 1
    assert result.Q[0] == pytest.approx([1 + 0.9 * 18.0, 18.0], abs=1e-6)


def test_forest_matches_exact_policy_evaluation():
    P, R = forest()
    gamma, epsilon = 0.9, 0.01
    result = value_iteration(P, R, gamma, epsilon=epsilon)
    policy, V_star = brute_force(P, R, gamma)
    assert list(result.policy) == [0, 0, 0] == list(policy)  # pymdptoolbox's documented answer
    # Epsilon-optimality of the greedy policy, and the values close to V*.
    V_greedy = policy_values(P, R, gamma, result.policy)
    assert np.all(V_star - V_greedy <= epsilon)
    assert np.abs(result.V - V_star).max() < epsilon
    assert result.max_change < epsilon * (1 - gamma) / (2 * gamma)


def test_random_mdps_against_brute_force():
    rng = np.random.default_rng(0)
    for _ in range(5):
        A, S, gamma = 3, 4, 0.8
        P = rng.random((A, S, S)) ** 3
        P /= P.sum(axis=2, keepdims=True)
        R = rng.normal(size=(A, S, S))
        result = value_iteration(P, R, gamma, epsilon=1e-9, max_iter=10000)
        policy, V_star = brute_force(P, R, gamma)
        assert np.allclose(result.V, V_star, atol=1e-8)
        assert np.allclose(policy_values(P, R, gamma, result.policy), V_star, atol=1e-8)


def test_sparse_and_dense_agree_and_reward_shapes():
    P, R = forest(S=6)
    dense = value_iteration(P, R, 0.95, epsilon=1e-6)
    sparse = value_iteration([sp.csr_matrix(m) for m in P], R, 0.95, epsilon=1e-6)
    assert np.allclose(dense.V, sparse.V) and np.array_equal(dense.policy, sparse.policy)
    assert dense.iterations == sparse.iterations
    # (A, S, S) rewards reduce to (S, A) expectations, dense or sparse.
    R3 = np.repeat(R.T[:, :, None], 6, axis=2)
    assert np.allclose(expected_rewards(P, R3), R)
    assert np.allclose(expected_rewards([sp.csr_matrix(m) for m in P], [sp.csr_matrix(r) for r in R3]), R)
    assert np.allclose(expected_rewards(P, R[:, 0]), np.repeat(R[:, :1], 2, axis=1))


def test_stops_at_max_iter_and_checks_inputs():
    P, R = forest()
    result = value_iteration(P, R, 0.99, epsilon=1e-12, max_iter=3)
    assert result.iterations == 3 and not result.converged
    with pytest.raises(QzError, match=r"P\[0\] row 0"):
        value_iteration(P * 0.5, R, 0.9)
    with pytest.raises(QzError, match="discount"):
        value_iteration(P, R, 1.5)
    with pytest.raises(QzError, match="R = "):
        value_iteration(P, np.zeros((2, 2)), 0.9)
    with pytest.raises(QzError, match=r"P\[1\]"):
        value_iteration([P[0], P[1][:2, :2]], R, 0.9)
