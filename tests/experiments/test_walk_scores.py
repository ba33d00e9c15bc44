"""A capability model scored on whole walks' missions (issue 37)."""

import math

import numpy as np
import pytest

from qz_drake.capability import patches as P
from qz_drake.errors import QzError
from qz_drake.experiments.walk_scores import mission_actions, predict_mission, score_missions
from qz_drake.terrain import make_terrain


class StubModel:
    """success_all's interface: each action kind walks and plans with fixed chances (turns by
    direction), recorded per call."""

    WALK = {"orthogonal": 0.9, "diagonal": 0.8, "turn": (0.99, 0.95)}
    PLAN = {"orthogonal": 0.95, "diagonal": 0.9, "turn": (1.0, 0.97)}

    def __init__(self):
        self.calls = []

    def success_all(self, patches, feet, kind):
        (topology, f), = feet.items()
        assert patches.shape == (1, 20, 20) and f.shape == (1, 6, 3) and np.isfinite(f).all()
        self.calls.append(kind)
        if kind == "turn":
            return {topology: (np.array([[self.WALK["turn"][0]], [self.WALK["turn"][1]]]),
                               np.array([[self.PLAN["turn"][0]], [self.PLAN["turn"][1]]]), None)}
        return {topology: (np.array([self.WALK[kind]]), np.array([self.PLAN[kind]]), None)}


def test_a_mission_is_the_planners_actions_it_amounts_to():
    # One cell ahead: one orthogonal move.
    assert mission_actions((0, 0, 0), (1, 0, 0)) == [("orthogonal", -1, 0.0, 0.0, 0.0)]
    # A diagonal cell to the left: a left turn to face it, a diagonal move along it.
    (turn, move) = mission_actions((0, 0, 0), (1, 1, math.pi / 4))
    assert turn == ("turn", P.TURN_LEFT, 0.0, 0.0, 0.0)
    assert move[:2] == ("diagonal", -1) and move[4] == pytest.approx(math.pi / 4)
    # Two cells along x then a right turn to -45 deg: two moves from 0 and 1 m, one turn at 2 m.
    actions = mission_actions((0, 0, 0), (2, 0, -math.pi / 4))
    assert [a[0] for a in actions] == ["orthogonal", "orthogonal", "turn"]
    assert [a[2] for a in actions] == pytest.approx([0.0, 1.0, 2.0]) and actions[2][1] == P.TURN_RIGHT
    # In place: 90 deg left is two turns; a turn smaller than a step is one.
    assert [a[:2] for a in mission_actions((0, 0, 0), (0, 0, math.pi / 2))] == [("turn", P.TURN_LEFT)] * 2
    assert [a[:2] for a in mission_actions((0, 0, 0), (0.1, 0, 0.1))] == [("turn", P.TURN_LEFT)]


def test_a_missions_outcomes_are_products_over_its_actions():
    model = StubModel()
    flat = make_terrain("flat")
    mission = {"topology": "nominal", "start": [0.0, 0.0, 0.0], "target": [1.0, 1.0, math.pi / 4],
               "feet": np.zeros((6, 3)).tolist()}
    p = predict_mission(model, flat, mission)
    assert model.calls == ["turn", "diagonal"]
    walked, planned = 0.99 * 0.8, 1.0 * 0.9
    assert p["walked"] == pytest.approx(walked) and p["no_plan"] == pytest.approx(1 - planned)
    assert p["failed"] == pytest.approx(planned - walked)
    assert sum(p.values()) == pytest.approx(1.0)


def test_walks_missions_are_scored_per_mission_and_per_cell():
    model = StubModel()

    def mission(outcome, target):
        return {"topology": "nominal", "start": [-1.0, 0.0, 0.0], "target": target, "feet": np.zeros((6, 3)).tolist(),
                "outcome": outcome}

    records = [
        {"planner": "astar", "terrain": "stairs", "difficulty": "simple", "seed": 0, "reason": "", "success": True,
         "mission_records": [mission("walked", [0.0, 0.0, 0.0]), mission("walked", [0.0, 0.0, 0.0])]},
        {"planner": "astar", "terrain": "stairs", "difficulty": "simple", "seed": 1, "reason": "leg_contact",
         "success": False, "mission_records": [mission("walked", [0.0, 0.0, 0.0]), mission("failed", [0.0, 1.0, 0.0])]},
        {"planner": "astar", "terrain": "stairs", "difficulty": "simple", "seed": 2, "reason": "unreachable",
         "success": False, "mission_records": [mission("no_plan", [0.0, 1.0, 0.0])]},
        {"planner": "astar", "terrain": "stairs", "difficulty": "simple", "seed": 3, "reason": "error"},
        {"planner": "capplanner", "terrain": "stairs", "difficulty": "simple", "seed": 0, "reason": "", "success": True},
    ]
    scores = score_missions(records, model, scale=0.3)
    assert (scores["missions"], scores["walks"], scores["walks_without_missions"]) == (5, 3, 1)
    assert scores["outcomes"] == {"walked": 3, "no_plan": 1, "failed": 1}
    assert scores["failed"]["n"] == 5 and scores["failed"]["positives"] == 1
    (cell,) = scores["cells"]
    assert (cell["planner"], cell["walks"], cell["missions"]) == ("astar", 3, 5)
    assert cell["walks_without_execution_failure"] == pytest.approx(2 / 3)
    assert cell["missions_walked"] == pytest.approx(3 / 5)
    # Straight 1 m missions: one orthogonal move; the diagonal-ish ones a turn and a move.
    assert 0 < cell["predicted_walked"] < 1 and 0 < cell["predicted_without_execution_failure"] < 1
    with pytest.raises(QzError, match="record_missions"):
        score_missions(records[3:], model, scale=0.3)


