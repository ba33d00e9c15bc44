"""Bad input refused before work is lost (issue 39): each case runs ``qz`` in-process and must
exit with status 2 and one line on stderr naming the field and the value, with no traceback,
before anything is computed or written.

Measured before these checks: ``qz blc --duration 1e9`` and ``qz terrain flat --param
size_x=1e6`` were killed by the kernel at 24 GB; a binary file as a scenario was a
UnicodeDecodeError traceback; a read-only --out failed after the simulation had run; a 3 x 997
pixel map "stood successfully" with the feet off it.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from qz_drake.cli import main

REPO = Path(__file__).resolve().parents[1]
STAND_FLAT = str(REPO / "scenarios" / "stand_flat.yaml")
TROT_FLAT = str(REPO / "scenarios" / "trot_flat.yaml")

# Scenario files written for the cases, by name.
SCENARIO_TEXTS = {
    "duration_1.0e9.yaml": "simulation: {duration: 1.0e9}\n",
    "time_step_1e-9.yaml": "simulation: {duration: 10.0, time_step: 1e-9}\n",
    "stairs_rise_-5.yaml": "terrain: {kind: stairs, params: {rise: -5}}\n",
    "flat_0.5_m_wide.yaml": "terrain: {kind: flat, params: {size_y: 0.5}}\n",
    "flat_1e6_m_long.yaml": "terrain: {kind: flat, params: {size_x: 1e6}}\n",
    "narrow_png.yaml": "terrain: {kind: file, file: narrow.png, params: {resolution: 0.05, max_height: 0.4}}\n",
    "seed_1.5.yaml": "terrain: {kind: rough, params: {seed: 1.5}}\n",
}


def _simulate(name: str) -> list[str]:
    """``qz simulate`` of the input ``name``."""
    return ["simulate", f"{{tmp}}/{name}", "--out", "{tmp}/o"]


# (id, argv with {tmp} for the inputs folder, texts the one error line must hold).
CASES = [
    ("blc_duration_1e9", ["blc", "--distance", "1", "--duration", "1e9"],
     ["--duration = 1000000000.0", "120 s"]),
    ("blc_duration_nan", ["blc", "--distance", "1", "--duration", "nan"], ["--duration = nan"]),
    ("blc_dynamics_dt_1e-6", ["blc", "--distance", "1", "--duration", "2", "--blc-param", "dynamics_dt=1e-6"],
     ["--blc-param dynamics_dt = 1e-06", "samples"]),
    ("blc_dense_check_rate_1e9", ["blc", "--distance", "1", "--duration", "2", "--blc-param", "dense_check_rate=1e9"],
     ["--blc-param dense_check_rate = 1000000000.0"]),
    ("blc_map_narrower_than_robot", ["blc", "--distance", "1", "--duration", "2", "--terrain-param", "size_y=0.5"],
     ["--terrain-param = ['size_y=0.5']", "smaller than"]),
    ("blc_terrain_size_x_1e6", ["blc", "--distance", "1", "--duration", "2", "--terrain-param", "size_x=1e6"],
     ["terrain.size_x = 1000000.0", "cells"]),
    ("blc_topology_unknown", ["blc", "--distance", "1", "--duration", "2", "--topology", "tripod"],
     ["--topology = 'tripod'"]),
    ("blc_robot_unknown", ["blc", "--distance", "1", "--duration", "2", "--robot", "walker"], ["robot = 'walker'"]),
    ("blc_out_empty", ["blc", "--distance", "1", "--duration", "2", "--out", ""], ["--out = ''", "empty"]),
    ("blc_out_is_a_folder", ["blc", "--distance", "1", "--duration", "2", "--out", "{tmp}"],
     ["--out = ", "is a folder"]),
    ("terrain_size_x_1e6", ["terrain", "flat", "--param", "size_x=1e6", "--out", "{tmp}/t.png"],
     ["terrain.size_x = 1000000.0", "cells"]),
    ("terrain_resolution_1e-5", ["terrain", "rough", "--param", "resolution=1e-5", "--out", "{tmp}/t.png"],
     ["terrain.resolution = 1e-05", "cells"]),
    ("terrain_obstacles_count_1e9", ["terrain", "obstacles", "--param", "count=1e9", "--out", "{tmp}/t.png"],
     ["terrain.count = 1000000000.0"]),
    ("terrain_rough_correlation_1e6",
     ["terrain", "rough", "--param", "correlation_length=1e6", "--out", "{tmp}/t.png"],
     ["terrain.correlation_length = 1000000.0"]),
    ("terrain_stairs_rise_-5", ["terrain", "stairs", "--param", "rise=-5", "--out", "{tmp}/t.png"],
     ["terrain.rise = -5.0", "45 degrees"]),
    ("terrain_seed_1.5", ["terrain", "long_range", "--param", "seed=1.5", "--out", "{tmp}/t.png"],
     ["terrain.seed = 1.5"]),
    ("terrain_out_empty", ["terrain", "stairs", "--out", ""], ["--out = ''", "empty"]),
    ("terrain_out_inside_a_file", ["terrain", "stairs", "--out", "{tmp}/a_file.txt/t.png"],
     ["--out = ", "is a file"]),
    ("terrain_save_is_a_folder", ["terrain", "stairs", "--out", "{tmp}/t.png", "--save", "{tmp}"],
     ["--save = ", "is a folder"]),
    ("simulate_binary_garbage", _simulate("garbage.yaml"),
     ["scenario = ", "garbage.yaml", "not UTF-8"]),
    ("simulate_png_as_scenario", _simulate("picture.png"),
     ["scenario = ", "picture.png", "PNG picture"]),
    ("simulate_npz_as_scenario", _simulate("map.npz"),
     ["scenario = ", "map.npz", "zip archive"]),
    ("simulate_yaml_duration_1.0e9", _simulate("duration_1.0e9.yaml"),
     ["scenario.simulation.duration = 1000000000.0", "1200 s"]),
    ("simulate_yaml_time_step_1e-9", _simulate("time_step_1e-9.yaml"),
     ["scenario.simulation.time_step = 1e-09", "plant steps"]),
    ("simulate_yaml_stairs_rise_-5", _simulate("stairs_rise_-5.yaml"),
     ["terrain.rise = -5.0", "45 degrees"]),
    ("simulate_png_map_3x997", _simulate("narrow_png.yaml"),
     ["scenario.terrain.file = ", "narrow.png", "smaller than Qingzhui's footprint"]),
    ("simulate_map_0.5_m_wide", _simulate("flat_0.5_m_wide.yaml"),
     ["scenario.terrain.params = {'size_y': 0.5}", "smaller than Qingzhui's footprint"]),
    ("simulate_yaml_size_x_1e6", _simulate("flat_1e6_m_long.yaml"),
     ["terrain.size_x = 1000000.0", "cells"]),
    ("simulate_yaml_seed_1.5", _simulate("seed_1.5.yaml"), ["terrain.seed = 1.5"]),
    ("simulate_duration_1e9", ["simulate", STAND_FLAT, "--duration", "1e9", "--out", "{tmp}/o"],
     ["--duration = 1000000000.0", "1200 s"]),
    ("simulate_out_empty", ["simulate", STAND_FLAT, "--out", ""], ["--out = ''", "empty"]),
    ("simulate_out_read_only", ["simulate", STAND_FLAT, "--out", "{tmp}/read_only"],
     ["--out = ", "read_only", "not writable"]),
    ("simulate_out_below_read_only", ["simulate", STAND_FLAT, "--out", "{tmp}/read_only/run1"],
     ["--out = ", "run1", "not writable"]),
    ("simulate_out_inside_a_file", ["simulate", STAND_FLAT, "--out", "{tmp}/a_file.txt/run1"],
     ["--out = ", "is a file"]),
    ("simulate_hardware_garbage",
     ["simulate", STAND_FLAT, "--station", "lcm", "--hardware", "{tmp}/garbage.yaml", "--out", "{tmp}/o"],
     ["--hardware = ", "not UTF-8"]),
    ("static_gait_binary_garbage", ["static-gait", "{tmp}/garbage.yaml", "--out", "{tmp}/o"],
     ["scenario = ", "not UTF-8"]),
    ("demo_duration_1e9", ["demo", "--duration", "1e9", "--out", "{tmp}/o"], ["--duration = 1000000000.0"]),
    ("demo_out_empty", ["demo", "--out", ""], ["--out = ''", "empty"]),
    ("trot_duration_1e9", ["trot", TROT_FLAT, "--duration", "1e9", "--out", "{tmp}/o"],
     ["--duration = 1000000000.0"]),
    ("classify_run_duration_1e9", ["classify", "collect", "--run-duration", "1e9", "--out", "{tmp}/o"],
     ["--run-duration = 1000000000.0"]),
    ("costmap_out_is_a_file", ["costmap", STAND_FLAT, "--out", "{tmp}/a_file.txt"], ["--out = ", "is a file"]),
    ("astar_out_read_only", ["astar", STAND_FLAT, "--out", "{tmp}/read_only"], ["--out = ", "not writable"]),
    ("plan_map_narrower_than_robot",
     ["plan", "--terrain", "flat", "--terrain-param", "size_y=0.5", "--start", "0,0", "--goal", "1,0",
      "--out", "{tmp}/o"], ["--terrain = 'flat'", "smaller than Qingzhui's footprint"]),
    ("plan_out_empty", ["plan", "--terrain", "flat", "--start", "0,0", "--goal", "1,0", "--out", ""],
     ["--out = ''", "empty"]),
    ("capability_collect_out_empty", ["capability", "collect", "--out", "", "--scenes", "1"], ["--out = ''"]),
    ("capability_map_out_is_a_folder", ["capability", "map", "--terrain", "flat", "--out", "{tmp}"],
     ["--out = ", "is a folder"]),
    ("experiment_out_empty", ["experiment", "capplanner-vs-astar", "--out", ""], ["--out = ''"]),
    ("experiment_negative_blc_retries", ["experiment", "capplanner-vs-astar", "--out", "{tmp}/x", "--blc-retries", "-1"],
     ["--blc-retries = -1"]),
]


def _write_inputs(folder: Path) -> None:
    from PIL import Image

    from qz_drake.terrain import HeightMap

    # Bytes that no UTF-8 text starts with, as random binary data does.
    (folder / "garbage.yaml").write_bytes(bytes(range(0xC0, 0x100)) * 8)
    Image.fromarray(np.zeros((4, 4), np.uint8)).save(folder / "picture.png")
    # 3 pixels wide, 997 high: 0.10 m x 49.8 m at 0.05 m.
    Image.fromarray(np.full((997, 3), 128, np.uint8)).save(folder / "narrow.png")
    HeightMap(np.zeros((4, 4)), 0.1).save_npz(folder / "map.npz")
    (folder / "a_file.txt").write_text("not a folder\n")
    for name, text in SCENARIO_TEXTS.items():
        (folder / name).write_text(text)
    (folder / "read_only").mkdir()
    (folder / "read_only").chmod(0o555)


@pytest.fixture
def inputs(tmp_path, monkeypatch):
    """The inputs folder, and an empty working folder as the current one: a relative or empty
    --out would write there."""
    folder = tmp_path / "inputs"
    folder.mkdir()
    _write_inputs(folder)
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    if os.geteuid() == 0:
        # Root writes into a read-only folder anyway; deny it as the kernel denies a user.
        real_access = os.access
        read_only = str(folder / "read_only")
        monkeypatch.setattr(os, "access", lambda path, mode, **kw: False if str(path) == read_only and mode & os.W_OK
                            else real_access(path, mode, **kw))
    yield folder
    (folder / "read_only").chmod(0o755)


def run_qz(argv: list[str], capsys) -> tuple[int, str, str]:
    """``qz ARGV`` in-process: (exit status, stdout, stderr); argparse's own refusals exit."""
    try:
        code = main(argv)
    except SystemExit as e:
        code = e.code
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _listing(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


@pytest.mark.parametrize("argv, named", [(argv, named) for _, argv, named in CASES], ids=[c[0] for c in CASES])
def test_bad_input_is_refused_in_one_line_before_any_work(inputs, capsys, monkeypatch, argv, named):
    import qz_drake.simulation
    import qz_drake.trajopt.solver
    # Modules that bind these functions at import are imported first: imported while they are
    # patched, they would keep the patch after the test (demo.py's ``simulate`` did).
    import qz_drake.demo  # noqa: F401

    def no_work(*args, **kwargs):
        raise AssertionError("the work started before the input was checked")

    # The long computations: none may start on bad input.
    monkeypatch.setattr(qz_drake.simulation, "simulate", no_work)
    monkeypatch.setattr(qz_drake.trajopt.solver, "solve_blc", no_work)
    before, repository = _listing(inputs), set(os.listdir(REPO))
    code, out, err = run_qz([a.replace("{tmp}", str(inputs)) for a in argv], capsys)
    lines = err.strip().splitlines()
    assert code == 2, (code, out, err)
    assert len(lines) == 1 and "Traceback" not in err, err
    for text in named:
        assert text in lines[0], lines[0]
    assert out == ""
    assert _listing(inputs) == before and not list(Path.cwd().iterdir())
    assert set(os.listdir(REPO)) <= repository


# -- what the checks must still let through ------------------------------------------------------
@pytest.mark.parametrize("text, duration", [("1e1", 10.0), ("1.0e1", 10.0), ("1.0e+1", 10.0), ("2.5E-1", 0.25),
                                            ("1_0.0", 10.0)])
def test_yaml_numbers_in_either_exponent_form(text, duration):
    from qz_drake.config import load_scenario_text

    scenario = load_scenario_text(f"simulation: {{duration: {text}}}\nterrain: {{kind: stairs, params: {{rise: 1e-1}}}}")
    assert scenario.simulation.duration == duration
    assert scenario.terrain.params == {"rise": 0.1}


def test_blc_param_reads_exponents():
    from qz_drake.cli.blc import blc_parameters

    assert blc_parameters(["tolerance=1e-5"]).tolerance == 1e-5


def test_terrain_param_seed_seeds_the_generator():
    # Was: make_terrain() got multiple values for keyword argument 'seed' (a traceback).
    from qz_drake.capability.model_commands import load_terrain
    from qz_drake.terrain import make_terrain

    heightmap = load_terrain("long_range", ["seed=4711", "size_x=8", "size_y=8"], 0)
    np.testing.assert_array_equal(heightmap.heights, make_terrain("long_range", seed=4711, size_x=8, size_y=8).heights)
    assert not np.array_equal(heightmap.heights, make_terrain("long_range", seed=0, size_x=8, size_y=8).heights)


def test_scenario_params_seed_seeds_the_terrain():
    from qz_drake.config import load_scenario_text
    from qz_drake.station import make_heightmap
    from qz_drake.terrain import make_terrain

    scenario = load_scenario_text("random_seed: 3\nterrain: {kind: rough, params: {seed: 7}}")
    np.testing.assert_array_equal(make_heightmap(scenario.terrain, scenario.random_seed).heights,
                                  make_terrain("rough", seed=7).heights)


def test_terrain_command_takes_seed_as_a_param(tmp_path, capsys):
    code, out, err = run_qz(["terrain", "long_range", "--param", "seed=4711", "--param", "size_x=8",
                             "--param", "size_y=8", "--out", str(tmp_path / "t.png")], capsys)
    assert code == 0, err
    assert (tmp_path / "t.png").is_file()


@pytest.mark.slow
def test_plan_with_terrain_param_seed(tmp_path, capsys):
    # The user's command of issue 39 on a smaller world (the 20 m one takes 8 s more).
    code, out, err = run_qz(["plan", "--terrain", "long_range", "--terrain-param", "seed=4711", "--terrain-param",
                             "size_x=8", "--terrain-param", "size_y=8", "--start", "0,0", "--goal", "5,5",
                             "--out", str(tmp_path), "--json"], capsys)
    assert code in (0, 1) and err.count("error") == 0, err
    assert (tmp_path / "plan.json").is_file()


def test_stairs_down_are_descent_and_no_steeper_than_45_degrees():
    from qz_drake.errors import TerrainError
    from qz_drake.terrain import make_terrain

    down = make_terrain("stairs", rise=-0.4, run=0.4, count=2)
    assert down.heights.min() == pytest.approx(-0.8)
    with pytest.raises(TerrainError, match=r"terrain\.rise = 0\.41"):
        make_terrain("stairs", rise=0.41, run=0.4)


def test_stairs_beyond_the_map_cost_nothing_and_change_nothing():
    from qz_drake.terrain import make_terrain

    # 10 steps of 0.4 m reach past the 4 m ahead of the start; a trillion ask for no more work.
    np.testing.assert_array_equal(make_terrain("stairs", count=10**12).heights, make_terrain("stairs", count=10).heights)


def test_a_picture_too_large_is_refused_before_it_is_decoded(tmp_path):
    from PIL import Image

    from qz_drake.errors import TerrainError
    from qz_drake.terrain import HeightMap

    Image.new("L", (5000, 4000)).save(tmp_path / "huge.png")  # 20 million pixels, a few kB of zeros
    with pytest.raises(TerrainError, match=r"heightmap\.image = .*huge\.png.*cells"):
        HeightMap.from_image(tmp_path / "huge.png", 0.05, 0.0, 0.4)


def test_out_folder_missing_is_created(tmp_path, capsys):
    code, _, err = run_qz(["terrain", "flat", "--out", str(tmp_path / "new" / "deeper" / "t.png")], capsys)
    assert code == 0, err
    assert (tmp_path / "new" / "deeper" / "t.png").is_file()


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write into a read-only folder")
def test_read_only_out_as_a_user(tmp_path, capsys):
    folder = tmp_path / "read_only"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        code, _, err = run_qz(["terrain", "flat", "--out", str(folder / "t.png")], capsys)
    finally:
        folder.chmod(0o755)
    assert code == 2 and "not writable" in err


# -- --version and help pages ------------------------------------------------------------------------
def test_version_is_the_installed_package_version(capsys):
    from importlib.metadata import version

    code, out, _ = run_qz(["--version"], capsys)
    assert code == 0 and out.strip() == f"qz {version('qz_drake')}"


def _help(argv, capsys) -> str:
    code, out, _ = run_qz([*argv, "--help"], capsys)
    assert code == 0
    return "".join(out.split())  # argparse wraps lines, also at hyphens


def test_help_pages_list_the_valid_choices(capsys):
    import inspect

    from qz_drake.bench import SUITES
    from qz_drake.capability.patches import KINDS
    from qz_drake.robot.topology import TOPOLOGY_NAMES
    from qz_drake.terrain import MATERIALS, TERRAIN_KINDS
    from qz_drake.trajopt.gait import GAIT_NAMES
    from qz_drake.trajopt.robot_model import ROBOT_NAMES

    terrain = _help(["terrain"], capsys)
    for kind, generator in TERRAIN_KINDS.items():
        names = [p for p in inspect.signature(generator).parameters if p != "seed"]
        assert f"{kind}:" + "".join(f"{p}=" for p in names[:1]) in terrain
        assert all(f"{p}=" in terrain for p in names)
    blc = _help(["blc"], capsys)
    for name in (*TOPOLOGY_NAMES, *ROBOT_NAMES, *GAIT_NAMES, *TERRAIN_KINDS, "grid_map"):
        assert name in blc, name
    plan = _help(["plan"], capsys)
    assert all(name in plan for name in (*TOPOLOGY_NAMES, *TERRAIN_KINDS))
    collect = _help(["capability", "collect"], capsys)
    assert all(name in collect for name in (*TOPOLOGY_NAMES, *KINDS))
    capability_map = _help(["capability", "map"], capsys)
    assert all(name in capability_map for name in (*TOPOLOGY_NAMES, *TERRAIN_KINDS))
    assert all(name in _help(["classify", "collect"], capsys) for name in MATERIALS)
    assert all(name in _help(["bench"], capsys) for name in SUITES)
