"""How much the capability model gains from more episodes (issue 37): the boosted learner
trained on growing shares of the training scenes, scored on the same held-out scenes and on the
validation walks' missions.

    python benchmarks/capability_learning_curve.py [--dataset data/capability_episodes]
        [--walks data/walk_validation] [--shares 0.25,0.5,0.75,1] [--seed 0] [--json]

The scenes are split once (training.split_scenes, 70/15/15, as the shipped model's training);
each row trains one learner (``members=1``, mirrored, stopped on the validation scenes) on the
first share of the training scenes in a fixed random order, so each larger share holds the
smaller ones. Reported per share: training missions, the test scenes' ROC AUC of each outcome
and the three-outcome Brier score, and on the walks (walk_scores.score_missions) the ROC AUC of
P(no plan) and P(walked) per mission. A curve still rising at the full share says more episodes
would pay; a flat one says the collection's remaining hours are better spent on walks.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def main(argv=None) -> int:
    from qz_drake.capability.boosted import (OUTCOMES, BoostedCapabilityModel, BoostedConfig, _fit_member,
                                             record_features)
    from qz_drake.capability.dataset import load_training_arrays
    from qz_drake.capability.training import outcome_classes, outcome_scores, split_scenes
    from qz_drake.capability.evaluation import binary_metrics
    from qz_drake.experiments.fig9 import read_results
    from qz_drake.experiments.walk_scores import score_missions

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", default="data/capability_episodes")
    parser.add_argument("--walks", default="data/walk_validation")
    parser.add_argument("--shares", default="0.25,0.5,0.75,1")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    shares = [float(v) for v in args.shares.split(",")]
    if not shares or any(not 0.0 < s <= 1.0 for s in shares):
        parser.error(f"--shares {args.shares}: expected numbers in (0, 1]")

    arrays, manifest = load_training_arrays(args.dataset)
    keep = np.asarray(arrays["kind"]).astype(str) != "switch"
    arrays = {k: (np.asarray(v)[keep] if np.ndim(v) and len(v) == len(keep) else v) for k, v in arrays.items()}
    config = BoostedConfig(members=1, seed=args.seed).check()
    split = split_scenes(arrays["scene"], config.split, config.seed)
    scene = np.asarray(arrays["scene"], dtype=np.int64)
    rows = {name: np.flatnonzero(np.isin(scene, ids)) for name, ids in split.items()}
    order = np.random.default_rng(args.seed).permutation(np.asarray(split["train"]))
    Xv, yv = record_features(arrays, rows["validation"])
    Xt, yt = record_features(arrays, rows["test"])
    walks = read_results(args.walks)
    out = {"dataset": args.dataset, "fingerprint": manifest["fingerprint"], "records": int(len(scene)),
           "train_scenes": int(len(order)), "test_records": int(len(yt)),
           "test_counts": {o: int(np.sum(yt == i)) for i, o in enumerate(OUTCOMES)}, "rows": []}

    for share in shares:
        scenes = order[:max(1, int(round(share * len(order))))]
        train = np.flatnonzero(np.isin(scene, scenes))
        X, y = record_features(arrays, train, mirror=config.mirror)
        start = time.perf_counter()
        trees, best, loss = _fit_member(X, y, Xv, yv, config, config.seed)
        model = BoostedCapabilityModel([trees], {"fingerprint": manifest["fingerprint"]})
        probs = model.outcomes_of_features(Xt)
        scored = score_missions(walks, model)
        row = {"share": share, "train_scenes": int(len(scenes)), "train_missions": int(len(train)),
               "iterations": best, "train_seconds": round(time.perf_counter() - start, 1),
               **{f"test_{o}_auc": binary_metrics(yt == i, probs[:, i])["auc"] for i, o in enumerate(OUTCOMES)},
               "test_brier": outcome_scores(probs, yt)["brier"],
               "walks_no_plan_auc": scored["no_plan"]["auc"], "walks_walked_auc": scored["walked"]["auc"]}
        out["rows"].append(row)
        if not args.json:
            print(json.dumps(row), flush=True)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
