"""Plan chains (the capability collection's BLC-only labels, ``--protocol plans``) from two
source trees, side by side: their wall time and whether every record is the same.

    git worktree add --detach /tmp/base COMMIT
    python benchmarks/plan_chains_side_by_side.py /tmp/base . [--scenes 2] [--runs 2] [--seed 16777300]

Each run is ``--scenes`` scenes' chains (one a topology: six a scene, as the collection draws
them from ``--seed``, 2^24 and above being the episodes' scenes) planned one after the other in
a fresh interpreter on one tree (tree_runs.run_in_tree), after one chain that is not timed (the
imports and the schedule parts' first build); the trees alternate (base, new, base, new, ...).
A run prints its wall time, its labelled missions and a SHA-256 of its records with the
timing fields (time_*) left out; the records must be the same in both trees (the script exits 1
otherwise). Prints one JSON line per run, then the medians, missions an hour on one worker and
the ratio (new / base).
"""

import argparse
import json
import statistics
import sys

from tree_runs import run_in_tree

_CHAINS = r"""
import hashlib, json, time
from qz_drake.capability.episodes import episode_specs
from qz_drake.capability.plan_chains import run_plan_chain
from qz_drake.capability.trials import TrialConfig

seed, scenes = int(sys.argv[2]), int(sys.argv[3])
specs = episode_specs(seed, scenes + 1)
config = TrialConfig()
run_plan_chain(next(s for s in specs if s.scene == scenes), config)  # not timed: imports, first builds
digest, missions = hashlib.sha256(), 0
clock = time.perf_counter()
for spec in [s for s in specs if s.scene < scenes]:
    for record in run_plan_chain(spec, config):
        missions += 1
        kept = {k: v for k, v in record.items() if not k.startswith("time_")}
        digest.update(json.dumps(kept, sort_keys=True, default=str).encode())
wall = time.perf_counter() - clock
print(json.dumps({"wall_s": wall, "missions": missions, "records": digest.hexdigest()[:16]}))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("base")
    parser.add_argument("new")
    parser.add_argument("--scenes", type=int, default=2)
    parser.add_argument("--runs", type=int, default=2)
    parser.add_argument("--seed", type=int, default=16777300)
    args = parser.parse_args()
    if args.scenes < 1 or args.runs < 1:
        sys.exit("--scenes and --runs must be at least 1")
    runs = {"base": [], "new": []}
    for k in range(args.runs):
        for name in ("base", "new"):
            r = run_in_tree(getattr(args, name), _CHAINS, args.seed, args.scenes)
            runs[name].append(r)
            print(json.dumps({"run": k, "tree": name, **r}), flush=True)
    digests = {r["records"] for rs in runs.values() for r in rs}
    summary = {name: {"wall_s_median": statistics.median(r["wall_s"] for r in rs),
                      "missions": rs[0]["missions"],
                      "missions_an_hour": 3600.0 * rs[0]["missions"] / statistics.median(r["wall_s"] for r in rs)}
               for name, rs in runs.items()}
    summary["ratio"] = summary["new"]["wall_s_median"] / summary["base"]["wall_s_median"]
    summary["same_records"] = len(digests) == 1
    print(json.dumps(summary))
    if len(digests) != 1:
        sys.exit(1)


if __name__ == "__main__":
    main()
