"""An unfinished relabelling's labels against the source's, on the same episodes.

    python benchmarks/relabel_subsample.py SOURCE RELABELLED OUT_PREFIX [--seed 7]

A relabelling stores the episodes it copies at once and the ones it walks again as it goes, so
its dataset over-represents the episodes in which nothing was refused or failed until it ends.
This draws an unbiased subsample of episodes from what is done: every episode walked again so
far (a fraction f of those to walk again) and the same fraction f of the copied ones (seeded),
and trains a boosted model on that subsample twice, once on the source's labels and once on the
relabelled ones (OUT_PREFIX_source, OUT_PREFIX_ladder), so that the two differ in their labels
alone. Score them with `qz experiment score-missions WALKS --model MODEL` on walks made with the
same ladder. Interim only: the finished dataset is what a model ships from.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from qz_drake.capability.boosted import BoostedConfig, save_boosted, train_boosted
from qz_drake.capability.dataset import load_records, load_training_arrays
from qz_drake.capability.relabel import _unchanged


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source")
    parser.add_argument("relabelled")
    parser.add_argument("out_prefix")
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args()
    source, source_manifest = load_training_arrays(args.source)
    relabelled, relabelled_manifest = load_training_arrays(args.relabelled)
    raw, _ = load_records(args.source)
    copied, walked_again = _unchanged(raw)  # what the relabelling copies, what it walks again
    done = set(np.asarray(relabelled["index"]).tolist()) & walked_again
    fraction = len(done) / len(walked_again)
    copied = sorted(copied)
    rng = np.random.default_rng(args.seed)
    chosen = sorted(set(rng.choice(copied, size=round(fraction * len(copied)), replace=False).tolist()) | done)
    summary = {"walked_again_done": len(done), "walked_again": len(walked_again), "fraction": fraction,
               "copied_chosen": len(chosen) - len(done), "copied": len(copied)}
    for name, arrays, manifest in (("source", source, source_manifest), ("ladder", relabelled, relabelled_manifest)):
        keep = np.isin(np.asarray(arrays["index"]), chosen)
        subset = {k: v[keep] for k, v in arrays.items()}
        result = train_boosted(subset, fingerprint=manifest.get("fingerprint"), fingerprints=manifest.get("fingerprints"),
                               config=BoostedConfig(seed=0), progress=False)
        out = save_boosted(result, f"{args.out_prefix}_{name}")
        test = result.card["test"]["all"]
        summary[name] = {"model": str(out), "records": int(keep.sum()), "no_plan": int((~subset["blc_success"]).sum()),
                         "test_walked_auc": test["walked"]["auc"], "test_brier": test["model"]["brier"]}
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
