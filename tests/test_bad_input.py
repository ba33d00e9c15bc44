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
STATIC_GAIT_FLAT = str(REPO / "scenarios" / "static_gait" / "static_gait_flat.yaml")
WALK_FLAT = str(REPO / "scenarios" / "walk_flat.yaml")

# Scenario files written for the cases, by name.
SCENARIO_TEXTS = {
    "duration_1.0e9.yaml": "simulation: {duration: 1.0e9}\n",
    "time_step_1e-9.yaml": "simulation: {duration: 10.0, time_step: 1e-9}\n",
    "stairs_rise_-5.yaml": "terrain: {kind: stairs, params: {rise: -5}}\n",
    "flat_0.5_m_wide.yaml": "terrain: {kind: flat, params: {size_y: 0.5}}\n",
    "flat_1e6_m_long.yaml": "terrain: {kind: flat, params: {size_x: 1e6}}\n",
    "narrow_png.yaml": "terrain: {kind: file, file: narrow.png, params: {resolution: 0.05, max_height: 0.4}}\n",
    "seed_1.5.yaml": "terrain: {kind: rough, params: {seed: 1.5}}\n",
    "one_pixel_png.yaml": "terrain: {kind: file, file: one_pixel.png, params: {resolution: 0.05, max_height: 0.4}}\n",
    "not_a_zip_npz.yaml": "terrain: {kind: file, file: not_a_zip.npz}\n",
    "simulation_twice.yaml": "simulation: {duration: 3.0}\nterrain: {kind: flat}\nsimulation: {duration: 5.0}\n",
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
    # Issue 56: files that are not what they are named, sizes that never end, numbers out of range.
    ("plan_npz_not_a_zip", ["plan", "--terrain", "{tmp}/not_a_zip.npz", "--start", "0,0", "--goal", "1,0",
                            "--out", "{tmp}/o"], ["--terrain = ", "not_a_zip.npz", "not a zip archive"]),
    ("plan_picture_without_scale", ["plan", "--terrain", "{tmp}/picture.png", "--start", "0,0", "--goal", "1,0",
                                    "--out", "{tmp}/o"],
     ["--terrain = ", "picture.png", "--terrain-param resolution=", "max_height="]),
    ("plan_min_success_2", ["plan", "--terrain", "flat", "--start", "0,0", "--goal", "1,0", "--min-success", "2",
                            "--out", "{tmp}/o"], ["--min-success = 2.0", "[0, 1]"]),
    ("plan_min_success_nan", ["plan", "--terrain", "flat", "--start", "0,0", "--goal", "1,0", "--min-success", "nan",
                              "--out", "{tmp}/o"], ["--min-success = nan"]),
    ("simulate_png_map_1x1", _simulate("one_pixel_png.yaml"),
     ["scenario.terrain.file = ", "one_pixel.png", "1 x 1 pixels", "at least 2 x 2"]),
    ("simulate_npz_map_not_a_zip", _simulate("not_a_zip_npz.yaml"),
     ["scenario.terrain.file = ", "not_a_zip.npz", "not a zip archive"]),
    ("simulate_yaml_simulation_twice", _simulate("simulation_twice.yaml"),
     ["simulation_twice.yaml", "duplicate key 'simulation' on lines 1 and 3"]),
    ("simulate_lcm_url_bogus", ["simulate", STAND_FLAT, "--station", "lcm", "--lcm-url", "bogus://x", "--out", "{tmp}/o"],
     ["--lcm-url = 'bogus://x'", "unknown LCM provider 'bogus'", "udpm://"]),
    ("robot_sim_lcm_url_bogus", ["robot-sim", WALK_FLAT, "--lcm-url", "bogus://x", "--duration", "1"],
     ["--lcm-url = 'bogus://x'", "unknown LCM provider 'bogus'"]),
    ("robot_sim_lcm_url_not_multicast", ["robot-sim", WALK_FLAT, "--lcm-url", "udpm://999.1.1.1:1", "--duration", "1"],
     ["--lcm-url = 'udpm://999.1.1.1:1'", "not an IPv4 multicast group"]),
    ("robot_sim_lcm_url_port_0", ["robot-sim", WALK_FLAT, "--lcm-url", "udpm://239.255.76.67:0", "--duration", "1"],
     ["--lcm-url = 'udpm://239.255.76.67:0'", "1..65535"]),
    ("robot_sim_nice_30", ["robot-sim", WALK_FLAT, "--nice", "30", "--duration", "1"],
     ["--nice = 30", "-20 (the most CPU) .. 19"]),
    ("static_gait_steps_1e9", ["static-gait", STATIC_GAIT_FLAT, "--steps", "1000000000", "--json", "--out", "{tmp}/o"],
     ["--steps = 1000000000", "at most 544 swings"]),
    ("static_gait_depth_1e9", ["static-gait", STATIC_GAIT_FLAT, "--depth", "1000000000", "--out", "{tmp}/o"],
     ["--depth = 1000000000", "100"]),
    ("gait_depth_study_terrains_1e9", ["gait-depth-study", "--terrains", "1000000000", "--out", "{tmp}/o"],
     ["--terrains = 1000000000", "1000"]),
    ("gait_depth_study_max_nodes_1e9", ["gait-depth-study", "--max-nodes", "1000000000", "--out", "{tmp}/o"],
     ["--max-nodes = 1000000000", "100000"]),
    ("gait_depth_study_depths_1e9", ["gait-depth-study", "--depths", "1,1000000000", "--out", "{tmp}/o"],
     ["--depths = '1,1000000000'", "100"]),
    ("gait_depth_study_seed_-1", ["gait-depth-study", "--seed", "-1", "--out", "{tmp}/o"], ["--seed = -1"]),
    ("capability_collect_scenes_1e9", ["capability", "collect", "--scenes", "1000000000", "--out", "{tmp}/o"],
     ["--scenes = 1000000000", "1e+06"]),
    ("capability_collect_headings_1e9", ["capability", "collect", "--headings", "1000000000", "--out", "{tmp}/o"],
     ["--headings = 1000000000", "1e+06"]),
    ("capability_collect_workers_1e6", ["capability", "collect", "--workers", "1000000", "--out", "{tmp}/o"],
     ["--workers = 1000000", "per CPU"]),
    ("capability_collect_seed_-1", ["capability", "collect", "--seed", "-1", "--out", "{tmp}/o"], ["--seed = -1"]),
    ("capability_collect_time_step_1e-9", ["capability", "collect", "--time-step", "1e-9", "--out", "{tmp}/o"],
     ["--time-step = 1e-09", "0.0001 s"]),
    ("capability_train_members_1e9", ["capability", "train", "--learner", "boosted", "--members", "1000000000",
                                      "--dataset", "{tmp}", "--out", "{tmp}/o"], ["--members = 1000000000", "100"]),
    ("experiment_tasks_1e6", ["experiment", "capplanner-vs-astar", "--tasks", "1000000", "--out", "{tmp}/o"],
     ["--tasks = 1000000", "1000"]),
    ("experiment_blc_retries_1e9", ["experiment", "capplanner-vs-astar", "--blc-retries", "1000000000",
                                    "--out", "{tmp}/o"], ["--blc-retries = 1000000000", "10"]),
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
    Image.fromarray(np.zeros((1, 1), np.uint8)).save(folder / "one_pixel.png")
    # A zip's first bytes and then none of it: zipfile.BadZipFile in numpy's loader.
    (folder / "not_a_zip.npz").write_bytes(b"PK\x03\x04" + b"not a zip archive" * 4)
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
    import qz_drake.capability.collect
    import qz_drake.planning.depth_study
    import qz_drake.planning.static_gait_scenario
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
    monkeypatch.setattr(qz_drake.planning.static_gait_scenario, "search_gait", no_work)
    monkeypatch.setattr(qz_drake.planning.depth_study, "search_gait", no_work)
    monkeypatch.setattr(qz_drake.capability.collect.LocalPool, "run", no_work)
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


# -- issue 56: library calls, signals, the shipped dataset ----------------------------------------
@pytest.mark.parametrize("content", [b"", b"not a zip", b"PK\x03\x04" + b"\x00" * 40], ids=["empty", "text", "zip_head"])
def test_npz_that_is_no_zip_archive_names_the_file(tmp_path, content):
    # Was: zipfile.BadZipFile (zip head), EOFError (empty), or numpy's advice to load a pickle.
    from qz_drake.errors import TerrainError
    from qz_drake.terrain import HeightMap

    (tmp_path / "garbage.npz").write_bytes(content)
    with pytest.raises(TerrainError, match=r"heightmap\.file = .*garbage\.npz.*not a zip archive"):
        HeightMap.load_npz(tmp_path / "garbage.npz")


@pytest.mark.parametrize("text", [None, b"simulation: {duration: 1.0}"], ids=["none", "bytes"])
def test_load_scenario_text_of_no_text_names_the_argument(text):
    # Was: AttributeError: 'NoneType' object has no attribute 'read'.
    from qz_drake.config import load_scenario_text
    from qz_drake.errors import QzError

    with pytest.raises(QzError, match=r"^text = .*expected the text of a scenario YAML file"):
        load_scenario_text(text)


def test_duplicate_keys_are_refused_at_any_depth_and_merge_keys_still_override():
    from qz_drake.config import load_scenario_text
    from qz_drake.errors import ConfigError

    with pytest.raises(ConfigError, match=r"duplicate key 'duration' twice on line 1"):
        load_scenario_text("simulation: {duration: 3.0, duration: 5.0}\n")
    # A key a merge key brings in may be given again: that is YAML's override, not a duplicate.
    scenario = load_scenario_text("simulation:\n  <<: {duration: 3.0, time_step: 0.002}\n  duration: 4.0\n")
    assert scenario.simulation.duration == 4.0


@pytest.mark.parametrize("duration", [-1.0, 0.0, float("nan"), float("inf"), 1e9])
def test_simulate_refuses_a_bad_duration_before_building(duration):
    # Was: Drake's assertion on AdvanceTo, a SystemExit(1) with no field named.
    from qz_drake.config import load_scenario
    from qz_drake.errors import QzError
    from qz_drake.simulation import simulate

    with pytest.raises(QzError, match=r"^duration = "):
        simulate(load_scenario(STAND_FLAT), duration=duration)


def test_plan_terrain_takes_a_picture_with_its_scale(tmp_path):
    from PIL import Image

    from qz_drake.capability.model_commands import load_terrain

    Image.fromarray(np.full((40, 60), 255, np.uint8)).save(tmp_path / "map.png")
    heightmap = load_terrain(str(tmp_path / "map.png"), ["resolution=0.05", "max_height=0.4"], 0)
    assert heightmap.heights.shape == (40, 60) and heightmap.resolution == 0.05
    np.testing.assert_allclose(heightmap.heights, 0.4)


def test_static_gait_scenario_sizes_are_bounded():
    from qz_drake.errors import QzError
    from qz_drake.planning.static_gait_scenario import load_static_gait_scenario, validate_static_gait_scenario

    scenario = load_static_gait_scenario(STATIC_GAIT_FLAT)
    scenario.simulation.time_step = 1e-9
    with pytest.raises(QzError, match=r"scenario\.simulation\.time_step = 1e-09: .* at most 600000"):
        validate_static_gait_scenario(scenario)
    scenario = load_static_gait_scenario(STATIC_GAIT_FLAT)
    scenario.gait.max_nodes = 10**9
    with pytest.raises(QzError, match=r"static_gait\.max_nodes = 1000000000: must be at most 100000"):
        validate_static_gait_scenario(scenario)


@pytest.mark.parametrize("url", ["memq://", "udpm://", "udpm://239.255.76.67:7667?ttl=1", "mpudpm://239.255.76.67:7667",
                                 "tcpq://127.0.0.1:7700", "file:///tmp/log.lcm?mode=w"])
def test_lcm_urls_drake_takes_pass_the_check(url):
    from qz_drake.hardware.relay import check_lcm_url

    assert check_lcm_url(url, "--lcm-url") == url


def test_stairs_up_stats_rebuild_each_scene_from_its_record():
    # Was: KeyError: 'rise' on the shipped dataset: a scene index names another scene kind once
    # the mix of scene kinds changes; the record holds its own difficulty and scene seed.
    from qz_drake.capability.scenes import make_scene, scene_recipe
    from qz_drake.capability.stats import stairs_up_rows

    index = next(i for i in range(100) if scene_recipe(0, i)[0] != "stairs")
    scene = next(make_scene("stairs", 0.5, seed) for seed in range(100)
                 if make_scene("stairs", 0.5, seed).params["rise"] > 0)
    record = {"status": ["executed"], "scene_kind": ["stairs"], "kind": ["orthogonal"], "scene": [index],
              "heading": [0.0], "topology": ["nominal"], "success": [True], "difficulty": [0.5],
              "scene_seed": [scene.seed]}
    arrays = {k: np.asarray(v) for k, v in record.items()}
    rows = stairs_up_rows(arrays, seed=0)
    assert len(rows) == 1 and rows[0]["executed"] == 1
    low, high = rows[0]["rise_m"]
    assert low <= scene.params["rise"] < high
    # Records without their recipe are looked up by index: not stairs there, so no row, no crash.
    assert stairs_up_rows({k: v for k, v in arrays.items() if k not in ("difficulty", "scene_seed")}, seed=0) == []


def _python(code: str, folder: Path):
    """``python -c code`` in ``folder`` (its modules importable, by the workers a pool spawns
    too), in a session of its own: a signal to its group reaches it and its children only."""
    import subprocess
    import sys

    path = os.pathsep.join([str(folder), *filter(None, [os.environ.get("PYTHONPATH")])])
    # Ctrl-C as in a terminal: a pytest-xdist worker ignores SIGINT, and an ignored signal stays
    # ignored in the processes it starts (Python then installs no KeyboardInterrupt handler).
    code = "import signal\nsignal.signal(signal.SIGINT, signal.default_int_handler)\n" + code
    return subprocess.Popen([sys.executable, "-c", code], cwd=folder, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True, env={**os.environ, "PYTHONPATH": path})


def test_sigterm_prints_the_interrupted_line_and_exits_143(tmp_path):
    # Was: killed silently with 143. The command sends itself the signal once it runs.
    process = _python("import os, signal, sys, time\n"
                      "from qz_drake.cli import core, main\n"
                      "core._cmd_terrain = lambda args: (os.kill(os.getpid(), signal.SIGTERM), time.sleep(30))\n"
                      "sys.exit(main(['terrain', 'flat', '--out', 't.png']))\n", tmp_path)
    out, err = process.communicate(timeout=60)
    assert process.returncode == 143, (process.returncode, err)
    assert err == "qz terrain: interrupted\n" and out == ""


# A trial that takes a minute, announcing on stdout that it has started.
_SLOW_TRIAL = '''
import time


def run(spec, config):
    print("started", flush=True)
    time.sleep(60)
'''
_LOCAL_POOL_DRIVER = '''
import sys

import slow_trial
from qz_drake.capability.collect import LocalPool

pool = LocalPool(1, None, 0, function=slow_trial.run, crashed=lambda spec, message, config: message)
try:
    pool.run([1], print)
except KeyboardInterrupt:
    print("interrupted", file=sys.stderr)
finally:
    pool.close()
'''


@pytest.mark.parametrize("to_the_group", [True, False], ids=["terminal_ctrl_c", "driver_only"])
def test_ctrl_c_stops_a_local_pool_without_a_worker_traceback(tmp_path, to_the_group):
    # Was: the worker's KeyboardInterrupt traceback before "interrupted" (a terminal's Ctrl-C
    # reaches every process of the command); a worker the driver alone was told of ran on.
    import signal
    import time

    (tmp_path / "slow_trial.py").write_text(_SLOW_TRIAL)
    process = _python(_LOCAL_POOL_DRIVER, tmp_path)
    try:
        assert process.stdout.readline() == "started\n"
        clock = time.monotonic()
        os.killpg(process.pid, signal.SIGINT) if to_the_group else process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
    assert err == "interrupted\n", err
    assert time.monotonic() - clock < 5  # the busy worker is stopped, not waited for


@pytest.mark.slow
def test_stats_of_the_shipped_dataset(capsys):
    # The user's command of issue 56 (5 s: 21600 records): it ended in KeyError: 'rise'.
    code, out, err = run_qz(["capability", "stats", str(REPO / "data" / "capability"), "--json"], capsys)
    assert code == 0, err
    import json

    summary = json.loads(out)
    assert summary["stairs_up"] and all(row["executed"] for row in summary["stairs_up"])
