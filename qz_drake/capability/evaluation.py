"""Honest evaluation of the capability networks (issue #13; paper 000 section III-B reports none).

Per network, on held-out test scenes: accuracy at 0.5, ROC AUC, Brier score, expected
calibration error (ECE), the reliability curve and the confusion matrix, all through
scikit-learn's metric functions. The same numbers for two baselines on the same rows:

* the base rate: the training set's success rate for every query (what a planner knows
  without looking at the terrain);
* logistic regression and gradient boosting (scikit-learn) on hand-made features of the
  same patch: the largest step height, the largest slope and the largest roughness of
  qz_drake.terrain.features (paper 003's body features) and the patch's height range, plus
  d for turns.

A test set with one class only has no ROC AUC: it is reported as ``None``, not an error.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from qz_drake.capability.dataset import check_arrays
from qz_drake.capability.patches import MOVE_PATCH_SPACING, TURN_PATCH_SPACING

# Names of the baseline's patch features, in column order.
FEATURE_NAMES = ("max_step_height", "max_slope", "max_roughness", "height_range")
# Patches per body_features mosaic.
FEATURE_CHUNK = 2048


@dataclasses.dataclass
class EvaluationConfig:
    """How calibration is measured."""

    # Equal-width probability bins of the ECE and the reliability diagram. Ten is the usual
    # choice; with a few hundred test trials per network, more bins leave most of them with a
    # handful of trials and the ECE measures noise.
    ece_bins: int = 10
    # Disc radius of the baseline's slope / roughness / step features: about a foot's
    # neighbourhood, so that one stair edge is local (the body's 0.7 m would see the whole patch). [m]
    feature_radius: float = 0.3


def _bin_ids(probabilities: np.ndarray, bins: int) -> np.ndarray:
    # The binning of sklearn.calibration.calibration_curve(strategy="uniform"): a probability
    # on an inner edge belongs to the lower bin (searchsorted's default side, as sklearn's).
    edges = np.linspace(0.0, 1.0, bins + 1)
    return np.searchsorted(edges[1:-1], probabilities)


def expected_calibration_error(labels, probabilities, bins: int = 10) -> float:
    """sum_b n_b / N |mean label_b - mean probability_b| over equal-width bins.

    The per-bin means come from sklearn.calibration.calibration_curve (empty bins dropped);
    the weights n_b / N use the same binning.
    """
    from sklearn.calibration import calibration_curve

    y = np.asarray(labels, dtype=float)
    p = np.clip(np.asarray(probabilities, dtype=float), 0.0, 1.0)
    prob_true, prob_pred = calibration_curve(y, p, n_bins=bins, strategy="uniform")
    counts = np.bincount(_bin_ids(p, bins), minlength=bins)
    weights = counts[counts > 0] / len(y)
    return float(np.sum(weights * np.abs(prob_true - prob_pred)))


def ece_floor(probabilities, bins: int = 10, draws: int = 400, seed: int = 0) -> float:
    """The ECE a perfectly calibrated model with these predictions would score on this many
    trials, on average: labels drawn as Bernoulli(p), ``draws`` times (seeded). ECE is biased
    upwards on small samples (each bin's observed rate is noisy), so a test set of ~150 trials
    puts this floor at a few hundredths; an ECE near it is as calibrated as the test can show.
    Per draw, ECE = sum_b |successes_b - sum of p_b| / N (expected_calibration_error's bins)."""
    p = np.clip(np.asarray(probabilities, dtype=float).ravel(), 0.0, 1.0)
    if len(p) == 0:
        return float("nan")
    ids = _bin_ids(p, bins)
    labels = np.random.default_rng(seed).random((draws, len(p))) < p
    # (draws, bins): successes per bin, minus the predictions' sum per bin.
    observed = np.stack([np.bincount(ids, weights=row, minlength=bins) for row in labels.astype(float)])
    predicted = np.bincount(ids, weights=p, minlength=bins)
    return float(np.mean(np.abs(observed - predicted).sum(axis=1)) / len(p))


def mcnemar_exact_p(only_a: int, only_b: int) -> float:
    """McNemar's exact test of two paired outcomes (the same trials or tasks, two systems):
    the two-sided binomial test of the discordant pairs, ``only_a`` succeeding only under the
    first and ``only_b`` only under the second (scipy.stats.binomtest); 1 without any."""
    from scipy.stats import binomtest

    n = int(only_a) + int(only_b)
    return float(binomtest(int(only_a), n, 0.5).pvalue) if n else 1.0


def mcnemar_power(pairs: int, discordant: float, difference: float, alpha: float = 0.05) -> float:
    """Power of McNemar's exact test (:func:`mcnemar_exact_p` < ``alpha``) on ``pairs`` paired
    tasks, when a share ``discordant`` of them is walked by one system only and the first
    system's success rate is ``difference`` above the second's. Exact: the discordant count D
    is Binomial(pairs, discordant), and given D, the first system's share of them is
    Binomial(D, (discordant + difference) / (2 discordant))."""
    from scipy.stats import binom

    if not (0.0 < discordant <= 1.0 and 0.0 <= difference <= discordant):
        from qz_drake.errors import bad_value

        raise bad_value("discordant", (discordant, difference), "needs 0 < discordant <= 1 and "
                                                                 "0 <= difference <= discordant")
    q = (discordant + difference) / (2.0 * discordant)
    d = np.arange(1, int(pairs) + 1)
    weight = binom.pmf(d, int(pairs), discordant)
    keep = weight >= 1e-12
    d, weight = d[keep], weight[keep]
    # Every discordant count at once (a loop over them took 1.1 s at 5000 pairs, and
    # pairs_for_power asks a dozen times). The exact two-sided p-value of a symmetric binomial is
    # twice the smaller tail (mcnemar_exact_p's), so the first system's win counts that reject
    # are k <= c and k >= d - c, c the largest with 2 P(K <= c) < alpha (K ~ Binomial(d, 1/2);
    # c = -1: none rejects).
    c = binom.ppf(alpha / 2.0, d, 0.5).astype(int)
    for _ in range(2):  # ppf is the first count whose tail reaches alpha / 2: step below it
        c = np.where((c >= 0) & (2.0 * binom.cdf(c, d, 0.5) >= alpha), c - 1, c)
    low = np.where(c >= 0, binom.cdf(c, d, q), 0.0)
    high = np.where(c >= 0, binom.sf(d - c - 1, d, q), 0.0)
    return float(np.sum(weight * (low + high)))


def pairs_for_power(discordant: float, difference: float, *, alpha: float = 0.05, power: float = 0.8,
                    most: int = 5000) -> int | None:
    """Fewest paired tasks whose McNemar test has at least ``power`` (see :func:`mcnemar_power`);
    None if not within ``most``."""
    low, high = 1, most
    if mcnemar_power(high, discordant, difference, alpha) < power:
        return None
    while low < high:  # power grows with the pairs (up to the test's discreteness)
        mid = (low + high) // 2
        if mcnemar_power(mid, discordant, difference, alpha) >= power:
            high = mid
        else:
            low = mid + 1
    return low


def binary_metrics(labels, probabilities, *, bins: int = 10) -> dict:
    """n, positives, accuracy at 0.5, ROC AUC (None for one class), Brier score, ECE and its
    small-sample floor (:func:`ece_floor`), confusion matrix [[TN, FP], [FN, TP]] and the
    reliability curve."""
    from sklearn.calibration import calibration_curve
    from sklearn.metrics import accuracy_score, brier_score_loss, confusion_matrix, roc_auc_score

    y = np.asarray(labels, dtype=bool)
    p = np.clip(np.asarray(probabilities, dtype=float), 0.0, 1.0)
    if len(y) == 0:
        return {"n": 0, "positives": 0, "accuracy": None, "auc": None, "brier": None, "ece": None,
                "ece_floor": None, "confusion": [[0, 0], [0, 0]], "reliability": {"predicted": [], "observed": [], "count": []}}
    two_classes = 0 < y.sum() < len(y)
    prob_true, prob_pred = calibration_curve(y, p, n_bins=bins, strategy="uniform")
    counts = np.bincount(_bin_ids(p, bins), minlength=bins)
    return {
        "n": int(len(y)),
        "positives": int(y.sum()),
        "accuracy": float(accuracy_score(y, p >= 0.5)),
        "auc": float(roc_auc_score(y, p)) if two_classes else None,
        "brier": float(brier_score_loss(y, p, pos_label=True)),
        "ece": expected_calibration_error(y, p, bins),
        "ece_floor": ece_floor(p, bins),
        "confusion": confusion_matrix(y, p >= 0.5, labels=[False, True]).tolist(),
        "reliability": {"predicted": prob_pred.tolist(), "observed": prob_true.tolist(),
                        "count": counts[counts > 0].tolist()},
    }


def patch_features(patches, kind: str, config: EvaluationConfig | None = None) -> np.ndarray:
    """(N, 4) hand-made features of each patch (FEATURE_NAMES), from terrain.features.body_features.

    All patches go through one body_features call: each is edge-padded by the features' reach
    and the padded patches are tiled into one mosaic, so every patch sees its own border
    continued as a plateau (the HeightMap convention) and never its neighbour.
    """
    from qz_drake.terrain.features import BodyFeatureConfig, body_features

    config = config or EvaluationConfig()
    patches = np.asarray(patches, dtype=float)
    n, size = len(patches), patches.shape[-1]
    if n == 0:
        return np.zeros((0, len(FEATURE_NAMES)))
    if n > FEATURE_CHUNK:
        # Mosaics of a few thousand patches keep the FFTs' memory in the tens of megabytes.
        return np.concatenate([patch_features(patches[i:i + FEATURE_CHUNK], kind, config)
                               for i in range(0, n, FEATURE_CHUNK)])
    spacing = TURN_PATCH_SPACING if kind == "turn" else MOVE_PATCH_SPACING
    body = BodyFeatureConfig(radius=max(config.feature_radius, spacing))
    pad = int(np.ceil(body.radius / spacing)) + max(1, int(round(body.step_window / spacing))) + 1
    tile = size + 2 * pad
    columns = int(np.ceil(np.sqrt(n)))
    rows = int(np.ceil(n / columns))
    padded = np.pad(patches, ((0, rows * columns - n), (pad, pad), (pad, pad)), mode="edge")
    mosaic = padded.reshape(rows, columns, tile, tile).transpose(0, 2, 1, 3).reshape(rows * tile, columns * tile)
    features = body_features(mosaic, spacing, config=body)

    def per_patch(field: np.ndarray) -> np.ndarray:
        tiles = field.reshape(rows, tile, columns, tile).transpose(0, 2, 1, 3).reshape(-1, tile, tile)
        return tiles[:n, pad:pad + size, pad:pad + size].max(axis=(1, 2))

    height_range = patches.max(axis=(1, 2)) - patches.min(axis=(1, 2))
    return np.column_stack([per_patch(features.step_height), per_patch(features.slope),
                            per_patch(features.roughness), height_range])


def baseline_inputs(patches, direction, kind: str, config: EvaluationConfig | None = None) -> np.ndarray:
    """The baseline's design matrix: patch features, plus d for the turn network."""
    X = patch_features(patches, kind, config)
    if kind == "turn":
        X = np.column_stack([X, np.asarray(direction, dtype=float)])
    return X


def fit_baseline(X, y, kind: str = "logistic", seed: int = 0):
    """A baseline classifier on the patch features, or None when y has one class.

    ``logistic``: standardised logistic regression (a threshold on a weighted sum of the
    features); ``gradient_boosting``: scikit-learn's histogram gradient boosting (feature
    interactions and non-monotone effects), with its default early stopping on large sets.
    """
    from sklearn.ensemble import HistGradientBoostingClassifier
    from sklearn.linear_model import LogisticRegression
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    y = np.asarray(y, dtype=bool)
    if y.all() or not y.any():
        return None
    if kind == "logistic":
        model = make_pipeline(StandardScaler(), LogisticRegression(max_iter=1000, random_state=seed))
    elif kind == "gradient_boosting":
        model = HistGradientBoostingClassifier(max_iter=200, random_state=seed)
    else:
        raise ValueError(kind)
    return model.fit(X, y)


# The fitted baselines of baseline_metrics (besides the base rate).
BASELINES = ("logistic", "gradient_boosting")


def baseline_metrics(train_X, train_y, test_X, test_y, *, bins: int = 10, seed: int = 0) -> dict:
    """Metrics of the base rate and of each fitted baseline on the test rows."""
    train_y = np.asarray(train_y, dtype=bool)
    rate = float(train_y.mean()) if len(train_y) else 0.5
    out = {"base_rate": dict(binary_metrics(test_y, np.full(len(test_y), rate), bins=bins), rate=rate)}
    for kind in BASELINES:
        model = fit_baseline(train_X, train_y, kind, seed)
        p = np.full(len(test_y), rate) if model is None or len(test_y) == 0 else model.predict_proba(test_X)[:, 1]
        out[kind] = binary_metrics(test_y, p, bins=bins)
    return out


def beats_baselines(network: dict, baselines: dict) -> bool | None:
    """Whether the CNN beats every baseline on the test rows: a higher AUC and a lower Brier
    score than each fitted baseline, and a lower Brier score than the base rate. None where
    the test rows have one class (nothing to rank)."""
    if network.get("auc") is None or network.get("n", 0) == 0:
        return None
    for kind in BASELINES:
        other = baselines[kind]
        if (other["auc"] is not None and network["auc"] <= other["auc"]) or network["brier"] >= other["brier"]:
            return False
    return bool(network["brier"] < baselines["base_rate"]["brier"])


# The manifest fingerprints of what produces a label: a dataset from other scenes is fair
# game for evaluation, one from another BLC-robot system is not.
LABEL_COMPONENTS = ("robot", "blc", "controller", "verdict")


def _label_lineage(manifest: dict) -> list[dict]:
    """The label components' fingerprints the dataset's labels are certified for: the current
    ones and, from the newest back, those each recertification moved the dataset from (a
    recertification re-ran a sample of the stored trials under the new code and found them
    the same, so labels of the old code are labels of the new)."""
    lineage = [manifest.get("fingerprints") or {}]
    for certification in reversed(manifest.get("certifications") or []):
        before = certification.get("fingerprints_before")
        if isinstance(before, dict):
            lineage.append(before)
    return lineage


def check_fingerprints(model_card: dict, manifest: dict) -> None:
    """Refuses a dataset whose labels came from another robot / BLC / controller / verdict
    than the model's: raises a QzError naming the first differing field. Other components
    (e.g. the scene generator's) may differ: evaluating on other scenes is the point. A model
    trained before a recertification of the dataset (the code changed, the labels did not)
    still matches it."""
    from qz_drake.errors import ConfigError

    ours, theirs = model_card.get("fingerprints") or {}, manifest.get("fingerprints") or {}
    if ours and any(all(ours.get(key) == fingerprints.get(key) for key in LABEL_COMPONENTS)
                    for fingerprints in _label_lineage(manifest)):
        return
    for key in LABEL_COMPONENTS:
        if ours.get(key) != theirs.get(key):
            raise ConfigError(f"dataset.manifest.fingerprints.{key} = {theirs.get(key)!r}: differs from the model's "
                              f"{ours.get(key)!r}; its labels are not those of the model's BLC-robot system")
    if not ours and not theirs and model_card.get("fingerprint") != manifest.get("fingerprint"):
        raise ConfigError(f"dataset.manifest.fingerprint = {manifest.get('fingerprint')!r}: differs from the "
                          f"model's {model_card.get('fingerprint')!r}")


def evaluate_model(model, arrays: dict, manifest: dict, config: EvaluationConfig | None = None) -> list[dict]:
    """The test metrics of every network of ``model`` on every row of a dataset.

    The dataset's fingerprints must be the model's (check_fingerprints). Rows of networks the
    model lacks are reported with ``"missing"`` and no scores. Returns one entry per
    (topology, kind) present in the data: topology, kind and the metrics of binary_metrics.
    """
    from qz_drake.capability.patches import KINDS
    from qz_drake.robot.topology import TOPOLOGY_NAMES

    config = config or EvaluationConfig()
    check_fingerprints(model.card, manifest)
    check_arrays(arrays)
    topology = np.asarray(arrays["topology"]).astype(str)
    kind = np.asarray(arrays["kind"]).astype(str)
    results = []
    for t in TOPOLOGY_NAMES:
        for k in KINDS:
            rows = np.nonzero((topology == t) & (kind == k))[0]
            if len(rows) == 0:
                continue
            labels = np.asarray(arrays["success"][rows], dtype=bool)
            if not model.has_network(t, k):
                results.append({"topology": t, "kind": k, "n": int(len(rows)), "positives": int(labels.sum()),
                                "auc": None, "brier": None, "ece": None, "accuracy": None, "missing": True})
                continue
            direction = arrays["direction"][rows] if k == "turn" else None
            p = model.success(arrays["patch"][rows], arrays["feet"][rows], k, t, direction=direction)
            results.append({"topology": t, "kind": k, **binary_metrics(labels, p, bins=int(config.ece_bins))})
    return results
