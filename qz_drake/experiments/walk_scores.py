"""A capability model scored on whole walks (issue 37): does it predict what ends a walk?

The networks predict single actions of the planner (a move of one cell, a 45 deg turn) from a
standing start; a walk's BLC missions are longer (A*'s up to a metre along any heading,
CapPlanner's merged actions) and start where the last one ended. A mission is read as the
actions it amounts to (:func:`mission_actions`: turns to face its target, moves of one cell,
turns to its final heading), each predicted from the pose it starts in: the first with the
feet the BLC planned the mission from, the next ones standing on the topology's nominal
footholds, as the planner's map assumes. The mission then walks with the product of the
actions' P(walked); the BLC plans it with the product of their P(planned); the rest of the
planned share is "executed and failed".

:func:`score_missions` compares those predictions with the outcomes kept by a Fig. 9 run with
``record_missions`` (qz_drake.capability.walk_missions): the ROC AUC of P(executed and failed)
and of P(no plan) over the missions, and per planner, terrain and difficulty the predicted
against the observed share of missions walked and of walks without an executed failure.
"""

from __future__ import annotations

import math

import numpy as np

from qz_drake.capability import patches as P
from qz_drake.errors import bad_value

# A mission that moves the body less than this is a turn in place. [m]
TURN_IN_PLACE = 0.25


def _turns(yaw: float, to: float) -> list[int]:
    """45 deg turns from ``yaw`` to (the nearest multiple of 45 deg from) ``to``: TURN_LEFT or
    TURN_RIGHT each."""
    steps = int(round(math.remainder(to - yaw, 2 * math.pi) / P.HEADING_STEP))
    return [P.TURN_LEFT if steps > 0 else P.TURN_RIGHT] * abs(steps)


def mission_actions(start, target) -> list[tuple[str, int, float, float, float]]:
    """The planner's actions a mission from ``start`` to ``target`` (x, y, yaw) amounts to, each
    as (kind, direction, x, y, yaw) of the pose it starts from: turns to face the target, moves
    of one cell along that bearing (diagonal where the bearing is nearest an odd one of the
    planner's eight headings), turns to the target's yaw. A turn in place is its turns alone (at least one)."""
    x, y, yaw = (float(v) for v in start)
    tx, ty, tyaw = (float(v) for v in target)
    actions = []
    distance = math.hypot(tx - x, ty - y)
    if distance >= TURN_IN_PLACE:
        bearing = math.atan2(ty - y, tx - x)
        for d in _turns(yaw, bearing):
            actions.append(("turn", d, x, y, yaw))
            yaw += P.HEADING_STEP if d == P.TURN_LEFT else -P.HEADING_STEP
        # The network of the nearest of the planner's eight headings: diagonal on the odd ones.
        kind = "diagonal" if int(round(bearing / P.HEADING_STEP)) % 2 else "orthogonal"
        count = max(1, int(round(distance / P.move_distance(kind))))
        for k in range(count):
            actions.append((kind, -1, x + (tx - x) * k / count, y + (ty - y) * k / count, bearing))
        x, y, yaw = tx, ty, bearing
    turns = _turns(yaw, tyaw)
    if not actions and not turns:  # a mission that neither moves nor turns a step: one turn's worth
        turns = [P.TURN_LEFT if math.remainder(tyaw - yaw, 2 * math.pi) >= 0 else P.TURN_RIGHT]
    for d in turns:
        actions.append(("turn", d, x, y, yaw))
        yaw += P.HEADING_STEP if d == P.TURN_LEFT else -P.HEADING_STEP
    return actions


def predict_mission(model, heightmap, mission: dict) -> dict:
    """P(walked), P(no plan), P(executed and failed) of one mission record (walk_missions):
    products over its actions (module docstring). A model without a plan output predicts no
    split: P(no plan) and P(failed) are then None."""
    from qz_drake.capability.model_base import pose_inputs
    from qz_drake.robot.params import DEFAULT_PARAMS
    from qz_drake.robot.topology import get_topology

    topology = mission["topology"]
    walked, planned = 1.0, 1.0
    feet_W = np.asarray(mission["feet"], dtype=float)
    for k, (kind, direction, x, y, yaw) in enumerate(mission_actions(mission["start"], mission["target"])):
        if k > 0:  # standing on the topology's nominal footholds, as the planner's map assumes
            feet_W = P.nominal_feet_W(heightmap, x, y, yaw, get_topology(topology), DEFAULT_PARAMS.foot_radius)
        patch, feet = pose_inputs(heightmap, x, y, yaw, kind, feet_W)
        success, plan, _ = model.success_all(patch[None], {topology: feet[None]}, kind)[topology]
        pick = (lambda a: float(np.asarray(a)[direction][0])) if kind == "turn" else (lambda a: float(np.asarray(a)[0]))
        walked *= pick(success)
        planned = None if plan is None or planned is None else planned * pick(plan)
    if planned is None:
        return {"walked": walked, "no_plan": None, "failed": None}
    return {"walked": walked, "no_plan": 1.0 - planned, "failed": max(planned - walked, 0.0)}


