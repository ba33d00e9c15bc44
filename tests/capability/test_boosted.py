"""The boosted capability model (qz_drake.capability.boosted): its exported trees answer what
scikit-learn answers, it learns three outcomes of a known rule, and it loads, plans a map and
refuses bad input as the networks' model does."""

import json

import numpy as np
import pytest

from qz_drake.capability import boosted as B
from qz_drake.capability import patches as P
from qz_drake.capability.model import CapabilityModel, CapabilityModelError
from qz_drake.capability.model_base import CapabilityModelBase
from qz_drake.capability.synthetic import SYNTHETIC_MAX_STEP, synthetic_arrays
from qz_drake.errors import QzError


def test_exported_trees_answer_as_scikit_learn():
    from sklearn.ensemble import HistGradientBoostingClassifier

    rng = np.random.default_rng(0)
    X = rng.normal(size=(600, 6))
    X[rng.random(X.shape) < 0.02] = np.nan  # missing values take the learned side
    y = (np.nan_to_num(X[:, 0]) > 0.3).astype(int) + (np.nan_to_num(X[:, 1]) > 0.8).astype(int)
    model = HistGradientBoostingClassifier(max_iter=30, max_leaf_nodes=15, random_state=0).fit(X, y)
    Xq = rng.normal(size=(300, 6))
    Xq[:5, 2] = np.nan
    trees = B.Trees.from_sklearn(model)
    assert trees.iterations == 30
    np.testing.assert_allclose(trees.probabilities(Xq), model.predict_proba(Xq), rtol=0, atol=1e-12)
    # Cut at an iteration: the staged prediction of that iteration.
    cut = B.Trees.from_sklearn(model, 7)
    staged = list(model.staged_predict_proba(Xq))[6]
    np.testing.assert_allclose(cut.probabilities(Xq), staged, rtol=0, atol=1e-12)
    # Arrays round trip, and inconsistent ones are refused.
    again = B.Trees.from_arrays(trees.arrays("m0_"), "m0_")
    np.testing.assert_array_equal(again.raw(Xq), trees.raw(Xq))
    broken = trees.arrays()
    broken["left"] = broken["left"][:-1]
    with pytest.raises(QzError, match="inconsistent"):
        B.Trees.from_arrays(broken)


def test_forest_scorer_adds_the_same_leaves_as_the_tree_walk():
    """QuickScorer's pass over every member at once gives Trees.raw's sums bit for bit, rows
    with missing values included (they may go right), and softmax's probabilities."""
    from sklearn.ensemble import HistGradientBoostingClassifier

    rng = np.random.default_rng(1)
    members = []
    for seed, leaves in ((0, 31), (1, 63), (2, 2)):
        X = rng.normal(size=(800, 7))
        X[rng.random(X.shape) < 0.03] = np.nan
        y = (np.nan_to_num(X[:, 0], nan=1.0) > 0.2).astype(int) + (np.nan_to_num(X[:, 3]) + X[:, 4] > 0.5).astype(int)
        model = HistGradientBoostingClassifier(max_iter=12, max_leaf_nodes=leaves, min_samples_leaf=5,
                                               random_state=seed).fit(X, y)
        members.append(B.Trees.from_sklearn(model))
    scorer = B.ForestScorer(members)
    Xq = rng.normal(size=(500, 7))
    Xq[rng.random(Xq.shape) < 0.05] = np.nan
    Xq[:3] = np.nan
    Xq[3:6] = [[float(members[0].threshold[0])] * 7] * 3  # on a split's threshold: left
    expected = np.stack([t.raw(Xq) for t in members])
    np.testing.assert_array_equal(scorer.raw(Xq), expected)
    np.testing.assert_array_equal(scorer.probabilities(Xq), np.stack([t.probabilities(Xq) for t in members]))
    np.testing.assert_allclose(scorer.probabilities(Xq).sum(axis=2), 1.0, rtol=0, atol=1e-12)
    # Groups of rows sharing their first columns (a cell's patch in every topology): the same.
    shared, variants = rng.normal(size=(120, 3)), rng.normal(size=(120, 4, 4))
    variants[:, 1, 0] = 0.25  # a column that fails the same splits in every group
    shared[5, 1] = variants[7, 2, 3] = np.nan
    rows = np.concatenate([np.repeat(shared, 4, axis=0), variants.reshape(480, 4)], axis=1)
    grouped = scorer.raw_grouped(shared, variants)
    assert grouped.shape == (3, 120, 4, 3)
    np.testing.assert_array_equal(grouped.reshape(3, 480, 3), np.stack([t.raw(rows) for t in members]))
    with pytest.raises(QzError, match="variants"):
        scorer.raw_grouped(shared[:, :2], variants)
    # Columns past the last one a tree splits on are read and ignored.
    wider = np.column_stack([Xq, rng.normal(size=len(Xq))])
    np.testing.assert_array_equal(scorer.raw(wider), expected)
    np.testing.assert_array_equal(scorer.raw_grouped(shared, np.concatenate([variants, variants[..., :1]], axis=2)),
                                  grouped)


