"""A* for the body centre over a direction-dependent cost map (paper 003, section 2.3, Eq. 16-20).

The extracted paper lost its symbols; this is how we reconstructed the equations.

* Eq. 16, the cost of cell g for heading d: ``C(g, d) = w_b C_body(g) + w_f C_feet(g, d)``
  with w_b + w_f = 1, both terms in [0, 1] (``CostMap.heading_cost``, terrain/features.py).
* Eq. 18, the heading of a move is fixed by the two cells: d = atan2(dy, dx), one of the
  8 directions k * pi / 4.
* Eq. 17, the edge cost from cell i to its neighbour j:
  ``E(i, j) = |p_j - p_i| * (w_1 + w_2 * (C(i, d_ij) + C(j, d_ij)) / 2)``, |p_j - p_i| the
  metric distance (the cell sizes r_x = r_y = resolution times 1 or sqrt 2), w_1 + w_2 = 1
  (we normalise the given weights). w_1 prices distance, w_2 safety: the larger w_2, the more
  the path detours through cheap cells. We integrate the safety term over the move's length so
  that a diagonal through costly cells is not cheaper than the two straight moves it replaces.
* Eq. 19-20, the heuristic: ``h(n) = (w_1 + w_2 C_min) * octile(n, goal)`` in metres, C_min the
  cheapest finite cell cost. Every move to the goal costs at least (w_1 + w_2 C_min) per metre
  and covers at most its octile distance, so h(n) <= E(n, m) + h(m) (Eq. 20, consistency) and
  A* is optimal. The paper's Euclidean form is also consistent; the octile form is tighter on an
  8-connected grid and expands fewer cells.

No move cuts the corner of a blocked cell. The search itself is ``grid_search.search_directional``.
"""

import dataclasses
import math

import numpy as np

from qz_drake.errors import bad_value
from qz_drake.planning.grid_search import MOVE_HEADINGS, GridPath, _check_costs, search_directional
from qz_drake.terrain.features import CostMap


@dataclasses.dataclass
class AStarConfig:
    # Weight of distance, w_1 in Eq. 17; normalised with safety_weight to sum 1.
    distance_weight: float = 0.5
    # Weight of safety, w_2 in Eq. 17: larger values trade length for cheaper terrain.
    safety_weight: float = 0.5
    # Factor on the heuristic: 1 keeps A* optimal; > 1 is faster and at most that much costlier.
    heuristic_weight: float = 1.0


@dataclasses.dataclass(frozen=True)
class AStarResult:
    """A body-centre path over a cost map, or why there is none."""

    # True when the goal was reached.
    found: bool
    # "found", or why not (blocked start or goal, unreachable goal).
    reason: str
    # (K, 2) int cells (row, col) from start to goal; (0, 2) when not found.
    cells: np.ndarray
    # (K, 2) world (x, y) of the cell centres. [m]
    xy: np.ndarray
    # (K,) heading of the body at each point: of the move that reaches it (the first point
    # takes the first move's). [rad]
    headings: np.ndarray
    # Total edge cost of Eq. 17 (metre-weighted); inf when not found.
    cost: float
    # Path length. [m]
    length: float
    # Length-weighted mean of the Eq. 16 cost along the path, in [0, 1]; nan when not found.
    mean_cell_cost: float
    # Cells taken off the open list.
    expansions: int
    # Search wall time. [s]
    time_s: float
    config: AStarConfig


def _weights(config: AStarConfig) -> tuple[float, float]:
    w = []
    for name in ("distance_weight", "safety_weight"):
        value = getattr(config, name)
        try:
            v = float(value)
        except (TypeError, ValueError):
            v = math.nan
        if not (math.isfinite(v) and v >= 0):
            raise bad_value(f"astar.{name}", value, "must be a finite number >= 0")
        w.append(v)
    if w[0] + w[1] <= 0:
        raise bad_value("astar.safety_weight", config.safety_weight,
                        "distance_weight and safety_weight must not both be 0")
    total = w[0] + w[1]
    return w[0] / total, w[1] / total


