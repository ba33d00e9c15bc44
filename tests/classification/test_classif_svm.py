"""Per-leg RBF SVMs: [0, 1] scaling from the training set, grid search, the reports of Tables
1-2 and a model file that loads without pickle."""

import numpy as np
import pytest
from sklearn.svm import SVC

from qz_drake.classification.dataset import MIXED_RUN_ID, CollectConfig, StanceDataset
from qz_drake.classification.svm import (SvmModel, evaluation_report, format_tables, load_models, model_from_svc,
                                         repeated_holdout, save_models, train_all_legs, train_leg)
from qz_drake.errors import ConfigError, TerrainError

CLASSES = ("concrete", "wood", "foam")


def _blobs(n=40, seed=0):
    rng = np.random.default_rng(seed)
    centres = rng.normal(0, 3, (3, 18)) * np.linspace(1, 100, 18)
    X = np.vstack([c + rng.normal(0, 1, (n, 18)) * np.linspace(1, 100, 18) for c in centres])
    return X, np.repeat([0, 1, 2], n)


def test_decision_matches_libsvm_one_against_one():
    X, y = _blobs()
    svc = SVC(C=4.0, gamma=0.05, decision_function_shape="ovo").fit(X / 100, y)
    model = SvmModel(CLASSES, np.zeros(18), np.full(18, 100.0), svc.support_vectors_, svc.n_support_,
                     svc.dual_coef_, svc.intercept_, 0.05, 4.0)
    probe = _blobs(seed=3)[0]
    np.testing.assert_allclose(model.pair_decisions(probe), svc.decision_function(probe / 100), atol=1e-9)
    np.testing.assert_array_equal(model.predict_index(probe), svc.predict(probe / 100))


def test_two_classes_vote_like_libsvm():
    X, y = _blobs()
    two = y < 2
    svc = SVC(C=4.0, gamma=0.05).fit(X[two] / 100, y[two])
    model = model_from_svc(svc, CLASSES[:2], np.zeros(18), np.full(18, 100.0))
    probe = _blobs(seed=4)[0]
    np.testing.assert_array_equal(model.predict_index(probe), svc.predict(probe / 100))
    # LIBSVM's convention: a positive decision votes for the first class.
    np.testing.assert_allclose(model.pair_decisions(probe)[:, 0], -svc.decision_function(probe / 100), atol=1e-9)


def test_training_scales_with_the_training_split_and_evaluates_the_held_out_fifth():
    X, y = _blobs(n=50)
    model, report = train_leg(X, y, CLASSES, C_grid=(0.25, 4.0), gamma_grid=(0.0625, 1.0))
    assert report["test_size"] == 30 and report["train_size"] == 120
    assert report["accuracy"] > 0.95
    assert np.sum(report["confusion"]) == 30
    assert model.C in (0.25, 4.0) and model.gamma in (0.0625, 1.0)
    # The scaling comes from the 80 % only: the full set reaches beyond [0, 1] somewhere.
    Z = model.scale(X)
    assert Z.min() >= -0.5 and Z.max() <= 1.5
    assert np.all(model.scale_min >= X.min(axis=0))


def test_report_precision_and_recall_like_table_2():
    # The paper's Table 1: 40/0/0, 3/37/0, 0/1/39.
    y_true = np.repeat([0, 1, 2], 40)
    y_pred = np.concatenate([np.zeros(40), [0] * 3 + [1] * 37, [1] + [2] * 39]).astype(int)
    r = evaluation_report(y_true, y_pred, CLASSES)
    assert r["confusion"] == [[40, 0, 0], [3, 37, 0], [0, 1, 39]]
    assert r["accuracy"] == pytest.approx(116 / 120)
    np.testing.assert_allclose(r["precision"], [40 / 43, 37 / 38, 1.0])
    np.testing.assert_allclose(r["recall"], [1.0, 37 / 40, 39 / 40])


