import math
from pathlib import Path

import numpy as np
import pytest

from qz_drake.errors import ConfigError
from qz_drake.planning import GridPath, grid_search, search_directional

# The Moving AI Lab's arena benchmark, copied into the repository (data/external/movingai/SOURCE.md).
MOVINGAI = Path(__file__).resolve().parents[2] / "data" / "external" / "movingai"


def _arena_costs() -> np.ndarray:
    lines = (MOVINGAI / "arena.map").read_text().splitlines()
    header = {l.split()[0]: l.split()[1] for l in lines[:lines.index("map")]}
    rows = lines[lines.index("map") + 1:][:int(header["height"])]
    assert header["type"] == "octile" and all(len(r) == int(header["width"]) for r in rows)
    return np.array([[1.0 if ch == "." else math.inf for ch in row] for row in rows])


def _path_cost(cost, path):
    a, b = path[:-1], path[1:]
    length = np.hypot(*(b - a).T)
    return float((length * 0.5 * (cost[a[:, 0], a[:, 1]] + cost[b[:, 0], b[:, 1]])).sum())


def _check_path(cost, result: GridPath, start, goal):
    """Consecutive 8-neighbours on free cells, no corner cut, reported cost = recomputed cost."""
    path = result.path
    assert tuple(path[0]) == tuple(start) and tuple(path[-1]) == tuple(goal)
    if len(path) == 1:
        assert result.cost == 0.0
        return
    steps = np.diff(path, axis=0)
    assert np.abs(steps).max() == 1 and (np.abs(steps).sum(axis=1) > 0).all()
    assert np.isfinite(cost[path[:, 0], path[:, 1]]).all()
    for (r, c), (dr, dc) in zip(path[:-1], steps):
        if dr and dc:
            assert np.isfinite(cost[r, c + dc]) and np.isfinite(cost[r + dr, c])
    assert result.cost == pytest.approx(_path_cost(cost, path), rel=1e-12)


def test_arena_scenarios_match_optimal_octile_lengths():
    cost = _arena_costs()
    scenarios = [l.split("\t") for l in (MOVINGAI / "arena.map.scen").read_text().splitlines()[1:] if l.strip()]
    assert len(scenarios) == 160
    for fields in scenarios:
        # Columns: bucket, map, width, height, start x, start y, goal x, goal y, optimal length.
        sx, sy, gx, gy = (int(v) for v in fields[4:8])
        result = grid_search(cost, (sy, sx), (gy, gx))
        assert result.found, fields
        assert abs(result.cost - float(fields[8])) < 1e-4, fields
        assert abs(result.length - float(fields[8])) < 1e-4, fields
        _check_path(cost, result, (sy, sx), (gy, gx))


def test_cost_is_length_times_mean_of_the_two_cells():
    result = grid_search(np.array([[1.0, 3.0, 5.0]]), (0, 0), (0, 2))
    assert result.cost == pytest.approx((1 + 3) / 2 + (3 + 5) / 2)
    result = grid_search(np.array([[1.0, 9.0], [9.0, 3.0]]), (0, 0), (1, 1))
    assert result.path.tolist() == [[0, 0], [1, 1]]
    assert result.cost == pytest.approx(math.sqrt(2) * 2.0)


def test_diagonal_may_not_cut_a_blocked_corner():
    open_square = np.ones((2, 2))
    assert grid_search(open_square, (0, 0), (1, 1)).cost == pytest.approx(math.sqrt(2))
    for blocked in [(0, 1), (1, 0)]:
        cost = open_square.copy()
        cost[blocked] = math.inf
        result = grid_search(cost, (0, 0), (1, 1))
        assert result.found and result.cost == pytest.approx(2.0) and len(result.path) == 3
    # Around a blocked centre: the diagonals beside it are forbidden, so 4 straight moves.
    cost = np.ones((3, 3))
    cost[1, 1] = math.inf
    result = grid_search(cost, (0, 0), (2, 2))
    assert result.cost == pytest.approx(4.0) and result.length == pytest.approx(4.0)


def test_unreachable_goal_and_blocked_ends_are_results():
    cost = np.ones((5, 5))
    cost[:, 2] = math.inf
    result = grid_search(cost, (0, 0), (4, 4))
    assert not result.found and result.reason == "goal unreachable"
    assert result.cost == math.inf and result.path.shape == (0, 2) and result.expansions == 10
    # A diagonal gap between two blocked cells is no way through either.
    cost = np.ones((2, 2))
    cost[0, 1] = cost[1, 0] = math.inf
    assert grid_search(cost, (0, 0), (1, 1)).reason == "goal unreachable"
    cost = np.ones((3, 3))
    cost[0, 0] = cost[2, 2] = math.inf
    assert "start (0, 0) is blocked" in grid_search(cost, (0, 0), (1, 1)).reason
    assert "goal (2, 2) is blocked" in grid_search(cost, (1, 1), (2, 2)).reason
    same = grid_search(np.ones((3, 3)), (1, 1), (1, 1))
    assert same.found and same.cost == 0.0 and same.path.tolist() == [[1, 1]] and same.length == 0.0


