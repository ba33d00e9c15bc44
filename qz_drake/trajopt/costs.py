"""Optional costs of the BLC (none by default: paper 000 poses a feasibility problem).

Each cost is a convex quadratic ``weight * |A x|^2`` of a linear map A of the decision vector,
handed to Drake as a ``QuadraticCost`` on only the variables A touches, so Ipopt evaluates it in
C++ without calling Python.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from qz_drake.errors import ConfigError, bad_value


def cost_matrix(name: str, variables, dynamics_times) -> sp.csr_matrix:
    """The map A of a named cost (see parameters.COST_REASONS)."""
    v = variables
    N = v.num_vars
    if name == "base_linear_acceleration":
        return v.base_position.sample(dynamics_times, 2).sparse(N)
    if name == "base_angular_velocity":
        idx = v.base_ang[:, 1].reshape(-1)
    elif name == "force_rate":
        idx = np.concatenate([nodes[nodes[:, 1, 0] >= 0, 1].reshape(-1) for nodes in v.force_nodes])
    else:
        raise bad_value("blc.costs", name, "unknown cost", ConfigError)
    return sp.csr_matrix((np.ones(len(idx)), (np.arange(len(idx)), idx)), shape=(len(idx), N))


def quadratic_cost_terms(A: sp.csr_matrix, weight: float):
    """(Q, columns) with weight |A x|^2 = 0.5 x[columns]^T Q x[columns]."""
    A = sp.csc_matrix(A)
    columns = np.flatnonzero(np.diff(A.indptr))
    sub = A[:, columns]
    Q = 2.0 * weight * (sub.T @ sub).toarray()
    return Q, columns