def test_models_round_trip_without_pickle(tmp_path):
    X, y = _blobs(n=12)
    legs = np.tile(np.arange(6), 6)
    data = StanceDataset(CLASSES, X, y, legs, np.zeros(36), np.zeros(36, int), np.zeros((3, 6), int), {})
    data.save(tmp_path / "dataset.npz")
    loaded = StanceDataset.load(tmp_path)  # a folder means its dataset.npz
    np.testing.assert_array_equal(loaded.features, X)
    # Two stances per (class, leg) are not enough for a 20 % split and 3 folds.
    with pytest.raises(ConfigError, match="too few"):
        train_all_legs(loaded, C_grid=(1.0,), gamma_grid=(0.1,))
    X, y = _blobs(n=60)
    legs = np.tile(np.arange(6), 30)
    data = StanceDataset(CLASSES, X, y, legs, np.zeros(180), np.zeros(180, int), np.zeros((3, 6), int), {})
    models, report = train_all_legs(data, C_grid=(1.0, 16.0), gamma_grid=(0.1,))
    assert [leg["leg"] for leg in report["per_leg"]] == ["MF", "RF", "RB", "MB", "LB", "LF"]
    assert "Precision/%" in format_tables(report)
    path = save_models(models, tmp_path / "models.npz", metadata={"seed": 0})
    with np.load(path, allow_pickle=False) as d:  # plain arrays only
        assert all(d[k].dtype != object for k in d.files)
    again, meta = load_models(path)
    assert meta == {"seed": 0}
    for a, b in zip(models, again):
        np.testing.assert_array_equal(a.predict_index(X), b.predict_index(X))
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(ConfigError, match="other.npz"):
        load_models(tmp_path / "other.npz")
    with pytest.raises(ConfigError, match="missing.npz"):
        load_models(tmp_path / "missing.npz")


def test_collect_config_names_bad_values():
    with pytest.raises(TerrainError, match="'gravel'"):
        CollectConfig(materials=["concrete", "gravel"]).check()
    with pytest.raises(ConfigError, match="stances_per_class"):
        CollectConfig(stances_per_class=0).check()
    with pytest.raises(ConfigError, match="speed_range"):
        CollectConfig(speed_range=[0.5, 0.2]).check()


def test_mixed_floor_stances_train_but_are_reported_apart():
    X, y = _blobs(n=60)
    legs = np.tile(np.arange(6), 30)
    runs = np.where((np.arange(180) // 6) % 3 == 0, MIXED_RUN_ID, 0)
    data = StanceDataset(CLASSES, X, y, legs, np.zeros(180), runs, np.zeros((3, 6), int), {})
    _, report = train_all_legs(data, C_grid=(4.0,), gamma_grid=(0.1,))
    for leg in report["per_leg"]:
        # 20 one-material stances per leg (4 held out) and 10 mixed-floor ones (2 held out).
        assert leg["test_size"] == 4 and leg["mixed"]["test_size"] == 2
        assert leg["train_size"] == 16 + 8
    assert report["mean_accuracy_mixed_floors"] is not None


def test_repeated_holdout_varies_the_split_and_averages():
    X, y = _blobs(n=60)
    # Two blobs overlap a little so that different splits give different accuracies.
    X[y == 1] = X[y == 0][:60] + np.random.default_rng(5).normal(0, 60, (60, 18)) * np.linspace(1, 100, 18) / 50
    legs = np.tile(np.arange(6), 30)
    data = StanceDataset(CLASSES, X, y, legs, np.zeros(180), np.zeros(180, int), np.zeros((3, 6), int), {})
    result = repeated_holdout(data, repeats=3, seed=7, C_grid=(4.0,), gamma_grid=(0.1,))
    accuracy = np.asarray(result["accuracy"])
    assert accuracy.shape == (3, 6) and result["seeds"] == [7, 8, 9]
    assert result["mean_accuracy"] == pytest.approx(accuracy.mean())
    assert result["per_leg_min"]["MF"] == pytest.approx(accuracy[:, 0].min())
    # The first repeat is the single report of the same seed.
    _, single = train_all_legs(data, seed=7, C_grid=(4.0,), gamma_grid=(0.1,))
    np.testing.assert_allclose(accuracy[0], [leg["accuracy"] for leg in single["per_leg"]])
    assert not np.all(accuracy == accuracy[0])
    with pytest.raises(ConfigError, match="repeats = 0"):
        repeated_holdout(data, repeats=0)
