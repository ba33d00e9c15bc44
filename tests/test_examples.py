"""The scripts of examples/ run as a user runs them, and say what they promise.

Each runs as a program (``python examples/NAME.py --out DIR``) from a folder of its own, so a
script that leans on being started from the repository's root, or that writes beside its
``--out``, fails here. The examples are read before the package: they import only its public
names, never the tests or the command line.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

from qz_drake.viz.recording import recording_summary
from test_self_contained import outside_references

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
# The simulation station's controller ports, which the LCM station has too.
CONTROLLER_PORTS = "in: joint_torque; out: state, joint_torque_measured, imu, foot_contact"


def run_example(name: str, folder: Path, *args: str) -> str:
    """Runs examples/NAME.py with ``--out folder/out`` from ``folder``; returns its output,
    having checked that it exited 0 and wrote nothing outside its --out."""
    folder.mkdir(parents=True, exist_ok=True)
    done = subprocess.run([sys.executable, str(EXAMPLES / f"{name}.py"), "--out", str(folder / "out"), *args],
                          cwd=folder, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert sorted(p.name for p in folder.iterdir()) == ["out"]
    return done.stdout


@pytest.fixture(scope="module")
def station_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("station_and_controller")
    return run_example("station_and_controller", folder, "--duration", "2"), folder / "out"


@pytest.fixture(scope="module")
def lcm_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lcm_station")
    return run_example("lcm_station", folder, "--duration", "2"), folder / "out"


def _trunk_change_mm(output: str) -> float:
    return float(re.search(r"largest change ([\d.]+) mm", output).group(1))


def test_station_and_controller_stands_and_names_the_ports(station_run):
    output, out = station_run
    assert f"simulation station, {CONTROLLER_PORTS}" in output
    assert "\nstood; recording:" in output
    # The scenario's bound on the trunk height is 2 cm; standing still it moves by millimetres.
    assert _trunk_change_mm(output) < 5.0
    assert recording_summary(out / "recording.html")["has_animation"]


def test_lcm_station_has_the_same_ports_and_the_same_stand(station_run, lcm_run):
    output, out = lcm_run
    assert f"LCM station (QingzhuiHardwareInterface), {CONTROLLER_PORTS}" in output
    assert "\nstood; recording:" in output
    assert abs(_trunk_change_mm(output) - _trunk_change_mm(station_run[0])) < 2.0
    # Every 2 ms plant step answered by one status, none lost, no safe stop.
    received = int(re.search(r"LCM statuses received (\d+), missed 0, rejected 0; safe stop: none", output).group(1))
    assert received >= 900
    assert recording_summary(out / "recording.html")["has_animation"]


def test_blc_solve_and_plot_solves_and_writes_the_png(tmp_path):
    output = run_example("blc_solve_and_plot", tmp_path, "--distance", "1.0")
    assert output.startswith("BLC solved: Success")
    end = re.search(r"to \[([-\d. ]+)\] m in ([\d.]+) s", output)
    x, y, _ = (float(v) for v in end.group(1).split())
    assert abs(x - 1.0) < 0.02 and abs(y) < 0.02
    png = tmp_path / "out" / "blc_stairs.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


def _check_plan_and_walk(output: str, out: Path, goal: str) -> None:
    assert re.search(rf"TLC: \d+ actions to \({goal}\), predicted P\(success\) 0\.\d\d", output), output
    assert f"to ({goal}) heading 0 deg in nominal" in output
    assert "walk succeeded" in output
    error = float(re.search(r"final error ([\d.]+) m", output).group(1))
    assert error < 0.15
    assert (out / "plan.png").stat().st_size > 20_000
    assert recording_summary(out / "walk" / "recording.html")["has_animation"]
    assert '"success": true' in (out / "walk" / "metrics.json").read_text()


def test_plan_and_walk_short_plans_then_walks_to_the_goal(tmp_path):
    _check_plan_and_walk(run_example("plan_and_walk", tmp_path, "--short"), tmp_path / "out", "2.0, 0.0")


@pytest.mark.slow
def test_plan_and_walk_default_walks_over_the_stairs(tmp_path):
    _check_plan_and_walk(run_example("plan_and_walk", tmp_path), tmp_path / "out", "4.0, 0.0")


def _imports(path: Path) -> list[tuple[str, str]]:
    """(module, name) of each import of a script (name "" for ``import module``)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found += [(alias.name, "") for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            found += [(node.module, alias.name) for alias in node.names]
    return found


def test_examples_use_the_public_api_and_stay_in_the_repository():
    scripts = sorted(EXAMPLES.glob("*.py"))
    assert [p.stem for p in scripts] == ["blc_solve_and_plot", "lcm_station", "plan_and_walk",
                                         "station_and_controller"]
    siblings = {p.stem for p in scripts}
    readme = (EXAMPLES / "README.md").read_text()
    for script in scripts:
        assert f"examples/{script.name}" in readme and f"examples/{script.name}" in script.read_text()
        for module, name in _imports(script):
            assert not module.startswith(("tests", "test_", "qz_drake.cli")), (script.name, module)
            assert not name.startswith("_") and "._" not in module, (script.name, module, name)
            assert module.split(".")[0] in {"argparse", "math", "sys", "pathlib", "numpy", "matplotlib", "pydrake",
                                            "qz_drake", *siblings}, (script.name, module)
        assert outside_references(f"examples/{script.name}", script.read_text()) == []
