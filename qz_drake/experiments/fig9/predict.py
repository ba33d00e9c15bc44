"""What CapPlanner's model expected of each task before walking it (``qz experiment report
--predict``): the plan from the start and its predicted chance of arriving, kept in
``predictions.jsonl``, and the route-level calibration of those predictions against the walks.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from qz_drake.errors import bad_value
from qz_drake.progress import ProgressReport
from qz_drake.experiments.fig9.results import (MODEL_IDENTITY, PREDICTIONS, RESULTS, drop_cut_off_record,
                                               read_config, read_json_lines, read_results, read_settings)
from qz_drake.experiments.fig9.tasks import ExperimentConfig, TaskSpec, _mdp_overrides
from qz_drake.experiments.worlds import DIFFICULTIES, TERRAINS, make_task


def predict_route(spec: TaskSpec, config: ExperimentConfig = ExperimentConfig(), model=None) -> dict:
    """What CapPlanner's model expected of a task before walking it: the plan from the start
    (the walk's first plan: same model, MDP settings, start cell and heading), its predicted
    chance that no action ends the walk (fall_free), the product of the actions' success
    (success), both as the plan weighs them (the ensemble's doubt, the tuned share of refusals
    counted as failures), the model's own estimate of the same route walking without an
    action ending it, refusals gone round (expected_fall_free: CapabilityPlan.expected_fall_free),
    the actions and topology changes; reaches False where it found no path."""
    from qz_drake.capability.model import CapabilityModel
    from qz_drake.capability.patches import KINDS, map_stance
    from qz_drake.planning.capability_mdp import plan
    from qz_drake.robot.topology import TOPOLOGY_NAMES
    from qz_drake.planning.capplanner_route import mdp_config

    model = model or CapabilityModel.load(config.capability_model or None)
    task = make_task(spec.terrain, spec.difficulty, spec.seed, scale=config.scale)
    topologies = [t for t in TOPOLOGY_NAMES if all(model.has_network(t, k) for k in KINDS)]
    mdp = mdp_config(_mdp_overrides(config), topologies, map_stance(config.blc_terminal_stance))
    heading = int(round(task.start_yaw / (np.pi / 4))) % 8
    result = plan(model, task.heightmap, task.start, heading, task.goal, config=mdp)
    return {"key": spec.key, "terrain": spec.terrain, "difficulty": spec.difficulty, "seed": spec.seed,
            "reaches": bool(result.reaches_goal),
            "fall_free": result.fall_free_probability if result.reaches_goal else 0.0,
            "success": result.success_probability if result.reaches_goal else 0.0,
            "expected_fall_free": result.expected_fall_free() if result.reaches_goal else 0.0,
            "actions": len(result.steps), "topology_changes": result.topology_changes}


def predict_routes(out, config: ExperimentConfig | None = None, model=None, progress: bool = False) -> list[dict]:
    """:func:`predict_route` for every CapPlanner task of a results folder, appended to
    ``predictions.jsonl`` (resumable: a task already predicted is skipped); returns them all.
    The config is the run's (settings.json) unless given."""
    from qz_drake.capability.model import CapabilityModel

    out = Path(out)
    if not (out / RESULTS).is_file():
        raise bad_value("results", str(out), f"no {RESULTS} there (run qz experiment capplanner-vs-astar)")
    records = [r for r in read_results(out) if r["planner"] == "capplanner" and r["reason"] != "error"]
    if config is None:
        config = read_config(out)
        identity = read_settings(out).get(MODEL_IDENTITY)
    else:
        identity = None
    model = model or CapabilityModel.load(config.capability_model or None)
    if identity and model.identity != identity:
        raise bad_value("capability model", model.identity,
                        f"the run at {out} walked with model {identity}; predict with that one")
    path = out / PREDICTIONS
    drop_cut_off_record(path)
    done = {p["key"]: p for p in read_json_lines(path)}
    # A prediction from before expected_fall_free existed is made again.
    todo = [r for r in records if "expected_fall_free" not in done.get(r["key"], {})]
    with path.open("a") as f, ProgressReport("predicting routes", len(records), unit="routes",
                                             completed=len(records) - len(todo), enabled=progress) as report:
        for r in todo:
            p = predict_route(TaskSpec(r["terrain"], r["difficulty"], r["seed"], "capplanner"), config, model)
            done[p["key"]] = p
            f.write(json.dumps(p) + "\n")
            f.flush()
            report.update(advance=1)
    return [done[r["key"]] for r in records if r["key"] in done]


def route_calibration(records: list[dict], predictions: list[dict]) -> list[dict]:
    """CapPlanner's route-level calibration per (terrain, difficulty), then per difficulty and
    over all: of the tasks it set out on (a path found), the mean predicted chance of no fall
    along the first plan (and the mean product of its actions' success, counting a planning
    failure as a failure too) against the share walked to the goal, and the share of tasks it
    declined (no path: the goal predicted unreachable) with how many of those A* walked; a
    task's last prediction counts."""
    walked = {r["key"]: bool(r["success"]) for r in records if r["reason"] != "error"}
    astar = {(r["terrain"], r["difficulty"], r["seed"]): bool(r["success"])
             for r in records if r["planner"] == "astar" and r["reason"] != "error"}
    # A task predicted again (a prediction from before a field existed) counts by its last one.
    usable = [p for p in {p["key"]: p for p in predictions}.values() if p["key"] in walked]

    def row(terrain, difficulty, cell):
        started = [p for p in cell if p["reaches"]]
        declined = [p for p in cell if not p["reaches"]]
        return {"terrain": terrain, "difficulty": difficulty, "tasks": len(cell), "started": len(started),
                "predicted_fall_free": float(np.mean([p["fall_free"] for p in started])) if started else None,
                "predicted_success": float(np.mean([p["success"] for p in started])) if started else None,
                "expected_fall_free": float(np.mean([p["expected_fall_free"] for p in started]))
                if started and all("expected_fall_free" in p for p in started) else None,
                "walked_rate": float(np.mean([walked[p["key"]] for p in started])) if started else None,
                "declined": len(declined),
                "declined_walked_by_astar": sum(astar.get((p["terrain"], p["difficulty"], p["seed"]), False)
                                                for p in declined)}

    rows = [row(t, d, [p for p in usable if (p["terrain"], p["difficulty"]) == (t, d)])
            for t in TERRAINS for d in DIFFICULTIES]
    rows += [row("all", d, [p for p in usable if p["difficulty"] == d]) for d in DIFFICULTIES]
    rows.append(row("all", "all", usable))
    return [r for r in rows if r["tasks"]]


# What a route calibration row predicts, as the report names it.
ROUTE_PREDICTIONS = {"expected_fall_free": "expected no-fall (the model's mean)",
                     "predicted_fall_free": "the plan's predicted no-fall",
                     "predicted_success": "the plan's predicted success"}


def route_calibration_check(rows: list[dict], tolerance: float) -> dict:
    """How close each of CapPlanner's route predictions (ROUTE_PREDICTIONS) comes to the share
    walked, cell by cell (the (terrain, difficulty) rows of :func:`route_calibration` that set
    out on at least one task; the pooled rows are left out): per prediction the cells within
    ``tolerance``, the worst cell and its gap, and whether every cell is within."""
    cells = [r for r in rows if "all" not in (r["terrain"], r["difficulty"]) and r["walked_rate"] is not None]
    out = {"tolerance": float(tolerance), "cells": len(cells)}
    for field in ROUTE_PREDICTIONS:
        gaps = [(abs(r[field] - r["walked_rate"]), r) for r in cells if r.get(field) is not None]
        if not gaps:
            continue
        gap, worst = max(gaps, key=lambda g: g[0])
        within = [g <= tolerance + 1e-12 for g, _ in gaps]
        out[field] = {"within": int(sum(within)), "cells": len(gaps), "worst_gap": float(gap),
                      "worst_cell": f"{worst['terrain']} {worst['difficulty']}", "holds": all(within)}
    return out
