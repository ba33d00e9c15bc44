"""Which learner for the capability (issue 37): boosted trees against pooled neural networks, on
the same held-out episode scenes and on the validation walks' missions.

    python benchmarks/capability_learners.py [--dataset data/capability_episodes]
        [--walks data/walk_validation] [--seed 0] [--json]

Every learner sees every topology and kind at once (the topology and kind as one-hot inputs)
and predicts the three outcomes (walked, no plan, executed and failed) as one softmax, trained
on the same training scenes (training.split_scenes, 70/15/15, mirrored), stopped on the same
validation scenes:

* ``boosted``: qz_drake.capability.boosted, one learner (``members=1``);
* ``cnn``: the paper's capability CNN (two 5 x 5 convolution layers of four kernels, a dense
  patch layer, two dense layers) with the feet, d and the one-hots in its second head, Adam,
  cross-entropy, early stopping;
* ``mlp``: a two-layer perceptron (128 units) on the boosted model's own features.

Reported: the test scenes' ROC AUC of each outcome and the three-outcome Brier score, and on
the walks (qz_drake.experiments.walk_scores.score_missions) the ROC AUC of P(no plan) and
P(walked) per mission, beside the height-range baseline.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def _torch_learner(kind_of_net: str, arrays, rows, seed: int):
    """A trained torch learner: a callable (patches, feet, kind, topology, d) -> (n, 3)."""
    import torch
    from torch import nn

    from qz_drake.capability.boosted import features, record_features

    torch.manual_seed(seed)
    Xtr, ytr = record_features(arrays, rows["train"], mirror=True)
    Xva, yva = record_features(arrays, rows["validation"])
    n_patch = 20  # the block features' columns are replaced by the patch for the CNN

    def patches_of(r, mirror):
        from qz_drake.capability.patches import mirror_inputs

        p = np.asarray(arrays["patch"])[r]
        if not mirror:
            return p
        kind = np.asarray(arrays["kind"]).astype(str)[r]
        mirrored = [mirror_inputs(p[kind == k], np.asarray(arrays["feet"])[r][kind == k], None, k)[0]
                    for k in np.unique(kind)]
        return np.concatenate([p] + mirrored)

    if kind_of_net == "cnn":
        Ptr, Pva = patches_of(rows["train"], True), patches_of(rows["validation"], False)

        class Net(nn.Module):
            def __init__(self, n_extra):
                super().__init__()
                self.conv1, self.conv2 = nn.Conv2d(1, 4, 5, padding=2), nn.Conv2d(4, 4, 5, padding=2)
                self.patch = nn.Linear(4 * 25, 32)
                self.dense1, self.dense2 = nn.Linear(32 + n_extra, 64), nn.Linear(64, 3)

            def forward(self, p, e):
                x = torch.relu(nn.functional.max_pool2d(self.conv1(p.unsqueeze(1)), 2))
                x = torch.relu(nn.functional.max_pool2d(self.conv2(x), 2))
                x = torch.relu(self.patch(x.flatten(1)))
                return self.dense2(torch.relu(self.dense1(torch.cat([x, e], 1))))

        extra = slice(n_patch, None)  # one-hots, d, feet (the patch statistics are the CNN's to learn)
        net = Net(Xtr[:, extra].shape[1])
        pm, ps = float(Ptr.mean()), float(Ptr.std())
        em, es = Xtr[:, extra].mean(0), np.maximum(Xtr[:, extra].std(0), 1e-2)

        def inputs(P, X):
            return (torch.as_tensor(((P - pm) / ps).astype(np.float32)),
                    torch.as_tensor(((X[:, extra] - em) / es).astype(np.float32)))
        weight_decay = 1e-3
    else:
        net = nn.Sequential(nn.Linear(Xtr.shape[1], 128), nn.ReLU(), nn.Linear(128, 128), nn.ReLU(), nn.Linear(128, 3))
        mu, sd = Xtr.mean(0), np.maximum(Xtr.std(0), 1e-2)
        Ptr = Pva = None

        def inputs(P, X):
            return (torch.as_tensor(((X - mu) / sd).astype(np.float32)),)
        weight_decay = 1e-4
    train_in, val_in = inputs(Ptr, Xtr), inputs(Pva, Xva)
    ytr_t, yva_t = torch.as_tensor(ytr), torch.as_tensor(yva)
    optimiser = torch.optim.Adam(net.parameters(), lr=2e-3 if kind_of_net == "cnn" else 1e-3, weight_decay=weight_decay)
    generator = torch.Generator().manual_seed(seed)
    best, best_state, since = np.inf, None, 0
    for _ in range(300):
        net.train()
        for batch in torch.randperm(len(ytr_t), generator=generator).split(256):
            optimiser.zero_grad()
            nn.functional.cross_entropy(net(*(t[batch] for t in train_in)), ytr_t[batch]).backward()
            optimiser.step()
        net.eval()
        with torch.no_grad():
            loss = float(nn.functional.cross_entropy(net(*val_in), yva_t))
        if loss < best - 1e-4:
            best, best_state, since = loss, {k: v.clone() for k, v in net.state_dict().items()}, 0
        elif (since := since + 1) >= 25:
            break
    net.load_state_dict(best_state)
    net.eval()

    def predict(patches, feet, kind, topology, d):
        X = features(patches, feet, kind, topology, d)
        with torch.no_grad():
            return torch.softmax(net(*inputs(np.asarray(patches, np.float32), X)), 1).numpy().astype(float)

    return predict


class _Adapter:
    """What walk_scores.score_missions asks of a model, for a learner callable."""

    def __init__(self, predict):
        self.predict = predict

    def success_all(self, patches, feet, kind):
        n = len(patches)
        directions = (0, 1) if kind == "turn" else (None,)
        out = {}
        for t, f in feet.items():
            probs = np.stack([self.predict(patches, f, kind, t, d) for d in directions])
            success, plan = probs[..., 0], 1.0 - probs[..., 1]
            out[t] = (success if kind == "turn" else success[0], plan if kind == "turn" else plan[0], None)
            assert out[t][0].shape[-1] == n
        return out


def main(argv=None) -> int:
    from qz_drake.capability.boosted import OUTCOMES, BoostedCapabilityModel, BoostedConfig, train_boosted
    from qz_drake.capability.dataset import load_training_arrays
    from qz_drake.capability.evaluation import binary_metrics
    from qz_drake.capability.training import outcome_classes, split_scenes
    from qz_drake.experiments.fig9 import read_results
    from qz_drake.experiments.walk_scores import score_missions

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", default="data/capability_episodes")
    parser.add_argument("--walks", default="data/walk_validation")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    arrays, manifest = load_training_arrays(args.dataset)
    keep = np.asarray(arrays["kind"]).astype(str) != "switch"
    arrays = {k: (np.asarray(v)[keep] if np.ndim(v) and len(v) == len(keep) else v) for k, v in arrays.items()}
    split = split_scenes(arrays["scene"], (0.7, 0.15, 0.15), args.seed)
    rows = {name: np.flatnonzero(np.isin(arrays["scene"], ids)) for name, ids in split.items()}
    test = rows["test"]
    y = outcome_classes(np.asarray(arrays["success"])[test], np.asarray(arrays["blc_success"])[test])
    walks = read_results(args.walks)
    out = {"records": int(len(arrays["scene"])), "test_records": int(len(test)),
           "test_counts": {o: int(np.sum(y == i)) for i, o in enumerate(OUTCOMES)}}
    for name in ("boosted", "cnn", "mlp"):
        start = time.perf_counter()
        if name == "boosted":
            result = train_boosted(arrays, fingerprint=manifest["fingerprint"],
                                   config=BoostedConfig(members=1, seed=args.seed))
            model = BoostedCapabilityModel(result.members, result.card)

            def predict(patches, feet, kind, topology, d, model=model):
                from qz_drake.capability.boosted import features

                return model.outcomes_of_features(features(patches, feet, kind, topology, d))
        else:
            predict = _torch_learner(name, arrays, rows, args.seed)
        seconds = time.perf_counter() - start
        a = arrays
        probs = np.concatenate([predict(a["patch"][test][m], a["feet"][test][m], k, a["topology"][test][m],
                                        a["direction"][test][m]) for k in np.unique(a["kind"][test])
                                for m in [np.asarray(a["kind"][test]) == k]])
        order = np.concatenate([np.flatnonzero(np.asarray(a["kind"][test]) == k) for k in np.unique(a["kind"][test])])
        labels = y[order]
        scored = score_missions(walks, _Adapter(predict))
        out[name] = {"train_seconds": round(seconds, 1),
                     **{f"test_{o}_auc": binary_metrics(labels == i, probs[:, i])["auc"] for i, o in enumerate(OUTCOMES)},
                     "test_brier": float(np.mean(np.sum((probs - np.eye(3)[labels]) ** 2, axis=1))),
                     "walks_no_plan_auc": scored["no_plan"]["auc"], "walks_walked_auc": scored["walked"]["auc"]}
        out["walks_height_range_auc"] = scored["baseline_auc"]
        if not args.json:
            print(name, json.dumps(out[name]), flush=True)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
