"""Every walking scenario file in scenarios/ reaches its goal (issue 4's must-show)."""

from pathlib import Path

import pytest

from qz_drake.config import load_scenario
from qz_drake.simulation import simulate

WALKS = sorted((Path(__file__).resolve().parents[1] / "scenarios").glob("walk_*.yaml"))


@pytest.mark.parametrize("path", WALKS, ids=lambda p: p.stem)
def test_walking_scenario_succeeds(path):
    m = simulate(load_scenario(path)).metrics
    assert m["success"], m
    assert m["trunk_terrain_contacts"] == 0 and m["max_tilt_deg"] < 30.0
    assert m["tracking_rms_m"] < 0.05
