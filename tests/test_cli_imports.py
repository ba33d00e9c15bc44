"""The ``qz`` command answers ``--help`` and a mistyped option without importing what its
commands run (issue 36): building the parser imports none of the slow libraries, each command
imports what it runs when it runs, and a help page lists the package's own names."""

import json
import subprocess
import sys

# Each takes from a tenth of a second (scipy.ndimage, numba) to most of one (pydrake, torch) to import.
SLOW = ("matplotlib", "pydrake", "torch", "numba", "scipy", "rich", "numpy", "yaml", "importlib.metadata")

_BUILD_THE_PARSER = """
import json, sys
from qz_drake.cli import build_parser
build_parser()
print(json.dumps(sorted(sys.modules)))
"""


def _qz(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "qz_drake.cli", *argv], capture_output=True, text=True, timeout=300)


def test_the_parser_imports_none_of_the_slow_libraries():
    # A fresh interpreter: this test run has imported everything already.
    done = subprocess.run([sys.executable, "-c", _BUILD_THE_PARSER], capture_output=True, text=True, timeout=300,
                          check=True)
    imported = json.loads(done.stdout)
    assert not [m for m in imported if m in SLOW or m.startswith(tuple(f"{s}." for s in SLOW))]
    # Nor the package's own modules beyond the command's and the light ones its options name.
    assert {m for m in imported if m.startswith("qz_drake.") and not m.startswith("qz_drake.cli")} == {
        "qz_drake.bench", "qz_drake.errors", "qz_drake.hardware", "qz_drake.hardware.relay",
        "qz_drake.hardware.scheduling"}
    top = _qz("--help")
    assert top.returncode == 0 and "capability" in top.stdout and "simulate" in top.stdout, top.stderr


def test_a_help_page_lists_the_names_of_the_modules_it_did_not_import():
    from qz_drake.capability.collect import PROTOCOLS
    from qz_drake.capability.patches import KINDS
    from qz_drake.cli import capability
    from qz_drake.robot.topology import TOPOLOGY_NAMES
    from qz_drake.terrain import TERRAIN_KINDS

    # The copies that spare the parser the trials' and the BLC's imports.
    assert capability.PROTOCOLS == PROTOCOLS
    from qz_drake.cli.arguments import TERMINAL_STANCES
    from qz_drake.trajopt.parameters import TERMINAL_STANCES as BLC_TERMINAL_STANCES

    assert TERMINAL_STANCES == BLC_TERMINAL_STANCES
    from qz_drake.cli.arguments import LEG_CLEARANCE_SOFTMIN, WALK_CONTROL_MODE, WALK_TIME_STEP
    from qz_drake.config import WalkDrives
    from qz_drake.trajopt.parameters import BlcParameters

    assert (WALK_CONTROL_MODE, WALK_TIME_STEP) == (WalkDrives.control_mode, WalkDrives.time_step)
    assert LEG_CLEARANCE_SOFTMIN == BlcParameters.leg_clearance_softmin
    collect = _qz("capability", "collect", "--help")
    assert collect.returncode == 0, collect.stderr
    page = " ".join(collect.stdout.split())
    for name in (*TOPOLOGY_NAMES, *KINDS, *PROTOCOLS):
        assert name in page, name
    terrain = _qz("terrain", "--help")
    assert terrain.returncode == 0, terrain.stderr
    for kind in TERRAIN_KINDS:
        assert f"  {kind}: " in terrain.stdout, kind
    assert "LazyText" not in collect.stdout + terrain.stdout


_PLAN_WITHOUT_OUT = """
import json, sys
from qz_drake.cli import main
code = main(["plan", "--terrain", "flat", "--start", "0,0", "--goal", "1,0", "--json"])
print(json.dumps({"code": code, "modules": sorted(sys.modules)}))
"""


def test_qz_plan_without_out_draws_nothing_and_imports_no_matplotlib(tmp_path):
    # Issue 53: matplotlib (a third of a second) is imported where a picture is asked for only.
    done = subprocess.run([sys.executable, "-c", _PLAN_WITHOUT_OUT], cwd=tmp_path, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.strip().splitlines()
    plan, after = json.loads(lines[0]), json.loads(lines[-1])
    assert after["code"] == 0 and plan["success"] and plan["png"] is None
    assert not [m for m in after["modules"] if m == "matplotlib" or m.startswith("matplotlib.")]
    assert not list(tmp_path.iterdir())  # no out/plan folder either
