"""CapabilityModel: save / load round trip, refusals, batched queries from a HeightMap, and the
train / evaluate / map commands (on synthetic data, the lead's dataset reader stubbed)."""

import argparse
import json
import subprocess
import sys

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from qz_drake.cli.capability import SUMMARY_KEYS, register_model_commands  # noqa: E402
from qz_drake.capability import model_commands  # noqa: E402
from qz_drake.capability import patches as P  # noqa: E402
from qz_drake.capability.model import CapabilityModel, save_model  # noqa: E402
from qz_drake.capability.synthetic import synthetic_arrays  # noqa: E402
from qz_drake.capability.training import TrainingConfig, train_networks  # noqa: E402
from qz_drake.errors import QzError  # noqa: E402
from qz_drake.terrain import make_terrain  # noqa: E402

torch.set_num_threads(1)
TINY = dict(max_epochs=3, patience=2, losses=["bce"], min_train_trials=10, min_train_per_class=1)


@pytest.fixture(scope="module")
def data():
    return synthetic_arrays(scenes=12, headings=5, seed=4)


@pytest.fixture(scope="module")
def trained(data):
    arrays, manifest = data
    config = TrainingConfig(networks=["nominal/orthogonal", "nominal/diagonal", "nominal/turn"], **TINY)
    return train_networks(arrays, fingerprint=manifest["fingerprint"], fingerprints=manifest["fingerprints"],
                          config=config)


@pytest.fixture
def saved(trained, tmp_path):
    return save_model(trained, tmp_path / "model")


def test_round_trip_is_bit_for_bit(trained, saved, data):
    arrays, manifest = data
    loaded = CapabilityModel.load(saved, fingerprint=manifest["fingerprint"])
    memory = CapabilityModel.from_training(trained)
    assert loaded.networks == memory.networks == [("nominal", k) for k in ("diagonal", "orthogonal", "turn")]
    for kind in P.KINDS:
        rows = arrays["kind"] == kind
        direction = arrays["direction"][rows] if kind == "turn" else None
        a = loaded.success(arrays["patch"][rows], arrays["feet"][rows], kind, "nominal", direction=direction)
        b = memory.success(arrays["patch"][rows], arrays["feet"][rows], kind, "nominal", direction=direction)
        assert a.dtype == np.float64 and np.array_equal(a, b)
    card = json.loads((saved / "nominal_turn.json").read_text())
    assert card["fingerprint"] == manifest["fingerprint"] and card["training_config"]["losses"] == ["bce"]
    assert set(card["test"]) >= {"auc", "brier", "ece", "accuracy"}
    top = json.loads((saved / "model.json").read_text())
    assert "split_up/turn" in top["missing"] and top["fingerprints"] == manifest["fingerprints"]


def test_queries_batch_over_any_shape(trained, data):
    arrays, _ = data
    model = CapabilityModel.from_training(trained)
    rows = np.nonzero(arrays["kind"] == "orthogonal")[0][:6]
    flat = model.success(arrays["patch"][rows], arrays["feet"][rows], "orthogonal", "nominal")
    shaped = model.success(arrays["patch"][rows].reshape(2, 3, 20, 20), arrays["feet"][rows].reshape(2, 3, 6, 3),
                           "orthogonal", "nominal")
    assert shaped.shape == (2, 3) and np.allclose(shaped.ravel(), flat, atol=1e-7)
    with pytest.raises(QzError, match="direction"):
        model.success(arrays["patch"][rows], arrays["feet"][rows], "turn", "nominal")
    # Both turn directions from one pass of the patch head.
    left, right = model.turn_success(arrays["patch"][rows], arrays["feet"][rows], "nominal")
    for d, p in ((0, left), (1, right)):
        assert np.allclose(p, model.success(arrays["patch"][rows], arrays["feet"][rows], "turn", "nominal", d),
                           atol=1e-7)
    with pytest.raises(QzError, match="feet"):
        model.success(arrays["patch"][rows], arrays["feet"][rows][:2], "orthogonal", "nominal")


