"""Training-protocol variants of the 18 capability networks, on several scene splits.

    python benchmarks/capability_training_variants.py --dataset data/capability --seeds 0 1 [--json]

Each variant is a TrainingConfig (qz_drake.capability.training); each split seed re-draws the
70/15/15 split by scene, so a variant is judged on more than one set of held-out scenes. Per
variant and seed: the mean over the 18 networks of the test ROC AUC and Brier score of the kept
network, and of the logistic-regression baseline on the same test scenes. The decisions it
supports are recorded in BENCHMARKS.md, "capability-networks".
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

VARIANTS = {
    "paper (one output, no mirror, weight decay 1e-4)": {"factored": False, "mirror": False, "weight_decay": 1e-4},
    "one output, mirror, weight decay 1e-4": {"factored": False, "mirror": True, "weight_decay": 1e-4},
    "one output, mirror, weight decay 1e-2": {"factored": False, "mirror": True, "weight_decay": 1e-2},
    "two outputs, mirror, weight decay 1e-2 (default)": {"factored": True, "mirror": True, "weight_decay": 1e-2},
}


def main() -> None:
    from qz_drake.capability.dataset import load_training_arrays
    from qz_drake.capability.training import TrainingConfig, train_networks

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", default="data/capability")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--variants", type=int, nargs="+", default=None,
                        help="indices (0-based) of the variants to run; default all: " +
                             "; ".join(f"{i} {name}" for i, name in enumerate(VARIANTS)))
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    chosen = list(VARIANTS) if args.variants is None else [list(VARIANTS)[i] for i in args.variants]
    arrays, manifest = load_training_arrays(args.dataset)
    rows = []
    for name in chosen:
        settings = VARIANTS[name]
        for seed in args.seeds:
            start = time.perf_counter()
            result = train_networks(arrays, fingerprint=manifest["fingerprint"],
                                    config=TrainingConfig(seed=seed, **settings))
            cards = [n.card for n in result.networks.values()]
            rows.append({"variant": name, "seed": seed, "trials": int(len(arrays["success"])),
                         "auc": float(np.mean([c["test"]["auc"] for c in cards])),
                         "brier": float(np.mean([c["test"]["brier"] for c in cards])),
                         "logistic_auc": float(np.mean([c["baselines"]["logistic"]["auc"] for c in cards])),
                         "logistic_brier": float(np.mean([c["baselines"]["logistic"]["brier"] for c in cards])),
                         "beats_baselines": int(sum(bool(c["beats_baselines"]) for c in cards)),
                         "plan_auc": (float(np.mean([c["test"]["plan"]["auc"] for c in cards]))
                                      if all("plan" in c["test"] for c in cards) else None),
                         "seconds": time.perf_counter() - start})
            if not args.json:
                r = rows[-1]
                print(f"{name:40s} seed {seed}: AUC {r['auc']:.3f} Brier {r['brier']:.3f} | logistic "
                      f"{r['logistic_auc']:.3f} / {r['logistic_brier']:.3f} | beats both {r['beats_baselines']}/18 "
                      f"({r['seconds']:.0f} s)")
    if args.json:
        print(json.dumps(rows))


if __name__ == "__main__":
    main()
