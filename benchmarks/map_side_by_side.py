"""The capability map of the 20 m long_range world from two source trees, side by side.

    git worktree add --detach /tmp/base COMMIT
    python benchmarks/map_side_by_side.py /tmp/base . --repeats 3

Each run is a fresh interpreter importing qz_drake from the tree given (the editable install's
finder is taken out of sys.meta_path, so PYTHONPATH alone would not do); the trees alternate
(base, new, base, new, ...); ``--world`` picks the 20 m long_range world (default) or a Fig. 9
task's world (e.g. ``obstacles-hard``, seed 0). Random weights (CapabilityModel.random, seed 0), single networks
and ensembles of five members, or with ``--shipped`` each tree's shipped model; torch on one thread. Prints one JSON line per run and the medians
with their ratios (new / base).
"""

import json
import statistics
import sys

from tree_runs import run_in_tree

_RUN = r"""
import json, time
import torch
torch.set_num_threads(1)
from qz_drake.capability.model import CapabilityModel, predict_map
from qz_drake.capability.networks import CapabilityEnsemble, CapabilityNet
from qz_drake.terrain import make_terrain
if sys.argv[2] == "long_range":
    hm, anchor = make_terrain("long_range", seed=0), (1, 1)
else:  # a Fig. 9 world: terrain-difficulty, e.g. obstacles-hard (flat outside its feature band)
    from qz_drake.experiments.worlds import make_task
    task = make_task(*sys.argv[2].split("-"), 0)
    hm, anchor = task.heightmap, task.start
if sys.argv[3] == "shipped":  # the tree's own shipped model
    models = (("shipped", CapabilityModel.load()),)
else:
    single = CapabilityModel.random(seed=0)
    torch.manual_seed(0)
    ensemble = CapabilityModel({k: CapabilityEnsemble([CapabilityNet(k[1]).eval() for _ in range(5)]).eval()
                                for k in single.networks}, dict(single.card))
    models = (("single", single), ("ensemble5", ensemble))
predict_map(models[0][1], hm, anchor=anchor)
out = {}
for name, model in models:
    clock = time.perf_counter()
    predict_map(model, hm, anchor=anchor)
    out[name] = time.perf_counter() - clock
print(json.dumps(out))
"""


def main(argv=None) -> int:
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("base")
    parser.add_argument("new")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--world", default="long_range",
                        help="long_range (the 20 m world) or a Fig. 9 cell such as obstacles-hard (seed 0)")
    parser.add_argument("--shipped", action="store_true",
                        help="each tree's shipped model instead of random CNNs (the boosted trees use the free "
                             "cores, or QZ_TORCH_THREADS)")
    args = parser.parse_args(argv)
    times = {"base": [], "new": []}
    for _ in range(args.repeats):
        for label in ("base", "new"):
            result = run_in_tree(getattr(args, label), _RUN, args.world, "shipped" if args.shipped else "random")
            print(json.dumps({"tree": label, **result}))
            times[label].append(result)
    medians = {label: {k: statistics.median(r[k] for r in rows) for k in rows[0]} for label, rows in times.items()}
    print(json.dumps({"medians": medians,
                      "ratio_new_over_base": {k: medians["new"][k] / medians["base"][k] for k in medians["new"]}}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