def test_missing_network_is_an_explicit_error(trained):
    model = CapabilityModel.from_training(trained)
    with pytest.raises(QzError, match=r"model.networks = 'split_up/diagonal'.*not trained: not requested"):
        model.success(np.zeros((1, 20, 20)), np.zeros((1, 6, 3)), "diagonal", "split_up")
    with pytest.raises(QzError, match="split_up/orthogonal"):
        model.map_success(make_terrain("flat"), ["nominal", "split_up"])


def test_foreign_weights_are_refused(saved, tmp_path):
    from safetensors.torch import save_file

    weights = saved / "nominal_orthogonal.safetensors"
    save_file({"w": torch.zeros(3)}, str(weights))  # a valid safetensors file, not ours
    with pytest.raises(QzError) as error:
        CapabilityModel.load(saved)
    assert "model.networks.nominal/orthogonal.weights" in str(error.value) and "\n" not in str(error.value)
    weights.write_bytes(b"not a safetensors file at all")
    with pytest.raises(QzError, match="not a safetensors file"):
        CapabilityModel.load(saved)


def test_replaced_weights_are_refused(saved):
    # Our format, right network, but not the file the card describes.
    (saved / "nominal_orthogonal.safetensors").write_bytes((saved / "nominal_orthogonal.safetensors").read_bytes())
    card_path = saved / "nominal_orthogonal.json"
    card = json.loads(card_path.read_text())
    card["weights_sha256"] = "0" * 64
    card_path.write_text(json.dumps(card))
    with pytest.raises(QzError, match="SHA-256"):
        CapabilityModel.load(saved)


def test_a_model_of_another_robot_is_refused_where_it_is_loaded(saved):
    # Every planner that loads a model gets the check (it was in two of eight callers).
    from qz_drake.capability.dataset import robot_fingerprint
    from qz_drake.capability.model import MODEL_CARD

    top = json.loads((saved / MODEL_CARD).read_text())
    top["fingerprints"] = dict(top["fingerprints"], robot=robot_fingerprint())
    (saved / MODEL_CARD).write_text(json.dumps(top))
    CapabilityModel.load(saved)
    top["fingerprints"]["robot"] = "0123456789abcdef"
    (saved / MODEL_CARD).write_text(json.dumps(top))
    with pytest.raises(QzError, match=r"model.fingerprints.robot = '0123456789abcdef': the model was trained on "
                                      r"another robot configuration"):
        CapabilityModel.load(saved)


def test_card_with_another_fingerprint_is_refused(saved):
    card_path = saved / "nominal_diagonal.json"
    card = json.loads(card_path.read_text())
    card["fingerprint"] = "someone-else"
    card_path.write_text(json.dumps(card))
    with pytest.raises(QzError, match=r"model.networks.nominal/diagonal.fingerprint = 'someone-else'"):
        CapabilityModel.load(saved)


def test_expected_fingerprint_and_missing_directory(saved, tmp_path, monkeypatch):
    with pytest.raises(QzError, match="model.fingerprint"):
        CapabilityModel.load(saved, fingerprint="another-dataset")
    with pytest.raises(QzError, match="not a model directory"):
        CapabilityModel.load(tmp_path / "nowhere")
    from qz_drake.capability import model as model_module
    monkeypatch.setattr(model_module, "DEFAULT_MODEL_DIR", tmp_path / "not-shipped")
    with pytest.raises(QzError, match="no model has been shipped yet"):
        CapabilityModel.load()


