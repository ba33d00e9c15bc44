"""Stance datasets (paper 002, section 5's first experiment): Qingzhui trots over each ground
material with a 5 kg payload at random speeds in 0-0.6 m/s; every finished stance of every leg
gives one labelled 18-feature row. Each run draws each leg's stance stiffness from the paper's
three (7, 9, 11 kN/m), and further runs cross floors of random material patches, labelled by
the material under each foot: the adaptive robot meets both.

Runs are saved one file per run under ``<out>/runs/``, so an interrupted collection resumes
where it stopped and a finished one is re-read instead of re-simulated (same config, same
seeds, same data). The dataset is a plain-array ``.npz`` (no pickle).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import zipfile
from pathlib import Path

import numpy as np

from qz_drake.classification import features as feat
from qz_drake.errors import ConfigError, bad_value
from qz_drake.progress import ProgressReport
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
    # Runs over floors of random material patches (stripes of patch length along x, cut every
    # patch width along y), labelled by the material under each foot: a foot's classifier
    # then sees its material with the other feet on every other material, as on a mixed floor.
    mixed_runs: int = 6
    # Range of the mixed floors' patch length and width. [m]
    mixed_patch_range: list[float] = dataclasses.field(default_factory=lambda: [0.6, 2.0])
    # Each leg's stance stiffness in a run is drawn from these (the paper's three): the
    # classifier must recognise the ground whichever stiffness an adaptive leg has switched
    # to. Empty: every leg at 9 kN/m. [N/m]
    stiffness_choices: list[float] = dataclasses.field(default_factory=lambda: [7000.0, 9000.0, 11000.0])

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
        if not (isinstance(self.mixed_runs, int) and self.mixed_runs >= 0):
            raise bad_value("mixed_runs", self.mixed_runs, "must be a non-negative integer")
        if not all(math.isfinite(k) and k > 0 for k in self.stiffness_choices):
            raise bad_value("stiffness_choices", self.stiffness_choices, "must be positive stiffnesses in N/m")
        lo, hi = self.mixed_patch_range
        if not (0.2 <= lo <= hi):
            raise bad_value("mixed_patch_range", self.mixed_patch_range, "expected 0.2 <= min <= max metres")
        return self


# Run ids of the mixed-floor runs start here (one-material runs: 1000 * material + k).
MIXED_RUN_ID = 100_000


@dataclasses.dataclass
class StanceDataset:
    """Labelled stances: one row per stance of one leg."""

    classes: tuple[str, ...]
    features: np.ndarray  # (N, 18)
    labels: np.ndarray  # (N,) index into classes
    legs: np.ndarray  # (N,) leg id 0..5
    speeds: np.ndarray  # (N,) commanded forward speed [m/s]
    runs: np.ndarray  # (N,) run number within its material
    skipped: np.ndarray  # (n_classes, 6) stances too short for three windows (one-material runs)
    config: dict
    # Stances too short for three windows on the mixed floors, per leg.
    skipped_mixed: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(NUM_LEGS, dtype=int))
    # Run ids (as in ``runs``) of the runs in which the robot fell; their stances are not used.
    fallen_runs: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, dtype=int))

    def from_mixed_floors(self) -> np.ndarray:
        """Which rows come from the mixed floors (run ids from MIXED_RUN_ID on)."""
        return np.asarray(self.runs) >= MIXED_RUN_ID

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
                 skipped_mixed=self.skipped_mixed, fallen_runs=self.fallen_runs,
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
                           config=json.loads(str(d["config"])),
                           skipped_mixed=d["skipped_mixed"] if "skipped_mixed" in d.files else np.zeros(NUM_LEGS, int),
                           fallen_runs=d["fallen_runs"] if "fallen_runs" in d.files else np.zeros(0, int))
        except (KeyError, ValueError, OSError) as e:
            raise ConfigError(f"dataset = {str(path)!r}: not a qz stance dataset ({e})") from None
        if data.features.ndim != 2 or data.features.shape[1] != feat.NUM_FEATURES:
            raise bad_value("dataset", str(path), f"features must have {feat.NUM_FEATURES} columns")
        return data


def _run_file(out: Path, material: str, k: int) -> Path:
    return out / "runs" / f"{material}_{k:03d}.npz"


def _cached_run(path: Path, fingerprint: str) -> dict | None:
    """The saved run at ``path`` when its fingerprint matches, else None (also for a file
    that is not a whole run: one written before the run files were replaced atomically)."""
    if path.is_file():
        try:
            with np.load(path, allow_pickle=False) as d:
                if "fingerprint" in d.files and str(d["fingerprint"]) == fingerprint:
                    return {key: d[key] for key in d.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile):
            return None
    return None


@dataclasses.dataclass(frozen=True)
class _RunSpec:
    """One trotting run of a collection: what it simulates and where it is saved."""

    path: Path
    material: str  # the floor's material, or the mixed floors' default
    seed: int
    patch: tuple[float, float] | None  # mixed floor patch (length, width) [m], None: one material
    stiffness: tuple[float, ...]  # each leg's stance stiffness [N/m]

    def fingerprint(self, config: "CollectConfig") -> str:
        head = [config.run_duration, list(config.speed_range), config.speed_hold, config.payload_kg, self.seed]
        return json.dumps(head + ([] if self.patch is None else list(self.patch)) + [list(self.stiffness)])


def _simulate_run(spec: _RunSpec, config: "CollectConfig") -> dict:
    """Simulates one run and saves it under its fingerprint (also in a worker process). A run
    in which the robot falls is saved as such, with no stances: a fall is an outcome the
    collection reports, not an error."""
    from qz_drake.classification.runs import simulate_trot, speed_schedule, trot_scenario

    distance = config.run_duration * config.speed_range[1] + 1.0
    length, width = spec.patch if spec.patch is not None else (0.0, math.inf)
    scenario = trot_scenario(spec.material, distance=distance, payload_kg=config.payload_kg, seed=spec.seed,
                             mixed_patch_length=length, mixed_patch_width=width)
    times, speeds = speed_schedule(config.run_duration, config.speed_range, config.speed_hold, spec.seed)
    result = simulate_trot(scenario, duration=config.run_duration, speed=(times, speeds),
                           stiffness=np.asarray(spec.stiffness))
    # The stances before a fall are dropped with it: the last of them led to the fall.
    keep = np.zeros(len(result.stance_leg), dtype=bool) if result.fell else np.ones(len(result.stance_leg), dtype=bool)
    run = {"features": result.stance_features[keep], "legs": result.stance_leg[keep],
           "speeds": result.stance_speed[keep], "skipped": result.skipped_stances,
           "truth": np.asarray([result.classes[i] if i >= 0 else "" for i in result.stance_truth[keep]],
                               dtype=np.str_).reshape(-1),
           "fell": np.asarray(result.fell),
           "fingerprint": np.asarray(spec.fingerprint(config), dtype=np.str_)}
    # Written aside and renamed: an interrupted collection leaves whole runs only.
    partial = spec.path.with_name(spec.path.stem + ".partial.npz")
    np.savez(partial, **run)
    os.replace(partial, spec.path)
    return run


class _Runner:
    """Runs specs in order, from the cache where it can, else here (one worker) or on a pool of
    worker processes; the results do not depend on the number of workers."""

    def __init__(self, config: "CollectConfig", workers: int):
        self._config = config
        self._pool = None
        if workers > 1:
            import concurrent.futures
            import multiprocessing

            # Spawned workers: a fork would copy the parent's Drake and BLAS threads' state.
            self._pool = concurrent.futures.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"))

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)

    def map(self, specs):
        """Yields each spec's run, in order, as soon as it and those before it are done."""
        pending = []
        for spec in specs:
            cached = _cached_run(spec.path, spec.fingerprint(self._config))
            if cached is not None:
                pending.append(cached)
            elif self._pool is None:
                pending.append(_simulate_run(spec, self._config))
            else:
                pending.append(self._pool.submit(_simulate_run, spec, self._config))
        for item in pending:
            yield item if isinstance(item, dict) else item.result()


