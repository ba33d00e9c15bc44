"""Capability trials per hour (issue 12): a real collection with two local workers, and each
trial's time split into station build, BLC solve and simulation, per kind.

The collection is ``qz capability collect`` itself (seed 0, the first ``scenes`` scenes, all six
topologies and three kinds) into a temporary folder; the split comes from the wall times every
record carries. Throughput is executed trials per hour of wall time, two workers on the
machine's cores. ``control_mode`` and ``time_step`` are TrialConfig's (how the joints are
driven; the default is the datasets').
"""

import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from qz_drake.capability.collect import collect
from qz_drake.capability.dataset import load_records
from qz_drake.capability.trials import TrialConfig


def run(repeats: int = 1, quick: bool = False, scenes: int = 3, workers: int = 2, control_mode: str = "torque",
        time_step: float = 0.002) -> dict:
    if quick:  # seed 0's first scene is a start no topology stands on (18 invalid trials)
        scenes = 2
    rates, per_kind = [], {}
    for _ in range(repeats):
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "bench"
            clock = time.perf_counter()
            summary = collect(out, seed=0, scenes=scenes, workers=workers, progress=False,
                              config=TrialConfig(control_mode=control_mode, time_step=time_step))
            wall = time.perf_counter() - clock
            arrays, _ = load_records(out)
        executed = arrays["status"] == "executed"
        rates.append(3600.0 * int(executed.sum()) / wall)
        for kind in sorted(set(arrays["kind"].tolist())):
            sel = executed & (arrays["kind"] == kind)
            entry = per_kind.setdefault(kind, {k: [] for k in ("build", "solve", "sim", "total")})
            for key in entry:
                entry[key].extend(arrays[f"time_{key}_s"][sel].tolist())
        errors = summary.errors
    kinds = {}
    for kind, times in per_kind.items():
        if not times["total"]:  # every trial of the kind an invalid start: no times to report
            kinds[kind] = {"trials": 0}
            continue
        kinds[kind] = {f"{key}_s_median": statistics.median(v) for key, v in times.items()}
        kinds[kind]["total_s_mean"] = float(np.mean(times["total"]))
        kinds[kind]["trials"] = len(times["total"])
    return {"trials_per_hour_median": statistics.median(rates), "trials_per_hour": rates,
            "workers": workers, "scenes": scenes, "trials_per_run": int(executed.sum()),
            "errors": errors, "per_kind": kinds}
