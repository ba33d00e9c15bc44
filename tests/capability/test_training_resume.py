"""An interrupted ``qz capability train`` keeps the networks it finished, and the same command
goes on from them (qz_drake.capability.model_commands.train_resumably), on a tiny synthetic
dataset."""

import argparse
import json

import pytest

torch = pytest.importorskip("torch")

from qz_drake.cli.capability import register_model_commands  # noqa: E402
from qz_drake.capability import model_commands, training  # noqa: E402
from qz_drake.capability.model import UNFINISHED_DIR, CapabilityModel  # noqa: E402
from qz_drake.capability.synthetic import synthetic_arrays  # noqa: E402
from qz_drake.capability.training import TrainingConfig  # noqa: E402
from qz_drake.errors import QzError  # noqa: E402

torch.set_num_threads(1)
NETWORKS = ["nominal/orthogonal", "nominal/diagonal", "nominal/turn"]
TINY = dict(max_epochs=3, patience=2, losses=["bce"], min_train_trials=10, min_train_per_class=1)
TRAIN_ONE = training.train_one


@pytest.fixture(scope="module")
def data():
    return synthetic_arrays(scenes=12, headings=5, seed=4)


def _config(**changes):
    return TrainingConfig(networks=list(NETWORKS), **{**TINY, **changes})


class _Trainings:
    """Wraps training.train_one: records the networks trained, and interrupts (as Ctrl-C
    does) the one numbered ``interrupt_at`` (1-based)."""

    def __init__(self, monkeypatch, interrupt_at=None):
        self.trained, self._interrupt_at = [], interrupt_at

        def train_one(arrays, rows, topology, kind, *args, **kwargs):
            if len(self.trained) + 1 == self._interrupt_at:
                raise KeyboardInterrupt
            self.trained.append(f"{topology}/{kind}")
            return TRAIN_ONE(arrays, rows, topology, kind, *args, **kwargs)

        monkeypatch.setattr(training, "train_one", train_one)


def _interrupt_after_the_first(data, out, monkeypatch):
    """Trains NETWORKS into ``out`` and stops with Ctrl-C as the second network starts."""
    arrays, manifest = data
    trainings = _Trainings(monkeypatch, interrupt_at=2)
    with pytest.raises(KeyboardInterrupt):
        model_commands.train_resumably(arrays, manifest, _config(), out)
    assert trainings.trained == ["nominal/orthogonal"]


def _weights(model_dir):
    model = CapabilityModel.load(model_dir)
    return {key: model.network(*key).state_dict() for key in model.networks}


def test_an_interrupted_training_resumes_with_the_missing_networks_only(data, tmp_path, monkeypatch):
    arrays, manifest = data
    whole = tmp_path / "whole"
    model_commands.train_resumably(arrays, manifest, _config(), whole)

    out = tmp_path / "interrupted"
    _interrupt_after_the_first(data, out, monkeypatch)
    # What finished is on disk; no model.json yet: the folder is not mistaken for a model.
    assert sorted(p.name for p in (out / UNFINISHED_DIR).iterdir()) == ["nominal_orthogonal.json",
                                                                        "nominal_orthogonal.safetensors"]
    assert not (out / "model.json").exists()

    again = _Trainings(monkeypatch)
    result, resumed = model_commands.train_resumably(arrays, manifest, _config(), out)
    assert again.trained == ["nominal/diagonal", "nominal/turn"]
    assert resumed == [("nominal", "orthogonal")]
    assert list(result.networks) == [("nominal", "orthogonal"), ("nominal", "diagonal"), ("nominal", "turn")]
    assert not (out / UNFINISHED_DIR).exists()
    # The same networks, bit for bit, as the training that was never interrupted.
    expected, got = _weights(whole), _weights(out)
    assert sorted(expected) == sorted(got)
    for key in expected:
        for name, tensor in expected[key].items():
            assert torch.equal(tensor, got[key][name]), (key, name)


def test_a_resume_with_other_settings_or_data_is_refused(data, tmp_path, monkeypatch):
    arrays, manifest = data
    out = tmp_path / "model"
    _interrupt_after_the_first(data, out, monkeypatch)

    with pytest.raises(QzError, match=r"training_identity\.training_config\.max_epochs = 3: .*4.*--restart"):
        model_commands.train_resumably(arrays, manifest, _config(max_epochs=4), out)
    fewer = {k: v[:-5] for k, v in arrays.items()}  # the same fingerprints, other trials
    with pytest.raises(QzError, match=r"training_identity\.dataset_digest"):
        model_commands.train_resumably(fewer, manifest, _config(), out)
    # Fewer networks requested is the same training: the finished one is taken as it is.
    trainings = _Trainings(monkeypatch)
    result, resumed = model_commands.train_resumably(arrays, manifest, TrainingConfig(
        networks=["nominal/orthogonal", "nominal/turn"], **TINY), out)
    assert resumed == [("nominal", "orthogonal")] and trainings.trained == ["nominal/turn"]


def test_restart_discards_an_interrupted_training(data, tmp_path, monkeypatch):
    arrays, manifest = data
    out = tmp_path / "model"
    _interrupt_after_the_first(data, out, monkeypatch)
    trainings = _Trainings(monkeypatch)
    _, resumed = model_commands.train_resumably(arrays, manifest, _config(max_epochs=4), out, restart=True)
    assert resumed == [] and trainings.trained == NETWORKS


def _train_args(out, *extra):
    parser = argparse.ArgumentParser(prog="qz capability")
    register_model_commands(parser.add_subparsers(dest="command", required=True))
    return parser.parse_args(["train", "--dataset", "ds", "--out", str(out), "--network", "nominal/turn", *extra])


def test_the_command_says_what_it_kept_and_is_silent_with_json(data, tmp_path, monkeypatch, capsys):
    arrays, manifest = data
    monkeypatch.setattr(model_commands, "load_dataset", lambda path: (arrays, manifest))
    monkeypatch.setattr(training, "TrainingConfig", lambda seed: TrainingConfig(seed=seed, **TINY))
    # As on a terminal: rich draws its bar on stderr.
    monkeypatch.setenv("TTY_COMPATIBLE", "1")
    args = _train_args(tmp_path / "m")
    assert args.func(args) == 0
    captured = capsys.readouterr()
    assert "training networks" in captured.err and "1/1 networks" in captured.err
    assert "training networks" not in captured.out

    args = _train_args(tmp_path / "m2", "--json")
    assert args.func(args) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["resumed"] == [] and captured.err == ""

    _Trainings(monkeypatch, interrupt_at=1)
    with pytest.raises(KeyboardInterrupt):
        args.func(args)
    assert "0 trained networks kept" in capsys.readouterr().err
