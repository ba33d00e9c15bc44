"""Cost-map planning speed (paper 003): grid A* against pyastar2d, and the terrain features.

``bench_astar``: ``grid_search`` on a 1000 x 1000 random weighted grid (costs uniform in
[1, 10], seed 0, no blocked cells, so that pyastar2d's corner cutting cannot matter), corner
to corner, against ``pyastar2d`` (C++) on the
same array in the same run. The two use different cost conventions, so we compare them on the
same inputs and report what each optimises:

* 8-connected (timed): ours costs a move length x mean of the two cells and forbids cutting
  corners; pyastar2d costs a move the weight of the cell entered, diagonal or not, and may cut
  corners (which is why the map has no blocked cells: with them, pyastar2d's paths squeeze
  diagonally between blocked cells and leave our graph). Both are optimal for their own
  convention; we time both and also price pyastar2d's path in our convention (it can only be
  costlier, a check that ours is optimal).
* 4-connected (a correctness check): here the conventions agree up to a constant, since the
  sum of cell means along a path is the sum of entered cells minus (c_goal - c_start) / 2, so
  the two optimal costs must match exactly.

pyastar2d is optional (``pip install qz_drake[bench]``); without it the absolute times are
reported and ``pyastar2d`` says why it is missing.

``bench_costmap``: slope, roughness and step height (``body_features``) on a 1000 x 1000 map of
0.05 m cells (the grid_map test field tiled 2 x 2), and the full cost map (plus the foothold
features and the six feet's cost for the 8 headings). Medians of ``repeats`` runs.
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from qz_drake.planning.grid_search import grid_search, warm_up
from qz_drake.terrain import grid_map_terrain
from qz_drake.terrain.features import body_features, build_cost_map


def _random_grid(size: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(1.0, 10.0, (size, size))


def _path_cost(cost: np.ndarray, path: np.ndarray) -> float:
    """A path's cost in grid_search's convention (length x mean of the two cells)."""
    a, b = path[:-1], path[1:]
    length = np.where(np.abs(b - a).sum(axis=1) == 2, np.sqrt(2.0), 1.0)
    return float((length * 0.5 * (cost[a[:, 0], a[:, 1]] + cost[b[:, 0], b[:, 1]])).sum())


def _median_time(fn, repeats: int):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times, out


def bench_astar(repeats: int = 5, quick: bool = False, size: int = 1000) -> dict:
    """Median wall time of grid_search (whole call, checks included) and of pyastar2d."""
    if quick:
        repeats, size = 1, 300
    cost = _random_grid(size)
    start, goal = (0, 0), (size - 1, size - 1)
    warm_up()
    ours_s, ours_times, ours = _median_time(lambda: grid_search(cost, start, goal), repeats)
    out = {"map": f"{size}x{size} random costs uniform in [1, 10], none blocked, seed 0, corner to corner",
           "repeats": repeats, "grid_search_s": ours_s, "grid_search_times_s": ours_times,
           "grid_search_cost": ours.cost, "grid_search_expansions": ours.expansions,
           "grid_search_path_cells": len(ours.path)}
    try:
        import pyastar2d
    except ImportError as e:
        out["pyastar2d"] = f"not installed ({e}); pip install 'qz_drake[bench]'"
        return out
    weights = cost.astype(np.float32)
    theirs_s, theirs_times, theirs = _median_time(
        lambda: pyastar2d.astar_path(weights, start, goal, allow_diagonal=True), repeats)
    out.update({"pyastar2d_s": theirs_s, "pyastar2d_times_s": theirs_times,
                "ratio_grid_search_to_pyastar2d": ours_s / theirs_s,
                "pyastar2d_path_cells": len(theirs),
                "pyastar2d_path_cost_in_our_convention": _path_cost(cost, theirs)})
    # 4-connected: the conventions agree up to (c_goal - c_start) / 2.
    ours4 = grid_search(cost, start, goal, connectivity=4)
    theirs4 = pyastar2d.astar_path(weights, start, goal, allow_diagonal=False)
    entered = float(weights[theirs4[1:, 0], theirs4[1:, 1]].astype(float).sum())
    offset = 0.5 * (cost[goal] - cost[start])
    out["4_connected_costs_agree"] = bool(abs(ours4.cost - (entered - offset)) < 1e-3 * max(1.0, ours4.cost))
    return out


def _terrain(size: int) -> np.ndarray:
    heights = grid_map_terrain().heights
    reps = -(-size // heights.shape[0])
    return np.tile(heights, (reps, reps))[:size, :size]


def bench_costmap(repeats: int = 5, quick: bool = False, size: int = 1000) -> dict:
    """Median wall time of the three body features and of the whole cost map, 0.05 m cells."""
    if quick:
        repeats, size = 1, 300
    heights = _terrain(size)
    features_s, features_times, _ = _median_time(lambda: body_features(heights, 0.05), repeats)
    cost_map_s, cost_map_times, cost_map = _median_time(lambda: build_cost_map(heights, 0.05), repeats)
    return {"map": f"{size}x{size} cells of 0.05 m (grid_map terrain.png tiled, 0-0.4 m)",
            "repeats": repeats, "body_features_s": features_s, "body_features_times_s": features_times,
            "cost_map_s": cost_map_s, "cost_map_times_s": cost_map_times,
            "traversable_fraction": float(cost_map.traversable.mean())}


if __name__ == "__main__":
    import json
    import sys

    quick = "--quick" in sys.argv
    print(json.dumps({"astar": bench_astar(quick=quick), "costmap": bench_costmap(quick=quick)}, indent=2))
