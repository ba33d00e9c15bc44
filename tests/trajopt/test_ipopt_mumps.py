"""Ipopt with MUMPS on a Drake MathematicalProgram (trajopt/ipopt_mumps.py, issue 11 "speed"):
it solves what Drake's IpoptSolver solves, reading bounds, linear constraints and costs from
the program, evaluating generic constraints through their evaluators or, where given, one
vectorised function per group of bindings; and the BLC solved with it passes its verdict."""

import numpy as np
import pytest
from pydrake.solvers import IpoptSolver, MathematicalProgram

from qz_drake.errors import QzError
from qz_drake.trajopt import ipopt_mumps
from qz_drake.trajopt.ipopt_mumps import ProgramNlp, VectorisedRows
from qz_drake.trajopt.parameters import BlcParameters
from qz_drake.trajopt.robot_model import qingzhui
from qz_drake.trajopt.solver import BlcTask, solve_blc

# Hock & Schittkowski problem 71 (Ipopt's own example): its optimum.
HS071_X = np.array([1.0, 4.74299963, 3.82114998, 1.37940829])
HS071_F = 17.0140173


def _hs071(vectorised: bool):
    prog = MathematicalProgram()
    x = prog.NewContinuousVariables(4, "x")
    prog.AddBoundingBoxConstraint(1.0, 5.0, x)
    prog.AddCost(lambda z: z[0] * z[3] * (z[0] + z[1] + z[2]) + z[2], x)
    # Inactive at the optimum (its sum is 10.9); read from the program as a linear row.
    prog.AddLinearConstraint(np.ones((1, 4)), [-np.inf], [20.0], x)
    calls = {"bindings": 0, "vectorised": 0}

    def product(z):
        calls["bindings"] += 1
        return np.array([z[0] * z[1] * z[2] * z[3]])

    def squares(z):
        calls["bindings"] += 1
        return np.array([z @ z])

    b1 = prog.AddConstraint(product, [25.0], [np.inf], x)
    b2 = prog.AddConstraint(squares, [40.0], [40.0], x)
    groups = []
    if vectorised:
        def evaluate(v):
            calls["vectorised"] += 1
            return np.array([np.prod(v), v @ v])

        def with_jacobian(v):
            p = np.prod(v)
            return evaluate(v), np.concatenate([p / v, 2 * v])

        groups = [VectorisedRows([b1, b2], np.repeat([0, 1], 4), np.tile(np.arange(4), 2),
                                 evaluate, with_jacobian)]
    return prog, x, calls, groups


@pytest.mark.parametrize("vectorised", [False, True])
def test_hs071_reaches_its_known_optimum(vectorised):
    prog, x, calls, groups = _hs071(vectorised)
    result = ipopt_mumps.solve(prog, np.array([1.0, 5.0, 5.0, 1.0]), {"tol": 1e-9}, groups)
    assert result.success and result.status == "Success"
    assert result.iterations > 3
    np.testing.assert_allclose(result.x, HS071_X, atol=1e-6)
    assert result.objective == pytest.approx(HS071_F, abs=1e-6)
    if vectorised:  # the bindings' own Python functions are never called
        assert calls["vectorised"] > 0 and calls["bindings"] == 0
    else:
        assert calls["bindings"] > 0


def test_the_same_point_as_drakes_ipopt_on_hs071():
    prog, x, _, _ = _hs071(False)
    x0 = np.array([1.0, 5.0, 5.0, 1.0])
    drake = IpoptSolver().Solve(prog, x0)
    ours = ipopt_mumps.solve(prog, x0, {"tol": 1e-9})
    np.testing.assert_allclose(ours.x, drake.GetSolution(x), atol=1e-5)


def test_the_jacobian_matches_finite_differences_and_each_row_sits_where_the_program_says():
    prog, x, _, groups = _hs071(True)
    nlp = ProgramNlp(prog, groups)
    z = np.array([1.3, 2.1, 3.4, 1.7])
    rows, cols = nlp.jacobianstructure()
    J = np.zeros((nlp.num_constraints, 4))
    J[rows, cols] = nlp.jacobian(z)
    eps = 1e-6
    fd = np.column_stack([(nlp.constraints(z + eps * e) - nlp.constraints(z - eps * e)) / (2 * eps)
                          for e in np.eye(4)])
    np.testing.assert_allclose(J, fd, atol=1e-5)
    # Rows in order: the linear row, then the vectorised pair, with the program's bounds.
    np.testing.assert_allclose(nlp.constraints(z), [z.sum(), np.prod(z), z @ z])
    np.testing.assert_array_equal(nlp.constraint_lower, [-np.inf, 25.0, 40.0])
    np.testing.assert_array_equal(nlp.constraint_upper, [20.0, np.inf, 40.0])
    np.testing.assert_array_equal(nlp.lower, np.ones(4))
    # The generic cost's gradient through AutoDiff.
    g = nlp.gradient(z)
    fd_g = [(nlp.objective(z + eps * e) - nlp.objective(z - eps * e)) / (2 * eps) for e in np.eye(4)]
    np.testing.assert_allclose(g, fd_g, atol=1e-5)