def test_forest_scorer_declines_trees_wider_than_a_word(trained, monkeypatch):
    """A tree with more than 64 leaves cannot be a 64-bit word: the scorer refuses it, and a
    model whose trees it refuses walks them node by node, with the same answers."""
    arrays, _, _, result, _ = trained
    X = B.features(arrays["patch"][:300], arrays["feet"][:300], "orthogonal", "nominal")
    scored = B.BoostedCapabilityModel(result.members, result.card)
    assert scored.scorer is not None
    monkeypatch.setattr(B, "SCORER_MAX_LEAVES", 2)
    walked = B.BoostedCapabilityModel(result.members, result.card)
    assert walked.scorer is None
    np.testing.assert_array_equal(walked.member_outcomes(X), scored.member_outcomes(X))
    monkeypatch.undo()
    leaves = B.SCORER_MAX_LEAVES + 1
    # A chain: node 2k splits feature 0 at k, its left child a leaf, its right the next split.
    n = 2 * leaves - 1
    feature, threshold = np.zeros(n, np.int64), np.zeros(n)
    left, right, leaf, value = np.full(n, -1), np.full(n, -1), np.zeros(n, bool), np.zeros(n)
    for k in range(leaves - 1):
        threshold[2 * k], left[2 * k], right[2 * k] = k, 2 * k + 1, 2 * k + 2
        leaf[2 * k + 1], value[2 * k + 1] = True, k
    leaf[n - 1], value[n - 1] = True, leaves - 1
    wide = B.Trees(baseline=np.zeros(1), roots=np.zeros((1, 1), np.int64), feature=feature, threshold=threshold,
                   left=left, right=right, leaf=leaf, value=value, missing_left=np.ones(n, bool))
    assert B.ForestScorer.of([wide]) is None
    with pytest.raises(QzError, match="leaves"):
        B.ForestScorer([wide])
    X = np.arange(-1.0, leaves + 1.0)[:, None]
    np.testing.assert_array_equal(wide.raw(X)[:, 0], np.clip(np.ceil(X[:, 0]), 0, leaves - 1))


def _three_outcome_data(seed=0):
    arrays, manifest = synthetic_arrays(scenes=60, headings=6, topologies=("nominal", "split_up"),
                                        kinds=("orthogonal", "diagonal", "turn"), failure_band=0.06, label_noise=0.0, seed=seed)
    # A rule on the feet and the topology as well: a start with the first foot down a 0.1 m
    # step is not planned in split_up, whatever the terrain; nominal copes with it.
    stepped = np.arange(len(arrays["scene"])) % 3 == 0
    arrays["feet"][stepped, 0, 2] -= 0.1
    down = stepped & (arrays["topology"] == "split_up")
    arrays["success"][down], arrays["blc_success"][down] = False, False
    arrays["direction"] = np.asarray(arrays["direction"])
    return arrays, manifest, down


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    arrays, manifest, down = _three_outcome_data()
    result = B.train_boosted(arrays, fingerprint=manifest["fingerprint"], fingerprints=manifest["fingerprints"],
                             config=B.BoostedConfig(members=2, max_iter=40, learning_rate=0.25))
    folder = B.save_boosted(result, tmp_path_factory.mktemp("boosted"))
    return arrays, manifest, down, result, folder


