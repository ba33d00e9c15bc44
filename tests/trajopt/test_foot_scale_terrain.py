"""A fine, noisy elevation map at the foot's scale (issue 52; trajopt/terrain.py
FootScaleTerrain): the NLP sees heights and normals a foot meets, the verdict the map as given."""

import math

import numpy as np
import pytest

from qz_drake.errors import QzError
from qz_drake.terrain import HeightMap
from qz_drake.trajopt.parameters import BlcParameters
from qz_drake.trajopt.solver import BlcTask, solve_blc
from qz_drake.trajopt.terrain import FootScaleTerrain, GridTerrain, as_terrain


def _noisy_hills(resolution: float = 0.02, noise: float = 0.015, seed: int = 3) -> HeightMap:
    """4 m x 4 m round (0, 0): a gentle hill and pixel noise, as a depth camera's map."""
    rng = np.random.default_rng(seed)
    xs = -2.0 + resolution * (np.arange(int(round(4.0 / resolution))) + 0.5)
    gx, gy = np.meshgrid(xs, xs)
    heights = 0.08 * np.exp(-((gx - 0.6) ** 2 + (gy + 0.3) ** 2) / 0.8) + rng.normal(0.0, noise, gx.shape)
    return HeightMap(heights - heights.min(), resolution, (float(xs[0]), float(xs[0])))


def _tilt_deg(terrain, x, y):
    _, hx, hy, *_ = terrain.height_derivatives(x, y)
    return np.degrees(np.arctan(np.hypot(hx, hy)))


def test_the_foot_scale_surface_is_never_below_the_map_and_its_normals_are_a_foots():
    heightmap = _noisy_hills()
    terrain = as_terrain(heightmap, 0.02)
    assert isinstance(terrain, FootScaleTerrain) and terrain.given.heightmap is heightmap
    assert np.all(terrain.heights >= heightmap.heights - 1e-12)
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-1.8, 1.8, (2, 2000))
    # Between the cells too: above the given map's own interpolant everywhere sampled.
    assert np.all(terrain.height(x, y) >= terrain.given.height(x, y) - 1e-9)
    friction_cone = math.degrees(math.atan(BlcParameters().friction_coefficient))
    raw, smooth = _tilt_deg(terrain.given, x, y), _tilt_deg(terrain, x, y)
    assert np.median(raw) > friction_cone  # a pixel's normal: most of them outside the cone
    assert np.median(smooth) < 10 and np.quantile(smooth, 0.95) < friction_cone


def test_maps_of_coarser_cells_are_solved_as_they_are():
    # The Fig. 9 worlds and the capability scenes (5 cm cells): the same terrain as before.
    assert type(as_terrain(_noisy_hills(resolution=0.05), 0.02)) is GridTerrain
    assert type(as_terrain(_noisy_hills(), 0.0)) is GridTerrain
    with pytest.raises(QzError, match="terrain_foot_scale"):
        BlcParameters(terrain_foot_scale=-0.01)
    with pytest.raises(QzError, match="terrain_foot_scale"):
        FootScaleTerrain(_noisy_hills(resolution=0.05), 0.02)


def test_a_metre_on_a_noisy_map_plans_at_the_foot_scale_and_its_swings_clear_the_map_as_given():
    heightmap = _noisy_hills()
    task = BlcTask(target=(1.0, 0.0, 0.0))
    # Iteration budgets, not the wall-time limit, decide (a loaded machine is not a slow solve).
    raw = solve_blc(task, terrain=heightmap,
                    params=BlcParameters(terrain_foot_scale=0.0, max_iterations=60, time_limit=120.0))
    assert not raw.success  # every pixel's normal in the friction and stance rows
    solution = solve_blc(task, terrain=heightmap, params=BlcParameters(max_iterations=60, time_limit=120.0))
    assert solution.success, solution.reason
    given = as_terrain(heightmap)
    schedule = solution.contact_schedule
    times = np.arange(0.0, solution.duration, 0.01)
    for leg, foot in enumerate(solution.foot_positions):
        swing = times[~schedule.in_contact(times)[:, leg].astype(bool)]
        if len(swing):
            p = np.array([foot.value(t).ravel() for t in swing])
            clearance = p[:, 2] - solution.robot.foot_radius - given.height(p[:, 0], p[:, 1])
            assert clearance.min() >= -BlcParameters().dense_clearance_tolerance


def test_a_metre_on_a_noisy_map_plans_with_one_mean_leg_row_per_sample():
    """The smooth-minimum leg rows in their mean form (leg_clearance_softmin_mean) plan the noisy
    metre within the budget the point rows need (18 iterations; the conservative rows 182, as
    several points of a stance leg stand at their bound at once), the legs clear to the dense
    verdict."""
    params = BlcParameters(max_iterations=60, time_limit=120.0, leg_clearance_softmin=1000.0,
                           leg_clearance_softmin_mean=True)
    solution = solve_blc(BlcTask(target=(1.0, 0.0, 0.0)), terrain=_noisy_hills(), params=params)
    assert solution.success, solution.reason
    assert solution.dense.min_link_clearance >= -params.dense_link_tolerance
