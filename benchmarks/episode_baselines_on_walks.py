"""Simple learners trained on the capability episodes, scored on whole walks (issue 37).

    python benchmarks/episode_baselines_on_walks.py [--dataset data/capability_episodes]
        [--walks data/walk_validation]

Features of a record or of a walk mission's action: the height patch as 4 x 4 block means, its
range, max, min and standard deviation, and the start feet in the heading frame (18 numbers);
no topology or kind input (the feet say the topology). The label is "the BLC found no plan".
Logistic regression and gradient boosting (scikit-learn) are fitted on the episodes of every
topology and kind together, first with every fifth scene held out (its ROC AUC printed), then
on all of them, and then predict each mission of the validation walks as the product over its
actions (experiments.walk_scores.mission_actions), as the networks are scored by `qz experiment
score-missions`. A question for the model's design: do the episodes predict the walks' refusals
at all, and how much does pooling the topologies give (the 18 networks each see 1/18 of it)?
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def features(patch, feet) -> np.ndarray:
    blocks = np.asarray(patch).reshape(4, 5, 4, 5).mean(axis=(1, 3)).ravel()
    patch = np.asarray(patch)
    return np.concatenate([blocks, [patch.max() - patch.min(), patch.max(), patch.min(), patch.std()],
                           np.asarray(feet).ravel()])


def main(argv=None) -> int:
    from sklearn.ensemble import HistGradientBoostingClassifier
    from sklearn.linear_model import LogisticRegression
    from sklearn.metrics import roc_auc_score

    from qz_drake.capability import patches as P
    from qz_drake.capability.dataset import load_records
    from qz_drake.experiments.walk_scores import mission_actions
    from qz_drake.experiments.worlds import make_task
    from qz_drake.robot.params import DEFAULT_PARAMS
    from qz_drake.robot.topology import get_topology

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", default="data/capability_episodes")
    parser.add_argument("--walks", default="data/walk_validation")
    args = parser.parse_args(argv)
    a, _ = load_records(args.dataset)
    ok = (a["status"] == "executed") & (a["kind"] != "switch")
    X = np.array([features(p, f) for p, f in zip(a["patch"][ok], a["feet"][ok])])
    y = ~a["blc_success"][ok]
    held_out = a["scene"][ok] % 5 == 0
    walks = [json.loads(line) for line in (Path(args.walks) / "results.jsonl").read_text().splitlines() if line.strip()]
    out = {"records": int(ok.sum()), "no_plan": int(y.sum()), "held_out_records": int(held_out.sum())}
    for name, model in (("logistic", LogisticRegression(max_iter=2000)),
                        ("gradient_boosting", HistGradientBoostingClassifier(max_iter=200, random_state=0))):
        model.fit(X[~held_out], y[~held_out])
        held = float(roc_auc_score(y[held_out], model.predict_proba(X[held_out])[:, 1]))
        model.fit(X, y)
        labels, scores = [], []
        for r in walks:
            missions = r.get("mission_records") or []
            task = make_task(r["terrain"], r["difficulty"], int(r["seed"])) if missions else None
            for m in missions:
                feet_W, planned = np.asarray(m["feet"], dtype=float), 1.0
                for k, (kind, _, x, yy, yaw) in enumerate(mission_actions(m["start"], m["target"])):
                    ground = float(P.ground_reference(task.heightmap, x, yy))
                    patch = P.sample_patches(task.heightmap, x, yy, yaw, kind, ground=ground)
                    if k > 0:
                        feet_W = P.nominal_feet_W(task.heightmap, x, yy, yaw, get_topology(m["topology"]),
                                                  DEFAULT_PARAMS.foot_radius)
                    feet = P.feet_in_heading_frame(feet_W, x, yy, yaw, ground)
                    planned *= 1.0 - float(model.predict_proba(features(patch, feet)[None])[0, 1])
                labels.append(m["outcome"] == "no_plan")
                scores.append(1.0 - planned)
        out[name] = {"held_out_scenes_auc": held, "walk_missions_auc": float(roc_auc_score(labels, scores)),
                     "walk_missions": len(labels), "walk_refusals": int(np.sum(labels))}
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