def test_learns_three_outcomes_of_a_known_rule(trained):
    arrays, _, down, result, _ = trained
    test = result.card["test"]["all"]
    # Every outcome is ranked well on the held-out scenes, and the probabilities beat the
    # training frequencies as a constant.
    for outcome in B.OUTCOMES:
        assert test[outcome]["auc"] > 0.9, (outcome, test[outcome])
    assert test["model"]["brier"] < 0.5 * test["base_rate"]["brier"]
    model = B.BoostedCapabilityModel(result.members, result.card)
    rows = np.flatnonzero(np.isin(arrays["scene"], result.card["split"]["test"]))
    X, y = B.record_features(arrays, rows)
    p = model.outcomes_of_features(X)
    np.testing.assert_allclose(p.sum(axis=1), 1.0, atol=1e-12)
    # The foot rule: the same flat patches, split_up's first foot down a step is "no plan".
    height = arrays["patch"][rows].max(axis=(1, 2)) - arrays["patch"][rows].min(axis=(1, 2))
    flat = rows[(height < SYNTHETIC_MAX_STEP - 0.02) & (np.arange(len(arrays["scene"])) % 3 != 0)[rows]
                & (arrays["kind"][rows] == "orthogonal")]
    assert len(flat) > 10
    feet = arrays["feet"][flat].copy()
    stands = model.outcomes(arrays["patch"][flat], feet, "orthogonal", "split_up")
    feet[:, 0, 2] -= 0.1
    stepped = model.outcomes(arrays["patch"][flat], feet, "orthogonal", "split_up")
    assert stands[:, 1].mean() < 0.2 and stepped[:, 1].mean() > 0.8
    assert model.outcomes(arrays["patch"][flat], feet, "orthogonal", "nominal")[:, 1].mean() < 0.2


def test_saved_model_loads_and_answers_as_trained(trained):
    arrays, manifest, _, result, folder = trained
    model = CapabilityModel.load(folder, fingerprint=manifest["fingerprint"])
    assert isinstance(model, B.BoostedCapabilityModel) and isinstance(model, CapabilityModelBase)
    assert model.networks == sorted((t, k) for t in ("nominal", "split_up") for k in P.KINDS)
    rows = np.flatnonzero((arrays["kind"] == "turn") & (arrays["topology"] == "nominal"))[:40]
    patches, feet = arrays["patch"][rows], arrays["feet"][rows]
    left = model.success(patches, feet, "turn", "nominal", direction=0)
    fresh = B.BoostedCapabilityModel(result.members, result.card)
    np.testing.assert_array_equal(left, fresh.success(patches, feet, "turn", "nominal", direction=0))
    # success_all: each topology with its own feet, turns as (left, right), the members' spread.
    both = model.success_all(patches, {"nominal": feet, "split_up": feet}, "turn")
    (l, r), plan, spread = both["nominal"]
    np.testing.assert_allclose(l, left)
    np.testing.assert_allclose(r, model.success(patches, feet, "turn", "nominal", direction=1))
    assert plan.shape == (2, len(rows)) and np.all(plan >= l - 1e-12)
    assert spread.shape == (2, len(rows)) and np.all(spread >= 0)
    # The planner reads the share of failures that were refusals from the cards.
    share = model.plan_failure_share("nominal", "orthogonal")
    assert share is not None and 0.0 <= share <= 1.0


