"""Stance collection: the same dataset from one worker or several, runs re-read from the cache,
bad input named."""

import json

import numpy as np
import pytest

from qz_drake.classification.dataset import CollectConfig, collect_dataset
from qz_drake.errors import ConfigError, QzError


def _tiny(**overrides) -> CollectConfig:
    config = CollectConfig(materials=["concrete", "foam"], stances_per_class=4, run_duration=2.5,
                           speed_range=[0.2, 0.5], mixed_runs=1, mixed_patch_range=[0.6, 0.8])
    for key, value in overrides.items():
        setattr(config, key, value)
    return config


@pytest.mark.slow
def test_workers_give_the_same_dataset_and_runs_are_cached(tmp_path):
    serial = collect_dataset(_tiny(), tmp_path / "serial", progress=False)
    parallel = collect_dataset(_tiny(), tmp_path / "parallel", progress=False, workers=2)
    for name in ("features", "labels", "legs", "speeds", "runs", "skipped", "skipped_mixed"):
        np.testing.assert_array_equal(getattr(serial, name), getattr(parallel, name), err_msg=name)
    assert np.all(serial.counts()[:, :] >= 4)
    runs = sorted((tmp_path / "serial" / "runs").glob("*.npz"))
    assert [p.stem for p in runs][-1] == "mixed_000"
    # Every leg drew its stance stiffness from the paper's three (the run's fingerprint holds them).
    with np.load(runs[0]) as run:
        stiffness = json.loads(str(run["fingerprint"]))[-1]
    assert len(stiffness) == 6 and set(stiffness) <= {7000.0, 9000.0, 11000.0}
    # A second collection re-reads every run instead of simulating it again.
    stamps = {p: p.stat().st_mtime_ns for p in runs}
    again = collect_dataset(_tiny(), tmp_path / "serial", progress=False, workers=2)
    np.testing.assert_array_equal(again.features, serial.features)
    assert {p: p.stat().st_mtime_ns for p in runs} == stamps
    # A changed setting is a different run: the cache is not reused for it.
    changed = collect_dataset(_tiny(stiffness_choices=[9000.0], mixed_runs=0), tmp_path / "serial", progress=False)
    assert not np.array_equal(changed.features[:4], serial.features[:4])


def test_bad_collect_settings_are_named(tmp_path):
    with pytest.raises(ConfigError, match="workers = 0"):
        collect_dataset(_tiny(), tmp_path, progress=False, workers=0)
    with pytest.raises(ConfigError, match="stiffness_choices"):
        collect_dataset(_tiny(stiffness_choices=[9000.0, -1.0]), tmp_path, progress=False)
    with pytest.raises(QzError, match="'gravel'"):
        collect_dataset(_tiny(materials=["concrete", "gravel"]), tmp_path, progress=False)


def _fake_run(path, spec, config, *, fell, stances_per_leg=3, truth="concrete"):
    """A saved run as _simulate_run writes it, with made-up stances."""
    n = 0 if fell else 6 * stances_per_leg
    rng = np.random.default_rng(len(str(path)))
    np.savez(path, features=rng.normal(size=(n, 18)), legs=np.tile(np.arange(6), n // 6), speeds=np.full(n, 0.3),
             skipped=np.zeros(6, int), truth=np.full(n, truth), fell=np.asarray(fell),
             fingerprint=np.asarray(spec.fingerprint(config)))


def test_a_fall_is_counted_and_its_run_left_out(tmp_path):
    from qz_drake.classification.dataset import _run_file, _RunSpec
    from qz_drake.classification.dataset import summary

    config = _tiny(stances_per_class=3, mixed_runs=0, stiffness_choices=[9000.0])
    (tmp_path / "runs").mkdir()
    stiffness = (9000.0,) * 6
    for material, m, runs in (("concrete", 0, (True, False)), ("foam", 1, (False,))):
        for k, fell in enumerate(runs):
            spec = _RunSpec(_run_file(tmp_path, material, k), material, config.seed + 1000 * m + k, None, stiffness)
            _fake_run(spec.path, spec, config, fell=fell, truth=material)
    data = collect_dataset(config, tmp_path, progress=False)
    # Concrete's first run fell: its stances come from the second; nothing was simulated.
    assert data.fallen_runs.tolist() == [0]
    assert set(data.runs[data.labels == 0].tolist()) == {1}
    assert np.all(data.counts() == 3)
    assert summary(data)["fallen_runs"] == [0]
    again = type(data).load(tmp_path / "dataset.npz")
    assert again.fallen_runs.tolist() == [0]
