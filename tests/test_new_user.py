"""What a new user trips over (issue 17): each friction found from a fresh clone, as a test.

The CLI is run as a user runs it, ``qz`` in a subprocess: bad input is one line naming the
field and its value, with exit status 2. Real data no one here made, grid_map's
``heightmap_generated.png``, is in the repository (``data/external/grid_map/``), as the
scenarios that read it expect.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SCENARIOS = REPO / "scenarios"
GENERATED_PNG = REPO / "data" / "external" / "grid_map" / "heightmap_generated.png"


def qz(*argv, cwd=REPO, timeout=600):
    """Runs ``qz ARGV`` in a subprocess; returns (exit code, stdout, stderr)."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run([sys.executable, "-m", "qz_drake.cli", *map(str, argv)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=timeout)
    return done.returncode, done.stdout, done.stderr


def assert_one_line_error(code, out, err, *named):
    assert code == 2, (code, out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    for text in named:
        assert text in lines[0], lines[0]
    assert "Traceback" not in err


# -- 1. the README's A* example and the walker agree -------------------------------------------------
def test_readme_astar_example_finds_the_walked_goal(tmp_path):
    code, out, err = qz("astar", "scenarios/walk_grid_map.yaml", "--out", tmp_path, "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert summary["found"] and summary["goal"] == [4.0, 0.0]


def test_astar_says_why_a_goal_is_blocked(tmp_path):
    # The old end of walk_grid_map (4, -0.3): within the body's disc of the corridor's wall.
    code, out, _ = qz("astar", "scenarios/walk_grid_map.yaml", "--goal", "4,-0.3", "--out", tmp_path, "--json")
    assert code == 1
    summary = json.loads(out)
    assert summary["reason"] == "goal (4, -0.3) m is blocked"
    why = summary["blocked_because"]["goal"]
    assert "step of" in why and "max_step_height" in why and "walker" in why


# -- 2. own heightmaps: a PNG with its scale, paths relative to the scenario ------------------------
def test_png_heightmap_with_scale_in_the_scenario():
    from qz_drake.config import load_scenario
    from qz_drake.station import make_heightmap

    scenario = load_scenario(SCENARIOS / "walk_own_terrain.yaml")
    assert Path(scenario.terrain.file).resolve() == GENERATED_PNG
    heightmap = make_heightmap(scenario.terrain)
    assert heightmap.shape == (195, 250) and heightmap.resolution == 0.05
    assert heightmap.heights.min() == pytest.approx(0.0) and heightmap.heights.max() == pytest.approx(0.4)
    assert heightmap.bounds[0] == pytest.approx(-6.225) and heightmap.bounds[3] == pytest.approx(4.85)


def test_relative_terrain_file_is_relative_to_the_scenario(tmp_path):
    from qz_drake.config import load_scenario
    from qz_drake.station import make_heightmap
    from qz_drake.terrain import HeightMap

    folder = tmp_path / "project" / "maps"
    folder.mkdir(parents=True)
    HeightMap(np.arange(12.0).reshape(3, 4) * 0.01, 0.1).save_npz(folder / "mine.npz")
    (folder / "mine.yaml").write_text("terrain: {kind: file, file: mine.npz}\n")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    cwd = os.getcwd()
    os.chdir(elsewhere)
    try:
        scenario = load_scenario(Path("..") / "project" / "maps" / "mine.yaml")
        assert make_heightmap(scenario.terrain).heights.max() == pytest.approx(0.11)
    finally:
        os.chdir(cwd)


def test_png_without_its_scale_names_the_param(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text(f"terrain: {{kind: file, file: {GENERATED_PNG}}}\n")
    assert_one_line_error(*qz("simulate", path, "--out", tmp_path / "o"), "scenario.terrain.params.resolution")


# -- 3. negative coordinates on the command line ------------------------------------------------------
def test_negative_coordinates_are_option_values(tmp_path):
    # Accepted as the value of --start (not taken for an option), then checked against the map.
    assert_one_line_error(*qz("astar", "scenarios/walk_grid_map.yaml", "--start", "-50,-30", "--goal", "-1.5e1,2",
                              "--out", tmp_path), "--start = '-50,-30'", "off the map")


def test_parser_takes_negative_pairs():
    from qz_drake.cli import build_parser

    args = build_parser().parse_args(["astar", "x.yaml", "--start", "-5,-3", "--goal", "-0.5,-1e-1"])
    assert (args.start, args.goal) == ("-5,-3", "-0.5,-1e-1")


# -- 4. validation gaps: one line naming the field and its value, exit 2 -----------------------------
@pytest.mark.parametrize("text, named", [
    ("controller: {kind: walk, route: [{x: 100.0, y: 0.0}]}\n", ("scenario.controller.route[0]", "off the map")),
    ("simulation: {duration: ten seconds}\n", ("scenario.simulation.duration = 'ten seconds'", "number")),
    ("robot: {initial_xy: 3.0}\n", ("scenario.robot.initial_xy = 3.0", "list")),
    ("", ("scenario = ", "no fields")),
    ("# only a comment\n", ("scenario = ", "no fields")),
    # Stairs as steep as allowed (45 degrees), the first step under the front feet.
    ("terrain: {kind: stairs, params: {rise: -0.4}}\n", ("scenario.terrain.params.rise = -0.4", "cannot stand")),
    ("terrain: {kind: stairs, params: {rise: 0.4, start_x: 0.0}}\n",
     ("scenario.terrain.params.rise = 0.4", "cannot stand")),
], ids=["waypoint_off_map", "duration_text", "initial_xy_scalar", "empty", "comment_only", "rise_down",
        "rise_up"])
def test_bad_scenario_is_one_line(tmp_path, text, named):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    result = qz("simulate", path, "--out", tmp_path / "o")
    assert_one_line_error(*result, *named)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("argv, named", [
    (("demo", "--duration", "-1"), "--duration = -1"),
    (("demo", "--duration", "nan"), "--duration = nan"),
    (("simulate", "scenarios/stand_flat.yaml", "--duration", "nan"), "--duration = nan"),
    (("simulate", "scenarios/stand_flat.yaml", "--out", "README.md"), "--out = 'README.md'"),
    (("demo", "--out", "README.md"), "--out = 'README.md'"),
    (("costmap", "scenarios/stand_flat.yaml", "--out", "README.md"), "--out = 'README.md'"),
    (("terrain", "stairs", "--out", "t.txt"), "--out = 't.txt'"),
], ids=["demo_negative", "demo_nan", "simulate_nan", "simulate_out_file", "demo_out_file", "costmap_out_file",
        "terrain_txt"])
def test_bad_argument_is_one_line(argv, named):
    assert_one_line_error(*qz(*argv), named)
    assert not (REPO / "t.txt").exists()


# -- 5. the viewer --------------------------------------------------------------------------------------
def test_batch_run_keeps_meshcat_quiet(tmp_path):
    from qz_drake.viz.recording import recording_summary

    code, out, err = qz("simulate", "scenarios/stand_flat.yaml", "--out", tmp_path, "--duration", "0.3")
    assert code == 0, err
    assert "Meshcat" not in out + err
    json.loads(out)  # the metrics alone on stdout
    summary = recording_summary(tmp_path / "recording.html")
    assert summary["has_animation"] and summary["follows_robot"]


def test_recording_meshcat_is_local_and_reused():
    from qz_drake.viz.recording import recording_meshcat

    first = recording_meshcat()
    assert recording_meshcat() is first
    assert first.web_url().startswith("http://localhost:")


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--use-gl=swiftshader",
                  "--enable-unsafe-swiftshader")


def robot_in_view(recording: Path, time: float, tmp_path: Path, screenshot: Path | None = None) -> list[float]:
    """Where the robot's base appears in a recording paused at ``time``: normalised device
    coordinates read back from headless Chromium (in view: x and y within [-1, 1])."""
    from qz_drake.viz.recording import recording_at

    page = recording_at(recording, time, tmp_path / f"at_{time:g}.html")
    dom = subprocess.run([CHROMIUM, *CHROMIUM_FLAGS, "--virtual-time-budget=20000", "--dump-dom", page.as_uri()],
                         capture_output=True, text=True, timeout=240).stdout
    match = re.search(r"qz-view (\{.*?\})</title>", dom)
    assert match, dom[-2000:]
    if screenshot is not None:
        subprocess.run([CHROMIUM, *CHROMIUM_FLAGS, "--window-size=1000,700", f"--screenshot={screenshot}",
                        page.as_uri()], capture_output=True, timeout=240)
    return json.loads(match.group(1))["ndc"]


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="needs chromium (apt-get install -y chromium) to render recordings")
def test_demo_recording_keeps_the_robot_in_view(tmp_path):
    # Before, the camera stood still and the robot walked out of the view by 15 s.
    code, out, err = qz("demo", "--out", tmp_path / "demo")
    assert code == 0, err
    assert "Meshcat" not in out + err
    duration = json.loads(out)["sim_time_s"]
    for time in (0.0, duration / 2, duration):
        x, y, z = robot_in_view(tmp_path / "demo" / "recording.html", time, tmp_path,
                                screenshot=tmp_path / f"demo_{time:g}.png")
        assert abs(x) < 0.5 and abs(y) < 0.5 and z < 1.0, (time, x, y, z)
        assert (tmp_path / f"demo_{time:g}.png").stat().st_size > 10_000


# -- 6. rough edges ---------------------------------------------------------------------------------------
def test_bench_help_lists_every_suite():
    from qz_drake.bench import SUITES

    code, out, _ = qz("bench", "--help")
    assert code == 0
    for name in SUITES:
        assert name in out


def test_trot_writes_a_recording_and_metrics(tmp_path):
    from qz_drake.viz.recording import recording_summary

    code, out, err = qz("trot", "scenarios/trot_flat.yaml", "--duration", "0.6", "--out", tmp_path)
    assert code in (0, 1), err
    metrics = json.loads(out)
    assert json.loads((tmp_path / "metrics.json").read_text())["scenario"] == metrics["scenario"]
    assert recording_summary(tmp_path / "recording.html")["has_animation"]


def test_cost_map_pictures_have_a_blocked_legend_and_map_high_colour_bars():
    import matplotlib.pyplot as plt

    from qz_drake.viz.costmap_plots import BLOCKED_LABEL, _draw

    image = np.ones((20, 60))
    image[5:8, 10:20] = np.inf
    fig, ax = plt.subplots(figsize=(7, 6))
    _draw(ax, fig, image, (0, 6, 0, 2), "cost", "t")
    fig.canvas.draw()
    assert [t.get_text() for t in ax.get_legend().get_texts()] == [BLOCKED_LABEL]
    colour_bar = fig.axes[1]
    assert colour_bar.get_position().height == pytest.approx(ax.get_position().height, rel=0.02)
    plt.close(fig)


def test_force_plot_has_a_legend_and_says_what_zero_means():
    from qz_drake.viz.blc_animation import plot_solution

    class _Solution:
        def sample(self, rate):
            t = np.linspace(0, 1, 11)
            return {"t": t, "base_pos": np.zeros((11, 3)), "base_rpy": np.zeros((11, 3)),
                    "foot_pos": np.zeros((11, 6, 3)), "foot_force": np.ones((11, 6, 3)),
                    "contact": np.ones((11, 6), bool)}

    fig = plot_solution(_Solution())
    ax = fig.axes[2]
    assert "swings" in ax.get_title() and ax.get_legend() is not None
    assert len(ax.get_legend().get_texts()) == 6


def test_dev_extra_installs_what_opens_the_notebooks():
    text = (REPO / "pyproject.toml").read_text()
    dev = re.search(r"^dev = \[(.*?)\]", text, re.S | re.M).group(1)
    assert '"notebook' in dev and '"nbconvert' in dev
    assert "jupyter notebook notebooks/" in (REPO / "README.md").read_text()


# -- the README's "Your own terrain" commands ----------------------------------------------------------
def _own_terrain_commands() -> list[str]:
    readme = (REPO / "README.md").read_text()
    block = readme.split("<!-- own-terrain commands:", 1)[1].split("```sh", 1)[1].split("```", 1)[0]
    return [line.split("  #")[0].strip() for line in block.strip().splitlines() if line.startswith("qz ")]


def test_readme_own_terrain_section_has_the_four_commands():
    commands = _own_terrain_commands()
    assert [c.split()[1] for c in commands] == ["simulate", "costmap", "astar", "simulate"]
    assert "--start -5,-3" in commands[2]


_COMMANDS = _own_terrain_commands()


@pytest.mark.parametrize("command", [
    pytest.param(c, marks=[pytest.mark.slow] if "walk_own_terrain" in c and "simulate" in c else [])
    for c in _COMMANDS], ids=["stand", "costmap", "astar", "walk"][:len(_COMMANDS)])
def test_readme_own_terrain_command(command, tmp_path):
    argv = shlex.split(command)[1:]
    for k, word in enumerate(argv):
        if k and argv[k - 1] == "--out":
            argv[k] = str(tmp_path / "out")
    code, out, err = qz(*argv)
    assert code == 0, (out, err)
    result = json.loads(out)
    if argv[0] == "simulate":
        assert result["success"], result["reason"]
    if argv[0] == "astar":
        assert result["found"] and result["start"] == [-5.0, -3.0]