def astar_grid(heading_cost, start, goal, *, resolution: float = 1.0, origin=(0.0, 0.0),
               config: AStarConfig | None = None) -> AStarResult:
    """A* between two cells (row, col) of an (8, H, W) direction-dependent cost map (Eq. 16).

    heading_cost[k] is the cost of each cell for a body moving along heading k * pi / 4; inf
    marks blocked cells. A start or goal off the map raises ConfigError; a blocked start or
    goal, or an unreachable goal, gives ``found=False`` with a reason.
    """
    config = config or AStarConfig()
    w_distance, w_safety = _weights(config)
    if not (math.isfinite(resolution) and resolution > 0):
        raise bad_value("resolution", resolution, "must be finite and positive")
    costs = _check_costs("heading_cost", heading_cost, 3)
    # Edge cost in metres: length_cells * resolution * (w_1 + w_2 * mean C); blocked cells stay
    # blocked when w_2 = 0 (inf * 0 would be nan).
    with np.errstate(invalid="ignore"):
        scaled = costs * (w_safety * resolution)
    scaled[np.isinf(costs)] = np.inf
    result: GridPath = search_directional(scaled, start, goal,
                                          distance_weight=w_distance * resolution,
                                          heuristic_weight=config.heuristic_weight)
    return _result(result, costs, resolution, origin, config)


def astar(cost_map: CostMap, start_xy, goal_xy, *, config: AStarConfig | None = None) -> AStarResult:
    """Body-centre path between two world points (x, y) [m] over a CostMap (Eq. 16-20).

    Points are snapped to the nearest cell; a point off the map raises ConfigError naming
    ``start`` or ``goal`` with its value.
    """
    H, W = cost_map.shape
    cells = []
    for name, point in (("start", start_xy), ("goal", goal_xy)):
        try:
            x, y = (float(v) for v in point)
        except (TypeError, ValueError):
            raise bad_value(name, point, "expected a world point (x, y) in metres") from None
        reason = off_map(cost_map, x, y)
        if reason:
            raise bad_value(name, (x, y), reason)
        cells.append(cost_map.cell(x, y))
    return astar_grid(cost_map.heading_cost(), cells[0], cells[1], resolution=cost_map.resolution,
                      origin=cost_map.origin, config=config)


def off_map(cost_map: CostMap, x: float, y: float) -> str:
    """Why the world point (x, y) [m] is off the cost map ("off the map (x in [..], y in [..])"),
    or "" where its nearest cell is on it."""
    H, W = cost_map.shape
    row, col = cost_map.cell(x, y)
    if 0 <= row < H and 0 <= col < W:
        return ""
    x0, y0 = cost_map.origin
    x1, y1 = x0 + (W - 1) * cost_map.resolution, y0 + (H - 1) * cost_map.resolution
    return f"off the map (x in [{x0:g}, {x1:g}], y in [{y0:g}, {y1:g}])"


def _result(path: GridPath, costs: np.ndarray, resolution: float, origin, config: AStarConfig) -> AStarResult:
    origin = tuple(float(v) for v in origin)
    cells = path.path
    xy = np.stack([origin[0] + cells[:, 1] * resolution, origin[1] + cells[:, 0] * resolution], axis=1)
    if not path.found:
        return AStarResult(False, path.reason, cells, xy, np.zeros(0), math.inf, math.nan, math.nan,
                           path.expansions, path.time_s, config)
    moves = path.move_indices
    headings = MOVE_HEADINGS[moves]
    headings = np.concatenate([headings[:1], headings]) if len(moves) else np.zeros(1)
    lengths = np.where(moves % 2 == 1, math.sqrt(2.0), 1.0) * resolution
    length = float(lengths.sum())
    r, c = cells[:, 0], cells[:, 1]
    mean_cost = 0.5 * (costs[moves, r[:-1], c[:-1]] + costs[moves, r[1:], c[1:]])
    mean_cell_cost = float((lengths * mean_cost).sum() / length) if length > 0 else float(
        costs[:, r[0], c[0]].min())
    return AStarResult(True, "found", cells, xy, headings, path.cost, length, mean_cell_cost,
                       path.expansions, path.time_s, config)

