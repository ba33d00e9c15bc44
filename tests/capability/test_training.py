"""Training protocol, metrics and baselines of the capability networks, on synthetic data
whose label is a known function of the patch (qz_drake.capability.synthetic)."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from qz_drake.capability import evaluation as ev  # noqa: E402
from qz_drake.capability.synthetic import synthetic_arrays, synthetic_rule  # noqa: E402
from qz_drake.capability.training import TrainingConfig, split_scenes, train_networks  # noqa: E402
from qz_drake.errors import QzError  # noqa: E402

torch.set_num_threads(1)


def small_config(**kw):
    # Single networks: the ensembles' training, saving and map are tested in
    # test_capability_model.py; here the protocol is.
    kw.setdefault("ensemble", 1)
    kw.setdefault("max_epochs", 60)
    kw.setdefault("patience", 10)
    kw.setdefault("networks", ["nominal/orthogonal"])
    return TrainingConfig(**kw)


@pytest.fixture(scope="module")
def learned():
    arrays, manifest = synthetic_arrays(scenes=60, headings=8, kinds=("orthogonal",), label_noise=0.02, seed=1)
    result = train_networks(arrays, fingerprint=manifest["fingerprint"], config=small_config(batch_size=64))
    return arrays, result


def test_split_is_by_scene_disjoint_and_reproducible():
    scenes = np.repeat(np.arange(40), 5)
    a, b = split_scenes(scenes, seed=3), split_scenes(scenes, seed=3)
    assert all(np.array_equal(a[k], b[k]) for k in a)
    assert [len(a[k]) for k in ("train", "validation", "test")] == [28, 6, 6]
    assert set(np.concatenate(list(a.values()))) == set(range(40))
    assert not set(a["train"]) & set(a["test"]) and not set(a["validation"]) & set(a["test"])
    assert not np.array_equal(split_scenes(scenes, seed=4)["test"], a["test"])
    with pytest.raises(QzError, match="dataset.scene"):
        split_scenes([0, 0, 1])


def test_learns_a_known_rule_on_held_out_scenes(learned):
    arrays, result = learned
    net = result.networks[("nominal", "orthogonal")]
    card = net.card
    # Against the noisy labels (2 % flipped, a few of 72 test trials) and the noiseless rule.
    assert card["test"]["auc"] > 0.9
    assert card["loss"] in ("mse", "bce") and set(card["runs"]) == {"mse", "bce"}
    # Early stopping kept the best validation epoch, before the cap.
    assert all(run["best_epoch"] <= run["epochs"] <= 60 for run in card["runs"].values())
    # Not one test scene was seen in training.
    assert not set(result.split["test"]) & set(result.split["train"])
    # The noiseless rule on the test scenes is ranked as well.
    rows = np.isin(arrays["scene"], result.split["test"])
    with torch.no_grad():
        p = net.net.probability(torch.as_tensor(arrays["patch"][rows]),
                                torch.as_tensor(arrays["feet"][rows].reshape(-1, 18))).numpy()
    from sklearn.metrics import roc_auc_score
    assert roc_auc_score(synthetic_rule(arrays["patch"][rows]), p) > 0.95
    # The baselines are scored on the same rows; the base rate ranks nothing.
    assert card["baselines"]["base_rate"]["n"] == card["test"]["n"]
    assert card["baselines"]["base_rate"]["auc"] is None or card["baselines"]["base_rate"]["auc"] == 0.5
    assert card["baselines"]["logistic"]["auc"] > 0.9  # the rule is a threshold on a hand-made feature
    assert card["baselines"]["gradient_boosting"]["n"] == card["test"]["n"]
    assert card["beats_baselines"] in (True, False)
    # The training trials' failures by what failed, and the share the planner reads from them.
    train = np.isin(arrays["scene"], result.split["train"]) & (arrays["topology"] == "nominal") \
        & (arrays["kind"] == "orthogonal")
    failed = train & ~arrays["success"]
    assert card["failures"] == {"planning": int(np.sum(failed & ~arrays["blc_success"])),
                                "execution": int(np.sum(failed & arrays["blc_success"]))}
    assert sum(card["failures"].values()) == card["n"]["train"] - card["positives"]["train"] > 0
    from qz_drake.capability.model import CapabilityModel
    share = CapabilityModel.from_training(result).plan_failure_share("nominal", "orthogonal")
    assert share == pytest.approx(card["failures"]["planning"] / sum(card["failures"].values()))
    assert CapabilityModel.random().plan_failure_share("nominal", "orthogonal") is None


def test_training_is_reproducible():
    arrays, manifest = synthetic_arrays(scenes=12, headings=6, kinds=("orthogonal",), seed=2)
    config = small_config(max_epochs=3, min_train_trials=10, min_train_per_class=1, losses=["bce"])
    a = train_networks(arrays, fingerprint="f", config=config).networks[("nominal", "orthogonal")].net
    b = train_networks(arrays, fingerprint="f", config=config).networks[("nominal", "orthogonal")].net
    for (ka, va), (kb, vb) in zip(a.state_dict().items(), b.state_dict().items()):
        assert ka == kb and torch.equal(va, vb)


def test_networks_without_enough_data_are_listed_missing():
    arrays, manifest = synthetic_arrays(scenes=12, headings=6, kinds=("orthogonal", "turn"), seed=2)
    keep = (arrays["kind"] == "orthogonal") | (np.arange(len(arrays["kind"])) % 9 == 0)
    arrays = {k: v[keep] for k, v in arrays.items()}
    config = small_config(max_epochs=2, networks=["nominal/orthogonal", "nominal/turn", "split_up/diagonal"],
                          min_train_trials=20, min_train_per_class=1, losses=["bce"])
    result = train_networks(arrays, fingerprint="f", config=config)
    assert list(result.networks) == [("nominal", "orthogonal")]
    assert "training trials" in result.missing["nominal/turn"]
    assert result.missing["split_up/diagonal"].startswith("0 training trials")


def test_bad_config_and_arrays_name_the_field():
    arrays, _ = synthetic_arrays(scenes=5, headings=2, kinds=("orthogonal",))
    with pytest.raises(QzError, match="training.split"):
        train_networks(arrays, fingerprint="f", config=TrainingConfig(split=[0.5, 0.5, 0.5]))
    with pytest.raises(QzError, match="training.losses"):
        TrainingConfig(losses=["hinge"]).check()
    broken = dict(arrays, feet=arrays["feet"][:, :5])
    with pytest.raises(QzError, match="dataset.feet"):
        train_networks(broken, fingerprint="f")
    with pytest.raises(QzError, match="fingerprint"):
        train_networks(arrays, fingerprint="")


def test_beats_baselines_needs_every_baseline_beaten():
    base = {"base_rate": {"brier": 0.25}, "logistic": {"auc": 0.8, "brier": 0.15},
            "gradient_boosting": {"auc": 0.85, "brier": 0.12}}
    assert ev.beats_baselines({"n": 10, "auc": 0.9, "brier": 0.1}, base) is True
    assert ev.beats_baselines({"n": 10, "auc": 0.83, "brier": 0.1}, base) is False
    assert ev.beats_baselines({"n": 10, "auc": None, "brier": 0.1}, base) is None


def test_metrics_with_one_class_report_no_auc():
    m = ev.binary_metrics(np.ones(5, bool), np.full(5, 0.8))
    assert m["auc"] is None and m["accuracy"] == 1.0 and m["brier"] == pytest.approx(0.04)
    assert m["confusion"] == [[0, 0], [0, 5]]
    assert ev.binary_metrics([], [])["n"] == 0


def test_expected_calibration_error_by_hand():
    y = np.array([1, 0, 1, 1, 0, 0, 1, 1], bool)
    p = np.array([0.05, 0.05, 0.35, 0.35, 0.95, 0.95, 0.95, 0.95])
    # bins: [0, .1): mean y .5 vs .05; [.3, .4): 1 vs .35; [.9, 1]: .5 vs .95
    expected = (2 * 0.45 + 2 * 0.65 + 4 * 0.45) / 8
    assert ev.expected_calibration_error(y, p, 10) == pytest.approx(expected)
    # Perfectly calibrated constant prediction.
    assert ev.expected_calibration_error([1, 0, 1, 0], [0.5] * 4) == pytest.approx(0.0)
    # Probabilities on the bins' inner edges (what an isotonic or Platt calibration can give)
    # belong to the lower bin, as in sklearn's calibration_curve: [.1, .2] holds 0.2, and the
    # reliability curve and the weights agree (this crashed when they did not).
    y = np.array([1, 0, 0, 1, 1], bool)
    p = np.array([0.2, 0.2, 0.15, 0.7, 0.75])
    expected = (3 * abs(1 / 3 - 0.55 / 3) + abs(1 - 0.7) + abs(1 - 0.75)) / 5
    assert ev.expected_calibration_error(y, p, 10) == pytest.approx(expected)
    assert sum(ev.binary_metrics(y, p)["reliability"]["count"]) == 5


def test_ece_floor_is_what_a_perfectly_calibrated_model_scores_on_so_few_trials():
    rng = np.random.default_rng(5)
    p = rng.uniform(0.0, 1.0, 150)
    floor = ev.ece_floor(p, 10)
    # Labels drawn from the predictions themselves: their ECE scatters around the floor.
    draws = [ev.expected_calibration_error(rng.random(150) < p, p, 10) for _ in range(300)]
    assert floor == pytest.approx(np.mean(draws), rel=0.1)
    assert 0.04 < floor < 0.15
    # It shrinks with the number of trials (about as 1 / sqrt(N)), and is zero for certainties.
    assert ev.ece_floor(np.tile(p, 16), 10) < floor / 3
    assert ev.ece_floor(np.array([0.0, 1.0, 1.0]), 10) == 0.0
    assert ev.binary_metrics(rng.random(150) < p, p)["ece_floor"] == pytest.approx(floor)


def test_patch_features_see_each_patch_alone(monkeypatch):
    flat = np.zeros((20, 20))
    step = flat.copy()
    step[12:] = 0.2
    features = ev.patch_features(np.stack([flat, step, flat]), "orthogonal")
    names = list(ev.FEATURE_NAMES)
    assert features.shape == (3, 4)
    # The step's neighbours in the mosaic stay flat: features do not leak between patches.
    assert np.allclose(features[[0, 2]], 0.0, atol=1e-6)  # FFT rounding only
    assert features[1, names.index("max_step_height")] == pytest.approx(0.2, abs=0.02)
    assert features[1, names.index("height_range")] == pytest.approx(0.2)
    assert features[1, names.index("max_slope")] > 0.1
    # Chunked mosaics give the same features.
    many = np.stack([flat, step, flat] * 3)
    whole = ev.patch_features(many, "turn")
    monkeypatch.setattr(ev, "FEATURE_CHUNK", 2)
    assert np.allclose(ev.patch_features(many, "turn"), whole, atol=1e-6)
    X = ev.baseline_inputs(np.stack([flat, step]), np.array([0, 1]), "turn")
    assert X.shape == (2, 5) and list(X[:, -1]) == [0, 1]


def test_pooled_initialisation_fine_tunes_a_network_trained_on_all_topologies():
    """With initialisations scratch and pooled, each loss is also trained from the weights of
    one network of the kind trained on every topology's training trials; the card names the
    run kept, chosen by validation Brier score among all four."""
    arrays, manifest = synthetic_arrays(scenes=24, headings=6, topologies=("nominal", "split_up"),
                                        kinds=("orthogonal",), seed=5)
    config = small_config(max_epochs=8, patience=4, min_train_trials=10, min_train_per_class=1,
                          initialisations=["scratch", "pooled"], networks=["split_up/orthogonal"])
    result = train_networks(arrays, fingerprint="f", config=config)
    card = result.networks[("split_up", "orthogonal")].card
    assert set(card["runs"]) == {"mse", "bce", "mse+pooled", "bce+pooled"}
    runs = card["runs"]
    best = min(runs, key=lambda r: runs[r]["validation"]["brier"])
    assert card["run"] == best and card["initialisation"] == runs[best]["initialisation"]
    assert card["loss"] == runs[best]["loss"]
    with pytest.raises(QzError, match="training.initialisations"):
        TrainingConfig(initialisations=["warm"]).check()


def test_mirror_augmentation_doubles_the_training_rows_only():
    arrays, manifest = synthetic_arrays(scenes=30, headings=4, kinds=("turn",), label_noise=0.0, seed=2)
    runs = {}
    for mirror in (False, True):
        config = small_config(networks=["nominal/turn"], losses=["bce"], max_epochs=5, mirror=mirror)
        runs[mirror] = train_networks(arrays, fingerprint=manifest["fingerprint"], config=config)
    plain, mirrored = (runs[m].networks[("nominal", "turn")].card for m in (False, True))
    assert plain["train_rows"] == plain["n"]["train"]
    assert mirrored["train_rows"] == 2 * mirrored["n"]["train"]
    # The held-out splits are the real trials only.
    assert mirrored["test"]["n"] == plain["test"]["n"] == mirrored["n"]["test"]
    with pytest.raises(QzError, match="training.mirror"):
        train_networks(arrays, fingerprint=manifest["fingerprint"], config=small_config(mirror="yes"))


def test_three_outcomes_are_learned_as_one_softmax_on_held_out_scenes():
    # The rule: a range <= 0.15 m walks, 0.15-0.20 m is executed and fails, higher is not planned.
    from qz_drake.capability.training import OUTCOMES, outcome_classes

    arrays, manifest = synthetic_arrays(scenes=60, headings=8, kinds=("orthogonal",), label_noise=0.0,
                                        failure_band=0.05, seed=2)
    classes = outcome_classes(arrays["success"], arrays["blc_success"])
    assert min(np.bincount(classes, minlength=3)) >= 40  # every outcome is in the data
    result = train_networks(arrays, fingerprint=manifest["fingerprint"], config=small_config(batch_size=64))
    card = result.networks[("nominal", "orthogonal")].card
    net = result.networks[("nominal", "orthogonal")].net
    assert net.outcomes and card["test"]["outcomes"]["counts"].keys() == set(OUTCOMES)
    scores = card["test"]["outcomes"]
    # Better than the outcome frequencies on the held-out scenes, and "executed and failed"
    # ranked on its own (it is no difference of two outputs).
    assert scores["network"]["brier"] < 0.6 * scores["base_rate"]["brier"]
    assert scores["network"]["log_loss"] < scores["base_rate"]["log_loss"]
    assert scores["failed"]["auc"] > 0.9
    rows = np.isin(arrays["scene"], result.split["test"])
    x, e = torch.as_tensor(arrays["patch"][rows]), torch.as_tensor(arrays["feet"][rows].reshape(-1, 18))
    with torch.no_grad():
        probs = net.outcome_probabilities(x, e).numpy()
        # success, plan and failure read off the same softmax: P(plan) = P(walked) + P(failed).
        np.testing.assert_allclose(net.probability(x, e).numpy(), probs[:, 0], atol=1e-6)
        np.testing.assert_allclose(net.plan_probability(x, e).numpy(), probs[:, 0] + probs[:, 2], atol=1e-6)
        np.testing.assert_allclose(net.failure_probability(x, e).numpy(), probs[:, 2], atol=1e-6)
    np.testing.assert_allclose(probs.sum(axis=1), 1.0, rtol=1e-5)
    predicted = probs.argmax(axis=1)
    assert np.mean(predicted == classes[rows]) > 0.85


def test_mcnemar_power_is_the_share_of_simulated_runs_the_exact_test_rejects():
    from qz_drake.capability.evaluation import mcnemar_exact_p, mcnemar_power, pairs_for_power

    rng = np.random.default_rng(0)
    pairs, discordant, difference = 120, 0.25, 0.10
    # Each pair: only A walked (p (d + diff) / 2), only B ((d - diff) / 2), or concordant.
    draws = rng.multinomial(pairs, [(discordant + difference) / 2, (discordant - difference) / 2,
                                    1 - discordant], size=4000)
    simulated = np.mean([mcnemar_exact_p(a, b) < 0.01 for a, b, _ in draws])
    assert mcnemar_power(pairs, discordant, difference, alpha=0.01) == pytest.approx(simulated, abs=0.025)
    assert mcnemar_power(pairs, discordant, 0.0, alpha=0.05) < 0.05  # no difference: the test's size
    needed = pairs_for_power(discordant, difference, alpha=0.01)
    assert mcnemar_power(needed, discordant, difference, 0.01) >= 0.8 > mcnemar_power(needed - 1, discordant,
                                                                                       difference, 0.01)
    with pytest.raises(QzError, match="discordant"):
        mcnemar_power(10, 0.05, 0.10)
