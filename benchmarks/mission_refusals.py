"""Where the BLC refuses each planner's missions: by mission length, turn and clearance from edges.

    python benchmarks/mission_refusals.py RUN [RUN ...]

Issue 54 asks why the learned A* (A*'s geometric route with the model as a cost) walks more of the
tuning tasks than CapPlanner with the same model, before CapPlanner's value iteration is tuned
further. Two differences were named (HISTORY "routes", session 48): CapPlanner merges its
actions into missions of up to 2 m on a grid of 45-degree headings where A* walks 1 m missions
along a fine route, and A* keeps its body disc clear of boxes where CapPlanner trusts the model.
This reads the missions the runs recorded (``--record-missions``) and tells them apart: per run,
the missions by length (how far the base is to move) and by turn, with the share the BLC refused
(after the ladder) and the share that failed walking; and, for refused against planned missions,
the clearance of the mission's path from an edge (the distance from the straight line between
the mission's start and target to the nearest map cell whose height differs from the ground under
the start by more than EDGE, measured on the task's world).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

# A cell this much above or below the ground under the mission's start is an edge. [m]
EDGE = 0.05
LENGTHS = ((0.0, 0.5), (0.5, 1.25), (1.25, 1.75), (1.75, 9.0))


def _records(run: Path) -> list[dict]:
    files = sorted(run.rglob("results.jsonl"))
    if len(files) != 1:
        raise SystemExit(f"{run}: expected one results.jsonl, found {len(files)}")
    return [json.loads(line) for line in files[0].read_text().splitlines() if line.strip()]


def clearance(heightmap, start, target) -> float:
    """Distance [m] from the segment start -> target to the nearest edge cell (EDGE) within 1.5 m."""
    x0, y0 = start[0], start[1]
    x1, y1 = target[0], target[1]
    ground = float(heightmap.height(np.array([x0]), np.array([y0]))[0])
    r = 1.5
    xs = np.arange(min(x0, x1) - r, max(x0, x1) + r, heightmap.resolution)
    ys = np.arange(min(y0, y1) - r, max(y0, y1) + r, heightmap.resolution)
    gx, gy = np.meshgrid(xs, ys)
    h = heightmap.height(gx.ravel(), gy.ravel())
    edge = np.abs(h - ground) > EDGE
    if not edge.any():
        return r
    px, py = gx.ravel()[edge], gy.ravel()[edge]
    dx, dy = x1 - x0, y1 - y0
    length2 = dx * dx + dy * dy
    t = np.clip(((px - x0) * dx + (py - y0) * dy) / length2, 0.0, 1.0) if length2 > 0 else np.zeros_like(px)
    d = np.hypot(px - (x0 + t * dx), py - (y0 + t * dy))
    return float(min(d.min(), r))


def summarise(run: Path) -> dict:
    from qz_drake.experiments.worlds import make_task

    settings = json.loads(next(run.rglob("settings.json")).read_text())
    scale = float(settings.get("scale", 1.0))
    rows = {b: {"missions": 0, "no_plan": 0, "failed": 0} for b in LENGTHS}
    turns = {"turn > 30 deg": {"missions": 0, "no_plan": 0}, "turn <= 30 deg": {"missions": 0, "no_plan": 0}}
    clear = {"no_plan": [], "walked": []}
    for record in _records(run):
        missions = record.get("mission_records") or []
        if not missions or record.get("reason") == "error":
            continue
        world = make_task(record["terrain"], record["difficulty"], record["seed"], scale).heightmap
        for m in missions:
            (x, y, yaw), (tx, ty, tyaw) = m["start"], m["target"]
            length = math.hypot(tx - x, ty - y)
            bucket = next(b for b in LENGTHS if b[0] <= length < b[1])
            rows[bucket]["missions"] += 1
            rows[bucket][m["outcome"]] = rows[bucket].get(m["outcome"], 0) + 1
            turn = abs(math.degrees(math.remainder(tyaw - yaw, 2 * math.pi)))
            if length >= 0.25:  # the heading the base moves along against the one it faces
                turn = max(turn, abs(math.degrees(math.remainder(math.atan2(ty - y, tx - x) - yaw, 2 * math.pi))))
            t = turns["turn > 30 deg" if turn > 30 else "turn <= 30 deg"]
            t["missions"] += 1
            t["no_plan"] += m["outcome"] == "no_plan"
            if m["outcome"] in clear:
                clear[m["outcome"]].append(clearance(world, m["start"], m["target"]))
    return {"run": str(run), "lengths": rows, "turns": turns,
            "clearance": {k: (float(np.median(v)) if v else None, len(v)) for k, v in clear.items()},
            "near_edge": {k: (float(np.mean(np.asarray(v) < 0.3)) if v else None) for k, v in clear.items()}}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path)
    args = parser.parse_args(argv)
    print("| run | missions by length [m]: refused / missions (failed walking) | turning > 30 deg: refused / missions "
          "| not turning | clearance from an edge, median: refused / walked [m] | within 0.3 m of an edge: refused / walked |")
    print("| --- | --- | --- | --- | --- | --- |")
    for run in args.runs:
        s = summarise(run)
        lengths = ", ".join(f"{lo:g}-{hi:g}: {r['no_plan']}/{r['missions']} ({r['failed']})"
                            for (lo, hi), r in s["lengths"].items() if r["missions"])
        t1, t0 = s["turns"]["turn > 30 deg"], s["turns"]["turn <= 30 deg"]
        (cr, nr), (cw, nw) = s["clearance"]["no_plan"], s["clearance"]["walked"]

        def num(v):
            return "-" if v is None else f"{v:.2f}"

        print(f"| {run} | {lengths} | {t1['no_plan']}/{t1['missions']} | {t0['no_plan']}/{t0['missions']} "
              f"| {num(cr)} ({nr}) / {num(cw)} ({nw}) | {num(s['near_edge']['no_plan'])} / {num(s['near_edge']['walked'])} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
