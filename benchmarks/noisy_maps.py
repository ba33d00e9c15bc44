"""1 m missions from standing on elevation maps as a depth camera makes them (issue 52): 2 cm
cells, gentle hills or hills with a step across the way, and 1-2 cm of pixel noise; each mission
planned by the BLC and walked in Drake, judged by the strict verdict.

    python benchmarks/noisy_maps.py OUT.jsonl --maps 20 [--foot-scale 0.02] [--first-seed 0]

One JSON line per map (resumable: maps already in OUT are skipped): its seed, kind, noise,
whether the first mission planned (the BLC's reason if not) and whether the walk succeeded (the
verdict's reasons). ``--foot-scale 0`` solves on the raw map (BlcParameters.terrain_foot_scale).
The BLC gets ``--iterations`` Ipopt iterations (100) and 60 s, so that the outcome does not
depend on the machine's load.
``--summary OUT.jsonl ...`` prints one table row per file.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

RESOLUTION = 0.02
HALF = 2.0  # the map spans [-HALF, HALF] m in x and y


def noisy_map(seed: int):
    """(HeightMap, description) of map ``seed``: even seeds hills, odd seeds hills and a step."""
    from qz_drake.terrain import HeightMap

    rng = np.random.default_rng([seed, 0x5EED])
    n = int(round(2 * HALF / RESOLUTION))
    xs = -HALF + RESOLUTION * (np.arange(n) + 0.5)
    gx, gy = np.meshgrid(xs, xs)
    heights = np.zeros_like(gx)
    for _ in range(3):  # gentle hills: bumps of 5-12 cm over 0.6-1.0 m
        cx, cy = rng.uniform(-1.5, 1.5, 2)
        amplitude, sigma = rng.uniform(0.05, 0.12), rng.uniform(0.6, 1.0)
        heights += amplitude * np.exp(-((gx - cx) ** 2 + (gy - cy) ** 2) / (2 * sigma ** 2))
    kind = "hills"
    if seed % 2:
        kind = "hills_step"
        x_step, rise = rng.uniform(0.3, 0.7), rng.choice([-1, 1]) * rng.uniform(0.06, 0.10)
        heights += np.where(gx > x_step, rise, 0.0)
    noise = float(rng.uniform(0.01, 0.02))
    heights += rng.normal(0.0, noise, heights.shape)
    heights -= heights.min()
    return HeightMap(heights, RESOLUTION, (float(xs[0]), float(xs[0]))), {"kind": kind, "noise_m": noise}


def walk_map(seed: int, foot_scale: float, iterations: int) -> dict:
    from qz_drake.config import (ControllerConfig, RobotConfig, Scenario, SimulationConfig, TerrainConfig,
                                 Waypoint)
    from qz_drake.simulation import walk
    from qz_drake.trajopt.parameters import BlcParameters

    heightmap, row = noisy_map(seed)
    start, yaw = (-0.5, 0.0), 0.0
    goal = (start[0] + math.cos(yaw), start[1] + math.sin(yaw))
    scenario = Scenario(name=f"noisy_map_{seed}",
                        terrain=TerrainConfig(kind="flat", region=[-HALF, HALF, -HALF, HALF]),
                        robot=RobotConfig(initial_xy=list(start), initial_yaw=yaw),
                        simulation=SimulationConfig(duration=10.0),
                        controller=ControllerConfig(kind="walk", planner="blc", mission_length=1.0,
                                                    route=[Waypoint(x=goal[0], y=goal[1], yaw=yaw,
                                                                    topology="nominal")]))
    clock = time.perf_counter()
    result = walk(scenario, heightmap=heightmap, stop_on_failure=True,
                  blc_params=BlcParameters(terrain_foot_scale=foot_scale, max_iterations=iterations,
                                           time_limit=60.0))
    m = result.metrics
    row.update(seed=seed, foot_scale=foot_scale, iterations=iterations, success=bool(m["success"]), reasons=list(m.get("reasons", [])),
               message=str(m.get("reason", ""))[:300], planned=int(m.get("blc_failures", 0)) == 0,
               blc_solve_time_s=float(m.get("blc_solve_time_s", 0.0)), wall_s=time.perf_counter() - clock)
    return row


def summary(paths) -> None:
    print("| run | maps | first mission planned | walked (strict verdict) | failures |")
    print("| --- | --- | --- | --- | --- |")
    for path in paths:
        rows = [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]
        reasons = {}
        for r in rows:
            if not r["success"]:
                key = r["reasons"][0] if r["reasons"] else "?"
                reasons[key] = reasons.get(key, 0) + 1
        print(f"| {path} (foot scale {rows[0]['foot_scale']:g} m) | {len(rows)} | "
              f"{sum(r['planned'] for r in rows)} | {sum(r['success'] for r in rows)} | "
              + ", ".join(f"{k} {v}" for k, v in sorted(reasons.items())) + " |")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", nargs="+", type=Path)
    parser.add_argument("--maps", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--foot-scale", type=float, default=0.02)
    parser.add_argument("--iterations", type=int, default=100,
                        help="the BLC's Ipopt iterations a solve (its time limit 60 s: deterministic)")
    parser.add_argument("--summary", action="store_true")
    args = parser.parse_args(argv)
    if args.summary:
        summary(args.out)
        return 0
    out = args.out[0]
    done = set()
    if out.exists():
        done = {json.loads(line)["seed"] for line in out.read_text().splitlines() if line.strip()}
    with out.open("a") as f:
        for seed in range(args.first_seed, args.first_seed + args.maps):
            if seed in done:
                continue
            row = walk_map(seed, args.foot_scale, args.iterations)
            f.write(json.dumps(row) + "\n")
            f.flush()
            print(f"map {seed} ({row['kind']}, noise {row['noise_m']:.3f} m): planned {row['planned']}, "
                  f"success {row['success']} {row['message'][:120]}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
