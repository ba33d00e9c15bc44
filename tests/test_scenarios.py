"""Every walking scenario file in scenarios/ reaches its goal (issue 4's must-show)."""

from pathlib import Path

import pytest

from qz_drake.config import load_scenario
from qz_drake.simulation import simulate

# `make test` leaves out the walks whose path the fast suite walks elsewhere (issue 56: make test
# in 6 minutes on 2 cores); `make test-all` walks every file.
# walk_grid_map (25 s of a loaded make test, the longest): the tripod walk on hydroelastic mesh
# contact is walk_slope's, a walk on a heightmap read from a picture walk_own_terrain's (grid_map's
# heightmap_generated.png), and the grid_map test field under the standing robot, mesh contact
# included, test_station's.
# walk_flat: the same 3 m on the same ground is walk_flat_position's, which differs only in
# driving the joints through the drives' PD; the tripod walk on flat ground in torque mode is
# test_walking's route on flat ground, under that test's stricter assertions.
# walk_flat_blc: the BLC-planned walk on flat ground is test_walking's, which also counts its
# solves; a scenario file with planner: blc walks in walk_stairs_blc.
SLOW = {"walk_grid_map", "walk_flat", "walk_flat_blc"}
WALKS = [pytest.param(p, id=p.stem, marks=[pytest.mark.slow] if p.stem in SLOW else [])
         for p in sorted((Path(__file__).resolve().parents[1] / "scenarios").glob("walk_*.yaml"))]


@pytest.mark.parametrize("path", WALKS)
def test_walking_scenario_succeeds(path):
    m = simulate(load_scenario(path)).metrics
    assert m["success"], m
    assert m["trunk_terrain_contacts"] == 0 and m["max_tilt_deg"] < 30.0
    assert m["tracking_rms_m"] < 0.05


def test_the_demo_scenario_file_is_the_demos_walk_driven_as_the_trials_and_fig9():
    # `qz simulate scenarios/capplanner_long_range.yaml` walks what `qz demo` walks, and both drive
    # the joints as the capability trials that label the model's data and Fig. 9's walks do.
    import dataclasses

    from qz_drake.capability.trials import TrialConfig
    from qz_drake.config import WalkDrives
    from qz_drake.demo import demo_scenario
    from qz_drake.experiments.fig9 import ExperimentConfig

    path = Path(__file__).resolve().parents[1] / "scenarios" / "capplanner_long_range.yaml"
    demo = demo_scenario()
    assert dataclasses.asdict(load_scenario(path)) == dataclasses.asdict(demo)
    assert (demo.station.control_mode, demo.simulation.time_step) == (WalkDrives.control_mode, WalkDrives.time_step)
    station, simulation = TrialConfig().station_and_simulation(demo.simulation.duration)
    assert station == demo.station and simulation.time_step == demo.simulation.time_step
    config = ExperimentConfig()
    assert (config.control_mode, config.time_step) == (station.control_mode, simulation.time_step)
