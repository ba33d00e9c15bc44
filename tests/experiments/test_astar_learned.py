"""The learned A* (issue 54's baseline from the field): A*'s geometric search with the capability
model's answers as an edge cost and veto (astar_baseline.LearnedCost)."""

import numpy as np
import pytest

from qz_drake.capability.model_base import CapabilityMap
from qz_drake.capability.patches import grid_centres
from qz_drake.errors import QzError
from qz_drake.experiments.astar_baseline import AStarBaseline, AStarBaselineConfig, LearnedCost
from qz_drake.terrain import HeightMap

START, GOAL = (0.5, 2.5), (7.5, 2.5)


def _open_world():
    """8 m x 5 m of level ground: the geometric A* runs straight along y = 2.5 m."""
    return HeightMap(np.zeros((101, 161)), 0.05, (0.0, 0.0))


def _capability_map(heightmap, low_cells=(), low=0.3):
    """Every move walks with 0.99, but moves from the 1 m cells in ``low_cells`` (ix, iy) along
    the x axis (headings 0 and 4) walk with ``low``."""
    xs, ys = grid_centres(heightmap, anchor=START)
    forward = np.full((1, 8, len(ys), len(xs)), 0.99)
    for ix, iy in low_cells:
        forward[0, [0, 4], iy, ix] = low
    return CapabilityMap(xs=xs, ys=ys, topologies=("nominal",), forward=forward, turn_left=forward.copy(),
                         turn_right=forward.copy())


def test_the_learned_cost_is_the_grid_cells_and_the_veto_blocks_by_heading():
    heightmap = _open_world()
    cm = _capability_map(heightmap, low_cells=[(3, 2)])
    baseline = AStarBaseline(heightmap, AStarBaselineConfig())
    cost = LearnedCost(cm, weight=2.0, veto=0.5).heading_cost(baseline.cost_map)
    assert cost.shape == (8,) + baseline.cost_map.shape
    # A cost-map cell in grid cell (3, 2) (x in [3, 4), y in [2, 3)): blocked along x, priced by
    # -log 0.99 per metre across.
    row, col = baseline.cost_map.cell(3.5, 2.5)
    assert np.isinf(cost[0, row, col]) and np.isinf(cost[4, row, col])
    assert cost[2, row, col] == pytest.approx(2.0 * -np.log(0.99))
    # A diagonal step pays for its neighbours' headings too (a zigzag walks along x): blocked.
    assert np.isinf(cost[1, row, col]) and np.isinf(cost[7, row, col])
    row, col = baseline.cost_map.cell(2.5, 3.5)
    assert cost[1, row, col] == pytest.approx(2.0 * -np.log(0.99) / np.sqrt(2.0))
    # Elsewhere along x: the high success's small cost.
    row, col = baseline.cost_map.cell(1.5, 2.5)
    assert cost[0, row, col] == pytest.approx(2.0 * -np.log(0.99))


def test_a_route_goes_round_moves_the_model_says_fail_and_is_the_geometric_one_without_them():
    heightmap = _open_world()
    geometric = AStarBaseline(heightmap, AStarBaselineConfig()).route(START, GOAL)
    assert geometric.found and np.abs(geometric.path_xy[:, 1] - 2.5).max() < 1e-9
    # Nothing the model doubts: the same route.
    same = AStarBaseline(heightmap, AStarBaselineConfig(),
                         learned=LearnedCost(_capability_map(heightmap), weight=10.0, veto=0.5)).route(START, GOAL)
    np.testing.assert_allclose(same.path_xy, geometric.path_xy)
    # Moves along x from the grid cell on the line at x in [3, 4) are vetoed: the route leaves
    # the line there and comes back after.
    learned = AStarBaseline(heightmap, AStarBaselineConfig(),
                            learned=LearnedCost(_capability_map(heightmap, low_cells=[(3, 2)]), 10.0, 0.5))
    route = learned.route(START, GOAL)
    assert route.found
    inside = (route.path_xy[:, 0] >= 3.0) & (route.path_xy[:, 0] < 4.0)
    assert np.all(np.abs(route.path_xy[inside, 1] - 2.5) >= 0.5 - 1e-9)


def test_bad_learned_settings_name_the_field():
    cm = _capability_map(_open_world())
    with pytest.raises(QzError, match="astar_learned_weight"):
        LearnedCost(cm, weight=-1.0)
    with pytest.raises(QzError, match="astar_learned_veto"):
        LearnedCost(cm, veto=1.0)
    with pytest.raises(QzError, match="topologies"):
        LearnedCost(CapabilityMap(xs=cm.xs, ys=cm.ys, topologies=("front_bend",), forward=cm.forward,
                                  turn_left=cm.forward, turn_right=cm.forward))
