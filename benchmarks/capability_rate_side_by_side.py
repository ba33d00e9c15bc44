"""Trials an hour with two workers (bench_capability's collection) with the datasets' joint
drive and with Eq. 7's PD in the drives, alternating, and each trial's outcome under both.

    python benchmarks/capability_rate_side_by_side.py [--scenes 3] [--runs 2] [--time-step 0.004]

Each run is a collection of ``--scenes`` scenes (seed 0, every topology and kind: 18 trials a
scene) into a temporary folder by two local workers, first with TrialConfig's default
(control_mode torque, 2 ms), then with control_mode position at ``--time-step``, and so on.
Prints each run's executed trials an hour, the medians and their ratio, and, trial by trial,
how many kept their outcome (walked / no plan / executed and failed) from one setting to the
other.
"""

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np


def _collect(scenes: int, config):
    from qz_drake.capability.collect import collect
    from qz_drake.capability.dataset import load_records

    with tempfile.TemporaryDirectory() as tmp:
        clock = time.perf_counter()
        collect(Path(tmp) / "bench", seed=0, scenes=scenes, workers=2, progress=False, config=config)
        wall = time.perf_counter() - clock
        arrays, _ = load_records(Path(tmp) / "bench")
    from qz_drake.capability.training import OUTCOMES, outcome_classes

    executed = arrays["status"] == "executed"
    outcome = np.where(executed, np.asarray(OUTCOMES)[outcome_classes(arrays["success"], arrays["blc_success"])],
                       "not executed")
    return 3600.0 * int(executed.sum()) / wall, dict(zip(arrays["index"].tolist(), outcome.tolist()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=3)
    parser.add_argument("--runs", type=int, default=2)
    parser.add_argument("--time-step", type=float, default=0.004)
    args = parser.parse_args()
    from qz_drake.capability.trials import TrialConfig

    settings = {"torque 2 ms": TrialConfig(),
                f"drives {args.time_step * 1e3:g} ms": TrialConfig(control_mode="position", time_step=args.time_step)}
    rates = {name: [] for name in settings}
    outcomes = {}
    for _ in range(args.runs):
        for name, config in settings.items():
            rate, outcome = _collect(args.scenes, config)
            rates[name].append(rate)
            outcomes[name] = outcome
            print(f"{name}: {rate:.0f} executed trials an hour", flush=True)
    (a, b) = settings
    medians = {name: statistics.median(r) for name, r in rates.items()}
    print(f"median: {a} {medians[a]:.0f}, {b} {medians[b]:.0f} trials an hour; ratio {medians[b] / medians[a]:.3f}")
    same = sum(outcomes[a][i] == outcomes[b].get(i) for i in outcomes[a])
    changed = [(i, outcomes[a][i], outcomes[b].get(i)) for i in sorted(outcomes[a]) if outcomes[a][i] != outcomes[b].get(i)]
    print(f"trials with the same outcome: {same} of {len(outcomes[a])}; changed: {changed}")


if __name__ == "__main__":
    main()