def test_importing_the_model_does_not_import_torch():
    code = "import sys, qz_drake.capability.model, qz_drake.capability.model_commands; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_query_inputs_and_map_success_agree_with_patches(trained):
    model = CapabilityModel.from_training(trained)
    heightmap = make_terrain("stairs", rise=0.1, count=2)
    patches, feet = model.query_inputs(heightmap, [0.5, 1.5], [0.5, -0.5], [0, 3], "diagonal", "nominal")
    assert patches.shape == (2, 20, 20) and feet.shape == (2, 6, 3)
    yaw = P.heading_yaw(np.array([0, 3]))
    assert np.array_equal(patches, P.sample_patches(heightmap, np.array([0.5, 1.5]), np.array([0.5, -0.5]), yaw,
                                                    "diagonal"))
    cmap = model.map_success(heightmap, ["nominal"])
    xs, ys = P.grid_centres(heightmap)
    assert cmap.forward.shape == (1, 8, len(ys), len(xs)) and cmap.queries == 3 * 8 * len(xs) * len(ys)
    # One cell and heading, recomputed on its own.
    i, j, k = 1, 2, 3
    p, f = model.query_inputs(heightmap, xs[j], ys[i], k, "diagonal", "nominal")
    assert cmap.forward[0, k, i, j] == pytest.approx(float(model.success(p, f, "diagonal", "nominal")), abs=1e-6)
    p, f = model.query_inputs(heightmap, xs[j], ys[i], k, "turn", "nominal")
    assert cmap.turn_right[0, k, i, j] == pytest.approx(float(model.success(p, f, "turn", "nominal", 1)), abs=1e-6)


@pytest.mark.parametrize("kind", ["orthogonal", "turn"])
def test_all_topologies_at_once_give_each_networks_own_answer(kind):
    """success_all (the first convolutions of all topologies stacked, each network's input
    standardisation folded into its kernels, zero padding included) gives what each network
    gives alone, on networks that standardise with different scalars and have a plan output."""
    model = CapabilityModel.random(seed=3)
    rng = np.random.default_rng(0)
    with torch.no_grad():
        for i, (t, k) in enumerate(model.networks):
            net = model.network(t, k)
            net.patch_mean.fill_(0.02 * i - 0.1)
            net.patch_scale.fill_(0.05 + 0.01 * i)
            net.extra_mean.normal_(0.0, 0.2)
            net.extra_scale.uniform_(0.05, 0.5)
    topologies = ["nominal", "front_bend", "split_up"]
    patches = rng.normal(0.0, 0.08, (3, 5, 20, 20)) + rng.uniform(-0.2, 0.2, (3, 5, 1, 1))
    feet = {t: model.query_inputs(make_terrain("flat"), np.zeros((3, 5)), np.zeros((3, 5)), 0, kind, t)[1]
            for t in topologies}
    together = model.success_all(patches, feet, kind)
    means = {float(model.network(t, kind).patch_mean) for t in topologies}
    assert len(means) == len(topologies)  # the folding is exercised with different scalars
    for t in topologies:
        success, plan, spread = together[t]
        assert spread is None  # single networks
        net = model.network(t, kind)
        directions = (0, 1) if kind == "turn" else (None,)
        assert success.shape == ((2, 3, 5) if kind == "turn" else (3, 5))
        for i, d in enumerate(directions):
            alone = model.success(patches, feet[t], kind, t, d)
            np.testing.assert_allclose(success[i] if kind == "turn" else success, alone, atol=2e-6)
            if net.factored:  # the plan output, recomputed by the network alone
                extra = feet[t].reshape(15, 18).astype(np.float32)
                if d is not None:
                    extra = np.column_stack([extra, np.full(15, d, np.float32)])
                with torch.no_grad():
                    expected = net.plan_probability(torch.as_tensor(patches.reshape(15, 20, 20).astype(np.float32)),
                                                    torch.as_tensor(extra)).numpy().reshape(3, 5)
                np.testing.assert_allclose(plan[i] if kind == "turn" else plan, expected, atol=2e-6)
            else:
                assert plan is None
    with pytest.raises(QzError, match=r"feet\[split_up\]"):
        model.success_all(patches, {**feet, "split_up": feet["split_up"][:2]}, kind)


