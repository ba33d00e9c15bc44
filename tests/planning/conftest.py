"""A brute-force reference for the grid planners: textbook Dijkstra with heapq."""

import heapq
import math

import numpy as np
import pytest

MOVES = [(0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1), (-1, 0), (-1, 1)]


def dijkstra_costs(costs, start, *, distance_weight=0.0, connectivity=8):
    """Cost from ``start`` to every cell. costs: (H, W) or (8, H, W); move k from a to b costs
    length * (distance_weight + (C[k or 0][a] + C[k or 0][b]) / 2); no corner cutting past a
    cell that is inf in every direction."""
    costs = np.asarray(costs, dtype=float)
    directional = costs.ndim == 3
    free = np.isfinite(costs).any(axis=0) if directional else np.isfinite(costs)
    H, W = free.shape
    dist = np.full((H, W), math.inf)
    dist[start] = 0.0
    queue = [(0.0, start)]
    while queue:
        d, (r, c) = heapq.heappop(queue)
        if d > dist[r, c]:
            continue
        for k, (dr, dc) in enumerate(MOVES):
            if connectivity == 4 and k % 2:
                continue
            nr, nc = r + dr, c + dc
            if not (0 <= nr < H and 0 <= nc < W) or not free[nr, nc]:
                continue
            if dr and dc and not (free[r, nc] and free[nr, c]):
                continue
            grid = costs[k] if directional else costs
            step = math.hypot(dr, dc) * (distance_weight + 0.5 * (grid[r, c] + grid[nr, nc]))
            if d + step < dist[nr, nc]:
                dist[nr, nc] = d + step
                heapq.heappush(queue, (d + step, (nr, nc)))
    return dist


@pytest.fixture
def dijkstra():
    return dijkstra_costs
