import math

import numpy as np
import pytest

from qz_drake.errors import ConfigError
from qz_drake.planning import MOVE_HEADINGS, AStarConfig, astar, astar_grid
from qz_drake.terrain import HeightMap, grid_map_terrain
from qz_drake.terrain.features import Footprint, build_cost_map


@pytest.fixture(scope="module")
def grid_map_costs():
    # The real test field of grid_map: 500 x 500 cells of 0.05 m, heights 0-0.4 m.
    return build_cost_map(grid_map_terrain(resolution=0.05, min_height=0.0, max_height=0.4))


def _config(safety):
    return AStarConfig(distance_weight=1.0 - safety, safety_weight=safety)


def test_larger_safety_weight_detours_through_cheaper_cells(grid_map_costs):
    """Paper 003 Fig. 13: a larger w_2 gives a longer path through lower-cost terrain."""
    start, goal = (-10.0, -10.0), (10.0, 10.0)
    short = astar(grid_map_costs, start, goal, config=_config(0.1))
    safe = astar(grid_map_costs, start, goal, config=_config(0.9))
    assert short.found and safe.found
    assert safe.mean_cell_cost < short.mean_cell_cost
    assert safe.length >= short.length
    for result in (short, safe):
        rows, cols = result.cells.T
        assert grid_map_costs.traversable[rows, cols].all()
        assert np.allclose(result.xy[[0, -1]], [start, goal], atol=grid_map_costs.resolution / 2)
        w1, w2 = result.config.distance_weight, result.config.safety_weight
        assert result.cost == pytest.approx(result.length * (w1 + w2 * result.mean_cell_cost), rel=1e-9)


def test_optimal_against_brute_force_dijkstra(dijkstra):
    rng = np.random.default_rng(3)
    for trial in range(3):
        costs = rng.uniform(0.0, 1.0, (8, 15, 18))
        costs[:, rng.random((15, 18)) < 0.2] = math.inf
        free = np.argwhere(np.isfinite(costs).any(axis=0))
        start = tuple(free[trial])
        config = AStarConfig(distance_weight=0.3, safety_weight=0.7 + trial)
        w1, w2 = 0.3 / (1.0 + trial), (0.7 + trial) / (1.0 + trial)
        resolution = 0.1
        reference = dijkstra(costs * (w2 * resolution), start, distance_weight=w1 * resolution)
        for goal in map(tuple, free[rng.choice(len(free), 10, replace=False)]):
            result = astar_grid(costs, start, goal, resolution=resolution, config=config)
            if math.isinf(reference[goal]):
                assert not result.found and result.reason == "goal unreachable"
                continue
            # Optimal cost: the heuristic of Eq. 19 never overestimates (Eq. 20).
            assert result.cost == pytest.approx(reference[goal], rel=1e-9)
            if len(result.cells) > 1:
                moves = np.diff(result.cells, axis=0)
                headings = np.arctan2(moves[:, 0], moves[:, 1]) % (2 * math.pi)
                assert np.allclose(result.headings[1:], headings)
                assert result.headings[0] == result.headings[1]


def test_heuristic_is_admissible_at_every_cell(dijkstra):
    """h(n) = (w_1 + w_2 C_min) * octile(n, goal) <= true cost to go, for all n (Eq. 20)."""
    rng = np.random.default_rng(11)
    costs = rng.uniform(0.2, 1.0, (8, 12, 14))
    costs[:, 5, 2:12] = math.inf
    goal = (11, 7)
    # Cost to go = cost from the goal on the reversed graph; reversing a move keeps its length
    # and swaps the cells, and the two cells' mean is symmetric, but the heading flips.
    reversed_costs = np.roll(costs, 4, axis=0)
    to_go = dijkstra(reversed_costs, goal, distance_weight=0.5)
    cmin = costs[np.isfinite(costs)].min()
    rows, cols = np.indices(to_go.shape)
    dr, dc = np.abs(rows - goal[0]), np.abs(cols - goal[1])
    octile = np.maximum(dr, dc) - np.minimum(dr, dc) + math.sqrt(2) * np.minimum(dr, dc)
    assert ((0.5 + cmin) * octile <= to_go + 1e-12).all()
    for start in [(0, 0), (0, 13), (4, 6)]:
        result = astar_grid(costs, start, goal, config=AStarConfig(0.5, 1.0))
        assert result.cost == pytest.approx(to_go[start] / 1.5, rel=1e-9)  # weights normalised


def test_blocked_ends_off_map_points_and_bad_weights():
    costs = np.full((8, 6, 6), 0.5)
    costs[:, 0, 0] = math.inf
    costs[:, 3, :] = math.inf
    result = astar_grid(costs, (0, 0), (5, 5))
    assert not result.found and "start (0, 0) is blocked" in result.reason
    assert result.cells.shape == (0, 2) and result.cost == math.inf
    result = astar_grid(costs, (1, 1), (5, 5))
    assert not result.found and result.reason == "goal unreachable"
    # Distance only: the shortest way round the blocked cells.
    shortest = astar_grid(costs, (0, 1), (2, 5), config=AStarConfig(1.0, 0.0))
    assert shortest.found and shortest.cost == pytest.approx(shortest.length) == pytest.approx(2 + 2 * math.sqrt(2))
    bad = costs.copy()
    bad[3, 1, 2] = -0.5
    with pytest.raises(ConfigError, match=r"^heading_cost\[3, 1, 2\] = -0.5"):
        astar_grid(bad, (1, 1), (2, 2), config=AStarConfig(1.0, 0.0))
    with pytest.raises(ConfigError, match="^goal = "):
        astar_grid(costs, (1, 1), (6, 0))
    with pytest.raises(ConfigError, match="astar.safety_weight"):
        astar_grid(costs, (1, 1), (2, 2), config=AStarConfig(0.5, -1.0))
    with pytest.raises(ConfigError, match="must not both be 0"):
        astar_grid(costs, (1, 1), (2, 2), config=AStarConfig(0.0, 0.0))


@pytest.mark.parametrize("footprint", [Footprint.qingzhui(), Footprint.quadruped()], ids=["hexapod", "quadruped"])
def test_cost_map_path_around_a_wall(footprint):
    # 8 m x 5 m of 0.05 m cells with a 0.3 m wall across x = 4 m, open for y > 2.5 m.
    res = 0.05
    heights = np.zeros((100, 160))
    heights[:50, 78:82] = 0.3
    terrain = HeightMap(heights, res, origin=(0.0, 0.0))
    cost_map = build_cost_map(terrain, footprint=footprint)
    result = astar(cost_map, (1.0, 0.5), (7.0, 0.5))
    assert result.found
    assert result.xy[:, 1].max() > 3.0  # went round the wall's end, body disc clear of it
    rows, cols = result.cells.T
    assert np.isfinite(cost_map.heading_cost()[:, rows, cols]).all()
    assert set(np.round(result.headings / (math.pi / 4)).astype(int) % 8) <= set(range(8))
    assert np.allclose(MOVE_HEADINGS[np.round(result.headings / (math.pi / 4)).astype(int) % 8] % (2 * math.pi),
                       result.headings % (2 * math.pi))
    with pytest.raises(ConfigError, match=r"^goal = \(9\.0, 0\.5\): off the map"):
        astar(cost_map, (1.0, 0.5), (9.0, 0.5))
