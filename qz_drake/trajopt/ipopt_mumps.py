"""Ipopt with MUMPS on a Drake ``MathematicalProgram`` (the BLC's default solver).

Drake's pip wheel builds Ipopt with SPRAL as its only linear solver, and on the BLC's KKT
systems SPRAL's factorisations took more than half of a solve (BENCHMARKS "blc"). The
``cyipopt-wheels`` wheel carries Ipopt 3.14 built with MUMPS, the linear solver TOWR uses. This
module hands a MathematicalProgram to that Ipopt. The program stays the problem's one
definition: variable bounds, linear (in)equalities and linear or quadratic costs are read from
its bindings; a generic constraint is evaluated by its Drake evaluator (values in double, its
Jacobian through AutoDiff, on the sparsity pattern it declares); and generic constraints that
are rows of one vectorised numpy function (``VectorisedRows``, the BLC's sampled constraints)
are evaluated by that function once per point, with their analytic Jacobian and no AutoDiff.

Only what Ipopt can take is accepted: a program with conic, LMI or complementarity constraints
or l2-norm costs raises ValueError naming them.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp
from pydrake.autodiffutils import ExtractGradient, ExtractValue, InitializeAutoDiff

# Ipopt's ApplicationReturnStatus -> the words Drake's IpoptSolverDetails uses for them.
STATUS = {
    0: "Success",
    1: "Stop at acceptable point",
    2: "Local infeasibility",
    3: "Stop at tiny step",
    4: "Divergent iterates",
    5: "User requested stop",
    6: "Feasible point found",
    -1: "Max iteration exceeded",
    -2: "Restoration failed",
    -3: "Error in step computation",
    -4: "CPU time exceeded",
    -5: "Wall time exceeded",
    -10: "Too few degrees of freedom",
    -11: "Invalid problem definition",
    -12: "Invalid option",
    -13: "Invalid number detected",
    -100: "Unrecoverable exception",
    -101: "Non-Ipopt exception",
    -102: "Out of memory",
    -199: "Internal error",
}

_UNSUPPORTED = ("lorentz_cone_constraints", "rotated_lorentz_cone_constraints",
                "exponential_cone_constraints", "positive_semidefinite_constraints",
                "linear_matrix_inequality_constraints", "linear_complementarity_constraints",
                "quadratic_constraints", "l2norm_costs")


def available() -> bool:
    """Whether the MUMPS build of Ipopt (package ``cyipopt-wheels``) can be imported."""
    try:
        _problem_class()
    except ImportError:
        return False
    return True


_PROBLEM = None


def _problem_class():
    """cyipopt's ``Problem``, loaded without cyipopt's SciPy interface where that is possible.

    ``import cyipopt`` runs the package's ``__init__``, which imports its ``minimize_ipopt``
    and with it ``scipy.optimize``: 0.3 s of a process's first BLC solve (`qz blc`, each
    collection worker) of about 0.6 s (BENCHMARKS "blc", session 41). The wheel's compiled
    module (``ipopt_wrapper``, a top-level module of cyipopt-wheels) needs only
    ``cyipopt.exceptions``. So ``cyipopt`` is registered as its package without running its
    ``__init__``, and the ``__init__`` runs in that same module the first time anything asks
    the package for a name it lacks (``cyipopt.minimize_ipopt``, ``from cyipopt import ...``):
    one package, one compiled module, the same classes. Where cyipopt is imported already, or
    the layout is another, ``import cyipopt``."""
    global _PROBLEM
    if _PROBLEM is not None:
        return _PROBLEM
    import importlib
    import importlib.util
    import sys
    import types

    if "cyipopt" not in sys.modules:
        spec = importlib.util.find_spec("cyipopt")
        if spec is None:
            raise ImportError("no module named 'cyipopt' (the package cyipopt-wheels)")
        if (importlib.util.find_spec("ipopt_wrapper") is not None and spec.submodule_search_locations
                and spec.origin):
            package = types.ModuleType("cyipopt")
            package.__path__ = list(spec.submodule_search_locations)
            package.__spec__, package.__file__, package.__package__ = spec, spec.origin, "cyipopt"

            def complete(name):
                # The package's own __init__, once, in this module (PEP 562's __getattr__).
                del package.__dict__["__getattr__"]
                with open(spec.origin) as f:
                    exec(compile(f.read(), spec.origin, "exec"), package.__dict__)
                return getattr(package, name)

            package.__getattr__ = complete
            sys.modules["cyipopt"] = package
            try:
                wrapper = importlib.import_module("ipopt_wrapper")
            except BaseException:
                del sys.modules["cyipopt"]
                raise
            if hasattr(wrapper, "Problem"):
                _PROBLEM = wrapper.Problem
                return _PROBLEM
    import cyipopt

    _PROBLEM = cyipopt.Problem
    return _PROBLEM


@dataclasses.dataclass
class VectorisedRows:
    """Generic constraint bindings of a program whose rows one numpy function computes together.

    The bindings' rows, in the order of ``bindings``, are rows 0..m-1 of ``evaluate``; the
    Jacobian entries ``evaluate_with_jacobian`` returns sit at (``rows``, ``cols``), ``cols``
    being the program's decision-variable indices (duplicate positions add up).
    """

    bindings: Sequence
    rows: np.ndarray
    cols: np.ndarray
    evaluate: Callable[[np.ndarray], np.ndarray]
    evaluate_with_jacobian: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclasses.dataclass
class IpoptResult:
    """What Ipopt returned: the point (all decision variables, in the program's order), its
    status in Drake's words and Ipopt's code, the iterations and the objective."""

    x: np.ndarray
    status: str
    status_code: int
    iterations: int
    objective: float
    solve_time: float

    @property
    def success(self) -> bool:
        return self.status_code in (0, 1)


class _Block:
    """Constraint rows of one kind: bounds, Jacobian positions and how to evaluate them."""

    def __init__(self, lower, upper, rows, cols, values, jacobian):
        self.lower = np.asarray(lower, dtype=float)
        self.upper = np.asarray(upper, dtype=float)
        self.rows = np.asarray(rows, dtype=np.int64)
        self.cols = np.asarray(cols, dtype=np.int64)
        self.values = values  # x -> g
        self.jacobian = jacobian  # x -> entries at (rows, cols)


class ProgramNlp:
    """A MathematicalProgram in cyipopt's problem interface (objective, gradient, constraints,
    Jacobian and its structure; the Hessian left to Ipopt's limited-memory approximation)."""

    def __init__(self, prog, vectorised: Sequence[VectorisedRows] = ()):
        for name in _UNSUPPORTED:
            if len(getattr(prog, name)()):
                raise ValueError(f"ipopt_mumps: the program has {name.replace('_', ' ')}, "
                                 "which this Ipopt interface does not take")
        self.prog = prog
        n = self.num_vars = prog.num_vars()
        self.lower = np.full(n, -np.inf)
        self.upper = np.full(n, np.inf)
        for b in prog.bounding_box_constraints():
            idx = self._indices(b)
            e = b.evaluator()
            np.maximum.at(self.lower, idx, e.lower_bound())
            np.minimum.at(self.upper, idx, e.upper_bound())
        blocks = []
        for b in list(prog.linear_equality_constraints()) + list(prog.linear_constraints()):
            blocks.append(self._linear_block(b))
        # pybind11 hands back the same Python object for an evaluator while one is alive, so
        # the covered evaluators are kept referenced while the generic bindings are matched.
        generic = prog.generic_constraints()
        in_program = {id(e): e for e in (b.evaluator() for b in generic)}
        covered = {}
        for v in vectorised:
            blocks.append(self._vectorised_block(v))
            for b in v.bindings:
                e = b.evaluator()
                if id(e) not in in_program:
                    raise ValueError(f"ipopt_mumps: VectorisedRows binding "
                                     f"'{e.get_description()}' is not a constraint of the program")
                covered[id(e)] = e
        for b in generic:
            if id(b.evaluator()) not in covered:
                blocks.append(self._generic_block(b))
        self.blocks = blocks
        offsets = np.cumsum([0] + [len(blk.lower) for blk in blocks])
        self.num_constraints = int(offsets[-1])
        self.constraint_lower = np.concatenate([blk.lower for blk in blocks] or [np.zeros(0)])
        self.constraint_upper = np.concatenate([blk.upper for blk in blocks] or [np.zeros(0)])
        rows = np.concatenate([blk.rows + o for blk, o in zip(blocks, offsets)] or
                              [np.zeros(0, np.int64)])
        cols = np.concatenate([blk.cols for blk in blocks] or [np.zeros(0, np.int64)])
        keys, self._inverse = np.unique(rows * max(n, 1) + cols, return_inverse=True)
        self._rows = (keys // max(n, 1)).astype(np.int32)
        self._cols = (keys % max(n, 1)).astype(np.int32)
        self._costs = self._cost_terms()
        self.iterations = 0

    def _indices(self, binding) -> np.ndarray:
        return np.asarray(self.prog.FindDecisionVariableIndices(binding.variables()), dtype=np.int64)

    def _linear_block(self, binding) -> _Block:
        e = binding.evaluator()
        A = sp.coo_matrix(e.get_sparse_A())
        idx = self._indices(binding)
        A_full = sp.csr_matrix((A.data, (A.row, idx[A.col])), shape=(A.shape[0], self.num_vars))
        data = A_full.tocoo()
        return _Block(e.lower_bound(), e.upper_bound(), data.row, data.col,
                      lambda x: A_full @ x, lambda x: data.data)

    def _vectorised_block(self, v: VectorisedRows) -> _Block:
        lower = np.concatenate([b.evaluator().lower_bound() for b in v.bindings])
        upper = np.concatenate([b.evaluator().upper_bound() for b in v.bindings])
        if len(v.rows) != len(v.cols) or (len(v.rows) and not 0 <= v.rows.min() <= v.rows.max()
                                          < len(lower)):
            raise ValueError(f"ipopt_mumps: VectorisedRows Jacobian positions do not fit its "
                             f"bindings' {len(lower)} rows")
        return _Block(lower, upper, v.rows, v.cols, v.evaluate,
                      lambda x: v.evaluate_with_jacobian(x)[1])

    def _generic_block(self, binding) -> _Block:
        e = binding.evaluator()
        idx = self._indices(binding)
        m = e.num_constraints()
        pattern = e.gradient_sparsity_pattern()
        if pattern is None:
            r, c = np.divmod(np.arange(m * len(idx)), len(idx))
        else:
            r, c = (np.array([p[k] for p in pattern], dtype=np.int64) for k in (0, 1))

        def values(x):
            return np.asarray(e.Eval(x[idx]), dtype=float).reshape(-1)

        def jacobian(x):
            out = e.Eval(InitializeAutoDiff(x[idx]))
            return ExtractGradient(out)[r, c]

        return _Block(e.lower_bound(), e.upper_bound(), r, idx[c], values, jacobian)

    def _cost_terms(self):
        terms = []
        for b in self.prog.quadratic_costs():
            e = b.evaluator()
            terms.append(("quadratic", self._indices(b), e.Q(), e.b(), e.c()))
        for b in self.prog.linear_costs():
            e = b.evaluator()
            terms.append(("linear", self._indices(b), None, e.a(), e.b()))
        for b in self.prog.generic_costs():
            terms.append(("generic", self._indices(b), b.evaluator(), None, None))
        return terms

    # -- cyipopt's interface ------------------------------------------------------------------
    def objective(self, x):
        total = 0.0
        for kind, idx, Q, b, c in self._costs:
            z = x[idx]
            if kind == "quadratic":
                total += 0.5 * z @ Q @ z + b @ z + c
            elif kind == "linear":
                total += b @ z + c
            else:
                total += float(np.asarray(Q.Eval(z)).reshape(-1)[0])
        return float(total)

    def gradient(self, x):
        g = np.zeros(self.num_vars)
        for kind, idx, Q, b, c in self._costs:
            z = x[idx]
            if kind == "quadratic":
                np.add.at(g, idx, Q @ z + b)
            elif kind == "linear":
                np.add.at(g, idx, b)
            else:
                out = Q.Eval(InitializeAutoDiff(z))
                np.add.at(g, idx, ExtractGradient(out).reshape(-1))
        return g

    def constraints(self, x):
        if not self.blocks:
            return np.zeros(0)
        return np.concatenate([blk.values(x) for blk in self.blocks])

    def jacobianstructure(self):
        return self._rows, self._cols

    def jacobian(self, x):
        if not self.blocks:
            return np.zeros(0)
        entries = np.concatenate([blk.jacobian(x) for blk in self.blocks])
        return np.bincount(self._inverse, weights=entries, minlength=len(self._rows))

    def intermediate(self, alg_mod, iter_count, *args):
        self.iterations = int(iter_count)
        return True


def solve(prog, x0, options: dict | None = None,
          vectorised: Sequence[VectorisedRows] = ()) -> IpoptResult:
    """Solves ``prog`` from ``x0`` (all its decision variables) with Ipopt and MUMPS.

    Args:
        prog: a pydrake MathematicalProgram.
        x0: the initial point, one value per decision variable in the program's order.
        options: Ipopt options by name (``linear_solver`` defaults to ``mumps``; the Hessian is
            always the limited-memory approximation).
        vectorised: generic bindings evaluated together (VectorisedRows).
    """
    problem_class = _problem_class()
    clock = time.perf_counter()
    nlp = ProgramNlp(prog, vectorised)
    x0 = np.asarray(x0, dtype=float).reshape(-1)
    if x0.shape != (nlp.num_vars,):
        raise ValueError(f"ipopt_mumps: x0 has {x0.size} values, the program "
                         f"{nlp.num_vars} decision variables")
    problem = problem_class(n=nlp.num_vars, m=nlp.num_constraints, problem_obj=nlp,
                              lb=nlp.lower, ub=nlp.upper, cl=nlp.constraint_lower,
                              cu=nlp.constraint_upper)
    settings = {"linear_solver": "mumps", "print_level": 0, "sb": "yes"}
    settings.update(options or {})
    settings["hessian_approximation"] = "limited-memory"
    for key, value in settings.items():
        if isinstance(value, (bool, np.bool_)):
            value = "yes" if value else "no"
        elif isinstance(value, (np.integer,)):
            value = int(value)
        elif isinstance(value, (np.floating,)):
            value = float(value)
        problem.add_option(key, value)
    x, info = problem.solve(x0)
    code = int(info["status"])
    return IpoptResult(x=np.asarray(x, dtype=float), status=STATUS.get(code, f"Ipopt status {code}"),
                       status_code=code, iterations=nlp.iterations,
                       objective=float(info["obj_val"]), solve_time=time.perf_counter() - clock)
