"""BLC solve times on a fixed suite (issue 3): `qz bench blc --json`.

Each case is one BlcTask solved ``repeats`` times from the straight-line guess (the solver is
deterministic, so the repeats measure time only); reported: median solve time (the whole
``solve_blc`` call: building the program, Ipopt, the verdict), Ipopt iterations, success, worst
constraint violation, sizes and the failure reason when there is one.

Qingzhui cases run on gridded HeightMaps from ``qz_drake.terrain`` (0.05 m cells, the BLC's
smooth interpolant over them), as the walking pipeline does; the start is the robot standing
with its CoM over (0, 0) and its front (MF) foot at x = 0.75 m, so the paper's "two stairs
0.4 m wide at 0.5 m in front of Qingzhui" puts the first stair nose at x = 1.25 m. (At x = 0.5 m
the front foot would start on the stair, and a 0.2 m rise under it alone is outside its box.) HyQ cases use TOWR's closed-form terrains and trot, so the
numbers compare with TOWR's on its own tasks (issue 3 lists TOWR's times on this machine).
"""

from __future__ import annotations

import statistics

import numpy as np

from qz_drake.config import TerrainConfig
from qz_drake.station import make_heightmap
from qz_drake.trajopt import terrain as closed_form
from qz_drake.trajopt.formulation import clear_schedule_parts
from qz_drake.trajopt.parameters import BlcParameters
from qz_drake.trajopt.robot_model import hyq, qingzhui
from qz_drake.trajopt.solver import BlcTask, solve_blc

STAIR_RISES = (0.05, 0.10, 0.15, 0.20)
STAIR_DISTANCES = (1.0, 1.5, 2.0)
# First stair nose: 0.5 m ahead of the front foot of Qingzhui standing over the origin. [m]
STAIRS_START_X = 1.25


def _grid(kind: str, **params):
    return make_heightmap(TerrainConfig(kind=kind, params=params))


def qingzhui_cases(quick: bool = False) -> dict:
    """name -> (robot, terrain, task)."""
    robot = qingzhui("nominal")
    cases = {
        "qz_flat_1m_2s": (robot, None, BlcTask(target=(1.0, 0.0, 0.0), duration=2.0)),
        "qz_flat_2m_3s": (robot, None, BlcTask(target=(2.0, 0.0, 0.0), duration=3.0)),
        "qz_slope_15deg": (robot, _grid("slope", angle_deg=15.0, start_x=0.5),
                           BlcTask(target=(1.5, 0.0, 0.0), duration=3.0)),
        "qz_gap_0.3m": (robot, _grid("gap", width=0.3, depth=0.5, start_x=0.9),
                        BlcTask(target=(1.5, 0.0, 0.0), duration=3.0)),
    }
    rises = (0.10,) if quick else STAIR_RISES
    distances = (1.0,) if quick else STAIR_DISTANCES
    for rise in rises:
        terrain = _grid("stairs", rise=rise, run=0.4, count=2, start_x=STAIRS_START_X)
        for distance in distances:
            duration = round(1.0 + distance / 0.5, 1)
            cases[f"qz_stairs_rise{rise:.2f}_d{distance:.1f}"] = (
                robot, terrain, BlcTask(target=(distance, 0.0, 0.0), duration=duration))
    return cases


def hyq_cases(quick: bool = False) -> dict:
    robot = hyq()
    cases = {
        "hyq_flat_1m_2s": (robot, None, BlcTask(target=(1.0, 0.0, 0.0), duration=2.0)),
        "hyq_flat_2m_3s": (robot, None, BlcTask(target=(2.0, 0.0, 0.0), duration=3.0)),
    }
    if not quick:
        cases.update({
            "hyq_block_0.5m": (robot, closed_form.block(start_x=0.7, height=0.5),
                               BlcTask(target=(1.0, 0.0, 0.0), duration=2.4)),
            "hyq_stairs_towr": (robot, closed_form.stairs(start_x=1.0, run=0.4, rises=(0.2, 0.2)),
                                BlcTask(target=(1.0, 0.0, 0.0), duration=2.4)),
            "hyq_gap_towr": (robot, closed_form.gap(start_x=1.0, end_x=1.5),
                             BlcTask(target=(1.0, 0.0, 0.0), duration=2.4)),
        })
    return cases


def impossible_cases() -> dict:
    robot = qingzhui("nominal")
    return {
        "qz_impossible_5m_1s": (robot, None, BlcTask(target=(5.0, 0.0, 0.0), duration=1.0)),
        "qz_impossible_wall_1m": (robot, _grid("step", height=1.0, start_x=1.0),
                                  BlcTask(target=(1.5, 0.0, 0.0), duration=3.0)),
    }


def solve_case(robot, terrain, task, repeats: int, params=None) -> dict:
    """The first solve builds the schedule's parts (formulation.ScheduleParts, cleared
    before it: "cold"), the later ones reuse them, as a walk's missions do ("warm")."""
    times, solution = [], None
    clear_schedule_parts()
    for _ in range(repeats):
        solution = solve_blc(task, robot, terrain, params)
        times.append(solution.solve_time)
    dense = solution.dense
    return {"solve_time_s_median": statistics.median(times), "solve_times_s": times,
            "cold_solve_time_s": times[0],
            "warm_solve_time_s_median": statistics.median(times[1:]) if repeats > 1 else None,
            "iterations": solution.iterations, "success": bool(solution.success),
            "max_violation": solution.max_violation, "n_vars": solution.num_variables,
            "n_constraints": solution.num_constraints, "reason": solution.reason,
            "dense": None if dense is None else dense.summary()}


def stairs_success_map(results: dict) -> dict:
    """Fig. 5 as a table: rise -> distance -> (success, median time)."""
    table = {}
    for rise in STAIR_RISES:
        for distance in STAIR_DISTANCES:
            r = results.get(f"qz_stairs_rise{rise:.2f}_d{distance:.1f}")
            if r is not None:
                table.setdefault(f"{rise:.2f}", {})[f"{distance:.1f}"] = {
                    "success": r["success"], "solve_time_s": r["solve_time_s_median"]}
    return table


def all_cases(quick: bool = False) -> dict:
    return {**qingzhui_cases(quick), **hyq_cases(quick), **impossible_cases()}


def run(repeats: int = 5, quick: bool = False, params=None) -> dict:
    if quick:
        repeats = 1
    results = {name: solve_case(*case, repeats, params) for name, case in all_cases(quick).items()}
    results["stairs_success_map"] = stairs_success_map(results)
    # Which Ipopt solved them: MUMPS through the cyipopt wheel (the default) or Drake's SPRAL.
    results["linear_solver"] = (params or BlcParameters()).linear_solver
    return results


if __name__ == "__main__":
    import json
    import sys

    out = run(repeats=int(sys.argv[1]) if len(sys.argv) > 1 else 1, quick="--quick" in sys.argv)
    print(json.dumps(out, indent=1, default=lambda o: np.asarray(o).tolist()))