def test_the_trees_answer_the_same_on_one_thread_or_several(trained, monkeypatch):
    """The free cores share a map's queries (QZ_TORCH_THREADS sets how many): the answers are
    the same to the last bit, block by block, as on one thread."""
    arrays, _, _, result, _ = trained
    model = B.BoostedCapabilityModel(result.members, result.card)
    rng = np.random.default_rng(3)
    rows = rng.choice(len(arrays["kind"]), size=3 * B.PARALLEL_ROWS, replace=True)
    patches, feet = arrays["patch"][rows], arrays["feet"][rows]
    answers = {}
    for threads in ("1", "3"):
        monkeypatch.setenv("QZ_TORCH_THREADS", threads)
        answers[threads] = model.success_all(patches, {"nominal": feet, "split_up": feet[::-1]}, "turn")
    for topology in ("nominal", "split_up"):
        for one, several in zip(answers["1"][topology], answers["3"][topology]):
            np.testing.assert_array_equal(one, several)
    monkeypatch.setenv("QZ_TORCH_THREADS", "3")
    X = np.concatenate([B.features(patches, feet, "orthogonal", "nominal")] * 2)
    np.testing.assert_array_equal(model.member_outcomes(X)[:, :len(rows)], model.member_outcomes(X)[:, len(rows):])


def test_a_map_taken_in_chunks_answers_as_in_one(trained, monkeypatch):
    """success_all takes a map's patches a chunk at a time (memory): the chunks do not change a
    number, turns' two directions and the members' spread included."""
    arrays, _, _, result, _ = trained
    model = B.BoostedCapabilityModel(result.members, result.card)
    rows = np.arange(100)
    patches, feet = arrays["patch"][rows].reshape(4, 25, 20, 20), arrays["feet"][rows].reshape(4, 25, 6, 3)
    whole = model.success_all(patches, {"nominal": feet, "split_up": feet[::-1]}, "turn")
    monkeypatch.setattr(B, "MAP_CHUNK", 7)
    chunked = model.success_all(patches, {"nominal": feet, "split_up": feet[::-1]}, "turn")
    for topology in ("nominal", "split_up"):
        assert whole[topology][0].shape == (2, 4, 25)
        for one, other in zip(whole[topology], chunked[topology]):
            np.testing.assert_array_equal(one, other)
    # A cell's patch taken once for all its topologies and directions: the numbers of each
    # query on its own.
    for topology, f in (("nominal", feet), ("split_up", feet[::-1])):
        for d in (0, 1):
            X = B.features(patches.reshape(100, 20, 20), f.reshape(100, 6, 3), "turn", topology, d)
            probs = model.member_outcomes(X)
            np.testing.assert_array_equal(whole[topology][0][d].reshape(100), probs[..., 0].mean(axis=0))
            np.testing.assert_array_equal(whole[topology][1][d].reshape(100), (1.0 - probs[..., 1]).mean(axis=0))
            np.testing.assert_array_equal(whole[topology][2][d].reshape(100), probs[..., 0].std(axis=0))


def test_refuses_tampered_or_foreign_files_and_bad_queries(trained, tmp_path):
    _, manifest, _, result, folder = trained
    copy = B.save_boosted(result, tmp_path / "m")
    with np.load(copy / B.WEIGHTS_FILE) as data:
        arrays = {k: data[k] for k in data.files}
    arrays["m0_value"] = arrays["m0_value"] + 0.1
    with open(copy / B.WEIGHTS_FILE, "wb") as f:
        np.savez_compressed(f, **arrays)
    with pytest.raises(CapabilityModelError, match="SHA-256"):
        CapabilityModel.load(copy)
    card = json.loads((folder / "model.json").read_text())
    with pytest.raises(CapabilityModelError, match="fingerprint"):
        CapabilityModel.load(folder, fingerprint="another")
    model = CapabilityModel.load(folder)
    patch, feet = np.zeros((2, 20, 20), np.float32), np.zeros((2, 6, 3), np.float32)
    with pytest.raises(CapabilityModelError, match="tripod"):
        model.success(patch, feet, "orthogonal", "tripod")
    with pytest.raises(QzError, match="direction"):
        model.success(patch, feet, "turn", "nominal")
    with pytest.raises(QzError, match="feet"):
        model.success(patch, feet[:1], "orthogonal", "nominal")
    with pytest.raises(QzError, match="device"):
        CapabilityModel.load(folder, device="cuda")
    assert card["learner"] == "boosted" and card["members_count"] == 2
    with pytest.raises(QzError, match="boosted.members"):
        B.BoostedConfig(members=0).check()


