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

Ipopt is called through its C interface (``IpStdCInterface.h``) in the library that wheel ships,
with ctypes (:class:`_CIpopt`): cyipopt's compiled wrapper copies the Jacobian to Ipopt one
Python-indexed entry at a time (about 60 ns each: a tenth of a solve of the BLC's 40 000-130 000
entries), where a numpy copy into Ipopt's buffer takes microseconds. Ipopt sees the same numbers
in the same calls, so the solves are the same, bit for bit. Where that library is not found (a
cyipopt built against another Ipopt), cyipopt's ``Problem`` runs the solve.
"""

from __future__ import annotations

import ctypes
import dataclasses
import glob
import os
import threading
import time
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp
from pydrake.autodiffutils import ExtractGradient, InitializeAutoDiff

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
    """Whether the MUMPS build of Ipopt (package ``cyipopt-wheels``) can be used."""
    if _ipopt_library() is not None:
        return True
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


# Ipopt 3.14's C interface: ipindex is int, ipnumber double, its flags C99 bool.
_INDEX, _NUMBER, _BOOL = ctypes.c_int, ctypes.c_double, ctypes.c_bool
_NUMBERS, _INDICES = ctypes.POINTER(_NUMBER), ctypes.POINTER(_INDEX)
_EVAL_F = ctypes.CFUNCTYPE(_BOOL, _INDEX, _NUMBERS, _BOOL, _NUMBERS, ctypes.c_void_p)
_EVAL_GRAD_F = ctypes.CFUNCTYPE(_BOOL, _INDEX, _NUMBERS, _BOOL, _NUMBERS, ctypes.c_void_p)
_EVAL_G = ctypes.CFUNCTYPE(_BOOL, _INDEX, _NUMBERS, _BOOL, _INDEX, _NUMBERS, ctypes.c_void_p)
_EVAL_JAC_G = ctypes.CFUNCTYPE(_BOOL, _INDEX, _NUMBERS, _BOOL, _INDEX, _INDEX, _INDICES, _INDICES, _NUMBERS,
                               ctypes.c_void_p)
_EVAL_H = ctypes.CFUNCTYPE(_BOOL, _INDEX, _NUMBERS, _BOOL, _NUMBER, _INDEX, _NUMBERS, _BOOL, _INDEX, _INDICES,
                           _INDICES, _NUMBERS, ctypes.c_void_p)
_INTERMEDIATE = ctypes.CFUNCTYPE(_BOOL, _INDEX, _INDEX, _NUMBER, _NUMBER, _NUMBER, _NUMBER, _NUMBER, _NUMBER,
                                 _NUMBER, _NUMBER, _INDEX, ctypes.c_void_p)
_LIBRARY: list = []  # [CDLL or None], once looked for


def _ipopt_library():
    """The Ipopt 3.14 library cyipopt-wheels ships (beside its compiled module), its C
    interface's functions typed; None where there is none."""
    if _LIBRARY:
        return _LIBRARY[0]
    import importlib.util

    library = None
    spec = importlib.util.find_spec("ipopt_wrapper")
    if spec is not None and spec.origin:
        folder = os.path.join(os.path.dirname(spec.origin), "cyipopt_wheels.libs")
        found = sorted(glob.glob(os.path.join(folder, "libipopt-*.so.3.14*")))
        if found:
            # The wheel's libraries find each other through its compiled module's RPATH, which
            # a library opened on its own lacks: its dependencies (MUMPS, BLAS, gfortran) are
            # opened first, by path, each once the ones it needs are (the loader then matches
            # them by name).
            waiting = [f for f in sorted(glob.glob(os.path.join(folder, "*.so*"))) if f != found[-1]]
            while waiting:
                failed = []
                for path in waiting:
                    try:
                        ctypes.CDLL(path)
                    except OSError:
                        failed.append(path)
                if len(failed) == len(waiting):
                    break
                waiting = failed
            try:
                library = ctypes.CDLL(found[-1])
            except OSError:
                found = []
        if found:
            library.CreateIpoptProblem.restype = ctypes.c_void_p
            library.CreateIpoptProblem.argtypes = [_INDEX, _NUMBERS, _NUMBERS, _INDEX, _NUMBERS, _NUMBERS, _INDEX,
                                                   _INDEX, _INDEX, _EVAL_F, _EVAL_G, _EVAL_GRAD_F, _EVAL_JAC_G,
                                                   _EVAL_H]
            library.FreeIpoptProblem.restype = None
            library.FreeIpoptProblem.argtypes = [ctypes.c_void_p]
            library.AddIpoptStrOption.restype = _BOOL
            library.AddIpoptStrOption.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_char_p]
            library.AddIpoptNumOption.restype = _BOOL
            library.AddIpoptNumOption.argtypes = [ctypes.c_void_p, ctypes.c_char_p, _NUMBER]
            library.AddIpoptIntOption.restype = _BOOL
            library.AddIpoptIntOption.argtypes = [ctypes.c_void_p, ctypes.c_char_p, _INDEX]
            library.SetIntermediateCallback.restype = _BOOL
            library.SetIntermediateCallback.argtypes = [ctypes.c_void_p, _INTERMEDIATE]
            library.IpoptSolve.restype = ctypes.c_int
            library.IpoptSolve.argtypes = [ctypes.c_void_p, _NUMBERS, _NUMBERS, _NUMBERS, _NUMBERS, _NUMBERS,
                                           _NUMBERS, ctypes.c_void_p]
    _LIBRARY.append(library)
    return library