def test_distinct_rows_is_exact():
    """distinct_rows groups equal rows only: every row is its group's first exactly, NaN rows
    stand alone, and the groups are as many as the distinct rows."""
    from qz_drake.capability.model import distinct_rows

    rng = np.random.default_rng(3)
    base = rng.normal(size=(7, 400)).astype(np.float32)
    rows = base[rng.integers(0, 7, 500)].copy()
    rows[10, 3] = np.nan
    rows[11] = rows[12]
    rows[12, 399] = np.nextafter(rows[12, 399], np.float32(1.0))  # one ulp apart: not equal
    first, inverse = distinct_rows(rows)
    same = (rows[first[inverse]] == rows) | (np.isnan(rows) & (np.arange(500) == 10)[:, None])
    assert same.all() and inverse[10] not in np.delete(inverse, 10)
    assert len(set(inverse.tolist())) == len({r.tobytes() for r in rows})


@pytest.mark.parametrize("kind", ["diagonal", "turn"])
def test_repeated_patches_are_evaluated_once_and_answer_as_each_query(kind):
    """success_all runs the convolutions once per distinct patch (flat ground repeats one):
    queries that share a patch but stand on other feet get their own answers, the same as
    the same queries given apart."""
    model = CapabilityModel.random(seed=2)
    rng = np.random.default_rng(4)
    distinct = rng.normal(0.0, 0.08, (3, 20, 20))
    pick = rng.integers(0, 3, 40)
    patches = distinct[pick]
    feet = model.query_inputs(make_terrain("flat"), np.zeros(40), np.zeros(40), 1, kind, "nominal")[1]
    feet = feet + rng.normal(0.0, 0.02, feet.shape)  # every query its own feet
    together = model.success_all(patches, {"nominal": feet}, kind)["nominal"][0]
    for i in range(0, 40, 7):
        alone = model.success_all(patches[i:i + 1], {"nominal": feet[i:i + 1]}, kind)["nominal"][0]
        np.testing.assert_allclose(together[..., i], alone[..., 0], atol=1e-6)
    assert np.ptp(together[..., pick == pick[0]]) > 0  # one patch, other feet: other answers


# -- commands ---------------------------------------------------------------------------------
def _parser():
    parser = argparse.ArgumentParser(prog="qz capability")
    register_model_commands(parser.add_subparsers(dest="command", required=True))
    return parser


