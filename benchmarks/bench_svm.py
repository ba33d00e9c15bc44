"""Terrain classification speed (paper 002: about 10 ms per stance on the robot; we aim under 1 ms).

Cases, medians of ``repeats`` timings:

* measurement: Eq. 6 foot forces, foot speeds, pitch and roll of all six legs, one control step;
* feature extraction: the 18 features (Eq. 7-8) of one 0.3 s stance (150 samples at 2 ms);
* classification: one stance's features through one leg's model as the TerrainClassifier runs
  it (numpy one-against-one decision from the saved arrays), and through scikit-learn's SVC for
  comparison;
* training: all six legs' grid searches (11 x 9 grid, 3-fold CV) and fits;
* trotting: real-time factor of the diagram every stance comes from (station, trotting
  controller, SphericalImpedance, TerrainClassifier recording), 10 s on foam at 0.6 m/s.

The data are ``out/classify/dataset.npz`` (``qz classify collect``) when it exists, otherwise a
small dataset collected on the spot into a temporary folder.
"""

import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from qz_drake.classification import features as feat
from qz_drake.classification.dataset import CollectConfig, StanceDataset, collect_dataset
from qz_drake.classification.svm import DEFAULT_C_GRID, DEFAULT_GAMMA_GRID, train_all_legs

DEFAULT_DATASET = Path(__file__).resolve().parents[1] / "out" / "classify" / "dataset.npz"


def _median_time(fn, repeats: int, inner: int) -> float:
    """Median over ``repeats`` of the mean time of ``inner`` calls. [ms]"""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(inner):
            fn()
        times.append((time.perf_counter() - start) / inner * 1e3)
    return statistics.median(times)


def _dataset(quick: bool, path=None) -> tuple[StanceDataset, str]:
    path = Path(path) if path else DEFAULT_DATASET
    if path.is_file() and not quick:
        return StanceDataset.load(path), str(path)
    folder = tempfile.mkdtemp(prefix="qz_bench_svm_")
    config = CollectConfig(stances_per_class=6, run_duration=4.0, speed_range=[0.2, 0.6])
    return collect_dataset(config, folder, progress=False), f"collected {config.stances_per_class} per class and leg"


def _trot_realtime_factor(repeats: int, duration: float) -> float:
    """Median simulated time per wall second of a trot on foam at 0.6 m/s (loop only)."""
    from qz_drake.classification.runs import simulate_trot, trot_scenario

    factors = []
    for _ in range(repeats):
        run = simulate_trot(trot_scenario("foam", distance=0.6 * duration + 1.0), duration=duration, speed=0.6)
        factors.append(duration / run.wall_time_s)
    return statistics.median(factors)


def run(repeats: int = 5, quick: bool = False, dataset=None) -> dict:
    from pydrake.math import RollPitchYaw
    from sklearn.svm import SVC

    from qz_drake.robot.topology import get_topology
    from qz_drake.station import standing_state
    from qz_drake.terrain import make_terrain

    if quick:
        repeats = 1
    data, source = _dataset(quick, dataset)
    rng = np.random.default_rng(0)

    x = standing_state(make_terrain("flat"), get_topology("nominal"))
    tau, imu = rng.normal(0, 20, 18), np.zeros(10)
    imu[:4] = RollPitchYaw(0.01, -0.02, 0.0).ToQuaternion().wxyz()
    v = rng.normal(0, 0.5, 18)
    measurement_ms = _median_time(lambda: feat.measure(x[7:25], v, tau, imu), repeats, 200)

    stance = np.column_stack([200 + 20 * rng.normal(size=150), np.full(150, 0.01), np.full(150, -0.01),
                              np.full(150, 0.3)])
    features_ms = _median_time(lambda: feat.stance_features(stance), repeats, 500)

    grids = (DEFAULT_C_GRID, DEFAULT_GAMMA_GRID) if not quick else (DEFAULT_C_GRID[::3], DEFAULT_GAMMA_GRID[::3])
    start = time.perf_counter()
    models, report = train_all_legs(data, C_grid=grids[0], gamma_grid=grids[1])
    training_s = time.perf_counter() - start

    model = models[0]
    one = data.features[data.legs == 0][:1]
    classify_ms = _median_time(lambda: model.predict_index(one), repeats, 500)
    svc = SVC(C=model.C, gamma=model.gamma).fit(model.scale(data.features[data.legs == 0]),
                                                data.labels[data.legs == 0])
    scaled = model.scale(one)
    sklearn_ms = _median_time(lambda: svc.predict(scaled), repeats, 500)
    return {
        "dataset": source, "stances": int(len(data.labels)), "repeats": repeats,
        "measurement_per_step_ms": measurement_ms,
        "feature_extraction_per_stance_ms": features_ms,
        "classification_per_stance_ms": classify_ms,
        "classification_per_stance_sklearn_ms": sklearn_ms,
        "support_vectors_leg_MF": int(len(model.support_vectors)),
        "training_all_legs_s": training_s,
        "grid": [len(grids[0]), len(grids[1])],
        "mean_held_out_accuracy": report["mean_accuracy"],
        "trot_realtime_factor": _trot_realtime_factor(min(repeats, 3), 2.0 if quick else 10.0),
    }