def height_range(heightmap, mission: dict) -> float:
    """The simple baseline a model must beat on walks: the largest height range (max - min) of
    the patches of a mission's actions [m] (the taller the terrain the robot meets, the likelier
    the BLC refuses or the walk fails); no learning, no feet."""
    out = 0.0
    for kind, _, x, y, yaw in mission_actions(mission["start"], mission["target"]):
        patch = P.sample_patches(heightmap, x, y, yaw, kind, ground=float(P.ground_reference(heightmap, x, y)))
        out = max(out, float(np.max(patch) - np.min(patch)))
    return out


def score_missions(records: list[dict], model, *, scale: float = 1.0) -> dict:
    """A model scored on the missions a Fig. 9 run kept (``record_missions``): every mission's
    predicted outcomes against its outcome, and the tables of module docstring. ``records``
    are the run's results (fig9.read_results); walks without ``mission_records`` are skipped
    and counted."""
    from qz_drake.capability.evaluation import binary_metrics
    from qz_drake.experiments.worlds import make_task

    rows, skipped = [], 0
    for r in records:
        if r.get("reason") == "error":
            continue
        missions = r.get("mission_records")
        if missions is None:
            skipped += 1
            continue
        task = make_task(r["terrain"], r["difficulty"], int(r["seed"]), scale=scale)
        predicted = [dict(predict_mission(model, task.heightmap, m), height_range=height_range(task.heightmap, m))
                     for m in missions]
        rows.append((r, missions, predicted))
    if not rows:
        raise bad_value("results", f"{len(records)} records", "no walk kept its missions (run the experiment "
                                                              "with record_missions)")
    flat = [(m, p) for _, missions, predicted in rows for m, p in zip(missions, predicted)]
    outcome = np.array([m["outcome"] for m, _ in flat])
    has_split = all(p["failed"] is not None for _, p in flat)
    scores = {"missions": len(flat), "walks": len(rows), "walks_without_missions": skipped,
              "outcomes": {o: int(np.sum(outcome == o)) for o in ("walked", "no_plan", "failed")},
              "walked": binary_metrics(outcome == "walked", [p["walked"] for _, p in flat])}
    if has_split:
        scores["failed"] = binary_metrics(outcome == "failed", [p["failed"] for _, p in flat])
        scores["no_plan"] = binary_metrics(outcome == "no_plan", [p["no_plan"] for _, p in flat])
    # The baseline (height_range), as a ranking: its ROC AUC for each outcome the model ranks.
    scores["baseline_auc"] = {name: _auc(outcome == name, [p["height_range"] for _, p in flat])
                              for name in ("no_plan", "failed")}
    scores["baseline_auc"]["walked"] = _auc(outcome == "walked", [-p["height_range"] for _, p in flat])
    cells = {}
    for r, missions, predicted in rows:
        key = (r["planner"], r["terrain"], r["difficulty"])
        cell = cells.setdefault(key, {"walks": 0, "walks_ok": 0, "walk_predicted": [], "missions": 0,
                                      "missions_walked": 0, "mission_predicted": []})
        cell["walks"] += 1
        cell["walks_ok"] += int(not any(m["outcome"] == "failed" for m in missions))
        if has_split:
            cell["walk_predicted"].append(float(np.prod([1.0 - p["failed"] for p in predicted])))
        cell["missions"] += len(missions)
        cell["missions_walked"] += sum(m["outcome"] == "walked" for m in missions)
        cell["mission_predicted"] += [p["walked"] for p in predicted]
    scores["cells"] = [{"planner": planner, "terrain": terrain, "difficulty": difficulty,
                        "walks": c["walks"], "walks_without_execution_failure": c["walks_ok"] / c["walks"],
                        "predicted_without_execution_failure": float(np.mean(c["walk_predicted"]))
                        if c["walk_predicted"] else None,
                        "missions": c["missions"],
                        "missions_walked": c["missions_walked"] / c["missions"] if c["missions"] else None,
                        "predicted_walked": float(np.mean(c["mission_predicted"])) if c["mission_predicted"] else None}
                       for (planner, terrain, difficulty), c in sorted(cells.items())]
    return scores


def _auc(labels, scores) -> float | None:
    """ROC AUC (scikit-learn's; ties count half), None without both classes."""
    from sklearn.metrics import roc_auc_score

    labels = np.asarray(labels, dtype=bool)
    if labels.all() or not labels.any():
        return None
    return float(roc_auc_score(labels, np.asarray(scores, dtype=float)))
