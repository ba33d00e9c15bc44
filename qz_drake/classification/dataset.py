"""Stance datasets (paper 002, section 5's first experiment): Qingzhui trots over each ground
material with a 5 kg payload at random speeds in 0-0.6 m/s; every finished stance of every leg
gives one labelled 18-feature row.

Runs are saved one file per run under ``<out>/runs/``, so an interrupted collection resumes
where it stopped and a finished one is re-read instead of re-simulated (same config, same
seeds, same data). The dataset is a plain-array ``.npz`` (no pickle).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from qz_drake.classification import features as feat
from qz_drake.errors import ConfigError, bad_value
from qz_drake.robot.params import LEG_NAMES, NUM_LEGS


@dataclasses.dataclass
class CollectConfig:
    # Ground materials, one class each (qz_drake.terrain.materials).
    materials: list[str] = dataclasses.field(default_factory=lambda: ["concrete", "wood", "foam"])
    # Stances to collect per class and leg (paper: 200 per experiment).
    stances_per_class: int = 200
    # Simulated time of one run; a run trots straight ahead on one material. [s]
    run_duration: float = 20.0
    # Forward speeds are drawn uniformly from this range and held for speed_hold. [m/s], [s]
    speed_range: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.6])
    speed_hold: float = 2.0
    # Payload on the trunk (paper: 5 kg). [kg]
    payload_kg: float = 5.0
    # Seeds the speed schedules (run k of material m uses seed + 1000 m + k).
    seed: int = 0
    # Most runs per material before giving up on stances_per_class.
    max_runs: int = 40

    def check(self) -> "CollectConfig":
        from qz_drake.terrain import get_material

        if not self.materials:
            raise bad_value("materials", self.materials, "give at least one ground material")
        for name in self.materials:
            get_material(name)
        if len(set(self.materials)) != len(self.materials):
            raise bad_value("materials", self.materials, "names must be distinct")
        if not (isinstance(self.stances_per_class, int) and self.stances_per_class >= 1):
            raise bad_value("stances_per_class", self.stances_per_class, "must be a positive integer")
        if not (math.isfinite(self.run_duration) and self.run_duration > 1.0):
            raise bad_value("run_duration", self.run_duration, "must exceed 1 s")
        lo, hi = self.speed_range
        if not (0.0 <= lo <= hi <= 1.0):
            raise bad_value("speed_range", self.speed_range, "expected 0 <= min <= max <= 1 m/s")
        if not (math.isfinite(self.speed_hold) and self.speed_hold > 0):
            raise bad_value("speed_hold", self.speed_hold, "must be positive")
        if not (0.0 <= self.payload_kg <= 20.0):
            raise bad_value("payload_kg", self.payload_kg, "must be within [0, 20] kg")
        if not (isinstance(self.max_runs, int) and self.max_runs >= 1):
            raise bad_value("max_runs", self.max_runs, "must be a positive integer")
        return self


@dataclasses.dataclass
class StanceDataset:
    """Labelled stances: one row per stance of one leg."""

    classes: tuple[str, ...]
    features: np.ndarray  # (N, 18)
    labels: np.ndarray  # (N,) index into classes
    legs: np.ndarray  # (N,) leg id 0..5
    speeds: np.ndarray  # (N,) commanded forward speed [m/s]
    runs: np.ndarray  # (N,) run number within its material
    skipped: np.ndarray  # (n_classes, 6) stances too short for three windows
    config: dict

    def counts(self) -> np.ndarray:
        """Stances per (class, leg)."""
        out = np.zeros((len(self.classes), NUM_LEGS), dtype=int)
        np.add.at(out, (self.labels, self.legs), 1)
        return out

    def save(self, path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, classes=np.asarray(self.classes, dtype=np.str_), features=self.features, labels=self.labels,
                 legs=self.legs, speeds=self.speeds, runs=self.runs, skipped=self.skipped,
                 feature_names=np.asarray(feat.FEATURE_NAMES, dtype=np.str_),
                 config=np.asarray(json.dumps(self.config), dtype=np.str_))
        return path

    @classmethod
    def load(cls, path) -> "StanceDataset":
        path = Path(path)
        if path.is_dir():
            path = path / "dataset.npz"
        if not path.is_file():
            raise bad_value("dataset", str(path), "no such file")
        try:
            with np.load(path, allow_pickle=False) as d:
                data = cls(classes=tuple(str(c) for c in d["classes"]), features=d["features"], labels=d["labels"],
                           legs=d["legs"], speeds=d["speeds"], runs=d["runs"], skipped=d["skipped"],
                           config=json.loads(str(d["config"])))
        except (KeyError, ValueError, OSError) as e:
            raise ConfigError(f"dataset = {str(path)!r}: not a qz stance dataset ({e})") from None
        if data.features.ndim != 2 or data.features.shape[1] != feat.NUM_FEATURES:
            raise bad_value("dataset", str(path), f"features must have {feat.NUM_FEATURES} columns")
        return data


def _run_file(out: Path, material: str, k: int) -> Path:
    return out / "runs" / f"{material}_{k:03d}.npz"


def collect_dataset(config: CollectConfig, out_dir, *, progress: bool = True) -> StanceDataset:
    """Trots over each material until every leg has ``stances_per_class`` stances there (or
    ``max_runs`` runs); writes ``<out_dir>/dataset.npz`` and returns the dataset."""
    from qz_drake.classification.runs import simulate_trot, speed_schedule, trot_scenario

    config.check()
    out = Path(out_dir)
    (out / "runs").mkdir(parents=True, exist_ok=True)
    classes = tuple(config.materials)
    rows = {"features": [], "labels": [], "legs": [], "speeds": [], "runs": []}
    skipped = np.zeros((len(classes), NUM_LEGS), dtype=int)
    bar = _progress(progress)
    with bar:
        task = bar.add_task("collecting stances", total=len(classes) * config.stances_per_class)
        for m, material in enumerate(classes):
            have = np.zeros(NUM_LEGS, dtype=int)
            for k in range(config.max_runs):
                if have.min() >= config.stances_per_class:
                    break
                path = _run_file(out, material, k)
                seed = config.seed + 1000 * m + k
                fingerprint = json.dumps([config.run_duration, list(config.speed_range), config.speed_hold,
                                          config.payload_kg, seed])
                run = None
                if path.is_file():
                    with np.load(path, allow_pickle=False) as d:
                        if "fingerprint" in d.files and str(d["fingerprint"]) == fingerprint:
                            run = {key: d[key] for key in d.files}
                if run is None:
                    times, speeds = speed_schedule(config.run_duration, config.speed_range, config.speed_hold, seed)
                    distance = config.run_duration * config.speed_range[1] + 1.0
                    result = simulate_trot(trot_scenario(material, distance=distance, payload_kg=config.payload_kg,
                                                         seed=seed),
                                           duration=config.run_duration, speed=(times, speeds))
                    if result.fell:
                        raise RuntimeError(f"the robot fell on {material} (run {k}, seed {seed})")
                    run = {"features": result.stance_features, "legs": result.stance_leg,
                           "speeds": result.stance_speed, "skipped": result.skipped_stances,
                           "fingerprint": np.asarray(fingerprint, dtype=np.str_)}
                    np.savez(path, **run)
                n = len(run["legs"])
                rows["features"].append(run["features"])
                rows["legs"].append(run["legs"])
                rows["speeds"].append(run["speeds"])
                rows["labels"].append(np.full(n, m))
                rows["runs"].append(np.full(n, k))
                skipped[m] += run["skipped"]
                have += np.bincount(run["legs"], minlength=NUM_LEGS)
                bar.update(task, completed=m * config.stances_per_class + min(have.min(), config.stances_per_class))
    dataset = StanceDataset(classes=classes, features=np.vstack(rows["features"]),
                            labels=np.concatenate(rows["labels"]).astype(int),
                            legs=np.concatenate(rows["legs"]).astype(int),
                            speeds=np.concatenate(rows["speeds"]), runs=np.concatenate(rows["runs"]).astype(int),
                            skipped=skipped, config=dataclasses.asdict(config))
    # Keep exactly stances_per_class per (class, leg) when more were collected (the last run
    # overshoots), so that the classes stay balanced.
    keep = np.zeros(len(dataset.labels), dtype=bool)
    for c in range(len(classes)):
        for leg in range(NUM_LEGS):
            idx = np.flatnonzero((dataset.labels == c) & (dataset.legs == leg))
            keep[idx[:config.stances_per_class]] = True
    dataset = dataclasses.replace(dataset, features=dataset.features[keep], labels=dataset.labels[keep],
                                  legs=dataset.legs[keep], speeds=dataset.speeds[keep], runs=dataset.runs[keep])
    dataset.save(out / "dataset.npz")
    return dataset


def _progress(enabled: bool):
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                    disable=not enabled, transient=True)


def summary(dataset: StanceDataset) -> dict:
    counts = dataset.counts()
    return {"classes": list(dataset.classes), "stances": int(len(dataset.labels)),
            "per_class_per_leg": {c: dict(zip(LEG_NAMES, map(int, counts[i]))) for i, c in enumerate(dataset.classes)},
            "skipped_short_stances": {c: dict(zip(LEG_NAMES, map(int, dataset.skipped[i])))
                                      for i, c in enumerate(dataset.classes)}}