def _pointer(array: np.ndarray):
    return array.ctypes.data_as(_NUMBERS)


class _CIpopt:
    """One solve of a ProgramNlp through Ipopt's C interface, with cyipopt's ``Problem``'s
    calls and results (objective, gradient, constraints, Jacobian and its structure,
    ``intermediate``; the limited-memory Hessian): each callback gets a copy of Ipopt's x and
    writes its answer into Ipopt's buffer with one numpy copy. An exception in a callback stops
    the solve (the callback reports failure, the next intermediate call stops Ipopt) and is
    raised from :meth:`solve`, as cyipopt does."""

    def __init__(self, library, nlp: "ProgramNlp"):
        self._library, self._nlp = library, nlp
        self._error: BaseException | None = None
        n, m = nlp.num_vars, nlp.num_constraints
        rows, cols = nlp.jacobianstructure()
        self._rows = np.ascontiguousarray(rows, dtype=np.int32)
        self._cols = np.ascontiguousarray(cols, dtype=np.int32)
        bounds = [np.ascontiguousarray(b, dtype=np.float64) for b in
                  (nlp.lower, nlp.upper, nlp.constraint_lower, nlp.constraint_upper)]
        # The callbacks must outlive the problem: ctypes frees a trampoline with its object.
        self._callbacks = (_EVAL_F(self._objective), _EVAL_G(self._constraints), _EVAL_GRAD_F(self._gradient),
                           _EVAL_JAC_G(self._jacobian), _EVAL_H(self._hessian))
        self._intermediate_cb = _INTERMEDIATE(self._intermediate)
        self._problem = library.CreateIpoptProblem(n, *(_pointer(b) for b in bounds[:2]), m,
                                                   *(_pointer(b) for b in bounds[2:]), len(self._rows), 0, 0,
                                                   *self._callbacks)
        if not self._problem:
            raise RuntimeError("ipopt_mumps: Ipopt could not create the problem (check the bounds)")
        library.SetIntermediateCallback(self._problem, self._intermediate_cb)

    def __del__(self):
        problem, self._problem = getattr(self, "_problem", None), None
        if problem:
            self._library.FreeIpoptProblem(problem)

    def add_option(self, key: str, value) -> None:
        """An Ipopt option, typed as cyipopt's ``add_option`` types it (str, float or int)."""
        name = key.encode("utf-8")
        if isinstance(value, str):
            done = self._library.AddIpoptStrOption(self._problem, name, value.encode("utf-8"))
        elif type(value) is float:
            done = self._library.AddIpoptNumOption(self._problem, name, value)
        elif type(value) is int:
            done = self._library.AddIpoptIntOption(self._problem, name, value)
        else:
            raise TypeError(f"ipopt_mumps: option {key} = {value!r} is not a str, float or int")
        if not done:
            raise TypeError(f"ipopt_mumps: Ipopt refused option {key} = {value!r}")

    def solve(self, x0: np.ndarray) -> tuple[np.ndarray, int, float]:
        """(x, Ipopt's return status, objective) from x0; the problem is freed after it (one
        solve per object)."""
        if not self._problem:
            raise RuntimeError("ipopt_mumps: this problem has been solved already")
        n, m = self._nlp.num_vars, self._nlp.num_constraints
        x = np.array(x0, dtype=np.float64)
        g, mult_g = np.zeros(m), np.zeros(m)
        mult_lower, mult_upper = np.zeros(n), np.zeros(n)
        objective = _NUMBER(0.0)
        try:
            status = self._library.IpoptSolve(self._problem, _pointer(x), _pointer(g), ctypes.byref(objective),
                                              _pointer(mult_g), _pointer(mult_lower), _pointer(mult_upper), None)
        finally:
            self._library.FreeIpoptProblem(self._problem)
            # The callbacks refer to this object: dropped with the problem, no cycle is left.
            self._problem, self._callbacks, self._intermediate_cb = None, None, None
        if self._error is not None:
            raise self._error
        return x, int(status), float(objective.value)

    # -- the callbacks: Ipopt's pointers in, one copy out ---------------------------------------
    def _call(self, function, n, x, out, size):
        if self._error is not None:
            return False
        try:
            value = function(np.ctypeslib.as_array(x, shape=(n,)).copy())
            np.ctypeslib.as_array(out, shape=(size,))[:] = value
        except BaseException as e:  # raised again by solve()
            self._error = e
            return False
        return True

    def _objective(self, n, x, new_x, value, user_data):
        return self._call(lambda z: [self._nlp.objective(z)], n, x, value, 1)

    def _gradient(self, n, x, new_x, out, user_data):
        return self._call(self._nlp.gradient, n, x, out, n)

    def _constraints(self, n, x, new_x, m, out, user_data):
        return self._call(self._nlp.constraints, n, x, out, m)

    def _jacobian(self, n, x, new_x, m, count, rows, cols, values, user_data):
        if not values:  # the structure, asked once
            if count:  # (no entries: Ipopt's arrays may be null)
                np.ctypeslib.as_array(rows, shape=(count,))[:] = self._rows
                np.ctypeslib.as_array(cols, shape=(count,))[:] = self._cols
            return True
        return self._call(self._nlp.jacobian, n, x, values, count)

    def _hessian(self, *args):  # never asked: the Hessian is the limited-memory approximation
        return False

    def _intermediate(self, alg_mod, iter_count, *args):
        if self._error is not None:
            return False
        try:
            return bool(self._nlp.intermediate(alg_mod, iter_count, *args[:-1]))
        except BaseException as e:
            self._error = e
            return False


