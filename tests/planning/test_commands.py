"""``qz costmap`` and ``qz astar`` end to end on small scenarios (exit codes 0 / 1 / 2)."""

import json

import numpy as np
import pytest

from qz_drake.cli import main

STAIRS = """
name: cli_stairs
terrain:
  kind: stairs
  params: {rise: 0.1, run: 0.4, count: 2, start_x: 0.5}
controller:
  kind: walk
  route:
  - {x: 2.5, y: 0.0}
"""

# A 0.5 m wall across the whole course: over the 0.2 m step limit, so the far side is cut off.
WALL = """
name: cli_wall
terrain:
  kind: step
  params: {height: 0.5, start_x: 1.0, length: 0.3}
"""

GRID_MAP = """
name: cli_grid_map
terrain:
  kind: grid_map
"""


def _scenario(tmp_path, text, name="scenario.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def _json(capsys) -> dict:
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def test_costmap_writes_pngs_npz_and_summary(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["costmap", _scenario(tmp_path, STAIRS), "--out", str(out), "--json"]) == 0
    summary = _json(capsys)
    for stem in ("slope", "roughness", "step_height", "body_cost"):
        assert (out / f"{stem}.png").stat().st_size > 1000
    data = np.load(out / "cost_map.npz")
    assert data["body_cost"].shape == tuple(summary["shape"])
    assert data["heading_cost"].shape == (8, *summary["shape"])
    # Two 0.1 m stairs: a step is seen, and every cell stays traversable (limit 0.2 m).
    assert summary["max_step_height_m"] == pytest.approx(0.1, abs=0.02)
    assert summary["traversable_fraction"] == 1.0
    assert summary["robot"] == "qingzhui"


def test_costmap_quadruped_footprint(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["costmap", _scenario(tmp_path, STAIRS), "--out", str(out), "--robot", "quadruped",
                 "--json"]) == 0
    assert _json(capsys)["robot"] == "quadruped"


def test_astar_route_goal_found(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["astar", _scenario(tmp_path, STAIRS), "--out", str(out), "--json"]) == 0
    result = _json(capsys)
    assert result["found"] is True
    assert result["start"] == [0.0, 0.0] and result["goal"] == [2.5, 0.0]
    # The straight-line distance (to a cell: the points snap to cell centres), as the stairs
    # are traversable.
    assert result["length_m"] == pytest.approx(2.5, abs=0.1)
    assert result["cost"] > 0 and result["expansions"] > 0 and result["time_s"] >= 0
    assert (out / "astar_path.png").stat().st_size > 1000
    assert np.load(out / "astar_path.npz")["xy"].shape[1] == 2


def test_astar_on_cropped_grid_map(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["astar", _scenario(tmp_path, GRID_MAP), "--out", str(out), "--json",
                 "--start", "0,0", "--goal", "1.0,0.5", "--margin", "0.5"]) in (0, 1)
    result = _json(capsys)
    assert result["map_shape"][0] < 60 and result["map_shape"][1] < 60
    assert {"found", "length_m", "cost", "expansions", "time_s"} <= result.keys()


def test_astar_safety_weight_never_shortens_path(tmp_path, capsys):
    scenario = _scenario(tmp_path, STAIRS)
    lengths = []
    for w in ("0", "0.9"):
        assert main(["astar", scenario, "--out", str(tmp_path / w), "--json", "--safety-weight", w,
                     "--goal", "2.5,0.8"]) == 0
        lengths.append(_json(capsys)["length_m"])
    assert lengths[1] >= lengths[0] - 1e-9


def test_astar_unreachable_goal_exits_1(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["astar", _scenario(tmp_path, WALL), "--out", str(out), "--json",
                 "--start", "0,0", "--goal", "2,0", "--margin", "0.5"]) == 1
    result = _json(capsys)
    assert result["found"] is False and result["length_m"] is None
    assert (out / "astar_path.png").exists()


@pytest.mark.parametrize("argv, named", [
    (["--goal", "abc"], "--goal"),
    (["--start", "1,2,3"], "--start"),
    (["--goal", "50,0"], "--goal"),
    (["--safety-weight", "1.5"], "--safety-weight"),
    (["--margin", "-1"], "--margin"),
])
def test_astar_bad_arguments_exit_2(tmp_path, capsys, argv, named):
    assert main(["astar", _scenario(tmp_path, STAIRS), "--out", str(tmp_path / "o"), *argv]) == 2
    err = capsys.readouterr().err
    assert named in err and len(err.strip().splitlines()) == 1


def test_astar_without_goal_or_route_exits_2(tmp_path, capsys):
    assert main(["astar", _scenario(tmp_path, WALL), "--out", str(tmp_path / "o")]) == 2
    assert "--goal" in capsys.readouterr().err


def test_costmap_bad_scenario_exits_2(tmp_path, capsys):
    bad = _scenario(tmp_path, "terrain: {kind: no_such_terrain}\n")
    assert main(["costmap", bad, "--out", str(tmp_path / "o")]) == 2
    assert "no_such_terrain" in capsys.readouterr().err
