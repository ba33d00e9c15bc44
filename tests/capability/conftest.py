"""Fixtures shared by the capability tests."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest


@pytest.fixture
def certified_code(tmp_path):
    """The code a dataset's manifest names, against which the running code is "a change": a copy
    of this tree's qz_drake whose verdict module differs in syntax only. Returns (its folder,
    fingerprints(settings) -> that code's fingerprints for a TrialConfig's settings)."""
    certified = tmp_path / "certified"
    shutil.copytree(Path(__file__).resolve().parents[2] / "qz_drake", certified / "qz_drake",
                    ignore=shutil.ignore_patterns("__pycache__"))
    with open(certified / "qz_drake" / "verdict.py", "a") as f:
        f.write("\n_CERTIFIED_COPY = True\n")

    def fingerprints(settings: dict) -> dict:
        from qz_drake.capability.dataset import fingerprints as running
        from qz_drake.capability.trials import TrialConfig

        script = ("import json, sys; from qz_drake.capability.dataset import fingerprints; "
                  "from qz_drake.capability.trials import TrialConfig; "
                  "print(json.dumps(fingerprints(TrialConfig(**json.loads(sys.argv[1])))))")
        run = subprocess.run([sys.executable, "-c", script, json.dumps(settings)], capture_output=True,
                             text=True, env=dict(os.environ, PYTHONPATH=str(certified)), cwd=str(certified),
                             timeout=300, check=True)
        copy = json.loads(run.stdout)
        # The tests rely on the copy being the running code but for its verdict module.
        here = running(TrialConfig(**settings))
        assert sorted(k for k in set(copy) | set(here) if copy.get(k) != here.get(k)) == ["verdict"], (copy, here)
        return copy

    return certified, fingerprints
