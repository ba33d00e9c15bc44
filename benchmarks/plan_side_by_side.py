"""The whole TLC plan (`qz bench plan`'s worlds) from two source trees, side by side, with a
digest of what each plans.

    git worktree add --detach /tmp/base COMMIT
    python benchmarks/plan_side_by_side.py /tmp/base . --size 20 --repeats 5 [--threads 1] [--busy]

Each run is a fresh interpreter importing qz_drake from the tree given (the editable install's
finder taken out of sys.meta_path), loading that tree's shipped capability model, planning once
on a small world (numba's cached kernels and the model's first use), then timing the capability
map and the MDP, value iteration and path on the bench's world of ``--size`` metres
(bench_plan._world: the 20 m long_range world, or 5 x 5 of them for 100 m) from a corner to the
opposite one. The trees alternate (base, new, base, new, ...). ``--threads`` sets
QZ_TORCH_THREADS for both (default: each run chooses from the free cores); ``--busy`` keeps one
core busy with a spinning process beside every run (the "other core busy" case of issue 36).

Each run also prints the SHA-256 of the map's arrays (every probability, plan share and spread,
as float64 bytes) and of the path's actions: equal digests mean the two trees plan the same.
Prints one JSON line per run, then the medians with their ratios (new / base).
"""

import json
import multiprocessing
import os
import statistics
import sys

from tree_runs import run_in_tree

_RUN = r"""
import hashlib, json, time
import numpy as np
from bench_plan import _world
from qz_drake.capability.model import CapabilityModel, predict_map
from qz_drake.planning.capability_mdp import CapabilityMdpConfig, plan_on_map
from qz_drake.terrain import make_terrain

model = CapabilityModel.load()
small = make_terrain("long_range", seed=3)
plan_on_map(predict_map(model, small, anchor=(1.0, 1.0)), (1.0, 1.0), 1, (5.0, 5.0), config=CapabilityMdpConfig())
heightmap = _world(int(sys.argv[2]))
xmin, xmax, ymin, ymax = heightmap.bounds
start, goal = (xmin + 1.0, ymin + 1.0), (xmax - 1.0, ymax - 1.0)
clock = time.perf_counter()
capability = predict_map(model, heightmap, anchor=start)
middle = time.perf_counter()
result = plan_on_map(capability, start, 1, goal, config=CapabilityMdpConfig())
end = time.perf_counter()
digest = hashlib.sha256()
for name in ("forward", "turn_left", "turn_right", "forward_plan", "turn_left_plan", "turn_right_plan",
             "forward_spread", "turn_left_spread", "turn_right_spread"):
    value = getattr(capability, name)
    if value is not None:
        digest.update(np.ascontiguousarray(value, dtype=np.float64).tobytes())
path = hashlib.sha256(repr(result.steps).encode())
print(json.dumps({"plan_s": end - clock, "map_s": middle - clock, "mdp_s": end - middle,
                  "iterations": int(result.solution.iterations), "map_sha256": digest.hexdigest()[:16],
                  "path_sha256": path.hexdigest()[:16], "path_actions": len(result.steps)}))
"""


def _spin():  # pragma: no cover - a busy core for --busy
    while True:
        pass


def main(argv=None) -> int:
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("base")
    parser.add_argument("new")
    parser.add_argument("--size", type=int, default=20, help="20 or 100 (metres)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=None, help="QZ_TORCH_THREADS for both trees")
    parser.add_argument("--busy", action="store_true", help="one core kept busy beside every run")
    args = parser.parse_args(argv)
    env = dict(os.environ)
    if args.threads is not None:
        env["QZ_TORCH_THREADS"] = str(args.threads)
    spinner = None
    if args.busy:
        spinner = multiprocessing.Process(target=_spin, daemon=True)
        spinner.start()
    runs = {"base": [], "new": []}
    try:
        for _ in range(args.repeats):
            for label in ("base", "new"):
                result = run_in_tree(getattr(args, label), _RUN, args.size, env=env)
                print(json.dumps({"tree": label, **result}), flush=True)
                runs[label].append(result)
    finally:
        if spinner is not None:
            spinner.terminate()
    keys = ("plan_s", "map_s", "mdp_s")
    medians = {label: {k: statistics.median(r[k] for r in rows) for k in keys} for label, rows in runs.items()}
    same = ({r["map_sha256"] for r in runs["base"] + runs["new"]} == {runs["base"][0]["map_sha256"]}
            and {r["path_sha256"] for r in runs["base"] + runs["new"]} == {runs["base"][0]["path_sha256"]})
    print(json.dumps({"size_m": args.size, "threads": args.threads, "busy": args.busy, "medians": medians,
                      "ratio_new_over_base": {k: medians["new"][k] / medians["base"][k] for k in keys},
                      "same_map_and_path": same}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
