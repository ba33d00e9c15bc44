"""Capability models side by side on the episodes of the planners' own routes (issue 54's rounds).

    python benchmarks/route_rounds.py --dataset data/route_rounds/round0/routes \
        --models shipped data/route_rounds/round0/model [--test-of data/route_rounds/round0/model]

Each model's predictions of every mission of the dataset (topology switches left out, as the
learners leave them), scored as the boosted card scores its test scenes (``boosted.test_scores``):
the three outcomes' Brier score against the base rate, and per outcome the ROC AUC and the
calibration error (ECE). ``--test-of MODEL`` keeps the scenes that model held out for its test
(its card's split), so that a model trained on part of the dataset is scored on scenes it never
saw; the others are scored on the same rows. A model trained before the dataset's last
recertification is scored all the same (the comparison is of predictions, not a certificate).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def load(name: str):
    from qz_drake.capability.model import CapabilityModel

    return CapabilityModel.load(None if name == "shipped" else name)


def scores(model, arrays: dict, rows: np.ndarray) -> dict:
    from qz_drake.capability import boosted as B

    return B.test_scores(model, arrays, {"test": rows, "train": np.arange(len(arrays["scene"]))})["all"]


def main(argv=None) -> int:
    from qz_drake.capability import boosted as B
    from qz_drake.capability.dataset import load_training_arrays

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dataset", required=True, type=Path)
    parser.add_argument("--models", required=True, nargs="+", help="model folders, or 'shipped'")
    parser.add_argument("--test-of", default=None, type=Path, help="score on this model's test scenes only")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    arrays, _ = load_training_arrays(args.dataset)
    arrays = B._without_switches(arrays)
    rows = np.arange(len(arrays["scene"]))
    if args.test_of is not None:
        card = json.loads((args.test_of / "model.json").read_text())
        rows = np.flatnonzero(np.isin(arrays["scene"], card["split"]["test"]))
    out = []
    for name in args.models:
        s = scores(load(name), arrays, rows)
        out.append({"model": name, "missions": s["n"], "counts": s["counts"], "brier": s["model"]["brier"],
                    "base_rate_brier": s["base_rate"]["brier"],
                    **{f"{o}_auc": s[o]["auc"] for o in B.OUTCOMES}, **{f"{o}_ece": s[o]["ece"] for o in B.OUTCOMES}})
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"{args.dataset}, {len(rows)} missions" + (f" of {args.test_of}'s test scenes" if args.test_of else ""))
    print("| model | Brier (base rate) | walked AUC / ECE | no plan AUC / ECE | failed AUC |")
    print("| --- | --- | --- | --- | --- |")

    def num(v):
        return "-" if v is None else f"{v:.3f}"

    for r in out:
        print(f"| {r['model']} | {num(r['brier'])} ({num(r['base_rate_brier'])}) | {num(r['walked_auc'])} / "
              f"{num(r['walked_ece'])} | {num(r['no_plan_auc'])} / {num(r['no_plan_ece'])} | {num(r['failed_auc'])} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