def test_quadratic_costs_and_equalities_are_read_from_the_program():
    # min |x - (1, 2, 3)|^2 subject to x0 + x1 + x2 = 3: x = (0, 1, 2).
    prog = MathematicalProgram()
    x = prog.NewContinuousVariables(3)
    prog.AddQuadraticErrorCost(np.eye(3), [1.0, 2.0, 3.0], x)
    prog.AddLinearEqualityConstraint(np.ones((1, 3)), [3.0], x)
    result = ipopt_mumps.solve(prog, np.zeros(3))
    assert result.success
    np.testing.assert_allclose(result.x, [0.0, 1.0, 2.0], atol=1e-7)


def test_a_program_ipopt_cannot_take_is_refused_by_name():
    prog = MathematicalProgram()
    x = prog.NewContinuousVariables(3)
    prog.AddLorentzConeConstraint(x)
    with pytest.raises(ValueError, match="lorentz cone"):
        ipopt_mumps.solve(prog, np.ones(3))
    prog = MathematicalProgram()
    prog.NewContinuousVariables(2)
    with pytest.raises(ValueError, match="x0 has 3 values"):
        ipopt_mumps.solve(prog, np.ones(3))


def test_an_infeasible_program_is_a_status_not_a_crash():
    prog = MathematicalProgram()
    x = prog.NewContinuousVariables(2)
    prog.AddConstraint(lambda z: np.array([z @ z]), [-np.inf], [1.0], x)
    prog.AddLinearConstraint(np.ones((1, 2)), [3.0], [np.inf], x)
    result = ipopt_mumps.solve(prog, np.zeros(2))
    assert not result.success
    assert result.status == "Local infeasibility"


def test_the_blc_solves_the_same_task_with_both_linear_solvers():
    task = BlcTask(target=(1.0, 0.0, 0.0), duration=2.0)
    robot = qingzhui()
    mumps = solve_blc(task, robot, None, BlcParameters(time_limit=60.0))
    spral = solve_blc(task, robot, None, BlcParameters(time_limit=60.0, linear_solver="spral"))
    assert mumps.success, mumps.reason
    assert spral.success, spral.reason
    assert mumps.params.linear_solver == "mumps"
    assert mumps.max_violation <= mumps.params.violation_tolerance
    assert mumps.dense is not None and mumps.dense.passed
    # Both reach the target: the end of the body's path.
    for s in (mumps, spral):
        np.testing.assert_allclose(s.body_position.value(s.duration).ravel()[:2], [1.0, 0.0],
                                   atol=1e-3)
    # Deterministic: the same task solved again gives the same plan, bit for bit.
    again = solve_blc(task, robot, None, BlcParameters(time_limit=60.0))
    assert np.array_equal(again.x, mumps.x)


def test_an_unknown_linear_solver_is_refused_by_name():
    with pytest.raises(QzError, match="blc.linear_solver.*ma57"):
        BlcParameters(linear_solver="ma57")


def test_vectorised_rows_must_be_constraints_of_the_program():
    prog, x, _, groups = _hs071(True)
    other, _, _, other_groups = _hs071(True)
    with pytest.raises(ValueError, match="not a constraint of the program"):
        ProgramNlp(prog, other_groups)
    bad = VectorisedRows(groups[0].bindings, groups[0].rows + 5, groups[0].cols,
                         groups[0].evaluate, groups[0].evaluate_with_jacobian)
    with pytest.raises(ValueError, match="do not fit"):
        ProgramNlp(prog, [bad])


def test_the_blc_program_for_mumps_is_a_whole_drake_program_its_rows_agree_with():
    """Built without Drake's IpoptSolver helpers, the BLC's program still evaluates on its own
    (each binding through Drake), and its bindings' rows are the vectorised rows ipopt_mumps
    evaluates in their place."""
    from qz_drake.trajopt.formulation import BlcFormulation
    from qz_drake.trajopt.gait import make_gait
    from qz_drake.trajopt.initial_guess import straight_line_guess
    from qz_drake.trajopt.solver import standing_start
    from qz_drake.trajopt.terrain import as_terrain

    robot, terrain = qingzhui(), as_terrain(None)
    params = BlcParameters()
    schedule = make_gait(robot.gaits[0], robot.num_legs, 2.0, stand_duration=params.stand_duration)
    start, rpy, feet = standing_start(robot, terrain)
    f = BlcFormulation(robot, terrain, params, schedule, start_position=start, start_rpy=rpy,
                       start_feet=feet, target=(1.0, 0.0, 0.0))
    x = straight_line_guess(f) + 1e-3 * np.random.default_rng(0).standard_normal(
        f.variables.num_vars)
    program = f.build_program(drake_ipopt=False)
    assert len(program.vectorised) == len(f.nonlinear)
    for rows in program.vectorised:
        through_drake = np.concatenate([program.prog.EvalBinding(b, x) for b in rows.bindings])
        np.testing.assert_allclose(through_drake, rows.evaluate(x), rtol=0, atol=1e-12)
    nlp = ProgramNlp(program.prog, program.vectorised)
    assert nlp.num_constraints == f.num_constraints


