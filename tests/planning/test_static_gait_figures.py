"""Figures of paper 003: the search tree (Fig. 7) for depth 1 and 4 and the safety-weight paths
on the real heightmap (Fig. 13)."""

import numpy as np
import pytest

from qz_drake.planning import AStarConfig, astar
from qz_drake.planning.depth_study import DEPTH_STUDY_GAIT
from qz_drake.planning.static_gait import cuboid_terrain, search_gait
from qz_drake.terrain import grid_map_terrain
from qz_drake.terrain.features import build_cost_map
from qz_drake.viz.costmap_plots import plot_search_tree, plot_safety_weight_paths, plot_static_gait


def test_search_tree_of_depth_1_and_4(tmp_path):
    # The terrain of scenarios/static_gait/static_gait_cuboids.yaml: greedy hits a dead end.
    terrain = cuboid_terrain(1, max_height=0.025)
    results = {f"depth {d}": search_gait(terrain, (0.0, 0.0), 0.0, steps=12, depth=d, config=DEPTH_STUDY_GAIT,
                                         record_tree=True) for d in (1, 4)}
    greedy, deep = results["depth 1"], results["depth 4"]
    assert not greedy.success and deep.success
    for result in results.values():
        committed = [n for n in result.tree if n.committed]
        assert [n.step for n in committed] == list(range(len(result.states)))
        assert all(n.ok for n in committed)
        assert len(result.tree) == result.nodes_expanded + sum(not n.ok and n.why in ("swing_collision",
                                                                                     "support_margin")
                                                               for n in result.tree)
    # Greedy checks candidates of one step only; depth 4 looks further and backtracks.
    assert all(n.parent == -1 for n in greedy.tree)
    assert any(n.parent >= 0 for n in deep.tree)
    assert any(n.ok and not n.committed for n in deep.tree)
    png = plot_search_tree(results, tmp_path / "tree.png", max_steps=8)
    assert png.stat().st_size > 5000
    assert plot_static_gait(terrain, deep, tmp_path / "gait.png").stat().st_size > 5000


def test_safety_weight_picture_on_the_real_heightmap(tmp_path):
    """Fig. 13 on grid_map's terrain.png: w2 = 0.9 takes a longer path over lower-cost cells."""
    cost_map = build_cost_map(grid_map_terrain(resolution=0.05, min_height=0.0, max_height=0.4))
    start, goal = (-10.0, -10.0), (10.0, 10.0)
    results = {w: astar(cost_map, start, goal, config=AStarConfig(distance_weight=1 - w, safety_weight=w))
               for w in (0.1, 0.9)}
    assert results[0.9].length > results[0.1].length
    assert results[0.9].mean_cell_cost < results[0.1].mean_cell_cost
    png = plot_safety_weight_paths(cost_map, results, tmp_path / "fig13.png", start_xy=start, goal_xy=goal)
    assert png.stat().st_size > 20000
    # The paths differ somewhere: the picture shows two routes.
    assert not np.array_equal(results[0.1].cells, results[0.9].cells)
