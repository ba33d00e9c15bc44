"""Scenario files and the qz command: good input runs, bad input names the field, exit 2."""

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest

from qz_drake.cli import main
from qz_drake.config import Scenario, load_scenario, load_scenario_text, save_scenario
from qz_drake.errors import ConfigError, QzError

SCENARIOS = sorted((Path(__file__).resolve().parents[1] / "scenarios").glob("*.yaml"))


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.stem)
def test_shipped_scenarios_load(path):
    scenario = load_scenario(path)
    assert scenario.name == path.stem


def test_scenario_round_trip_keeps_only_differences(tmp_path):
    scenario = Scenario(name="x")
    scenario.terrain.kind = "stairs"
    scenario.terrain.params = {"rise": 0.1}
    save_scenario(scenario, tmp_path / "s.yaml")
    text = (tmp_path / "s.yaml").read_text()
    assert "duration" not in text and "stairs" in text
    assert load_scenario(tmp_path / "s.yaml") == scenario


@pytest.mark.parametrize("text, field", [
    ("terrain: {knd: flat}", "scenario.terrain.knd"),
    ("terrain: {kind: lava}", "scenario.terrain.kind"),
    ("terrain: {kind: grid_map, params: {resolution: -0.1}}", "scenario.terrain.params.resolution"),
    ("terrain: {kind: flat, params: {resolution: 0}}", "scenario.terrain.params.resolution"),
    ("robot: {topology: tripod}", "scenario.robot.topology"),
    ("simulation: {duration: -1}", "scenario.simulation.duration"),
    ("terrain: {material: lava}", "scenario.terrain.material"),
    ("simulation: {duration: ten seconds}", "scenario.simulation.duration"),
    ("robot: {initial_xy: 3.0}", "scenario.robot.initial_xy"),
    ("robot: {initial_xy: [1.0, x]}", r"scenario.robot.initial_xy[1]"),
    ("random_seed: 1.5", "scenario.random_seed"),
    ("terrain: {params: {rise: high}}", "scenario.terrain.params.rise"),
    ("controller: {route: [{x: 1.0, yaw: north}]}", "scenario.controller.route[0].yaw"),
    ("", "scenario"),
])
def test_bad_scenarios_name_the_field(text, field):
    with pytest.raises(ConfigError, match=re.escape(field) + " = "):
        load_scenario_text(text)


def _run_cli(capsys, *argv):
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.mark.parametrize("text, field", [
    ("terrain: {kind: lava}\n", "scenario.terrain.kind = 'lava'"),
    ("terrian: {kind: flat}\n", "scenario.terrian"),
    ("terrain: {kind: grid_map, params: {resolution: -0.05}}\n", "scenario.terrain.params.resolution = -0.05"),
])
def test_cli_bad_scenario_prints_one_line_and_exits_2(tmp_path, capsys, text, field):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    code, out, err = _run_cli(capsys, "simulate", str(path), "--out", str(tmp_path / "o"))
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and field in err
    assert not (tmp_path / "o").exists()


def test_cli_nan_height_file_exits_2(tmp_path, capsys):
    heights = np.zeros((10, 10))
    heights[3, 4] = np.nan
    np.savez(tmp_path / "map.npz", heights=heights, resolution=0.05, origin=np.zeros(2),
             materials=np.zeros((0, 0)), material_names=np.array([], dtype=str))
    path = tmp_path / "bad.yaml"
    path.write_text(f"terrain: {{kind: file, file: {tmp_path / 'map.npz'}}}\n")
    code, _, err = _run_cli(capsys, "simulate", str(path))
    assert code == 2
    assert "nan" in err.lower() and len(err.strip().splitlines()) == 1


def test_cli_simulate_writes_outputs(tmp_path, capsys):
    scenario = Path(__file__).resolve().parents[1] / "scenarios" / "stand_flat.yaml"
    code, out, _ = _run_cli(capsys, "simulate", str(scenario), "--out", str(tmp_path), "--duration", "1.0")
    assert code == 0
    metrics = json.loads(out)
    assert metrics["success"] and metrics["sim_time_s"] == 1.0
    for name in ("recording.html", "metrics.json", "base_and_contacts.png"):
        assert (tmp_path / name).is_file()


def test_cli_terrain_picture(tmp_path, capsys):
    code, out, _ = _run_cli(capsys, "terrain", "stairs", "--out", str(tmp_path / "t.png"),
                            "--param", "rise=0.15", "--param", "count=3")
    assert code == 0 and (tmp_path / "t.png").stat().st_size > 10_000
    info = json.loads(out)
    assert info["max_height"] == pytest.approx(0.45)
    code, _, err = _run_cli(capsys, "terrain", "stairs", "--out", str(tmp_path / "u.png"), "--param", "rise")
    assert code == 2 and "--param" in err


def test_cli_usage_error_is_one_line(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["simulate"])
    assert exc.value.code == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_qz_error_is_the_base_of_config_errors():
    assert issubclass(ConfigError, QzError)


def test_the_mission_timing_defaults_are_one_dataclasss():
    # Speed and tripod phase are written once (MissionTiming); the scenario's controller, the
    # capability trials, Fig. 9 and the tripod plan all start from it.
    from qz_drake.capability.trials import TrialConfig
    from qz_drake.config import ControllerConfig, MissionTiming
    from qz_drake.experiments.fig9 import ExperimentConfig
    from qz_drake.systems.reference_gait import TripodGaitPlan

    timing = MissionTiming()
    assert ControllerConfig().timing == timing
    for config in (TrialConfig(), ExperimentConfig()):
        assert MissionTiming(config.speed, config.phase_duration) == timing
    phase = next(f for f in dataclasses.fields(TripodGaitPlan) if f.name == "phase_duration")
    assert phase.default == timing.phase_duration
    assert ControllerConfig(speed=0.3, phase_duration=0.5).timing == MissionTiming(0.3, 0.5)
