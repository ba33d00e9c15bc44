"""The BLC's program solved by Ipopt with MUMPS (the default, ipopt_mumps.py), by Drake's
IpoptSolver with SPRAL and by SNOPT (both in Drake's wheel), side by side on the bench cases
(issue 11, "speed"): one program, the same straight-line guess, the same verdict
(``solver._verdict``: constraints, dense check). Run:

    python benchmarks/blc_solvers.py [CASE_SUBSTRING ...]

Prints a JSON line per case: success, wall time of the whole call, solver time and the ratios
of SPRAL's and SNOPT's times to MUMPS's.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

DEFAULT_CASES = ("qz_flat_1m_2s", "qz_flat_2m_3s", "qz_slope_15deg", "hyq_flat_1m_2s")


def snopt_solve(robot, terrain, task, params) -> dict:
    from pydrake.solvers import SnoptSolver, SolverOptions

    from qz_drake.trajopt.formulation import BlcFormulation
    from qz_drake.trajopt.initial_guess import straight_line_guess
    from qz_drake.trajopt.solver import _resolve, _verdict
    from qz_drake.trajopt.terrain import as_terrain

    clock = time.perf_counter()
    terrain = as_terrain(terrain)
    start, rpy, feet, target, schedule = _resolve(task, robot, terrain, params)
    f = BlcFormulation(robot, terrain, params, schedule, start_position=start, start_rpy=rpy,
                       start_feet=feet, target=target, start_velocity=task.start_velocity)
    x0 = straight_line_guess(f)
    program = f.build_program()
    prog, x_vars, counter = program.prog, program.x_vars, program.counter
    options = SolverOptions()
    sid = SnoptSolver.id()
    # Ipopt's tolerances in SNOPT's terms (the verdict checks the result the same way).
    options.SetOption(sid, "Major optimality tolerance", params.tolerance)
    options.SetOption(sid, "Major feasibility tolerance", params.constraint_tolerance * 0.01)
    options.SetOption(sid, "Time limit", params.time_limit)
    options.SetOption(sid, "Major iterations limit", params.max_iterations)
    solver_clock = time.perf_counter()
    result = SnoptSolver().Solve(prog, x0, options)
    solver_time = time.perf_counter() - solver_clock
    # SNOPT info 1: optimality conditions satisfied, the verdict's "Success".
    status = "Success" if result.is_success() else f"SNOPT: {result.get_solution_result()}"
    solution = _verdict(f, result.GetSolution(x_vars), status, counter["jacobians"], clock,
                        solver_time)
    return {"success": bool(solution.success), "time_s": round(time.perf_counter() - clock, 3),
            "solver_s": round(solver_time, 3), "snopt_info": result.get_solver_details().info,
            "reason": solution.reason[:120]}


def main(only: list[str]) -> None:
    from bench_blc import all_cases

    from qz_drake.trajopt.parameters import BlcParameters
    from qz_drake.trajopt.solver import solve_blc

    params = BlcParameters()
    for name, (robot, terrain, task) in all_cases().items():
        if not (any(o in name for o in only) if only else name in DEFAULT_CASES):
            continue
        row = {"case": name}
        for label, linear_solver in (("ipopt_mumps", "mumps"), ("ipopt_spral", "spral")):
            s = solve_blc(task, robot, terrain, dataclasses.replace(params,
                                                                     linear_solver=linear_solver))
            row[label] = {"success": bool(s.success), "time_s": round(s.solve_time, 3),
                          "solver_s": round(s.ipopt_time, 3), "iterations": s.iterations}
        row["snopt"] = snopt_solve(robot, terrain, task, params)
        base = row["ipopt_mumps"]["time_s"]
        row["ratio_spral_over_mumps"] = round(row["ipopt_spral"]["time_s"] / base, 2)
        row["ratio_snopt_over_mumps"] = round(row["snopt"]["time_s"] / base, 2)
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