def test_the_command_scores_a_trained_model_on_a_runs_missions(briefly_trained_model_dir, tmp_path, capsys):
    import json

    from qz_drake.cli import main

    def mission(outcome, target):
        return {"topology": "nominal", "start": [-1.0, 0.0, 0.0], "target": target, "feet": np.zeros((6, 3)).tolist(),
                "outcome": outcome}

    records = [{"key": f"stairs-simple-{s}-astar", "planner": "astar", "terrain": "stairs", "difficulty": "simple",
                "seed": s, "reason": "", "success": True,
                "mission_records": [mission("walked", [0.0, 0.0, 0.0]), mission(outcome, [0.0, 1.0, 0.0])]}
               for s, outcome in enumerate(("walked", "failed", "no_plan"))]
    (tmp_path / "results.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    (tmp_path / "settings.json").write_text(json.dumps({"scale": 0.3}))
    assert main(["experiment", "score-missions", str(tmp_path), "--model", str(briefly_trained_model_dir)]) == 0
    text = capsys.readouterr().out
    assert "6 missions of 3 walks (0 walks kept none): walked 4, no plan 1, executed and failed 1" in text
    assert "| astar | stairs | simple | 3 | 0.67 |" in text
    # Several runs' walks scored together (their worlds at one scale).
    other = tmp_path / "other"
    other.mkdir()
    (other / "results.jsonl").write_text(json.dumps(records[1]) + "\n")
    (other / "settings.json").write_text(json.dumps({"scale": 0.3}))
    assert main(["experiment", "score-missions", str(tmp_path), str(other),
                 "--model", str(briefly_trained_model_dir)]) == 0
    assert "8 missions of 4 walks (0 walks kept none): walked 5, no plan 1, executed and failed 2" in capsys.readouterr().out
    (other / "settings.json").write_text(json.dumps({"scale": 1.0}))
    assert main(["experiment", "score-missions", str(tmp_path), str(other),
                 "--model", str(briefly_trained_model_dir)]) == 2
    assert "scale" in capsys.readouterr().err
    assert main(["experiment", "score-missions", str(tmp_path / "nothing")]) == 2
    assert "results" in capsys.readouterr().err


def test_the_baseline_ranks_missions_by_the_tallest_terrain_they_meet():
    """The simple baseline of score-missions: a mission's largest patch height range; it ranks
    a mission over a 0.3 m box above missions on flat ground (AUC 1 when the refused one is the
    box's), and _auc counts ties half."""
    from qz_drake.experiments.walk_scores import _auc, height_range
    from qz_drake.terrain import HeightMap

    res = 0.05
    X, Y = np.meshgrid(res * np.arange(120), res * np.arange(80))
    world = HeightMap(np.where((X > 3.0) & (X < 3.5) & (Y > 1.5) & (Y < 2.5), 0.3, 0.0), res, (0.0, 0.0))

    def mission(x0, y0, x1, y1):
        return {"start": [x0, y0, 0.0], "target": [x1, y1, 0.0]}

    flat = [height_range(world, mission(0.5, 2.0, 1.5, 2.0)), height_range(world, mission(1.0, 0.6, 2.0, 0.6))]
    boxed = height_range(world, mission(2.6, 2.0, 3.6, 2.0))
    assert max(flat) < 0.01 and boxed == pytest.approx(0.3, abs=0.01)
    assert _auc([False, False, True], [*flat, boxed]) == 1.0
    assert _auc([True, False], [0.2, 0.2]) == 0.5 and _auc([True, True], [0.1, 0.2]) is None
