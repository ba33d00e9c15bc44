"""BLC solve times (`qz bench blc`'s cases) from two source trees, side by side, with a digest
of each case's plan.

    git worktree add --detach /tmp/base COMMIT
    python benchmarks/blc_side_by_side.py /tmp/base . [--runs 2] [--repeats 3] [--quick]
    python benchmarks/blc_side_by_side.py . . --new-blc leg_clearance_softmin=300

Each run is a fresh interpreter importing qz_drake from the tree given (the editable install's
finder taken out of sys.meta_path); it solves a flat 1 m task once (the process's cold start,
timed apart), then every case of bench_blc (``--quick``: its quick suite) ``--repeats`` times,
each case's time the median of its repeats (the whole ``solve_blc`` call). The trees alternate
(base, new, base, new, ...). Prints each case's medians over the runs, their ratio (new /
base), Ipopt's iterations and whether the two trees' plans are the same bit for bit (a SHA-256
of the decision vector). ``--base-blc`` / ``--new-blc NAME=VALUE`` (repeatable; the value as
JSON) solve that side's cases with those BlcParameters changed (one tree against itself under
another setting); the cold start keeps the defaults.
"""

import argparse
import json
import statistics

from tree_runs import blc_changes, run_in_tree

_RUN = r"""
import hashlib, json, statistics, time
repeats, quick, changes = int(sys.argv[2]), sys.argv[3] == "1", json.loads(sys.argv[4])
clock = time.perf_counter()
from qz_drake.trajopt.solver import BlcTask, solve_blc
from qz_drake.trajopt.robot_model import qingzhui
solve_blc(BlcTask(target=(1.0, 0.0, 0.0), duration=2.0), qingzhui())
cold = time.perf_counter() - clock
import dataclasses
import bench_blc
from qz_drake.trajopt.parameters import BlcParameters
params = dataclasses.replace(BlcParameters(), **changes) if changes else None
out = {"cold_s": cold, "cases": {}}
for name, (robot, terrain, task) in bench_blc.all_cases(quick).items():
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        s = solve_blc(task, robot, terrain, params)
        times.append(time.perf_counter() - t)
    out["cases"][name] = {"s": statistics.median(times), "iterations": int(s.iterations), "success": bool(s.success),
                          "digest": hashlib.sha256(s.x.tobytes()).hexdigest()[:12]}
print(json.dumps(out))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("base")
    parser.add_argument("new")
    parser.add_argument("--runs", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--base-blc", action="append", default=[], metavar="NAME=VALUE",
                        help="a BlcParameters field for the base tree's cases (value as JSON)")
    parser.add_argument("--new-blc", action="append", default=[], metavar="NAME=VALUE",
                        help="a BlcParameters field for the new tree's cases (value as JSON)")
    args = parser.parse_args()
    changes = {"base": blc_changes(args.base_blc, "--base-blc"), "new": blc_changes(args.new_blc, "--new-blc")}
    results = {"base": [], "new": []}
    for _ in range(args.runs):
        for label, root in (("base", args.base), ("new", args.new)):
            results[label].append(run_in_tree(root, _RUN, args.repeats, "1" if args.quick else "0",
                                              json.dumps(changes[label])))
            print(label, "cold", round(results[label][-1]["cold_s"], 3), flush=True)
    base, new = results["base"], results["new"]
    print(f"{'case':34s} {'base s':>8s} {'new s':>8s} {'ratio':>6s}  it.  same plan")
    ratios = []
    for name in base[0]["cases"]:
        b = statistics.median(r["cases"][name]["s"] for r in base)
        n = statistics.median(r["cases"][name]["s"] for r in new)
        same = all(r["cases"][name]["digest"] == base[0]["cases"][name]["digest"] for r in base + new)
        ratios.append(n / b)
        print(f"{name:34s} {b:8.3f} {n:8.3f} {n / b:6.2f} {new[0]['cases'][name]['iterations']:4d}  {same}"
              f"{'' if new[0]['cases'][name]['success'] else '  (not solved)'}")
    cold_b = statistics.median(r["cold_s"] for r in base)
    cold_n = statistics.median(r["cold_s"] for r in new)
    print(f"cold start (import + first solve) {cold_b:.3f} -> {cold_n:.3f} s ({cold_n / cold_b:.2f}); "
          f"median case ratio {statistics.median(ratios):.3f}")


if __name__ == "__main__":
    main()
