"""The BLC with the legs' clearance as one smooth-minimum row per leg and sample
(BlcParameters.leg_clearance_softmin) wherever the code solves with its defaults: a setup for
``trial_drives.py`` (stored episodes re-run with it, each mission's outcome against its label),
and a scenario's walk with and without it.

    python benchmarks/trial_drives.py data/capability_episodes 40 OUT.jsonl --uniform \\
        --control-mode torque --time-step 0.002 --setup blc_softmin:use --workers 1
    python benchmarks/blc_softmin.py data/drives_walks/demo_drives_4ms.yaml [--time-step 0.006] \\
        [--sharpness 300] [--runs 1]

``use(sharpness)`` makes every ``solver.solve_blc`` call solve with that sharpness (the caller's
other parameters kept) and returns the function that undoes it. The walk (a scenario file has no
BLC section) runs in fresh interpreters, without the sharpness and with it, alternating, and
prints one JSON line per walk: wall time, real-time factor, the BLC's time, the verdict.
"""

import argparse
import dataclasses
import subprocess
import sys

SHARPNESS = 300.0  # [1/m]


def use(sharpness: float = SHARPNESS):
    import qz_drake.trajopt.solver as solver
    from qz_drake.trajopt.parameters import BlcParameters

    original = solver.solve_blc

    def solve_blc(task, robot=None, terrain=None, params=None, *args, **kwargs):
        params = dataclasses.replace(params or BlcParameters(), leg_clearance_softmin=sharpness)
        return original(task, robot, terrain, params, *args, **kwargs)

    solver.solve_blc = solve_blc

    def undo():
        solver.solve_blc = original
    return undo


_WALK = r"""
import dataclasses, json, sys
sys.path.insert(0, sys.argv[4])
from qz_drake.config import load_scenario
from qz_drake.planning.capplanner_route import route_source_for
from qz_drake.simulation import walk
import blc_softmin
if sys.argv[2] != "none":
    blc_softmin.use(float(sys.argv[2]))
scenario = load_scenario(sys.argv[1])
if sys.argv[3] != "none":
    scenario = dataclasses.replace(scenario, simulation=dataclasses.replace(scenario.simulation,
                                                                            time_step=float(sys.argv[3])))
m = walk(scenario, route_source=route_source_for(scenario)).metrics
print(json.dumps({"sharpness": None if sys.argv[2] == "none" else float(sys.argv[2]),
                  "time_step": scenario.simulation.time_step,
                  "success": m["success"], "reason": m["reason"], "missions": m["missions"],
                  "wall_s": m["wall_time_s"], "realtime_factor": m["realtime_factor"],
                  "blc_solve_time_s": m["blc_solve_time_s"], "final_xy_error_m": m["final_xy_error_m"],
                  "max_joint_error_deg": m["max_joint_error_deg"], "max_foot_slip_m": m["max_foot_slip_m"]}))
"""


def main(argv=None) -> int:
    from pathlib import Path

    parser = argparse.ArgumentParser(description="a scenario's walk with and without the smooth-minimum rows")
    parser.add_argument("scenario")
    parser.add_argument("--sharpness", type=float, default=SHARPNESS)
    parser.add_argument("--time-step", type=float, default=None, help="the plant's step instead of the file's [s]")
    parser.add_argument("--runs", type=int, default=1)
    args = parser.parse_args(argv)
    here = str(Path(__file__).resolve().parent)
    step = "none" if args.time_step is None else repr(args.time_step)
    for _ in range(args.runs):
        for sharpness in ("none", repr(args.sharpness)):
            run = subprocess.run([sys.executable, "-c", _WALK, args.scenario, sharpness, step, here],
                                 capture_output=True, text=True)
            if run.returncode:
                sys.exit(run.stderr[-3000:])
            print(run.stdout.strip().splitlines()[-1], flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