def test_commands_train_evaluate_map(data, tmp_path, monkeypatch, capsys):
    arrays, manifest = data
    monkeypatch.setattr(model_commands, "load_dataset", lambda path: (arrays, manifest))
    from qz_drake.capability import training
    monkeypatch.setattr(training, "TrainingConfig", lambda seed: TrainingConfig(seed=seed, **TINY))
    parser = _parser()
    args = parser.parse_args(["train", "--dataset", "ds", "--out", str(tmp_path / "m"), "--json",
                              "--network", "nominal/orthogonal", "--network", "nominal/turn"])
    assert args.func(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert [(r["topology"], r["kind"]) for r in summary["networks"]] == [("nominal", "orthogonal"), ("nominal", "turn")]
    assert all((tmp_path / "m" / name).is_file() for name in ("reliability.png", "confusion.png", "model.json"))

    # Without --json: progress bars and the table.
    args = parser.parse_args(["train", "--dataset", "ds", "--out", str(tmp_path / "m2"), "--network", "nominal/turn"])
    assert args.func(args) == 0
    printed = capsys.readouterr().out
    assert "nominal/turn" in printed and "not requested: nominal/orthogonal" in printed

    args = parser.parse_args(["evaluate", "--model", str(tmp_path / "m"), "--dataset", "ds", "--json"])
    assert args.func(args) == 0
    result = json.loads(capsys.readouterr().out)
    entries = {(e["topology"], e["kind"]): e for e in result["networks"]}
    assert set(entries[("nominal", "orthogonal")]) == set(SUMMARY_KEYS)
    assert entries[("nominal", "orthogonal")]["n"] == int(np.sum((arrays["kind"] == "orthogonal")
                                                                   & (arrays["topology"] == "nominal")))
    assert entries[("nominal", "diagonal")].get("missing") is True

    # Other scenes are fine (the same metrics on any dataset of this BLC-robot system) ...
    scenes = dict(manifest, fingerprint="other", fingerprints=dict(manifest["fingerprints"], scenes="other-scenes"))
    monkeypatch.setattr(model_commands, "load_dataset", lambda path: (arrays, scenes))
    assert args.func(args) == 0
    capsys.readouterr()
    # ... another BLC is not.
    other = dict(manifest, fingerprints=dict(manifest["fingerprints"], blc="another-blc"))
    monkeypatch.setattr(model_commands, "load_dataset", lambda path: (arrays, other))
    with pytest.raises(QzError, match=r"dataset.manifest.fingerprints.blc = 'another-blc'"):
        args.func(args)
    # A dataset recertified since the model was trained (the BLC's code changed, a sample of
    # its trials re-ran the same) still has the model's labels; one whose certification came
    # from yet another BLC does not.
    certified = dict(other, certifications=[{"fingerprints_before": dict(manifest["fingerprints"]),
                                             "fingerprints_after": dict(other["fingerprints"])}])
    monkeypatch.setattr(model_commands, "load_dataset", lambda path: (arrays, certified))
    assert args.func(args) == 0
    capsys.readouterr()
    unrelated = dict(other, certifications=[{"fingerprints_before": dict(manifest["fingerprints"], blc="third-blc"),
                                             "fingerprints_after": dict(other["fingerprints"])}])
    monkeypatch.setattr(model_commands, "load_dataset", lambda path: (arrays, unrelated))
    with pytest.raises(QzError, match=r"dataset.manifest.fingerprints.blc = 'another-blc'"):
        args.func(args)

    heightmap_file = make_terrain("step", height=0.3, size_x=4.0, size_y=3.0).save_npz(tmp_path / "step.npz")
    args = parser.parse_args(["map", "--model", str(tmp_path / "m"), "--terrain", str(heightmap_file),
                              "--topology", "nominal", "--out", str(tmp_path / "map.png")])
    with pytest.raises(QzError, match="nominal/diagonal"):  # the model lacks it: no silent fallback
        args.func(args)


def test_map_command_draws_a_png(saved, tmp_path, capsys):
    args = _parser().parse_args(["map", "--model", str(saved), "--terrain", "stairs", "--terrain-param", "rise=0.1",
                                 "--topology", "nominal", "--out", str(tmp_path / "map.png")])
    assert args.func(args) == 0
    out = json.loads(capsys.readouterr().out)
    assert (tmp_path / "map.png").stat().st_size > 1000 and 0.0 <= out["min_forward_success"] <= 1.0
    bad = _parser().parse_args(["map", "--model", str(saved), "--terrain", "flat", "--topology", "upside_down",
                                "--out", str(tmp_path / "x.png")])
    with pytest.raises(QzError, match="--topology"):
        bad.func(bad)


def test_default_model_missing_is_a_clear_error(tmp_path, monkeypatch):
    from qz_drake.capability import model as model_module
    monkeypatch.setattr(model_module, "DEFAULT_MODEL_DIR", tmp_path / "capability_model")
    args = _parser().parse_args(["evaluate", "--dataset", "ds", "--json"])
    with pytest.raises(QzError, match="no model has been shipped yet"):
        args.func(args)


@pytest.mark.parametrize("kind", ["orthogonal", "diagonal", "turn"])
def test_the_compiled_map_sampler_gives_exactly_the_training_patches(kind):
    """Planning samples whole maps with a compiled kernel; the networks were trained on
    patches.sample_patches. The two must agree to the bit, inside the map and off its edges."""
    from qz_drake.capability.map_sampling import sample_patches_fast
    from qz_drake.terrain import make_terrain

    heightmap = make_terrain("long_range", seed=3)
    xmin, xmax, ymin, ymax = heightmap.bounds
    rng = np.random.default_rng(1)
    n = 500
    x = rng.uniform(xmin - 2, xmax + 2, n)
    y = rng.uniform(ymin - 2, ymax + 2, n)
    yaw = rng.integers(0, 8, n) * np.pi / 4 + rng.normal(0, 0.01, n)
    ground = rng.uniform(-0.2, 0.2, n)
    expected = P.sample_patches(heightmap, x, y, yaw, kind, ground)
    got = sample_patches_fast(heightmap, x.reshape(20, 25), y.reshape(20, 25), yaw.reshape(20, 25), kind,
                              ground.reshape(20, 25))
    assert got.dtype == np.float32 and got.shape == (20, 25, 20, 20)
    assert np.array_equal(got.reshape(n, 20, 20), expected)


def test_the_compiled_ground_reference_is_the_cells_median():
    """A map's cells stand on patches.ground_reference's height; the compiled sampler gives the
    same numbers, inside the map and off its edges."""
    from qz_drake.capability.map_sampling import ground_reference_fast
    from qz_drake.terrain import make_terrain

    heightmap = make_terrain("long_range", seed=3)
    xmin, xmax, ymin, ymax = heightmap.bounds
    rng = np.random.default_rng(2)
    x, y = rng.uniform(xmin - 2, xmax + 2, (30, 10)), rng.uniform(ymin - 2, ymax + 2, (30, 10))
    got = ground_reference_fast(heightmap, x, y)
    assert got.shape == (30, 10) and np.array_equal(got, P.ground_reference(heightmap, x, y))


@pytest.mark.parametrize("kind", ["diagonal", "turn"])
def test_an_ensembles_map_is_its_members_mean_with_their_spread(trained, saved, kind):
    """The default training makes deep ensembles (TrainingConfig.ensemble); saved and loaded,
    success_all (all members' first convolutions stacked) gives the members' mean success and
    plan and the standard deviation of their success."""
    model = CapabilityModel.load(saved)
    net = model.network("nominal", kind)
    assert len(net.members) == TrainingConfig().ensemble > 1
    rng = np.random.default_rng(1)
    patches = rng.normal(0.0, 0.08, (4, 3, 20, 20)) + rng.uniform(-0.2, 0.2, (4, 3, 1, 1))
    feet = model.query_inputs(make_terrain("flat"), np.zeros((4, 3)), np.zeros((4, 3)), 1, kind, "nominal")[1]
    success, plan, spread = model.success_all(patches, {"nominal": feet}, kind)["nominal"]
    for i, d in enumerate((0, 1) if kind == "turn" else (None,)):
        extra = feet.reshape(12, 18).astype(np.float32)
        if d is not None:
            extra = np.column_stack([extra, np.full(12, d, np.float32)])
        x, e = torch.as_tensor(patches.reshape(12, 20, 20).astype(np.float32)), torch.as_tensor(extra)
        with torch.no_grad():
            each = np.stack([m.probability(x, e).numpy() for m in net.members]).reshape(-1, 4, 3)
            plans = np.stack([m.plan_probability(x, e).numpy() for m in net.members]).reshape(-1, 4, 3)
        pick = (lambda a: a[i]) if kind == "turn" else (lambda a: a)
        np.testing.assert_allclose(pick(success), each.mean(0), atol=2e-6)
        np.testing.assert_allclose(pick(spread), each.std(0), atol=2e-6)
        np.testing.assert_allclose(pick(plan), plans.mean(0), atol=2e-6)
        np.testing.assert_allclose(model.success(patches, feet, kind, "nominal", d), each.mean(0), atol=2e-6)
    assert (spread > 0).all()
