"""How far the stances CapPlanner's missions start from are from what its map assumes (issue 54:
a planning state that decides the outcome). The map asks the capability model about every cell
with the robot at the cell centre, heading k * 45 deg, on its topology's nominal footholds; a
walk's mission starts where the last plan ended. For every recorded mission of CapPlanner's
walks (results folders walked with ``--record-missions``), the start's base offset from its
grid cell's centre, its heading's offset from k * 45 deg, and its feet's offsets from the
stance the map assumes there (horizontal, largest and mean; vertical, largest): the nominal
footholds, or the canonical stance for a run walked with ``--terminal-stance canonical``
(its settings.json), for the missions the BLC planned and those it refused, with each
offset's AUC as a predictor of the refusal:

    python benchmarks/stance_deviation.py RUN [RUN ...]

Only CapPlanner's records are read (A*'s missions are not on its grid). Worlds of seeds 50-99
are refused.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

MEASURES = ("base offset from the cell centre [m]", "heading offset from k x 45 deg [deg]",
            "largest foot offset from the map's stance, horizontal [m]",
            "mean foot offset from the map's stance, horizontal [m]",
            "largest foot offset from the map's stance, vertical [m]")


def offsets(runs) -> np.ndarray:
    """(n, 1 + len(MEASURES)): refused (1) or not, then MEASURES, per recorded mission."""
    from qz_drake.capability.patches import map_stance, stance_feet_W
    from qz_drake.experiments.fig9 import read_config, read_results
    from qz_drake.experiments.worlds import make_task
    from qz_drake.robot.params import DEFAULT_PARAMS
    from qz_drake.robot.topology import get_topology

    rows = []
    for run in runs:
        stance = map_stance(read_config(run).blc_terminal_stance)
        for r in read_results(run):
            if r["planner"] != "capplanner" or not r.get("mission_records"):
                continue
            if 50 <= r["seed"] <= 99:
                raise SystemExit("seeds 50-99 are reserved for checks outside the project")
            task = make_task(r["terrain"], r["difficulty"], r["seed"])
            sx, sy = task.start  # CapPlanner's grid is anchored on the start
            for m in r["mission_records"]:
                if m["outcome"] not in ("walked", "no_plan", "failed"):
                    continue
                x, y, yaw = m["start"]
                cx, cy = sx + round(x - sx), sy + round(y - sy)
                k_yaw = round(yaw / (np.pi / 4)) * np.pi / 4
                feet = np.asarray(m["feet"], dtype=float)
                nominal = stance_feet_W(task.heightmap, cx, cy, k_yaw, get_topology(m["switched_from"] or m["topology"]),
                                        DEFAULT_PARAMS.foot_radius, stance)
                horizontal = np.linalg.norm(feet[:, :2] - nominal[:, :2], axis=1)
                rows.append((float(m["outcome"] == "no_plan"), float(np.hypot(x - cx, y - cy)),
                             float(abs(np.degrees(yaw - k_yaw))), float(horizontal.max()), float(horizontal.mean()),
                             float(np.abs(feet[:, 2] - nominal[:, 2]).max())))
    return np.asarray(rows, dtype=float).reshape(-1, 1 + len(MEASURES))


def table(rows: np.ndarray) -> str:
    from sklearn.metrics import roc_auc_score

    refused = rows[:, 0] == 1
    lines = [f"{len(rows)} missions, {int(refused.sum())} refused", "",
             "| offset | planned: median / 90th percentile | refused: median / 90th percentile | AUC of the refusal |",
             "| --- | --- | --- | --- |"]
    for i, name in enumerate(MEASURES, 1):
        a, b = rows[~refused, i], rows[refused, i]
        auc = roc_auc_score(rows[:, 0], rows[:, i]) if 0 < refused.sum() < len(rows) else float("nan")
        lines.append(f"| {name} | {np.median(a):.3f} / {np.percentile(a, 90):.3f} "
                     f"| {np.median(b):.3f} / {np.percentile(b, 90):.3f} | {auc:.3f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path)
    args = parser.parse_args(argv)
    rows = offsets(args.runs)
    if not len(rows):
        raise SystemExit("no recorded CapPlanner missions in those folders (walk them with --record-missions)")
    print(table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