def collect_dataset(config: CollectConfig, out_dir, *, progress: bool = True, workers: int = 1) -> StanceDataset:
    """Trots over each material until every leg has ``stances_per_class`` stances there (or
    ``max_runs`` runs), then ``mixed_runs`` times over floors of random material patches;
    keeps ``stances_per_class`` one-material stances per class and leg and every mixed-floor
    stance; writes ``<out_dir>/dataset.npz`` and returns the dataset.

    With ``workers`` > 1 the runs are simulated in that many processes, ``workers`` runs of a
    material at a time; the dataset is the same as with one.
    """
    from qz_drake.classification.terrain_classifier import DEFAULT_STIFFNESS

    config.check()
    if not (isinstance(workers, int) and workers >= 1):
        raise bad_value("workers", workers, "must be a positive integer")
    out = Path(out_dir)
    (out / "runs").mkdir(parents=True, exist_ok=True)
    classes = tuple(config.materials)
    rows = {"features": [], "labels": [], "legs": [], "speeds": [], "runs": []}
    skipped = np.zeros((len(classes), NUM_LEGS), dtype=int)
    skipped_mixed = np.zeros(NUM_LEGS, dtype=int)
    fallen = []

    def leg_stiffness(seed) -> tuple[float, ...]:
        if not config.stiffness_choices:
            return (DEFAULT_STIFFNESS,) * NUM_LEGS
        choice = np.random.default_rng(seed).choice(np.asarray(config.stiffness_choices, dtype=float), NUM_LEGS)
        return tuple(float(k) for k in choice)

    def add(run, labels, run_id):
        if "fell" in run and bool(run["fell"]):
            fallen.append(run_id)
        rows["features"].append(np.asarray(run["features"]).reshape(-1, feat.NUM_FEATURES))
        rows["legs"].append(np.asarray(run["legs"], dtype=int))
        rows["speeds"].append(np.asarray(run["speeds"], dtype=float))
        rows["labels"].append(np.asarray(labels, dtype=int))
        rows["runs"].append(np.full(len(run["legs"]), run_id))

    # One step per stance of the class's leg with the fewest, then one per mixed-floor run.
    report = ProgressReport("classify collect", len(classes) * config.stances_per_class + config.mixed_runs,
                            unit="steps", enabled=progress)
    with report, _Runner(config, workers) as runner:
        for m, material in enumerate(classes):
            have = np.zeros(NUM_LEGS, dtype=int)
            k = 0
            while k < config.max_runs and have.min() < config.stances_per_class:
                batch = range(k, min(k + workers, config.max_runs))
                specs = [_RunSpec(_run_file(out, material, j), material, config.seed + 1000 * m + j, None,
                                  leg_stiffness(config.seed + 1000 * m + j)) for j in batch]
                for j, run in zip(batch, runner.map(specs)):
                    # Runs past the one that completes the class are simulated (and cached)
                    # alongside it but not used, as with one worker.
                    if have.min() >= config.stances_per_class:
                        break
                    add(run, np.full(len(run["legs"]), m), 1000 * m + j)
                    skipped[m] += run["skipped"]
                    have += np.bincount(np.asarray(run["legs"], dtype=int), minlength=NUM_LEGS)
                    report.update(m * config.stances_per_class + min(have.min(), config.stances_per_class),
                                  status=f"{material}: run {j + 1}, {have.min()}/{config.stances_per_class} "
                                         "stances on every leg")
                k = batch.stop
        rng = np.random.default_rng(config.seed)
        # Stripes along x cut into patches along y: every material borders every other.
        patches = [tuple(float(v) for v in rng.uniform(*config.mixed_patch_range, size=2))
                   for _ in range(config.mixed_runs)]
        specs = [_RunSpec(_run_file(out, "mixed", k), "concrete", config.seed + MIXED_RUN_ID + k, patch,
                          leg_stiffness(config.seed + MIXED_RUN_ID + k)) for k, patch in enumerate(patches)]
        for k, run in enumerate(runner.map(specs)):
            # Labelled by the material under the foot; stances off the known classes are dropped.
            known = np.array([str(t) in classes for t in run["truth"]], dtype=bool)
            labels = np.array([classes.index(str(t)) if str(t) in classes else -1 for t in run["truth"]], dtype=int)
            add({"features": np.asarray(run["features"])[known], "legs": np.asarray(run["legs"])[known],
                 "speeds": np.asarray(run["speeds"])[known], "fell": run.get("fell", False)},
                labels[known], MIXED_RUN_ID + k)
            skipped_mixed += run["skipped"]
            report.update(len(classes) * config.stances_per_class + k + 1,
                          status=f"mixed floor: run {k + 1}/{config.mixed_runs}")
    pool = StanceDataset(classes=classes, features=np.vstack(rows["features"]),
                         labels=np.concatenate(rows["labels"]).astype(int),
                         legs=np.concatenate(rows["legs"]).astype(int),
                         speeds=np.concatenate(rows["speeds"]), runs=np.concatenate(rows["runs"]).astype(int),
                         skipped=skipped, config=dataclasses.asdict(config), skipped_mixed=skipped_mixed,
                         fallen_runs=np.asarray(fallen, dtype=int))
    # Keep the first stances_per_class one-material stances per (class, leg) (the last run
    # overshoots), so that the classes stay balanced; keep every mixed-floor stance.
    keep = pool.from_mixed_floors()
    for c in range(len(classes)):
        for leg in range(NUM_LEGS):
            idx = np.flatnonzero((pool.labels == c) & (pool.legs == leg) & ~keep)
            keep[idx[:config.stances_per_class]] = True
    dataset = dataclasses.replace(pool, features=pool.features[keep], labels=pool.labels[keep],
                                  legs=pool.legs[keep], speeds=pool.speeds[keep], runs=pool.runs[keep])
    dataset.save(out / "dataset.npz")
    return dataset


def summary(dataset: StanceDataset) -> dict:
    """Stance counts of the one-material runs per class and leg, skipped stances, mixed-floor stances."""
    one_material = ~dataset.from_mixed_floors()
    counts = np.zeros((len(dataset.classes), NUM_LEGS), dtype=int)
    np.add.at(counts, (dataset.labels[one_material], dataset.legs[one_material]), 1)
    return {"classes": list(dataset.classes), "stances": int(len(dataset.labels)),
            "per_class_per_leg": {c: dict(zip(LEG_NAMES, map(int, counts[i]))) for i, c in enumerate(dataset.classes)},
            "skipped_short_stances": {c: dict(zip(LEG_NAMES, map(int, dataset.skipped[i])))
                                      for i, c in enumerate(dataset.classes)},
            "skipped_short_stances_mixed_floors": dict(zip(LEG_NAMES, map(int, dataset.skipped_mixed))),
            "stances_from_mixed_floors": int(np.count_nonzero(dataset.from_mixed_floors())),
            "fallen_runs": [int(r) for r in dataset.fallen_runs]}
