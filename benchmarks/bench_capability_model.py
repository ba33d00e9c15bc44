"""Capability model speed (paper 000 III-B: 0.013 ms a prediction; we aim under 0.01 ms, and
every forward move and turn of a 20 m x 20 m map in all six topologies under 0.5 s).

Cases, medians of ``repeats`` timings, torch on two threads and on one:

* per prediction: one network on a batch of ``batch`` queries (patches sampled from the
  long_range terrain), wall time / queries;
* latency: one query alone;
* whole map: ``CapabilityModel.map_success`` on the 20 m x 20 m long_range terrain, all six
  topologies: 20 x 20 cells x 8 headings, forward (orthogonal or diagonal) and both turns,
  patch and feet sampling included; the sampling alone (sample_map_inputs) is timed too.
  The turn network's patch head runs once for both directions (CapabilityModel.turn_success).

The networks have seeded random weights (``CapabilityModel.random``): the time does not
depend on the weights, and the real model is trained by the lead on the trial dataset.
"""

import statistics
import time

import numpy as np


def _median(fn, repeats: int, inner: int = 1) -> float:
    """Median over ``repeats`` of the mean wall time of ``inner`` calls. [s]"""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(inner):
            fn()
        times.append((time.perf_counter() - start) / inner)
    return statistics.median(times)


def run(repeats: int = 5, quick: bool = False, batch: int = 16384, threads=(2, 1)) -> dict:
    """The cases for each torch thread count (on a shared machine one thread can beat two:
    a second thread that waits for a busy core stalls every operation)."""
    out = {"weights": "random (CapabilityModel.random, seed 0): timing only"}
    for n in threads:
        out[f"threads_{n}"] = _run(repeats, quick, batch, n)
    return out


def _run(repeats: int, quick: bool, batch: int, threads: int) -> dict:
    import torch

    from qz_drake.capability.model import CapabilityModel, sample_map_inputs
    from qz_drake.robot.topology import TOPOLOGY_NAMES
    from qz_drake.terrain import make_terrain

    if quick:
        repeats, batch = 1, 2048
    torch.set_num_threads(threads)
    model = CapabilityModel.random(seed=0)
    heightmap = make_terrain("long_range")
    rng = np.random.default_rng(0)
    xmin, xmax, ymin, ymax = heightmap.bounds
    x, y = rng.uniform(xmin, xmax, batch), rng.uniform(ymin, ymax, batch)
    k = rng.integers(0, 4, batch) * 2
    patches, feet = model.query_inputs(heightmap, x, y, k, "orthogonal", "nominal")
    model.success(patches, feet, "orthogonal", "nominal")  # warm-up
    per_prediction = _median(lambda: model.success(patches, feet, "orthogonal", "nominal"), repeats) / batch
    latency = _median(lambda: model.success(patches[:1], feet[:1], "orthogonal", "nominal"), repeats, 50)

    def sampling():
        return sample_map_inputs(heightmap, TOPOLOGY_NAMES)

    whole = model.map_success(heightmap)
    map_s = _median(lambda: model.map_success(heightmap), repeats)
    sampling_s = _median(sampling, repeats)
    return {
        "torch": torch.__version__, "threads": threads, "repeats": repeats,
        "batch": batch,
        "per_prediction_ms": per_prediction * 1e3,
        "single_query_latency_ms": latency * 1e3,
        "map": {"terrain": "long_range", "size_m": [xmax - xmin + heightmap.resolution,
                                                    ymax - ymin + heightmap.resolution],
                "cells": list(whole.forward.shape[2:]), "headings": 8, "topologies": len(TOPOLOGY_NAMES),
                "predictions": whole.queries, "seconds": map_s, "sampling_seconds": sampling_s,
                "per_prediction_ms": map_s / whole.queries * 1e3},
    }


if __name__ == "__main__":
    import json

    print(json.dumps(run(), indent=2))