def test_ipopt_loads_without_scipy_optimize_and_cyipopt_stays_whole():
    """The first solve in a process does not import cyipopt's SciPy interface (scipy.optimize,
    0.3 s); a later ``import cyipopt`` is the whole package, with the same compiled module and
    exception classes (run in a fresh interpreter: the test's own imports would hide it)."""
    import subprocess
    import sys

    script = """
import sys
import numpy as np
from pydrake.solvers import MathematicalProgram
from qz_drake.trajopt import ipopt_mumps
prog = MathematicalProgram()
x = prog.NewContinuousVariables(2)
prog.AddQuadraticCost(np.eye(2), -np.ones(2), x)
result = ipopt_mumps.solve(prog, np.zeros(2), {"print_level": 0})
assert result.success and np.allclose(result.x, 1.0, atol=1e-6), result
assert "scipy.optimize" not in sys.modules
import cyipopt
import cyipopt.exceptions
assert cyipopt.Problem is ipopt_mumps._problem_class()
assert cyipopt.CyIpoptEvaluationError is cyipopt.exceptions.CyIpoptEvaluationError
assert np.allclose(cyipopt.minimize_ipopt(lambda z: ((z - 2.0) ** 2).sum(), np.zeros(2)).x, 2.0, atol=1e-6)
print("ok")
"""
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.strip().splitlines()[-1] == "ok"


def test_ipopts_c_interface_solves_as_cyipopt_does_bit_for_bit():
    """The solve goes through Ipopt's C interface (the library cyipopt-wheels ships is found
    here) and gives cyipopt's solve exactly: the same plan, iterations and status."""
    from qz_drake.trajopt import solver

    assert ipopt_mumps._ipopt_library() is not None
    task = BlcTask(target=(1.0, 0.0, 0.0), duration=2.0)
    robot = qingzhui()
    original = ipopt_mumps.solve
    results = {}
    try:
        for interface in ("cyipopt", "c"):
            def through(*args, interface=interface, **kwargs):
                return original(*args, interface=interface, **kwargs)

            solver.ipopt_mumps.solve = through
            results[interface] = solve_blc(task, robot, None, BlcParameters(time_limit=60.0))
    finally:
        solver.ipopt_mumps.solve = original
    c, cy = results["c"], results["cyipopt"]
    assert c.success and cy.success
    assert np.array_equal(c.x, cy.x)
    assert (c.iterations, c.status) == (cy.iterations, cy.status)
    prog, _, _, groups = _hs071(True)
    x0 = np.array([1.0, 5.0, 5.0, 1.0])
    a, b = (ipopt_mumps.solve(prog, x0, {"tol": 1e-9}, groups, interface=i) for i in ("c", "cyipopt"))
    assert np.array_equal(a.x, b.x) and (a.iterations, a.status_code, a.objective) == (b.iterations, b.status_code,
                                                                                      b.objective)


def test_an_error_in_a_constraint_is_raised_from_the_solve_and_a_bad_option_is_refused():
    prog, _, _, groups = _hs071(True)
    calls = {"n": 0}
    group = groups[0]

    def failing(v):
        calls["n"] += 1
        if calls["n"] == 3:
            raise ArithmeticError("constraint blew up")
        return group.evaluate_with_jacobian(v)

    broken = VectorisedRows(group.bindings, group.rows, group.cols, group.evaluate, failing)
    with pytest.raises(ArithmeticError, match="blew up"):
        ipopt_mumps.solve(prog, np.array([1.0, 5.0, 5.0, 1.0]), {}, [broken])
    with pytest.raises(TypeError, match="no_such_option"):
        ipopt_mumps.solve(prog, np.array([1.0, 5.0, 5.0, 1.0]), {"no_such_option": 3}, groups)
    with pytest.raises(ValueError, match="interface 'fortran'"):
        ipopt_mumps.solve(prog, np.array([1.0, 5.0, 5.0, 1.0]), {}, groups, interface="fortran")
