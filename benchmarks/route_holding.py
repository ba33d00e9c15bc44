"""CapPlanner's routes without the robot (issue 54, "routes that hold"): the TLC alone walks a
Fig. 9 task, each mission assumed to end at its target with the feet on its topology's nominal
footholds (no BLC, no simulation), and replans there as the walk's TLC does
(CapabilityVIPlanner.next_missions: the stance judged, value iteration solved again, the route
held or changed by ``hold_margin``). What it measures is the planner's own dithering and
detours, apart from the BLC's refusals and the robot's deviations:

    python benchmarks/route_holding.py OUT.jsonl [--seeds 1000-1003] [--margins none,0,2,5] [--mdp pessimism=0]
    python benchmarks/route_holding.py --summary OUT.jsonl

One JSON line per task, margin and MDP setting: whether the dry walk reached the goal cell, its
missions and actions, the path length walked against the straight line and against the first
plan's path, the first plan's predicted success and chance of no fall, and the planner's
decisions at each replan (the next 2 m the same, held, changed, off route, new). Worlds of seeds
50-99 are refused (kept for checks outside the project); the tuning seeds (1000+) are the
default. CapPlanner's settings are those a results folder's walks had (``--run``, by default
the tuned ones of session 45's ladder walks), ``--mdp`` sets others over them.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

# Most missions of one dry walk (a planner that loops never reaches the goal).
MAX_MISSIONS = 80


def _seeds(text: str) -> list[int]:
    out = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out.extend(range(int(lo), int(hi or lo) + 1))
    if any(50 <= s <= 99 for s in out):
        raise SystemExit("seeds 50-99 are reserved for checks outside the project")
    return out


def dry_walk(task, model, config, margin: float | None, mdp: dict | None = None) -> dict:
    from qz_drake.capability.patches import KINDS, nominal_feet_W
    from qz_drake.experiments.fig9.tasks import _mdp_overrides
    from qz_drake.planning.capability_planner import ROUTE_DECISIONS, CapabilityVIPlanner
    from qz_drake.planning.capplanner_route import mdp_config
    from qz_drake.planning.guidance import MissionSplitConfig
    from qz_drake.robot.params import DEFAULT_PARAMS
    from qz_drake.robot.topology import TOPOLOGY_NAMES, get_topology

    topologies = [t for t in TOPOLOGY_NAMES if all(model.has_network(t, k) for k in KINDS)]
    overrides = {**_mdp_overrides(config), **(mdp or {})}
    split = MissionSplitConfig(max_length=config.capplanner_mission_length,
                               min_success=config.capplanner_merge_min_success)
    clock = time.perf_counter()
    planner = CapabilityVIPlanner(model=model, heightmap=task.heightmap, goal=task.goal,
                                  start=(*task.start, task.start_yaw), mdp_config=mdp_config(overrides, topologies),
                                  split_config=split, min_route_success=config.capplanner_min_route_success,
                                  hold_margin=margin)
    route = list(planner.GetOutputPort("guidance").Eval(planner.CreateDefaultContext()))
    first = sum(m.length for m in route)
    plan = planner.first_plan
    reaches = plan is not None and plan.reaches_goal
    predicted = plan.success_probability if reaches else 0.0
    fall_free = plan.fall_free_probability if reaches else 0.0
    walked, missions, actions, replans, reached = 0.0, 0, 0, 0, False
    x, y = task.start
    while route and missions < MAX_MISSIONS:
        m, held = route[0], route[1:]
        missions += 1
        actions += len(m.steps)
        tx, ty, yaw = m.target
        walked += math.hypot(tx - x, ty - y) if m.back_out else m.length
        x, y = tx, ty
        ix, iy = planner.mdp.cell_of(x, y, margin=planner.mdp.config.cell_size)
        if (ix, iy) == planner.mdp.goal_cell:
            reached = True
            break
        feet = nominal_feet_W(task.heightmap, x, y, yaw, get_topology(m.topology), DEFAULT_PARAMS.foot_radius)
        new = planner.next_missions(float(missions), x, y, yaw, m.topology, feet, held)
        replans += 1
        route = new
    decisions = {d: sum(1 for _, x in planner.log.route_decisions if x == d) for d in ROUTE_DECISIONS}
    return {"reached": reached, "missions": missions, "actions": actions, "walked_m": walked, "first_plan_m": first,
            "first_plan_success": predicted, "first_plan_fall_free": fall_free,
            "replans": replans, "route_changes": decisions["changed"], "decisions": decisions,
            "back_outs": planner.log.back_outs, "wall_s": time.perf_counter() - clock}


def run(out: Path, seeds, margins, terrains, difficulties, config, mdp: dict) -> None:
    from qz_drake.capability.model import CapabilityModel
    from qz_drake.experiments.worlds import make_task

    done = set()
    if out.exists():
        done = {(r["key"], r["margin"], json.dumps(r.get("mdp", {}), sort_keys=True))
                for r in map(json.loads, out.read_text().splitlines())}
    model = CapabilityModel.load(config.capability_model or None)
    with out.open("a") as f:
        for seed in seeds:
            for terrain in terrains:
                for difficulty in difficulties:
                    task = make_task(terrain, difficulty, seed)
                    key = f"{terrain}-{difficulty}-{seed}"
                    for margin in margins:
                        if (key, margin, json.dumps(mdp, sort_keys=True)) in done:
                            continue
                        row = {"key": key, "terrain": terrain, "difficulty": difficulty, "seed": seed,
                               "margin": margin, "mdp": mdp, "straight_m": task.distance,
                               **dry_walk(task, model, config, margin, mdp)}
                        f.write(json.dumps(row) + "\n")
                        f.flush()
                        print(f"{key} margin {margin}: reached {row['reached']}, "
                              f"{row['walked_m'] / task.distance:.2f} of the straight line, "
                              f"{row['route_changes']} of {row['replans']} replans changed the next 2 m",
                              file=sys.stderr)


def summary(paths) -> str:
    rows = [r for p in paths for r in map(json.loads, Path(p).read_text().splitlines())]
    lines = ["| MDP settings | margin | difficulty | tasks | reached | walked / straight (reached) "
             "| walked / first plan (reached) | first plan's predicted success / no fall "
             "| replans changing the next 2 m "
             "| same / held / changed / off route / new | back-outs |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    arms = sorted({(json.dumps(r.get("mdp", {}), sort_keys=True), r["margin"]) for r in rows},
                  key=lambda a: (a[0], -1 if a[1] is None else a[1]))
    for mdp, margin in arms:
        for difficulty in sorted({r["difficulty"] for r in rows}):
            group = [r for r in rows if r["margin"] == margin and r["difficulty"] == difficulty
                     and json.dumps(r.get("mdp", {}), sort_keys=True) == mdp]
            if not group:
                continue
            ok = [r for r in group if r["reached"]]
            replans = sum(r["replans"] for r in group)
            d = {k: sum(r["decisions"][k] for r in group) for k in group[0]["decisions"]}
            names = ", ".join(f"{k} {v:g}" for k, v in json.loads(mdp).items()) or "tuned"
            lines.append(
                f"| {names} | {'none' if margin is None else margin} | {difficulty} | {len(group)} | {len(ok)} "
                f"| {np.mean([r['walked_m'] / r['straight_m'] for r in ok]):.3f} "
                f"| {np.mean([r['walked_m'] / max(r['first_plan_m'], 1e-9) for r in ok]):.3f} "
                f"| {np.mean([r.get('first_plan_success', np.nan) for r in group]):.3f} / "
                f"{np.mean([r.get('first_plan_fall_free', np.nan) for r in group]):.3f} "
                f"| {sum(r['route_changes'] for r in group)} of {replans} "
                f"({sum(r['route_changes'] for r in group) / max(replans, 1):.0%}) "
                f"| {' / '.join(str(d[k]) for k in d)} | {sum(r['back_outs'] for r in group)} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", nargs="?")
    parser.add_argument("--seeds", default="1000-1003")
    parser.add_argument("--margins", default="none,0,2,5")
    parser.add_argument("--terrains", default="stairs,obstacles,both")
    parser.add_argument("--difficulties", default="medium,hard")
    parser.add_argument("--run", default="data/blc_ladder/walks/cap_ladder",
                        help="a results folder whose CapPlanner settings the dry walks take")
    parser.add_argument("--mdp", default="", help="MDP settings over the tuned ones, e.g. pessimism=0,action_cost=2")
    parser.add_argument("--summary", nargs="+")
    args = parser.parse_args(argv)
    if args.summary:
        print(summary(args.summary))
        return 0
    if not args.out:
        parser.error("OUT.jsonl is required")
    margins = [None if m == "none" else float(m) for m in args.margins.split(",")]
    from qz_drake.experiments.fig9 import read_config

    config = read_config(args.run)
    mdp = {k: float(v) for k, _, v in (item.partition("=") for item in args.mdp.split(",") if item)}
    run(Path(args.out), _seeds(args.seeds), margins, args.terrains.split(","), args.difficulties.split(","), config,
        mdp)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
