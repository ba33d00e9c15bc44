"""Fig. 9 walks re-walked from two source trees, side by side: the wall time of each and whether
the two walks are the same walk (issue 53: a change that should not move a label, measured on
whole walks).

    git worktree add --detach /tmp/base COMMIT
    python benchmarks/walks_side_by_side.py /tmp/base . --run data/capplanner_tuning_s54/SETTING \\
        [--tasks stairs-hard-1000-capplanner,...] [--count 4] [--json OUT.jsonl]

``--run`` is a results folder of ``qz experiment capplanner-vs-astar``, ``tune-capplanner`` or
``tune-astar``: its settings.json gives the walks' ExperimentConfig and its records the tasks
(``--tasks``: those keys; else the first ``--count`` records that walked in under 90 s, short
walks for a quick check). Each task is walked by ``run_task`` in a fresh interpreter of each
tree (tree_runs.run_in_tree), base first, then new. Two walks are the same when their records
are equal but for the timings (wall, planning and route-check times): the outcome, every
count, the path to the centimetre and, with record_missions, every mission's start, feet,
target, outcome and time. Prints one line per task and the median ratio of the wall times
(new / base); ``--json`` appends each pair's figures.
"""

import argparse
import json
import statistics
import sys
from pathlib import Path

from tree_runs import run_in_tree

_RUN = r"""
import json, sys, time
from qz_drake.experiments.fig9.results import read_config
from qz_drake.experiments.fig9.tasks import TaskSpec, run_task
terrain, difficulty, seed, planner = json.loads(sys.argv[3])
clock = time.perf_counter()
record = run_task(TaskSpec(terrain, difficulty, int(seed), planner), read_config(sys.argv[2]))
record["run_s"] = time.perf_counter() - clock
print(json.dumps(record))
"""

# Fields that are timings: left out of the comparison.
TIMINGS = ("wall_time_s", "planning_time_s", "route_check_time_s", "run_s")


def same_walk(a: dict, b: dict) -> bool:
    """Whether two records of one task are the same walk (equal but for TIMINGS)."""
    strip = ({k: v for k, v in r.items() if k not in TIMINGS} for r in (a, b))
    return json.dumps(next(strip), sort_keys=True) == json.dumps(next(strip), sort_keys=True)


def _tasks(run: Path, keys, count: int) -> list:
    records = [json.loads(line) for line in (run / "results.jsonl").read_text().splitlines() if line.strip()]
    if keys:
        by_key = {r["key"]: r for r in records}
        missing = [k for k in keys if k not in by_key]
        if missing:
            sys.exit(f"walks_side_by_side: --tasks {','.join(missing)}: not in {run / 'results.jsonl'}")
        chosen = [by_key[k] for k in keys]
    else:
        chosen = [r for r in records if r.get("wall_time_s", 1e9) < 90.0][:count]
    return [(r["terrain"], r["difficulty"], r["seed"], r["planner"]) for r in chosen]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("base")
    parser.add_argument("new")
    parser.add_argument("--run", required=True, type=Path)
    parser.add_argument("--tasks", default="", help="comma-separated task keys of the run")
    parser.add_argument("--count", type=int, default=4)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    if not (args.run / "settings.json").is_file():
        sys.exit(f"walks_side_by_side: --run {args.run}: no settings.json there")
    ratios, same = [], 0
    tasks = _tasks(args.run, [k for k in args.tasks.split(",") if k], args.count)
    for task in tasks:
        base, new = (run_in_tree(tree, _RUN, str(args.run.resolve()), json.dumps(task)) for tree in (args.base, args.new))
        equal = same_walk(base, new)
        same += equal
        ratio = new["run_s"] / base["run_s"]
        ratios.append(ratio)
        print(f"{'-'.join(map(str, task)):36s} {'same walk' if equal else 'DIFFERENT'}  success {base['success']} / "
              f"{new['success']}  {base['run_s']:.1f} -> {new['run_s']:.1f} s ({ratio:.2f}x)", flush=True)
        if args.json is not None:
            with args.json.open("a") as f:
                f.write(json.dumps({"task": task, "same": equal, "base_s": base["run_s"], "new_s": new["run_s"],
                                    "base_success": base["success"], "new_success": new["success"]}) + "\n")
    if ratios:
        print(f"{same} of {len(ratios)} the same walk; wall time new / base: median {statistics.median(ratios):.3f}")
    return 0 if same == len(ratios) else 1


if __name__ == "__main__":
    raise SystemExit(main())
