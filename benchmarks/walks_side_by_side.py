"""Fig. 9 walks re-walked from two source trees, side by side: the wall time of each and whether
the two walks are the same walk (issue 53: a change that should not move a label, measured on
whole walks).

    git worktree add --detach /tmp/base COMMIT
    python benchmarks/walks_side_by_side.py /tmp/base . --run data/capplanner_tuning_s54/SETTING \\
        [--tasks stairs-hard-1000-capplanner,...] [--count 4] [--json OUT.jsonl]
    python benchmarks/walks_side_by_side.py . . --run RUN --new-setting control_mode=position \\
        --new-setting time_step=0.004 [--stored-base]

``--run`` is a results folder of ``qz experiment capplanner-vs-astar``, ``tune-capplanner`` or
``tune-astar``: its settings.json gives the walks' ExperimentConfig and its records the tasks
(``--tasks``: those keys; else the first ``--count`` records that walked in under 90 s, short
walks for a quick check). Each task is walked by ``run_task`` in a fresh interpreter of each
tree (tree_runs.run_in_tree), base first, then new. Two walks are the same when their records
are equal but for the timings (wall, planning and route-check times): the outcome, every
count, the path to the centimetre and, with record_missions, every mission's start, feet,
target, outcome and time. Prints one line per task and the median ratio of the wall times
(new / base); ``--json`` appends each pair's figures.

``--new-setting FIELD=VALUE`` (repeatable) walks the new side with that ExperimentConfig field
changed (a number, true / false, or text), so that one tree can be compared with itself under
another setting, e.g. the drives' PD (a change that does move labels: then the question is how
many walks keep their outcome). ``--stored-base`` takes the run's stored record as the base
walk instead of walking it again (for outcomes only: its wall time is from another run, so no
ratio is printed for it).
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
import dataclasses
terrain, difficulty, seed, planner = json.loads(sys.argv[3])
config = dataclasses.replace(read_config(sys.argv[2]), **json.loads(sys.argv[4]))
clock = time.perf_counter()
record = run_task(TaskSpec(terrain, difficulty, int(seed), planner), config)
record["run_s"] = time.perf_counter() - clock
print(json.dumps(record))
"""

# Fields that are timings: left out of the comparison.
TIMINGS = ("wall_time_s", "planning_time_s", "route_check_time_s", "run_s")


def same_walk(a: dict, b: dict) -> bool:
    """Whether two records of one task are the same walk (equal but for TIMINGS)."""
    strip = ({k: v for k, v in r.items() if k not in TIMINGS} for r in (a, b))
    return json.dumps(next(strip), sort_keys=True) == json.dumps(next(strip), sort_keys=True)


def parse_settings(pairs) -> dict:
    """``--new-setting`` FIELD=VALUE pairs as ExperimentConfig fields: a number, true / false,
    or the text itself."""
    import dataclasses

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from qz_drake.experiments.fig9.tasks import ExperimentConfig

    fields = {f.name for f in dataclasses.fields(ExperimentConfig)}
    settings = {}
    for pair in pairs:
        name, sep, text = pair.partition("=")
        if not sep or name not in fields:
            sys.exit(f"walks_side_by_side: --new-setting {pair!r}: expected FIELD=VALUE with an ExperimentConfig "
                     f"field")
        lowered = text.lower()
        if lowered in ("true", "false"):
            settings[name] = lowered == "true"
        else:
            try:
                settings[name] = int(text) if text.lstrip("-").isdigit() else float(text)
            except ValueError:
                settings[name] = text
    return settings


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
    parser.add_argument("--new-setting", action="append", default=[], metavar="FIELD=VALUE",
                        help="walk the new side with this ExperimentConfig field changed (repeatable)")
    parser.add_argument("--stored-base", action="store_true",
                        help="the run's stored record is the base walk (outcomes only, no time ratio)")
    args = parser.parse_args()
    if not (args.run / "settings.json").is_file():
        sys.exit(f"walks_side_by_side: --run {args.run}: no settings.json there")
    settings = json.dumps(parse_settings(args.new_setting))
    stored = {r["key"]: r for r in (json.loads(line) for line in (args.run / "results.jsonl").read_text().splitlines()
                                    if line.strip())}
    ratios, same, kept, walked = [], 0, 0, 0
    tasks = _tasks(args.run, [k for k in args.tasks.split(",") if k], args.count)
    for task in tasks:
        if args.stored_base:
            base = stored["-".join(map(str, task))]
        else:
            base = run_in_tree(args.base, _RUN, str(args.run.resolve()), json.dumps(task), "{}")
        new = run_in_tree(args.new, _RUN, str(args.run.resolve()), json.dumps(task), settings)
        walked += 1
        equal = same_walk(base, new)
        same += equal
        kept += base["success"] == new["success"] and base.get("reason") == new.get("reason")
        if args.stored_base:
            timing = f"{new['run_s']:.1f} s"
        else:
            ratios.append(new["run_s"] / base["run_s"])
            timing = f"{base['run_s']:.1f} -> {new['run_s']:.1f} s ({ratios[-1]:.2f}x)"
        print(f"{'-'.join(map(str, task)):36s} {'same walk' if equal else 'DIFFERENT'}  success {base['success']} / "
              f"{new['success']}  {base.get('reason') or '-'} / {new.get('reason') or '-'}  {timing}", flush=True)
        if args.json is not None:
            with args.json.open("a") as f:
                f.write(json.dumps({"task": task, "same": equal, "base_s": base.get("run_s"), "new_s": new["run_s"],
                                    "base_success": base["success"], "new_success": new["success"],
                                    "base_reason": base.get("reason", ""), "new_reason": new.get("reason", ""),
                                    "new_setting": json.loads(settings), "stored_base": args.stored_base,
                                    "base_sim_s": _sim_time(base), "new_sim_s": _sim_time(new),
                                    **{f"{side}_{k}": r.get(k) for side, r in (("base", base), ("new", new))
                                       for k in ("missions", "displacement_ratio", "replans", "message")}}) + "\n")
    if walked:
        print(f"{same} of {walked} the same walk, {kept} the same outcome (success and reason)"
              + (f"; wall time new / base: median {statistics.median(ratios):.3f}" if ratios else ""))
    return 0 if same == walked else 1


def _sim_time(record: dict) -> float | None:
    """The simulated seconds of a walk's missions, where the record keeps them."""
    missions = record.get("mission_records")
    return None if not missions else float(sum(m.get("sim_time_s") or 0.0 for m in missions))


if __name__ == "__main__":
    raise SystemExit(main())
