"""``qz static-gait`` and ``qz gait-depth-study`` end to end (exit codes 0 / 1 / 2), the
static-gait scenario files, and the depth study of Fig. 10 on a few terrains."""

import json
from pathlib import Path

import numpy as np
import pytest

from qz_drake.cli import main
from qz_drake.errors import ConfigError
from qz_drake.planning.depth_study import depth_study
from qz_drake.planning.static_gait_scenario import (StaticGaitScenario, load_static_gait_scenario,
                                                    make_static_gait_heightmap, save_static_gait_scenario,
                                                    validate_static_gait_scenario)
from qz_drake.viz.recording import recording_summary

# Static-gait scenarios have their own schema, so they live apart from the robot scenarios.
SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios" / "static_gait"

FLAT = """
name: cli_flat
terrain:
  kind: cuboids
  params: {max_height: 0.0, size_x: 0.8, size_y: 0.5}
steps: 4
depth: 1
simulation: {hold_duration: 0.2}
"""

# A 0.3 m wall 0.15 m ahead: no foothold can be reached, the search stops at a dead end.
WALL = """
name: cli_wall
terrain:
  kind: step
  params: {height: 0.3, start_x: 0.15, size_x: 3.0, size_y: 1.0, resolution: 0.005}
steps: 8
depth: 2
"""


def _scenario(tmp_path, text, name="scenario.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def _json(capsys) -> dict:
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


@pytest.mark.parametrize("path", sorted(SCENARIOS.glob("static_gait_*.yaml")), ids=lambda p: p.stem)
def test_scenario_files_load_and_round_trip(path, tmp_path):
    scenario = load_static_gait_scenario(path)
    assert scenario.name == path.stem
    heightmap = make_static_gait_heightmap(scenario)
    assert np.isfinite(heightmap.heights).all()
    save_static_gait_scenario(scenario, tmp_path / "again.yaml")
    assert load_static_gait_scenario(tmp_path / "again.yaml") == scenario


def test_static_gait_writes_states_recording_and_metrics(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["static-gait", _scenario(tmp_path, FLAT), "--out", str(out), "--json"]) == 0
    result = _json(capsys)
    assert result["success"] and result["search"]["states"] == 4
    assert result["walk"]["final_error_m"] < 0.02 and not result["walk"]["body_terrain_contact"]
    states = json.loads((out / "states.json").read_text())
    assert [s["leg"] for s in states["states"]] == ["LF", "RB", "RF", "LB"]
    npz = np.load(out / "states.npz")
    assert npz["feet"].shape == (4, 4, 3) and list(npz["leg"]) == ["LF", "RB", "RF", "LB"]
    assert np.allclose(npz["p_WB"], [s["p_WB"] for s in states["states"]])
    assert json.loads((out / "metrics.json").read_text())["walk"]["success"] is True
    assert recording_summary(out / "recording.html")["has_animation"]
    assert (out / "static_gait.png").stat().st_size > 1000


def test_depth_and_steps_override_and_a_dead_end_exits_1(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["static-gait", _scenario(tmp_path, WALL), "--out", str(out), "--json", "--steps", "6",
                 "--depth", "3"]) == 1
    result = _json(capsys)
    assert result["steps"] == 6 and result["depth"] == 3
    assert not result["success"] and "dead end" in result["search"]["reason"]
    assert (out / "metrics.json").is_file() and (out / "states.json").is_file()


@pytest.mark.parametrize("text, argv, named", [
    (FLAT, ["--depth", "0"], "--depth"),
    (FLAT, ["--steps", "two"], "--steps"),
    (FLAT.replace("max_height: 0.0", "max_hieght: 0.0"), [], "scenario.terrain.params.max_hieght"),
    (FLAT.replace("steps: 4", "stepz: 4"), [], "scenario.stepz"),
    (FLAT + "start_xy: [5.0, 0.0]\n", [], "scenario.start_xy"),
    (FLAT.replace("kind: cuboids", "kind: moon"), [], "scenario.terrain.kind"),
    (FLAT + "gait: {stride: -0.1}\n", [], "static_gait.stride"),
    # Into FLAT's own simulation section: a second `simulation:` key is refused as a duplicate.
    (FLAT.replace("simulation: {hold_duration: 0.2}", "simulation: {hold_duration: 0.2, kp: 0.0}"), [],
     "simulation.kp"),
])
def test_bad_input_exits_2_naming_the_field(tmp_path, capsys, text, argv, named):
    assert main(["static-gait", _scenario(tmp_path, text), "--out", str(tmp_path / "o"), *argv]) == 2
    err = capsys.readouterr().err
    assert named in err and len(err.strip().splitlines()) == 1


def test_missing_scenario_file_exits_2(tmp_path, capsys):
    assert main(["static-gait", str(tmp_path / "nope.yaml"), "--out", str(tmp_path / "o")]) == 2
    assert "nope.yaml" in capsys.readouterr().err


def test_depth_four_beats_greedy_on_cuboids():
    """Fig. 10 measured: on cuboids of random heights (edges invalid) looking four steps ahead
    finds gaits where a greedy search runs into a dead end, and never does worse."""
    study = depth_study((1, 4), terrains=10, steps=12, progress=True)
    assert study.success_rate[4] > study.success_rate[1]
    assert np.all(study.success[:, 1] >= study.success[:, 0])
    assert 0 < study.success_rate[1] < 1  # neither trivial nor impossible
    assert set(study.failure_causes[1]) <= {"reach", "support_margin", "swing_collision", "body_rear",
                                            "body_left", "body_right", "no valid foothold"}


def test_depth_study_command_writes_picture_and_json(tmp_path, capsys):
    out = tmp_path / "study"
    assert main(["gait-depth-study", "--out", str(out), "--terrains", "3", "--depths", "1,2", "--steps", "4",
                 "--json"]) == 0
    summary = _json(capsys)
    assert summary["terrains"] == 3 and set(summary["success_rate"]) == {"1", "2"}
    assert json.loads((out / "depth_study.json").read_text())["depths"] == [1, 2]
    assert (out / "depth_study.png").stat().st_size > 1000


@pytest.mark.parametrize("argv, named", [(["--depths", "0,2"], "--depths"), (["--terrains", "0"], "--terrains"),
                                         (["--max-height", "-1"], "--max-height")])
def test_depth_study_bad_arguments_exit_2(tmp_path, capsys, argv, named):
    assert main(["gait-depth-study", "--out", str(tmp_path / "o"), *argv]) == 2
    assert named in capsys.readouterr().err


def test_scenario_defaults_are_valid():
    scenario = StaticGaitScenario()
    assert scenario.terrain.kind == "cuboids" and scenario.depth == 4
    scenario.depth = 0
    with pytest.raises(ConfigError, match="scenario.depth"):
        validate_static_gait_scenario(scenario)
