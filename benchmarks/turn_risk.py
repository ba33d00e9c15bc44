"""How often the walks' turns failed beside an edge, against how often the model said they would.

    python benchmarks/turn_risk.py RUN [RUN ...] [--json]

CapPlanner's TLC plans turns in place on the model's word, and the model's trials rarely turn the
robot beside a box: on box fields its walks' turns in place failed far more often than it
predicted (session 52). This reads the missions the runs recorded (``--record-missions``), sorts
them by what they do (a turn in place, a move that turns, a move) and by the distance of the
mission's start from the nearest edge of the task's world, with the edge as the MDP sees it
(``capability_mdp.edge_distances``: a map cell whose height differs from a neighbour's by more
than 5 cm), and prints per terrain (stairs; box fields: obstacles and both) and bin the missions,
the share refused, the share that failed walking, and the model's predicted share of execution
failures (the shipped model, or the run's). What ``CapabilityMdpConfig.turn_edge_risk`` is set
from. Worlds of seeds 50-99 are refused.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
from pathlib import Path

import numpy as np

# Distance bins of a mission's start from the nearest edge. [m]
BINS = ((0.0, 0.2), (0.2, 0.3), (0.3, 0.4), (0.4, 0.5), (0.5, math.inf))
KINDS = ("turn in place", "move and turn", "move")


def kind_of(mission: dict) -> str:
    """What a recorded mission does: a turn in place (the base moves less than 0.3 m), a move
    that turns (by more than 0.3 rad), or a move."""
    (x, y, yaw), (tx, ty, tyaw) = mission["start"], mission["target"]
    if math.hypot(tx - x, ty - y) < 0.3:
        return "turn in place"
    return "move and turn" if abs(math.remainder(tyaw - yaw, 2 * math.pi)) > 0.3 else "move"


@functools.lru_cache(maxsize=None)
def _world(terrain: str, difficulty: str, seed: int, scale: float):
    from qz_drake.experiments.worlds import make_task
    from qz_drake.planning.capability_mdp import CapabilityMdpConfig, edge_distances

    if 50 <= seed <= 99:
        raise SystemExit(f"seed {seed}: worlds 50-99 are kept for checks outside the project")
    heightmap = make_task(terrain, difficulty, seed, scale).heightmap
    return heightmap, edge_distances(heightmap, CapabilityMdpConfig().edge_height)


def _records(run: Path) -> tuple[list[dict], float]:
    files = sorted(run.rglob("results.jsonl"))
    if len(files) != 1:
        raise SystemExit(f"{run}: expected one results.jsonl, found {len(files)}")
    settings = json.loads(next(run.rglob("settings.json")).read_text())
    return [json.loads(line) for line in files[0].read_text().splitlines() if line.strip()], \
        float(settings.get("scale", 1.0))


def tally(runs, model=None) -> dict:
    """{(terrain group, kind, bin): [missions, refused, failed walking, predicted failure sum]}."""
    from qz_drake.experiments.walk_scores import predict_mission

    table: dict = {}
    for run in runs:
        records, scale = _records(Path(run))
        for record in records:
            missions = record.get("mission_records") or []
            if not missions or record.get("reason") == "error":
                continue
            heightmap, distance = _world(record["terrain"], record["difficulty"], int(record["seed"]), scale)
            predicted = [predict_mission(model, heightmap, m)["failed"] or 0.0 for m in missions]
            group = "stairs" if record["terrain"] == "stairs" else "box fields"
            for mission, p_failed in zip(missions, predicted):
                ix, iy = heightmap.index(np.array([mission["start"][0]]), np.array([mission["start"][1]]))
                d = math.inf if distance is None else float(distance[iy[0], ix[0]])
                b = next(b for b in BINS if b[0] <= d < b[1])
                row = table.setdefault((group, kind_of(mission), b), [0, 0, 0, 0.0])
                row[0] += 1
                row[1] += mission["outcome"] == "no_plan"
                row[2] += mission["outcome"] == "failed"
                row[3] += float(p_failed)
    return table


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--model", default="", help="capability model folder (default: the shipped one)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    from qz_drake.capability.model import CapabilityModel

    table = tally(args.runs, CapabilityModel.load(args.model or None))
    if args.json:
        print(json.dumps([{"terrain": g, "kind": k, "from_edge_m": list(b), "missions": n, "refused": r,
                           "failed": f, "predicted_failed": p / n} for (g, k, b), (n, r, f, p) in sorted(table.items())]))
        return 0
    print("| terrain | mission | start from an edge [m] | missions | refused | failed walking | predicted |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for group in ("box fields", "stairs"):
        for kind in KINDS:
            for b in BINS:
                if (group, kind, b) not in table:
                    continue
                n, refused, failed, p = table[(group, kind, b)]
                print(f"| {group} | {kind} | {b[0]:g}-{b[1]:g} | {n} | {refused / n:.2f} | {failed / n:.2f} "
                      f"({failed}) | {p / n:.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
