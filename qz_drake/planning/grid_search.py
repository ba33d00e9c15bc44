"""Optimal search on an 8-connected weighted grid: the engine under every grid planner.

``grid_search`` is the plain form (one cost per cell); ``search_directional`` is the form the
cost-map A* of paper 003 (section 2.3, Eq. 16-20) needs, where a cell's cost depends on the
direction the body moves through it. Both run the same compiled A* (numba), because a heapq
loop in Python is two orders of magnitude too slow for the 1000 x 1000 maps the planners use.

Conventions shared by both forms:

* a cell is (row, col); row r lies at y = origin_y + r * resolution, col c at x = origin_x +
  c * resolution, as in ``HeightMap.heights[iy, ix]``;
* the 8 moves are numbered k = 0..7 counter-clockwise from +x (east): heading k * pi / 4, so
  ``MOVES[k] = (drow, dcol)``; even k are straight moves of length 1, odd k diagonal, sqrt(2);
* ``inf`` marks a blocked cell; a diagonal move may not cut the corner of a blocked cell (both
  orthogonal cells it passes between must be free), which is the Moving AI benchmark rule;
* the heuristic is the octile distance times the cheapest possible cost per unit length, so it
  is consistent (and admissible) and the search returns an optimal path when
  ``heuristic_weight`` is 1 (0 gives Dijkstra; above 1 a faster, at most that much costlier
  weighted A*).

A goal that cannot be reached, or a start or goal on a blocked cell, is a result
(``found=False`` with a reason). A start or goal outside the map is a user error and raises
``ConfigError`` naming ``start`` or ``goal``.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numba
import numpy as np

from qz_drake.errors import bad_value

MOVES = np.array([(0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1), (-1, 0), (-1, 1)], dtype=np.int64)
"""(drow, dcol) of move k; its heading in the world frame is k * pi / 4 (0 = +x, 2 = +y)."""

MOVE_LENGTHS = np.array([1.0, math.sqrt(2.0)] * 4)
"""Length of move k in cells."""

MOVE_HEADINGS = np.arange(8) * (math.pi / 4.0)
"""Heading of move k in the world frame. [rad]"""

SQRT2 = math.sqrt(2.0)


@dataclasses.dataclass(frozen=True)
class GridPath:
    """The outcome of a grid search."""

    # True when a path from start to goal exists and was found.
    found: bool
    # (K, 2) int64 cells (row, col) from start to goal; (0, 2) when not found.
    path: np.ndarray
    # Total cost of the path in the search's cost units; inf when not found.
    cost: float
    # Number of cells taken off the open list.
    expansions: int
    # "found", or why not: "start (r, c) is blocked", "goal ... is blocked", "goal unreachable".
    reason: str
    # Wall time of the search, compilation excluded after the first call. [s]
    time_s: float = 0.0

    @property
    def length(self) -> float:
        """Geometric length of the path in cells (1 per straight move, sqrt 2 per diagonal)."""
        if len(self.path) < 2:
            return 0.0
        steps = np.abs(np.diff(self.path, axis=0)).sum(axis=1)
        return float(np.count_nonzero(steps == 1) + SQRT2 * np.count_nonzero(steps == 2))

    @property
    def move_indices(self) -> np.ndarray:
        """(K-1,) index k into MOVES of each move along the path."""
        if len(self.path) < 2:
            return np.zeros(0, dtype=np.int64)
        d = np.diff(self.path, axis=0)
        # Heading index from (drow, dcol): atan2(drow, dcol) in units of pi/4.
        return np.rint(np.arctan2(d[:, 0], d[:, 1]) / (math.pi / 4.0)).astype(np.int64) % 8


# -- the compiled search ------------------------------------------------------------------------
# The open list is an indexed binary heap whose entries carry their keys (f, then g), so that
# sifting reads contiguous memory; pos[node] locates a node for decrease-key, so every cell
# is in the heap at most once.
@numba.njit(cache=True, inline="always")
def _before(fa, ga, fb, gb):
    """Heap order: lower f first; on ties the deeper node (larger g), which ends A* sooner."""
    return fa < fb or (fa == fb and ga > gb)


@numba.njit(cache=True)
def _sift_up(heap, hf, hg, pos, i, node, f, g):
    while i > 0:
        parent = (i - 1) >> 1
        if _before(f, g, hf[parent], hg[parent]):
            other = heap[parent]
            heap[i] = other
            hf[i] = hf[parent]
            hg[i] = hg[parent]
            pos[other] = i
            i = parent
        else:
            break
    heap[i] = node
    hf[i] = f
    hg[i] = g
    pos[node] = i


@numba.njit(cache=True)
def _sift_down(heap, hf, hg, pos, size, node, f, g):
    i = 0
    while True:
        child = 2 * i + 1
        if child >= size:
            break
        if child + 1 < size and _before(hf[child + 1], hg[child + 1], hf[child], hg[child]):
            child += 1
        if _before(hf[child], hg[child], f, g):
            other = heap[child]
            heap[i] = other
            hf[i] = hf[child]
            hg[i] = hg[child]
            pos[other] = i
            i = child
        else:
            break
    heap[i] = node
    hf[i] = f
    hg[i] = g
    pos[node] = i


@numba.njit(cache=True)
def _astar(costs, free, start, goal, connectivity, distance_weight, heuristic_scale):
    """A* over cells; returns (cost to goal, parent array, expansions).

    costs: (D, H, W), D = 1 (one cost per cell) or 8 (a cost per cell and move direction k).
    Move k from a to b costs MOVE_LENGTHS[k] * (distance_weight + (costs[d, a] + costs[d, b]) / 2)
    with d = 0 or k. free: (H, W) bool, the cells a diagonal may pass beside.

    Internally cells are numbered on the map framed by one ring of blocked cells, so a
    neighbour needs no bounds check; parent holds unframed flat indices.
    """
    D, H, W = costs.shape
    Wp = W + 2
    n = (H + 2) * Wp
    # 0 unseen, 1 open, 2 closed, 3 blocked (or the frame).
    state = np.full(n, np.int8(3))
    for r in range(H):
        for c in range(W):
            if free[r, c]:
                state[(r + 1) * Wp + c + 1] = 0
    g = np.full(n, np.inf)
    parent = np.full(n, -1, dtype=np.int32)
    pos = np.empty(n, dtype=np.int32)
    heap = np.empty(H * W, dtype=np.int32)
    hf = np.empty(H * W)
    hg = np.empty(H * W)
    drow = (0, 1, 1, 1, 0, -1, -1, -1)
    dcol = (1, 1, 0, -1, -1, -1, 0, 1)
    offset = np.empty(8, dtype=np.int64)
    for k in range(8):
        offset[k] = drow[k] * Wp + dcol[k]
    step = 1 if connectivity == 8 else 2
    goal_r, goal_c = goal // W + 1, goal % W + 1
    goal_p = goal_r * Wp + goal_c

    def heuristic(r, c):
        dr = abs(r - goal_r)
        dc = abs(c - goal_c)
        if connectivity == 4:
            return heuristic_scale * (dr + dc)
        lo = min(dr, dc)
        return heuristic_scale * (max(dr, dc) - lo + SQRT2 * lo)

    sr, sc = start // W + 1, start % W + 1
    start_p = sr * Wp + sc
    g[start_p] = 0.0
    state[start_p] = 1
    _sift_up(heap, hf, hg, pos, 0, start_p, heuristic(sr, sc), 0.0)
    size = 1
    expansions = 0
    while size > 0:
        cur = heap[0]
        size -= 1
        if size > 0:
            _sift_down(heap, hf, hg, pos, size, heap[size], hf[size], hg[size])
        state[cur] = 2
        expansions += 1
        if cur == goal_p:
            break
        r, c = cur // Wp, cur % Wp
        g_cur = g[cur]
        for k in range(0, 8, step):
            nb = cur + offset[k]
            if state[nb] >= 2:
                continue
            length = 1.0
            if k & 1:
                # No corner cutting: both cells the diagonal passes between must be free.
                if state[cur + dcol[k]] == 3 or state[cur + drow[k] * Wp] == 3:
                    continue
                length = SQRT2
            d = 0 if D == 1 else k
            nr, nc = r + drow[k], c + dcol[k]
            edge = length * (distance_weight + 0.5 * (costs[d, r - 1, c - 1] + costs[d, nr - 1, nc - 1]))
            g_new = g_cur + edge
            if g_new < g[nb]:
                g[nb] = g_new
                parent[nb] = cur
                f_new = g_new + heuristic(nr, nc)
                if state[nb] == 0:
                    state[nb] = 1
                    size += 1
                    _sift_up(heap, hf, hg, pos, size - 1, nb, f_new, g_new)
                else:
                    _sift_up(heap, hf, hg, pos, pos[nb], nb, f_new, g_new)
    # Back to unframed indices.
    out = np.full(H * W, -1, dtype=np.int32)
    cost = g[goal_p]
    if cost < np.inf:
        node = goal_p
        while parent[node] >= 0:
            prev = parent[node]
            out[(node // Wp - 1) * W + node % Wp - 1] = (prev // Wp - 1) * W + prev % Wp - 1
            node = prev
    return cost, out, expansions


def _trace(parent: np.ndarray, goal: int, width: int) -> np.ndarray:
    cells = [goal]
    while parent[cells[-1]] >= 0:
        cells.append(int(parent[cells[-1]]))
    flat = np.array(cells[::-1], dtype=np.int64)
    return np.stack([flat // width, flat % width], axis=1)


# -- argument checks ----------------------------------------------------------------------------
def _cell(name: str, value, shape: tuple[int, int]) -> tuple[int, int]:
    try:
        r, c = (int(v) for v in value)
        if (r, c) != tuple(value):
            raise ValueError
    except (TypeError, ValueError):
        raise bad_value(name, value, "expected a cell (row, col) of two integers") from None
    H, W = shape
    if not (0 <= r < H and 0 <= c < W):
        raise bad_value(name, value, f"outside the {H} x {W} map (rows 0..{H - 1}, cols 0..{W - 1})")
    return r, c


def _check_weight(name: str, value: float, *, minimum: float = 0.0) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise bad_value(name, value, "not a number") from None
    if not (math.isfinite(v) and v >= minimum):
        raise bad_value(name, value, f"must be finite and >= {minimum}")
    return v


def _check_costs(name: str, costs, ndim: int) -> np.ndarray:
    c = np.ascontiguousarray(costs, dtype=np.float64)
    if c.ndim != ndim or c.shape[-1] < 1 or c.shape[-2] < 1 or (ndim == 3 and c.shape[0] != 8):
        want = "(H, W)" if ndim == 2 else "(8, H, W)"
        raise bad_value(name, f"array of shape {c.shape}", f"expected shape {want}")
    bad = np.isnan(c) | (c < 0)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise bad_value(f"{name}[{', '.join(map(str, idx))}]", float(c[idx]),
                        "costs must be >= 0 or inf (blocked)")
    return c


def _run(costs3: np.ndarray, free: np.ndarray, start, goal, *, connectivity: int, distance_weight: float,
         heuristic_weight: float) -> GridPath:
    H, W = free.shape
    start, goal = _cell("start", start, (H, W)), _cell("goal", goal, (H, W))
    if connectivity not in (4, 8):
        raise bad_value("connectivity", connectivity, "expected 4 or 8")
    heuristic_weight = _check_weight("heuristic_weight", heuristic_weight)
    empty = np.zeros((0, 2), dtype=np.int64)
    if not free[start]:
        return GridPath(False, empty, math.inf, 0, f"start {start} is blocked")
    if not free[goal]:
        return GridPath(False, empty, math.inf, 0, f"goal {goal} is blocked")
    cheapest = float(np.min(costs3, initial=np.inf, where=np.isfinite(costs3)))
    # Cheapest cost per unit length any move can have: keeps the octile heuristic a lower bound.
    per_length = distance_weight + (cheapest if math.isfinite(cheapest) else 0.0)
    t0 = time.perf_counter()
    cost, parent, expansions = _astar(costs3, free, start[0] * W + start[1], goal[0] * W + goal[1],
                                      connectivity, distance_weight, heuristic_weight * per_length)
    elapsed = time.perf_counter() - t0
    if not math.isfinite(cost):
        return GridPath(False, empty, math.inf, int(expansions), "goal unreachable", elapsed)
    return GridPath(True, _trace(parent, goal[0] * W + goal[1], W), float(cost), int(expansions), "found",
                    elapsed)


# -- public API ---------------------------------------------------------------------------------
def grid_search(cell_cost, start, goal, *, heuristic_weight: float = 1.0, connectivity: int = 8) -> GridPath:
    """Cheapest path between two cells of a weighted grid (A*, optimal for heuristic_weight 1).

    A move between neighbouring cells costs its length (1 or sqrt 2 cells) times the mean of
    the two cells' costs; a diagonal may not cut the corner of a blocked cell.

    Args:
        cell_cost: (H, W) costs >= 0 per unit length; ``inf`` marks a blocked cell. NaN or
            negative entries raise ConfigError naming ``cell_cost[r, c]``.
        start: (row, col) of the start cell.
        goal: (row, col) of the goal cell.
        heuristic_weight: factor on the octile heuristic: 1 optimal A*, 0 Dijkstra, > 1
            weighted A* (faster; cost at most that factor above the optimum).
        connectivity: 8 (default) or 4 (straight moves only).

    Returns:
        GridPath; ``found`` is False with a reason for a blocked start or goal or an
        unreachable goal. A start or goal off the map raises ConfigError.
    """
    costs = _check_costs("cell_cost", cell_cost, 2)
    free = np.isfinite(costs)
    return _run(costs[None], free, start, goal, connectivity=connectivity, distance_weight=0.0,
                heuristic_weight=heuristic_weight)


def search_directional(heading_cost, start, goal, *, distance_weight: float = 0.0,
                       heuristic_weight: float = 1.0) -> GridPath:
    """Cheapest path when a cell's cost depends on the direction of the move (8-connected).

    Move k (see MOVES) from cell a to cell b costs
    ``MOVE_LENGTHS[k] * (distance_weight + (heading_cost[k, a] + heading_cost[k, b]) / 2)``:
    a cost per unit length for distance plus the mean of both cells' costs for that heading.
    A cell whose cost is ``inf`` for every heading is blocked, and diagonals may not cut its
    corner; a cell that is ``inf`` for some headings only cannot be entered or left that way.

    Args:
        heading_cost: (8, H, W) costs >= 0 (or inf) per unit length.
        start, goal: (row, col) cells.
        distance_weight: cost per unit length added to every move (>= 0).
        heuristic_weight: as in grid_search.
    """
    costs = _check_costs("heading_cost", heading_cost, 3)
    distance_weight = _check_weight("distance_weight", distance_weight)
    free = np.isfinite(costs).any(axis=0)
    return _run(costs, free, start, goal, connectivity=8, distance_weight=distance_weight,
                heuristic_weight=heuristic_weight)


def warm_up() -> None:
    """Compiles the search (or loads it from numba's cache) so a timed call measures search only."""
    grid_search(np.ones((3, 3)), (0, 0), (2, 2))
