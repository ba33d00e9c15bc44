"""Per-leg RBF support vector classifiers (paper 002, section 3.3), trained as LIBSVM's guide
says: features scaled linearly to [0, 1] with the training set's factors (reused at test
time), an RBF kernel, and C and gamma chosen by grid search with 3-fold cross-validation.

Training uses scikit-learn's SVC (LIBSVM inside). A trained model is kept as plain arrays
(scaling, support vectors, dual coefficients, intercepts) in an ``.npz`` that is loaded with
``allow_pickle=False``, and :class:`SvmModel` rebuilds LIBSVM's one-against-one decision
from them in numpy: nothing executable is ever unpickled from a model file.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from qz_drake.errors import ConfigError, bad_value
from qz_drake.robot.params import LEG_NAMES

# Grid of LIBSVM's guide, even powers of two so that it holds the paper's C = 2^-2 and
# gamma = 2^-4.
DEFAULT_C_GRID = tuple(2.0 ** k for k in range(-6, 15, 2))
DEFAULT_GAMMA_GRID = tuple(2.0 ** k for k in range(-14, 3, 2))


@dataclasses.dataclass
class SvmModel:
    """One leg's classifier as arrays: x -> [0, 1] scaling, then LIBSVM's one-against-one vote."""

    classes: tuple[str, ...]
    # Training minimum and range of each feature (range 1 where a feature was constant).
    scale_min: np.ndarray
    scale_range: np.ndarray
    support_vectors: np.ndarray  # (n_sv, n_features), scaled, grouped by class
    n_support: np.ndarray  # (n_classes,) support vectors per class, in class order
    dual_coef: np.ndarray  # (n_classes - 1, n_sv), LIBSVM's layout
    intercept: np.ndarray  # (n_classes (n_classes - 1) / 2,), pairs (0,1), (0,2), ..., (1,2), ...
    gamma: float
    C: float

    def scale(self, X: np.ndarray) -> np.ndarray:
        return (np.asarray(X, dtype=float) - self.scale_min) / self.scale_range

    def pair_decisions(self, X: np.ndarray) -> np.ndarray:
        """One-against-one decision values (n, n_pairs); positive votes for the pair's first class."""
        Z = self.scale(np.atleast_2d(X))
        sq = np.sum(Z * Z, axis=1)[:, None] + np.sum(self.support_vectors ** 2, axis=1)[None, :] \
            - 2.0 * Z @ self.support_vectors.T
        K = np.exp(-self.gamma * np.maximum(sq, 0.0))
        starts = np.concatenate([[0], np.cumsum(self.n_support)])
        k = len(self.classes)
        out = np.empty((len(Z), k * (k - 1) // 2))
        p = 0
        for i in range(k):
            si = slice(starts[i], starts[i + 1])
            for j in range(i + 1, k):
                sj = slice(starts[j], starts[j + 1])
                out[:, p] = (K[:, si] @ self.dual_coef[j - 1, si] + K[:, sj] @ self.dual_coef[i, sj]
                             + self.intercept[p])
                p += 1
        return out

    def predict_index(self, X: np.ndarray) -> np.ndarray:
        """Class indices by majority vote (ties to the lower index, as LIBSVM)."""
        decisions = self.pair_decisions(X)
        k = len(self.classes)
        votes = np.zeros((len(decisions), k), dtype=int)
        p = 0
        for i in range(k):
            for j in range(i + 1, k):
                wins = decisions[:, p] > 0
                votes[:, i] += wins
                votes[:, j] += ~wins
                p += 1
        return np.argmax(votes, axis=1)

    def predict(self, X: np.ndarray) -> np.ndarray:
        return np.asarray(self.classes, dtype=object)[self.predict_index(X)]


def model_from_svc(svc, classes: tuple[str, ...], scale_min: np.ndarray, scale_range: np.ndarray) -> SvmModel:
    """An SvmModel from a fitted scikit-learn SVC (RBF). For two classes scikit-learn flips the
    signs of LIBSVM's coefficients (its decision is positive for the second class); they are
    flipped back so that one decision rule serves any number of classes."""
    sign = -1.0 if len(classes) == 2 else 1.0
    return SvmModel(classes=tuple(classes), scale_min=scale_min, scale_range=scale_range,
                    support_vectors=svc.support_vectors_.copy(), n_support=svc.n_support_.copy(),
                    dual_coef=sign * svc.dual_coef_, intercept=sign * svc.intercept_,
                    gamma=float(svc.gamma), C=float(svc.C))


def fit_scaling(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[0, 1] scaling factors of a training set: (min, range)."""
    lo, hi = X.min(axis=0), X.max(axis=0)
    span = hi - lo
    return lo, np.where(span > 1e-12, span, 1.0)


def train_leg(X: np.ndarray, y: np.ndarray, classes: tuple[str, ...], *, seed: int = 0, test_fraction: float = 0.2,
              folds: int = 3, C_grid=DEFAULT_C_GRID, gamma_grid=DEFAULT_GAMMA_GRID,
              extra: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[SvmModel, dict]:
    """Trains one leg's classifier on labels y (indices into classes) and evaluates it on a
    held-out stratified ``test_fraction``; returns (model, report).

    ``extra`` (X, y) are further stances from another source (the mixed floors): they are
    split the same way, their training part joins the training set and their held-out part
    is reported separately (``mixed``), so that ``accuracy`` stays the paper's protocol.
    """
    from sklearn.model_selection import GridSearchCV, StratifiedKFold, train_test_split
    from sklearn.svm import SVC

    X = np.asarray(X, dtype=float)
    y = np.asarray(y, dtype=int)
    present = np.unique(y)
    if len(present) < 2:
        raise bad_value("dataset.labels", [classes[i] for i in present], "training needs at least two classes")
    counts = np.bincount(y, minlength=len(classes))
    if counts[present].min() < max(folds, 2) / (1.0 - test_fraction) + 1:
        raise bad_value("dataset", {classes[i]: int(counts[i]) for i in present},
                        f"too few stances per class for a {test_fraction:.0%} test split and {folds}-fold "
                        "cross-validation")
    X_train, X_test, y_train, y_test = train_test_split(X, y, test_size=test_fraction, stratify=y,
                                                        random_state=seed)
    X_extra_test = y_extra_test = None
    if extra is not None and len(extra[1]) >= 2:
        X_extra, y_extra = np.asarray(extra[0], dtype=float), np.asarray(extra[1], dtype=int)
        # Stratify where the held-out part can hold every class; otherwise a plain split.
        present_extra = np.unique(y_extra)
        can_stratify = (np.bincount(y_extra)[present_extra].min() >= 2
                        and np.ceil(test_fraction * len(y_extra)) >= len(present_extra))
        stratify = y_extra if can_stratify else None
        Xe_train, X_extra_test, ye_train, y_extra_test = train_test_split(
            X_extra, y_extra, test_size=test_fraction, stratify=stratify, random_state=seed)
        X_train, y_train = np.vstack([X_train, Xe_train]), np.concatenate([y_train, ye_train])
    lo, span = fit_scaling(X_train)
    Z_train = (X_train - lo) / span
    search = GridSearchCV(SVC(kernel="rbf"), {"C": list(C_grid), "gamma": list(gamma_grid)},
                          cv=StratifiedKFold(folds, shuffle=True, random_state=seed), n_jobs=1)
    search.fit(Z_train, y_train)
    svc = search.best_estimator_
    # Map the fitted (present) classes back to the full class list.
    fitted = [classes[c] for c in svc.classes_]
    model = model_from_svc(svc, tuple(fitted), lo, span)
    predicted = np.array([classes.index(c) for c in model.predict(X_test)])
    report = evaluation_report(y_test, predicted, classes)
    report.update(C=model.C, gamma=model.gamma, cv_accuracy=float(search.best_score_),
                  train_size=int(len(y_train)), test_size=int(len(y_test)),
                  grid_scores=search.cv_results_["mean_test_score"].reshape(len(C_grid), len(gamma_grid)).tolist())
    if X_extra_test is not None:
        mixed = np.array([classes.index(c) for c in model.predict(X_extra_test)])
        report["mixed"] = dict(evaluation_report(y_extra_test, mixed, classes), test_size=int(len(y_extra_test)))
    return model, report


def evaluation_report(y_true: np.ndarray, y_pred: np.ndarray, classes) -> dict:
    """Accuracy, confusion matrix (rows actual, columns predicted) and per-class precision and
    recall (Eq. 21-22), as the paper's Tables 1 and 2."""
    k = len(classes)
    confusion = np.zeros((k, k), dtype=int)
    np.add.at(confusion, (np.asarray(y_true, dtype=int), np.asarray(y_pred, dtype=int)), 1)
    predicted = confusion.sum(axis=0)
    actual = confusion.sum(axis=1)
    tp = np.diag(confusion)
    with np.errstate(invalid="ignore", divide="ignore"):
        precision = np.where(predicted > 0, tp / predicted, np.nan)
        recall = np.where(actual > 0, tp / actual, np.nan)
    return {"accuracy": float(tp.sum() / max(confusion.sum(), 1)), "confusion": confusion.tolist(),
            "precision": [None if np.isnan(v) else float(v) for v in precision],
            "recall": [None if np.isnan(v) else float(v) for v in recall]}


def format_tables(report: dict) -> str:
    """The report as text, one block per leg laid out like the paper's Tables 1 and 2."""
    classes = report["classes"]
    lines = []
    for leg in report["per_leg"]:
        lines.append(f"Leg {leg['leg']}: accuracy {100 * leg['accuracy']:.2f} % on {leg['test_size']} held-out "
                     f"stances (C = {leg['C']:g}, gamma = {leg['gamma']:g}, 3-fold CV {100 * leg['cv_accuracy']:.2f} %)")
        lines.append("  Actual class".ljust(16) + "".join(f"Pred. {c}".rjust(16) for c in classes))
        for c, row in zip(classes, leg["confusion"]):
            lines.append(f"  {c}".ljust(16) + "".join(str(n).rjust(16) for n in row))
        lines.append("  Terrain".ljust(16) + "Precision/%".rjust(16) + "Recall/%".rjust(16))
        for c, p, r in zip(classes, leg["precision"], leg["recall"]):
            fmt = (lambda v: "-" if v is None else f"{100 * v:.2f}")
            lines.append(f"  {c}".ljust(16) + fmt(p).rjust(16) + fmt(r).rjust(16))
        if "mixed" in leg:
            lines.append(f"  Mixed floors (held-out {leg['mixed']['test_size']} stances): accuracy "
                         f"{100 * leg['mixed']['accuracy']:.2f} %, confusion {leg['mixed']['confusion']}")
        lines.append("")
    return "\n".join(lines)


def save_models(models: list[SvmModel], path, *, metadata: dict | None = None) -> Path:
    """All legs' models in one npz of plain arrays (loadable without pickle)."""
    arrays = {"legs": np.asarray([LEG_NAMES[i] for i in range(len(models))], dtype=np.str_),
              "metadata": np.asarray(json.dumps(metadata or {}), dtype=np.str_)}
    for i, m in enumerate(models):
        prefix = f"leg{i}_"
        arrays.update({prefix + "classes": np.asarray(m.classes, dtype=np.str_),
                       prefix + "scale_min": m.scale_min, prefix + "scale_range": m.scale_range,
                       prefix + "support_vectors": m.support_vectors, prefix + "n_support": m.n_support,
                       prefix + "dual_coef": m.dual_coef, prefix + "intercept": m.intercept,
                       prefix + "gamma_C": np.array([m.gamma, m.C])})
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **arrays)
    return path


def load_models(path) -> tuple[list[SvmModel], dict]:
    """Models saved by :func:`save_models`; raises ConfigError naming the file when it is not one."""
    path = Path(path)
    if not path.is_file():
        raise bad_value("model", str(path), "no such file")
    try:
        with np.load(path, allow_pickle=False) as data:
            models = []
            for i in range(len(data["legs"])):
                p = f"leg{i}_"
                gamma, C = data[p + "gamma_C"]
                models.append(SvmModel(classes=tuple(str(c) for c in data[p + "classes"]),
                                       scale_min=data[p + "scale_min"], scale_range=data[p + "scale_range"],
                                       support_vectors=data[p + "support_vectors"], n_support=data[p + "n_support"],
                                       dual_coef=data[p + "dual_coef"], intercept=data[p + "intercept"],
                                       gamma=float(gamma), C=float(C)))
            metadata = json.loads(str(data["metadata"]))
    except (KeyError, ValueError, OSError) as e:
        raise ConfigError(f"model = {str(path)!r}: not a qz classifier model file ({e})") from None
    return models, metadata


def train_all_legs(dataset, *, seed: int = 0, test_fraction: float = 0.2, folds: int = 3,
                   C_grid=DEFAULT_C_GRID, gamma_grid=DEFAULT_GAMMA_GRID) -> tuple[list[SvmModel], dict]:
    """One classifier per leg from a StanceDataset; the report holds the held-out evaluation of
    each (accuracy, confusion, precision, recall, chosen C and gamma) on the one-material
    stances, as the paper's Tables 1-2, and, where the dataset has mixed-floor stances, on
    their own held-out 20 % (``mixed``)."""
    classes = tuple(dataset.classes)
    mixed = dataset.from_mixed_floors()
    models, per_leg = [], []
    for leg in range(len(LEG_NAMES)):
        rows = (dataset.legs == leg) & ~mixed
        if not rows.any():
            raise bad_value("dataset.legs", sorted(set(dataset.legs.tolist())), f"no stances of leg {LEG_NAMES[leg]}")
        extra_rows = (dataset.legs == leg) & mixed
        model, report = train_leg(dataset.features[rows], dataset.labels[rows], classes, seed=seed + leg,
                                  test_fraction=test_fraction, folds=folds, C_grid=C_grid, gamma_grid=gamma_grid,
                                  extra=(dataset.features[extra_rows], dataset.labels[extra_rows]))
        models.append(model)
        per_leg.append({"leg": LEG_NAMES[leg], **report})
    accuracies = [leg["accuracy"] for leg in per_leg]
    mixed_accuracies = [leg["mixed"]["accuracy"] for leg in per_leg if "mixed" in leg]
    return models, {"classes": list(classes), "per_leg": per_leg, "mean_accuracy": float(np.mean(accuracies)),
                    "mean_accuracy_mixed_floors": float(np.mean(mixed_accuracies)) if mixed_accuracies else None,
                    "min_accuracy": float(np.min(accuracies)), "C_grid": list(C_grid), "gamma_grid": list(gamma_grid)}


def repeated_holdout(dataset, *, repeats: int, seed: int = 0, first_report: dict | None = None,
                     **train_kwargs) -> dict:
    """Held-out accuracy over ``repeats`` random 80/20 splits (seeds ``seed``, ``seed`` + 1, ...),
    each with its own grid search: one split's 120 test stances per leg move its accuracy by
    0.8 % a stance, so the spread over splits says how far a single report can be trusted.
    ``first_report``: :func:`train_all_legs`'s report for ``seed`` when the caller has it
    already (it is not trained again)."""
    if not (isinstance(repeats, int) and repeats >= 1):
        raise bad_value("repeats", repeats, "must be a positive integer")
    accuracy = np.empty((repeats, len(LEG_NAMES)))
    for r in range(repeats):
        report = first_report if r == 0 and first_report is not None else \
            train_all_legs(dataset, seed=seed + r, **train_kwargs)[1]
        accuracy[r] = [leg["accuracy"] for leg in report["per_leg"]]
    return {"repeats": repeats, "seeds": list(range(seed, seed + repeats)),
            "per_leg_mean": dict(zip(LEG_NAMES, accuracy.mean(axis=0).tolist())),
            "per_leg_min": dict(zip(LEG_NAMES, accuracy.min(axis=0).tolist())),
            "mean_accuracy": float(accuracy.mean()), "std_of_split_means": float(accuracy.mean(axis=1).std()),
            "accuracy": accuracy.tolist()}
