"""Which prediction of a walk's success does CapPlanner's first plan support? (issue 54: the
predicted route success within 0.10 of the walked rate in every cell.) For every CapPlanner task
of a Fig. 9 results folder, the first plan is made again with the run's settings and the model's
own answers along it are kept (each action's doubted success, P(walked), P(the BLC plans it), the
ensemble's spread); the table sets four predictions of the walk beside the walked rate per cell:
the product of the doubted successes (what ``qz experiment report --predict`` calls success at
refusal risk 1), the chance that no action ends the walk (refusals gone round), that times the
chance of at most ``--refusals`` refusals (a walk ends at its fifth), and the same doubted by the
spread.

    python benchmarks/route_predictors.py OUT.jsonl --run data/fig9_decisive
    python benchmarks/route_predictors.py OUT.jsonl --summary [--refusals 4]

Resumable (tasks already in OUT are skipped). Worlds of seeds 50-99 are refused.
"""

from __future__ import annotations

import argparse
import collections
import json
from pathlib import Path

import numpy as np


def collect(out: Path, run: Path) -> None:
    from qz_drake.capability.model import CapabilityModel, predict_map
    from qz_drake.capability.patches import KINDS, map_stance
    from qz_drake.experiments.fig9 import read_config, read_results
    from qz_drake.experiments.fig9.tasks import _mdp_overrides
    from qz_drake.experiments.worlds import make_task
    from qz_drake.planning.capability_mdp import cells_on_map, plan_on_map, switchable_cells
    from qz_drake.planning.capplanner_route import mdp_config
    from qz_drake.robot.topology import TOPOLOGY_NAMES

    config = read_config(run)
    model = CapabilityModel.load(config.capability_model or None)
    topologies = [t for t in TOPOLOGY_NAMES if all(model.has_network(t, k) for k in KINDS)]
    mdp = mdp_config(_mdp_overrides(config), topologies, map_stance(config.blc_terminal_stance))
    done = {json.loads(line)["key"] for line in out.read_text().splitlines()} if out.exists() else set()
    records = [r for r in read_results(run) if r["planner"] == "capplanner" and r["reason"] != "error"
               and r["key"] not in done]
    if any(50 <= r["seed"] <= 99 for r in records):
        raise SystemExit("seeds 50-99 are reserved for checks outside the project")
    with out.open("a") as f:
        for r in records:
            task = make_task(r["terrain"], r["difficulty"], r["seed"], scale=config.scale)
            heading = int(round(task.start_yaw / (np.pi / 4))) % 8
            cm = predict_map(model, task.heightmap, topologies, cell_size=mdp.cell_size, anchor=task.start,
                             stance=mdp.stance)
            plan = plan_on_map(cm, task.start, heading, task.goal, config=mdp,
                               switchable=switchable_cells(task.heightmap, cm.xs, cm.ys, mdp),
                               on_map=cells_on_map(task.heightmap, cm.xs, cm.ys))
            steps = []
            for s in plan.steps:
                ix, iy = int(np.argmin(np.abs(cm.xs - s.x))), int(np.argmin(np.abs(cm.ys - s.y)))
                t = list(cm.topologies).index(s.action_topology)
                planned = getattr(cm, f"{s.motion}_plan", None)
                steps.append((s.success, float(getattr(cm, s.motion)[t, s.heading, iy, ix]),
                              1.0 if planned is None else float(planned[t, s.heading, iy, ix]),
                              float(getattr(cm, f"{s.motion}_spread")[t, s.heading, iy, ix])))
            f.write(json.dumps({"key": r["key"], "terrain": r["terrain"], "difficulty": r["difficulty"],
                                "walked": bool(r["success"]), "reason": r["reason"],
                                "reaches": bool(plan.reaches_goal), "steps": steps}) + "\n")
            f.flush()


def at_most(q, k: int) -> float:
    """P(at most k of independent events of probabilities q happen)."""
    dist = np.zeros(len(q) + 1)
    dist[0] = 1.0
    for qi in q:
        dist[1:] = dist[1:] * (1.0 - qi) + dist[:-1] * qi
        dist[0] *= 1.0 - qi
    return float(dist[:k + 1].sum())


PREDICTIONS = ("product of doubted successes", "no fall", "no fall x refusals within budget", "the same, doubted")


def predictions(row: dict, refusals: int) -> tuple[float, ...]:
    if not row["reaches"] or not row["steps"]:
        return (0.0,) * len(PREDICTIONS) if not row["reaches"] else (1.0,) * len(PREDICTIONS)
    doubted, walked, planned, spread = np.asarray(row["steps"], dtype=float).T
    q = np.clip(1.0 - planned, 0.0, 1.0 - walked)
    fall = np.clip(1.0 - walked - q, 0.0, 1.0)
    fall_doubted = np.clip(1.0 - np.clip(walked - spread, 0.0, 1.0) - q, 0.0, 1.0)
    budget = at_most(q, refusals)
    return (float(np.prod(doubted)), float(np.prod(1.0 - fall)), float(np.prod(1.0 - fall)) * budget,
            float(np.prod(1.0 - fall_doubted)) * budget)


def summary(out: Path, refusals: int) -> str:
    cells = collections.defaultdict(list)
    for row in map(json.loads, out.read_text().splitlines()):
        cells[(row["terrain"], row["difficulty"])].append((float(row["walked"]), *predictions(row, refusals)))
    lines = ["| terrain | difficulty | tasks | walked | " + " | ".join(PREDICTIONS) + " |",
             "| --- | --- | --- | --- | " + " | ".join("---" for _ in PREDICTIONS) + " |"]
    for (terrain, difficulty), values in sorted(cells.items()):
        m = np.mean(values, axis=0)
        lines.append(f"| {terrain} | {difficulty} | {len(values)} | {m[0]:.2f} | "
                     + " | ".join(f"{v:.2f}" for v in m[1:]) + " |")
    every = np.vstack([np.asarray(v) for v in cells.values()])
    largest = [max(abs(np.mean(np.asarray(v)[:, i]) - np.mean(np.asarray(v)[:, 0])) for v in cells.values())
               for i in range(1, len(PREDICTIONS) + 1)]
    lines.append("| all | Brier | " + str(len(every)) + " | | "
                 + " | ".join(f"{np.mean((every[:, i] - every[:, 0]) ** 2):.3f}"
                              for i in range(1, len(PREDICTIONS) + 1))
                 + " |")
    lines.append("| all | largest cell error | | | " + " | ".join(f"{v:.2f}" for v in largest) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out")
    parser.add_argument("--run", help="a Fig. 9 results folder (its CapPlanner tasks)")
    parser.add_argument("--refusals", type=int, default=4, help="refusals a walk goes round (default 4)")
    parser.add_argument("--summary", action="store_true")
    args = parser.parse_args(argv)
    if args.summary:
        print(summary(Path(args.out), args.refusals))
        return 0
    if not args.run:
        parser.error("--run is required to collect")
    collect(Path(args.out), Path(args.run))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