def test_plans_a_capability_map(trained):
    _, _, _, _, folder = trained
    from qz_drake.terrain import HeightMap

    model = CapabilityModel.load(folder)
    heights = np.zeros((60, 60))
    heights[:, 30:] = 0.25  # a riser the synthetic robot cannot climb
    terrain = HeightMap(heights, 0.1, origin=(0.0, 0.0))
    capability = model.map_success(terrain, ["nominal", "split_up"])
    assert capability.forward.shape[:2] == (2, 8)
    assert capability.forward_plan is not None and capability.forward_spread is not None
    xs = capability.xs
    # Heading 0 (+x) from the cell just before the riser is worse than on the flat far from it.
    near, far = int(np.argmin(np.abs(xs - 2.5))), int(np.argmin(np.abs(xs - 0.5)))
    assert capability.forward[0, 0, :, near].mean() < capability.forward[0, 0, :, far].mean() - 0.3


def test_a_map_taken_in_bands_of_rows_is_the_whole_map(trained, monkeypatch):
    """A boosted model answers each query on its own, so predict_map takes a large map a band
    of rows at a time (memory): every array the same as in one pass."""
    from qz_drake.capability import model_base
    from qz_drake.terrain import make_terrain

    _, _, _, _, folder = trained
    model = CapabilityModel.load(folder)
    terrain = make_terrain("long_range", seed=3)
    whole = model_base.predict_map(model, terrain, ["nominal", "split_up"], anchor=(1.0, 1.0))
    monkeypatch.setattr(model_base, "MAP_BAND_QUERIES", 8 * len(whole.xs) * 3)  # bands of 3 rows
    banded = model_base.predict_map(model, terrain, ["nominal", "split_up"], anchor=(1.0, 1.0))
    assert len(whole.ys) > 6
    for field in ("xs", "ys", "forward", "turn_left", "turn_right", "forward_plan", "turn_left_plan",
                  "turn_right_plan", "forward_spread", "turn_left_spread", "turn_right_spread",
                  "plan_failure_share"):
        np.testing.assert_array_equal(getattr(banded, field), getattr(whole, field), err_msg=field)
    assert banded.topologies == whole.topologies and banded.cell_size == whole.cell_size