@dataclasses.dataclass
class VectorisedRows:
    """Generic constraint bindings of a program whose rows one numpy function computes together.

    The bindings' rows, in the order of ``bindings``, are rows 0..m-1 of ``evaluate``; the
    Jacobian entries ``evaluate_with_jacobian`` returns sit at (``rows``, ``cols``), ``cols``
    being the program's decision-variable indices (duplicate positions add up). The values it
    returns beside them must be ``evaluate``'s: Ipopt is handed either (ProgramNlp evaluates
    the constraints with their Jacobian where it expects the Jacobian to be asked for next).
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

    def __init__(self, lower, upper, rows, cols, values, jacobian, both=None):
        self.lower = np.asarray(lower, dtype=float)
        self.upper = np.asarray(upper, dtype=float)
        self.rows = np.asarray(rows, dtype=np.int64)
        self.cols = np.asarray(cols, dtype=np.int64)
        self.values = values  # x -> g
        self.jacobian = jacobian  # x -> entries at (rows, cols)
        # x -> (g, entries) in one evaluation, with g the same to the bit as values(x); None:
        # values and jacobian apart.
        self.both = both


# Jacobian structures of recent programs (_jacobian_structure), newest last.
_STRUCTURES: dict = {}
_STRUCTURES_KEPT = 8
_STRUCTURES_LOCK = threading.Lock()  # a planning thread and a walk may solve at once


def _jacobian_structure(positions: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The distinct Jacobian entries of flat positions (row * n + column, duplicates adding up):
    (rows, columns) as Ipopt takes them and each position's entry (np.unique's inverse). A
    walk's missions of one schedule have the same structure: the last few are kept, found by
    the positions' bytes, and the sort (2-3 ms of a 100 ms solve) is done once for them."""
    key = (n, hash(positions.tobytes()))
    with _STRUCTURES_LOCK:
        kept = _STRUCTURES.pop(key, None)
        if kept is not None and np.array_equal(kept[0], positions):
            _STRUCTURES[key] = kept  # the newest again
            return kept[1]
    keys, inverse = np.unique(positions, return_inverse=True)
    structure = ((keys // n).astype(np.int32), (keys % n).astype(np.int32), inverse)
    for array in structure:
        array.flags.writeable = False  # shared by the programs of this structure
    with _STRUCTURES_LOCK:
        _STRUCTURES[key] = (positions.copy(), structure)
        while len(_STRUCTURES) > _STRUCTURES_KEPT:
            _STRUCTURES.pop(next(iter(_STRUCTURES)))
    return structure


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
        self._rows, self._cols, self._inverse = _jacobian_structure(rows * max(n, 1) + cols, max(n, 1))
        self._costs = self._cost_terms()
        self.iterations = 0
        # Ipopt asks for the constraints at a point and, once it accepts the point, for their
        # Jacobian there. The constraints are computed with their Jacobian (the vectorised
        # blocks' ``both``: one evaluation instead of two) and the entries kept for that
        # Jacobian; after a point whose Jacobian was never asked for (a line search trying
        # points), the constraints alone until the next Jacobian.
        self._kept_x: np.ndarray | None = None
        self._kept_entries: list | None = None
        self._kept_used = True
        self._speculate = True

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
                      lambda x: v.evaluate_with_jacobian(x)[1], v.evaluate_with_jacobian)

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
        if not self._kept_used:  # the last point's Jacobian was never asked for
            self._speculate = False
        self._kept_x, self._kept_entries, self._kept_used = None, None, True
        if not self._speculate:
            return np.concatenate([blk.values(x) for blk in self.blocks])
        values, entries = [], []
        for blk in self.blocks:
            if blk.both is not None:
                g, e = blk.both(x)
                values.append(g)
                entries.append(e)
            else:
                values.append(blk.values(x))
                entries.append(None)
        self._kept_x, self._kept_entries, self._kept_used = np.array(x, dtype=float), entries, False
        return np.concatenate(values)

    def jacobianstructure(self):
        return self._rows, self._cols

    def jacobian(self, x):
        if not self.blocks:
            return np.zeros(0)
        kept = self._kept_entries if self._kept_x is not None and np.array_equal(self._kept_x, x) else None
        self._speculate = True
        if kept is not None:
            self._kept_used = True
            entries = np.concatenate([blk.jacobian(x) if e is None else e for blk, e in zip(self.blocks, kept)])
        else:
            entries = np.concatenate([blk.jacobian(x) for blk in self.blocks])
        return np.bincount(self._inverse, weights=entries, minlength=len(self._rows))

    def intermediate(self, alg_mod, iter_count, *args):
        self.iterations = int(iter_count)
        return True


def solve(prog, x0, options: dict | None = None,
          vectorised: Sequence[VectorisedRows] = (), *, interface: str = "c") -> IpoptResult:
    """Solves ``prog`` from ``x0`` (all its decision variables) with Ipopt and MUMPS.

    Args:
        prog: a pydrake MathematicalProgram.
        x0: the initial point, one value per decision variable in the program's order.
        options: Ipopt options by name (``linear_solver`` defaults to ``mumps``; the Hessian is
            always the limited-memory approximation).
        vectorised: generic bindings evaluated together (VectorisedRows).
        interface: "c": Ipopt's C interface where its library is found (cyipopt's otherwise);
            "cyipopt": cyipopt's ``Problem`` (the same solve, slower; kept to compare).
    """
    library = _ipopt_library() if interface == "c" else None
    if interface not in ("c", "cyipopt"):
        raise ValueError(f"ipopt_mumps: interface {interface!r} (expected 'c' or 'cyipopt')")
    problem_class = None if library is not None else _problem_class()
    clock = time.perf_counter()
    nlp = ProgramNlp(prog, vectorised)
    x0 = np.asarray(x0, dtype=float).reshape(-1)
    if x0.shape != (nlp.num_vars,):
        raise ValueError(f"ipopt_mumps: x0 has {x0.size} values, the program "
                         f"{nlp.num_vars} decision variables")
    if library is not None:
        problem = _CIpopt(library, nlp)
    else:
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
    if library is not None:
        x, code, objective = problem.solve(x0)
    else:
        x, info = problem.solve(x0)
        code, objective = int(info["status"]), float(info["obj_val"])
    return IpoptResult(x=np.asarray(x, dtype=float), status=STATUS.get(code, f"Ipopt status {code}"),
                       status_code=code, iterations=nlp.iterations,
                       objective=objective, solve_time=time.perf_counter() - clock)