def test_user_errors_name_the_field():
    with pytest.raises(ConfigError, match=r"^start = \(5, 0\).*outside the 3 x 4 map"):
        grid_search(np.ones((3, 4)), (5, 0), (0, 0))
    with pytest.raises(ConfigError, match=r"^goal = \(0, -1\)"):
        grid_search(np.ones((3, 4)), (0, 0), (0, -1))
    with pytest.raises(ConfigError, match=r"^goal = 'ab'"):
        grid_search(np.ones((3, 4)), (0, 0), "ab")
    bad = np.ones((3, 4))
    bad[1, 2] = -1.0
    with pytest.raises(ConfigError, match=r"^cell_cost\[1, 2\] = -1\.0"):
        grid_search(bad, (0, 0), (2, 2))
    bad[1, 2] = math.nan
    with pytest.raises(ConfigError, match=r"^cell_cost\[1, 2\] = nan"):
        grid_search(bad, (0, 0), (2, 2))
    with pytest.raises(ConfigError, match="cell_cost"):
        grid_search(np.ones(5), (0, 0), (0, 1))
    with pytest.raises(ConfigError, match="heuristic_weight"):
        grid_search(np.ones((3, 3)), (0, 0), (2, 2), heuristic_weight=-1)
    with pytest.raises(ConfigError, match="connectivity"):
        grid_search(np.ones((3, 3)), (0, 0), (2, 2), connectivity=6)


@pytest.mark.parametrize("seed", range(4))
def test_optimal_on_random_weighted_maps(seed, dijkstra):
    rng = np.random.default_rng(seed)
    cost = rng.uniform(0.0, 5.0, (23, 31))
    cost[rng.random(cost.shape) < 0.25] = math.inf
    free = np.argwhere(np.isfinite(cost))
    start = tuple(free[0])
    reference = dijkstra(cost, start)
    for goal in map(tuple, free[rng.choice(len(free), 15, replace=False)]):
        result = grid_search(cost, start, goal)
        if math.isinf(reference[goal]):
            assert not result.found and result.reason == "goal unreachable"
            continue
        assert result.cost == pytest.approx(reference[goal], rel=1e-9)
        _check_path(cost, result, start, goal)
        assert grid_search(cost, start, goal, heuristic_weight=0.0).cost == pytest.approx(result.cost)
        # Weighted A*: never better than optimal, at most the weight times worse.
        weighted = grid_search(cost, start, goal, heuristic_weight=2.0)
        assert result.cost - 1e-9 <= weighted.cost <= 2.0 * result.cost + 1e-9
        four = grid_search(cost, start, goal, connectivity=4)
        reference4 = dijkstra(cost, start, connectivity=4)[goal]
        assert four.cost == pytest.approx(reference4) if math.isfinite(reference4) else not four.found


def test_heuristic_saves_expansions_on_open_ground():
    cost = np.ones((60, 60))
    astar = grid_search(cost, (0, 0), (59, 40))
    dijkstra = grid_search(cost, (0, 0), (59, 40), heuristic_weight=0.0)
    assert astar.cost == pytest.approx(dijkstra.cost)
    assert astar.expansions < dijkstra.expansions / 5


def test_directional_search_matches_reference(dijkstra):
    rng = np.random.default_rng(7)
    costs = rng.uniform(0.0, 1.0, (8, 17, 19))
    costs[:, rng.random((17, 19)) < 0.2] = math.inf
    # Some cells may only be crossed in some directions.
    costs[rng.random(costs.shape) < 0.05] = math.inf
    free = np.argwhere(np.isfinite(costs).any(axis=0))
    start = tuple(free[0])
    reference = dijkstra(costs, start, distance_weight=0.3)
    for goal in map(tuple, free[rng.choice(len(free), 12, replace=False)]):
        result = search_directional(costs, start, goal, distance_weight=0.3)
        if math.isinf(reference[goal]):
            assert not result.found
        else:
            assert result.cost == pytest.approx(reference[goal], rel=1e-9)
    with pytest.raises(ConfigError, match="heading_cost"):
        search_directional(np.ones((4, 3, 3)), (0, 0), (1, 1))
    with pytest.raises(ConfigError, match="distance_weight"):
        search_directional(np.ones((8, 3, 3)), (0, 0), (1, 1), distance_weight=math.inf)
