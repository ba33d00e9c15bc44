"""benchmarks/turn_risk.py: a run's recorded missions sorted by what they do and by their start's
distance from the nearest edge, against the model's predicted execution failures (what
CapabilityMdpConfig.turn_edge_risk was set from, session 53)."""

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "turn_risk.py"


def _script():
    spec = importlib.util.spec_from_file_location("turn_risk", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class TurnsFailModel:
    """success_all's interface: moves walk 0.99 and plan 1.0; turns walk 0.9 and plan 0.95."""

    def success_all(self, patches, feet, kind):
        (topology, _), = feet.items()
        if kind == "turn":
            return {topology: (np.full((2, 1), 0.9), np.full((2, 1), 0.95), None)}
        return {topology: (np.array([0.99]), np.array([1.0]), None)}


def test_missions_are_sorted_by_kind_and_distance_from_an_edge(tmp_path):
    from qz_drake.experiments.worlds import make_task
    from qz_drake.planning.capability_mdp import edge_distances

    turn_risk = _script()
    heightmap = make_task("obstacles", "hard", 1000, 0.3).heightmap
    distance = edge_distances(heightmap, 0.05)
    rows, cols = np.nonzero((distance > 0.02) & (distance < 0.15))
    near = heightmap.origin[0] + cols[0] * heightmap.resolution, heightmap.origin[1] + rows[0] * heightmap.resolution
    rows, cols = np.nonzero(distance > 0.8)
    far = heightmap.origin[0] + cols[0] * heightmap.resolution, heightmap.origin[1] + rows[0] * heightmap.resolution

    def mission(xy, target, outcome):
        return {"start": [*xy, 0.0], "target": target, "feet": np.zeros((6, 3)).tolist(), "topology": "nominal",
                "outcome": outcome}

    missions = [mission(near, [*near, math.pi / 4], "failed"),          # a turn in place by a box
                mission(near, [*near, math.pi / 4], "no_plan"),
                mission(far, [far[0] + 1.0, far[1], 0.0], "walked"),     # a move in the open
                mission(far, [far[0] + 1.0, far[1] + 1.0, math.pi / 4], "walked")]  # a move that turns
    record = {"key": "obstacles-hard-1000-capplanner", "terrain": "obstacles", "difficulty": "hard", "seed": 1000,
              "planner": "capplanner", "success": False, "reason": "leg_contact", "mission_records": missions}
    (tmp_path / "results.jsonl").write_text(json.dumps(record) + "\n")
    (tmp_path / "settings.json").write_text(json.dumps({"scale": 0.3}))
    table = turn_risk.tally([tmp_path], TurnsFailModel())
    assert table[("box fields", "turn in place", (0.0, 0.2))][:3] == [2, 1, 1]
    # One turn: walked 0.9 of the 0.95 it plans, twice.
    assert table[("box fields", "turn in place", (0.0, 0.2))][3] == pytest.approx(2 * 0.05)
    assert table[("box fields", "move", (0.5, math.inf))][:3] == [1, 0, 0]
    assert table[("box fields", "move and turn", (0.5, math.inf))][0] == 1
    # Worlds kept for checks outside the project are not read.
    record["seed"] = 60
    (tmp_path / "results.jsonl").write_text(json.dumps(record) + "\n")
    with pytest.raises(SystemExit, match="50-99"):
        turn_risk.tally([tmp_path], TurnsFailModel())