def test_cli_trains_a_boosted_model(tmp_path, monkeypatch, capsys):
    from qz_drake.capability import model_commands
    from qz_drake.cli import main

    arrays, manifest, _ = _three_outcome_data(seed=1)
    monkeypatch.setattr(model_commands, "load_dataset", lambda path: (arrays, manifest))
    out = tmp_path / "model"
    assert main(["capability", "train", "--dataset", "unused", "--out", str(out), "--learner", "boosted",
                 "--members", "1", "--max-iter", "30", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["learner"] == "boosted" and summary["test"][0]["network"] == "all"
    assert isinstance(CapabilityModel.load(out), B.BoostedCapabilityModel)
    assert main(["capability", "train", "--dataset", "unused", "--out", str(out), "--learner", "boosted",
                 "--members", "0"]) == 2
    assert "--members" in capsys.readouterr().err
    assert main(["capability", "train", "--dataset", "unused", "--out", str(out), "--members", "2"]) == 2
    assert "only the boosted learner" in capsys.readouterr().err


def _plan_chain_data():
    """Missions labelled by the BLC alone on other scenes (ids 1000 on): a rule the executed
    records never show, a nominal start with its fourth foot 0.1 m up, is not planned."""
    arrays, _ = synthetic_arrays(scenes=60, headings=6, topologies=("nominal", "split_up"),
                                 kinds=("orthogonal", "diagonal", "turn"), failure_band=0.06, label_noise=0.0, seed=7)
    arrays["scene"] = arrays["scene"] + 1000
    raised = np.arange(len(arrays["scene"])) % 3 == 1
    arrays["feet"][raised, 3, 2] += 0.1
    arrays["blc_success"][raised & (arrays["topology"] == "nominal")] = False
    arrays["success"][:] = False  # not walked: means nothing
    arrays["direction"] = np.asarray(arrays["direction"])
    return arrays


@pytest.fixture(scope="module")
def planned(trained, tmp_path_factory):
    arrays, manifest, _, _, _ = trained
    chains = _plan_chain_data()
    result = B.train_boosted(arrays, fingerprint=manifest["fingerprint"], fingerprints=manifest["fingerprints"],
                             config=B.BoostedConfig(members=2, max_iter=40, learning_rate=0.25),
                             plan_arrays=chains, plan_source={"dataset": "synthetic"})
    folder = B.save_boosted(result, tmp_path_factory.mktemp("planned"))
    return chains, result, folder


def test_plan_learners_learn_a_refusal_only_the_plan_chains_show(trained, planned):
    arrays, _, _, alone_result, _ = trained
    chains, result, folder = planned
    # The outcome learners are those trained without the chains (same bootstraps and seeds).
    for a, b in zip(result.members, alone_result.members):
        for name, value in a.arrays().items():
            np.testing.assert_array_equal(value, b.arrays()[name], err_msg=name)
    assert len(result.plan_members) == 2 and all(t.roots.shape[1] == 1 for t in result.plan_members)
    model = CapabilityModel.load(folder)
    assert isinstance(model, B.BoostedCapabilityModel) and len(model.plan_members) == 2
    alone = B.BoostedCapabilityModel(alone_result.members, alone_result.card)
    # Flat orthogonal starts of the chains' test scenes, the fourth foot raised 0.1 m.
    test = np.isin(chains["scene"], result.card["plan_learner"]["split"]["test"])
    height = chains["patch"].max(axis=(1, 2)) - chains["patch"].min(axis=(1, 2))
    rows = np.flatnonzero(test & (height < SYNTHETIC_MAX_STEP - 0.02) & (chains["kind"] == "orthogonal")
                          & (np.arange(len(test)) % 3 != 1))
    assert len(rows) > 10
    feet = chains["feet"][rows].copy()
    feet[:, 3, 2] += 0.1
    with_plan = model.outcomes(chains["patch"][rows], feet, "orthogonal", "nominal")
    without = alone.outcomes(chains["patch"][rows], feet, "orthogonal", "nominal")
    assert with_plan[:, 1].mean() > 0.7 and without[:, 1].mean() < 0.3
    np.testing.assert_allclose(with_plan.sum(axis=1), 1.0, atol=1e-12)
    # Walked and failed share the rest as the outcome learners share them.
    ratio = lambda p: p[:, 0] / (p[:, 0] + p[:, 2])  # noqa: E731
    member = model.member_outcomes(B.features(chains["patch"][rows], feet, "orthogonal", "nominal"))
    member_alone = alone.member_outcomes(B.features(chains["patch"][rows], feet, "orthogonal", "nominal"))
    for m in range(2):
        np.testing.assert_allclose(ratio(member[m]), ratio(member_alone[m]), rtol=1e-12)
    # The card scores no plan on the chains' test scenes with and without the plan learners.
    scores = result.card["test_plan"]
    with_plan, without = scores["with_plan_learners"]["no_plan"], scores["outcome_learners_alone"]["no_plan"]
    assert with_plan["auc"] > 0.99 and without["auc"] < 0.95, (with_plan["auc"], without["auc"])
    assert with_plan["brier"] < 0.5 * without["brier"]
    assert result.card["plan_learner"]["source"] == {"dataset": "synthetic"}
    assert not set(result.card["plan_learner"]["split"]["test"]) & set(result.card["plan_learner"]["split"]["train"])


def test_a_map_with_plan_learners_answers_each_query_as_on_its_own(planned, monkeypatch):
    chains, _, folder = planned
    model = CapabilityModel.load(folder)
    rows = np.arange(100)
    patches, feet = chains["patch"][rows].reshape(4, 25, 20, 20), chains["feet"][rows].reshape(4, 25, 6, 3)
    whole = model.success_all(patches, {"nominal": feet, "split_up": feet[::-1]}, "turn")
    monkeypatch.setenv("QZ_TORCH_THREADS", "1")
    monkeypatch.setattr(B, "MAP_CHUNK", 7)
    chunked = model.success_all(patches, {"nominal": feet, "split_up": feet[::-1]}, "turn")
    for topology, f in (("nominal", feet), ("split_up", feet[::-1])):
        for one, other in zip(whole[topology], chunked[topology]):
            np.testing.assert_array_equal(one, other)
        for d in (0, 1):
            X = B.features(patches.reshape(100, 20, 20), f.reshape(100, 6, 3), "turn", topology, d)
            probs = model.member_outcomes(X)
            np.testing.assert_array_equal(whole[topology][0][d].reshape(100), probs[..., 0].mean(axis=0))
            np.testing.assert_array_equal(whole[topology][1][d].reshape(100), (1.0 - probs[..., 1]).mean(axis=0))
    # Node by node (no scorer) the same numbers.
    X = B.features(patches.reshape(100, 20, 20), feet.reshape(100, 6, 3), "turn", "nominal", 0)
    walked = B.BoostedCapabilityModel(model.members, model.card, plan_members=model.plan_members)
    walked._scorer, walked._plan_scorer = None, None
    np.testing.assert_allclose(walked.member_outcomes(X), model.member_outcomes(X), rtol=0, atol=1e-12)


def test_plan_learners_are_checked_on_load_and_on_the_command_line(trained, planned, tmp_path, monkeypatch, capsys):
    from qz_drake.capability import dataset, model_commands
    from qz_drake.cli import main

    chains, result, folder = planned
    card = json.loads((folder / "model.json").read_text())
    assert card["plan_members_count"] == 2
    card["plan_members_count"] = 1
    (folder / "model.json").write_text(json.dumps(card))
    with pytest.raises(CapabilityModelError, match="plan_members_count"):
        CapabilityModel.load(folder)
    card["plan_members_count"] = 2
    (folder / "model.json").write_text(json.dumps(card))
    with pytest.raises(QzError, match="plan learner beside each"):
        B.BoostedCapabilityModel(result.members, result.card, plan_members=result.plan_members[:1])
    arrays, manifest, _, _, _ = trained
    monkeypatch.setattr(model_commands, "load_dataset", lambda path: (arrays, manifest))
    monkeypatch.setattr(dataset, "load_plan_arrays", lambda path: (chains, dict(manifest)))
    out = tmp_path / "model"
    assert main(["capability", "train", "--dataset", "d", "--plan-dataset", "p", "--out", str(out),
                 "--learner", "boosted", "--members", "1", "--max-iter", "30", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["test_plan"]["with_plan_learners"]["n"] > 0
    assert len(CapabilityModel.load(out).plan_members) == 1
    # Chains labelled by another BLC are refused; the networks take no chains.
    other = dict(manifest, fingerprints=dict(manifest["fingerprints"], blc="another"))
    monkeypatch.setattr(dataset, "load_plan_arrays", lambda path: (chains, other))
    assert main(["capability", "train", "--dataset", "d", "--plan-dataset", "p", "--out", str(out),
                 "--learner", "boosted"]) == 2
    assert "another BLC-robot system" in capsys.readouterr().err
    assert main(["capability", "train", "--dataset", "d", "--plan-dataset", "p", "--out", str(out)]) == 2
    assert "only the boosted learner" in capsys.readouterr().err
