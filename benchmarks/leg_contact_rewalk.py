"""Issue 34's first must-show: the Fig. 9 walks that ended with a leg link on the terrain,
walked again with the same routes and the current BLC (``qz_drake.experiments.fig9.run_task``
with the experiment's own settings).

    python benchmarks/leg_contact_rewalk.py data/fig9 --planner astar --out out/leg_rewalk --workers 2

Writes one record per walk to ``OUT/results.jsonl`` as it finishes (a rerun skips the walks
already there) and prints the table: how many no longer end in a leg contact, and what ended
them instead. To walk them with another version of the code, run the script from a worktree of
that version (``git worktree add --detach DIR COMMIT``).
"""

from __future__ import annotations

import argparse
import collections
import json
import multiprocessing
import sys
from pathlib import Path


def _walk(item):
    from qz_drake.experiments import fig9

    spec, config = item
    return fig9.run_task(spec, config)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("experiment", help="a Fig. 9 results folder (results.jsonl, settings.json)")
    parser.add_argument("--planner", default="astar", choices=("astar", "capplanner"))
    parser.add_argument("--reason", default="leg_contact", help="the walks to walk again: their failure reason")
    parser.add_argument("--out", required=True)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)

    from qz_drake.experiments.fig9 import MODEL_IDENTITY, ExperimentConfig, TaskSpec

    experiment = Path(args.experiment)
    settings = json.loads((experiment / "settings.json").read_text())
    settings.pop(MODEL_IDENTITY, None)
    config = ExperimentConfig(**settings)
    records = [json.loads(line) for line in (experiment / "results.jsonl").read_text().splitlines() if line]
    chosen = [r for r in records if r["planner"] == args.planner and r["reason"] == args.reason]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results_path = out / "results.jsonl"
    done = {json.loads(line)["key"] for line in results_path.read_text().splitlines() if line} \
        if results_path.exists() else set()
    (out / "settings.json").write_text(json.dumps(dict(experiment=str(experiment), planner=args.planner,
                                                       reason=args.reason, config=settings), indent=1))
    todo = [(TaskSpec(r["terrain"], r["difficulty"], r["seed"], r["planner"]), config)
            for r in chosen if r["key"] not in done]
    print(f"{len(chosen)} walks ended in {args.reason}; {len(todo)} to walk", file=sys.stderr, flush=True)
    with multiprocessing.get_context("spawn").Pool(args.workers) as pool, results_path.open("a") as f:
        for k, record in enumerate(pool.imap_unordered(_walk, todo), 1):
            f.write(json.dumps(record) + "\n")
            f.flush()
            print(f"[{k}/{len(todo)}] {record['key']}: {'walked' if record['success'] else record['reason']} "
                  f"{record['message'][:90]}", file=sys.stderr, flush=True)
    after = {json.loads(line)["key"]: json.loads(line) for line in results_path.read_text().splitlines() if line}
    reasons = collections.Counter("walked" if r["success"] else r["reason"] for r in after.values())
    still = reasons.get(args.reason, 0)
    print(json.dumps(dict(walks=len(after), still=still, no_longer=len(after) - still, outcomes=dict(reasons)), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
