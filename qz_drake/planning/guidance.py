"""From the TLC's guidance path to BLC missions (paper 000 II-E.2, III-B).

"The TLC split the guidance trajectory to many local targets suitable for the ability of
BLC-robot system." The most likely path of the capability MDP is a list of grid actions
(forward one cell, turn 45 deg, each in a topology). Consecutive actions are merged into one
BLC mission while

* the mission stays within the BLC's reach (``max_length`` of translation, ``max_turn`` of
  heading change),
* its predicted success (the product of its actions') stays at least ``min_success``, and
* its actions share one topology: a topology change starts a mission of its own (the BLC
  system then switches the robot's topology before solving it).

With ``turns_with_moves`` the success threshold never leaves a turn in place alone: turns
that would start a mission of their own take the turns and the forward move after them (within
the reach), and the BLC turns while it walks; a turn alone is left only where no move of the
same topology follows within 90 deg. Walks measured why (session 52, CapPlanner's recorded missions
of the tuning and validation walks): on box fields, 24 of 169 turns in place failed executing
(14 %: slips, a leg on a box, a missed heading) and 20 more were refused, against 4 of 365
missions that moved and turned (1 %); the turn network predicted 0.2 % for them.

A mission's target is the cell centre its last action ends in, with the heading it ends in;
with a target shift (:func:`place_targets`) the point of that cell, within the shift of its
centre and on the centre's level, farthest from the terrain's edges.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from qz_drake.capability.patches import CELL_SIZE, HEADING_STEP
from qz_drake.errors import bad_value

# Cell step of a forward move along heading k (k * 45 deg).
_STEPS = ((1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1))


@dataclasses.dataclass(frozen=True)
class MissionSplitConfig:
    # The BLC's reach in one mission (paper 000 Fig. 5: solve time and failures grow with the
    # distance; 2 m is where the stairs cases start to exceed the 5 s limit). [m]
    max_length: float = 2.0
    # Largest heading change in one mission. [rad]
    max_turn: float = math.pi / 2
    # Least predicted success of a merged mission: below it the moves go one mission each, so
    # that a risky move is planned (and fails) alone.
    min_success: float = 0.8
    # Whether turns that would otherwise be a mission of their own go with the forward move
    # that follows them whatever ``min_success`` says (module docstring; on since session 52,
    # False: as before). A refused mission's split into single actions (CapabilityVIPlanner)
    # still turns in place.
    turns_with_moves: bool = True

    def check(self) -> "MissionSplitConfig":
        if not self.max_length >= CELL_SIZE * math.sqrt(2):
            raise bad_value("missions.max_length", self.max_length, "must cover a diagonal move (1.42 m)")
        if not self.max_turn >= HEADING_STEP:
            raise bad_value("missions.max_turn", self.max_turn, "must allow one 45 deg turn")
        if not 0.0 <= self.min_success <= 1.0:
            raise bad_value("missions.min_success", self.min_success, "must be within [0, 1]")
        return self


@dataclasses.dataclass
class GuidedMission:
    """One BLC mission of the guidance: its target, topology and the actions it covers."""

    target: tuple[float, float, float]
    topology: str
    steps: list
    success: float
    # A way back out of a dead end (qz_drake.planning.back_out): no actions of the path; the
    # TLC plans on from its end.
    back_out: bool = False

    @property
    def length(self) -> float:
        return sum(CELL_SIZE * math.hypot(*_STEPS[s.heading]) for s in self.steps if s.motion == "forward")

    def polyline(self) -> np.ndarray:
        """(N, 2) x, y of the cell centres the mission's actions cross, in order (what the
        guidance path visualizer draws)."""
        points = [(self.steps[0].x, self.steps[0].y)] if self.steps else [tuple(self.target[:2])]
        for step in self.steps:
            x, y, _ = _after(step)
            if (x, y) != points[-1]:
                points.append((x, y))
        return np.asarray(points, dtype=float)


def _after(step) -> tuple[float, float, int]:
    """(x, y, heading index) after a path step."""
    if step.motion == "forward":
        dx, dy = _STEPS[step.heading % 8]
        return step.x + dx * CELL_SIZE, step.y + dy * CELL_SIZE, step.heading
    turn = 1 if step.motion == "turn_left" else -1
    return step.x, step.y, (step.heading + turn) % 8


def split_missions(steps, config: MissionSplitConfig = MissionSplitConfig(),
                   start_yaw: float | None = None) -> list[GuidedMission]:
    """Merges a most likely path's steps (qz_drake.planning.capability_mdp.PathStep) into
    BLC missions; yaws are unwrapped from ``start_yaw`` (default: the first step's heading)."""
    config = config.check()
    missions: list[GuidedMission] = []
    current: list = []
    success, turned, length = 1.0, 0.0, 0.0

    def close():
        if current:
            x, y, k = _after(current[-1])
            missions.append(GuidedMission((x, y, k * HEADING_STEP), current[0].action_topology,
                                          list(current), success))

    for step in steps:
        move = CELL_SIZE * math.hypot(*_STEPS[step.heading % 8]) if step.motion == "forward" else 0.0
        turn = 0.0 if step.motion == "forward" else HEADING_STEP
        within = (current and step.action_topology == current[0].action_topology
                  and length + move <= config.max_length + 1e-9 and turned + turn <= config.max_turn + 1e-9)
        # Turns in place alone take more turns or the move after them, whatever their success.
        turns_only = all(s.motion != "forward" for s in current)
        fits = within and (success * step.success >= config.min_success or (config.turns_with_moves and turns_only))
        if not fits:
            close()
            current, success, turned, length = [], 1.0, 0.0, 0.0
        current.append(step)
        success *= step.success
        turned += turn
        length += move
    close()
    # Unwrap the headings along the missions, so that each target's yaw is the previous one's
    # plus the turns in between (no 2 pi jumps for the BLC).
    previous = start_yaw if start_yaw is not None else (steps[0].heading * HEADING_STEP if steps else None)
    for m in missions:
        x, y, yaw = m.target
        if previous is not None:
            yaw = previous + math.remainder(yaw - previous, 2 * math.pi)
        m.target = (x, y, yaw)
        previous = yaw
    return missions


# place_targets: the clearance from edges a target is moved towards, and the least a move must
# gain of it. Walks measured the clearance (session 53, CapPlanner's recorded missions of the
# tuning walks on box fields): turns in place from within 0.2 m of an edge failed walking 41 of
# 96 times, from 0.2-0.3 m 11 of 57, from farther about 2 %; 0.4 m is also the turns' edge
# reach in the MDP (CapabilityMdpConfig.turn_edge_reach). The least gain leaves stairs alone: a
# stairs run (0.4 m) has no point more than 0.2 m from a riser, so a target on a run moves
# only off the riser itself. [m]
TARGET_CLEARANCE = 0.4
TARGET_MIN_GAIN = 0.2


def check_target_shift(value, field: str = "target_shift") -> float:
    """A target shift (:func:`place_targets`) as a float in [0, half a cell); anything else names
    ``field``."""
    try:
        if isinstance(value, bool):
            raise TypeError(value)
        shift = float(value)
    except (TypeError, ValueError):
        raise bad_value(field, value, "must be a number in metres") from None
    if not 0.0 <= shift < CELL_SIZE / 2:
        raise bad_value(field, value, f"must be at least 0 and less than half a cell ({CELL_SIZE / 2:g} m)")
    return shift


def placed_target(heightmap, distance, x: float, y: float, max_shift: float,
                  edge_height: float) -> tuple[float, float]:
    """The point within ``max_shift`` of (x, y) to stand at instead of (x, y): on the same level
    as (x, y) (its height within ``edge_height``) and as clear of edges as any there, up to
    TARGET_CLEARANCE, the nearest such to (x, y); (x, y) itself unless that gains at least
    TARGET_MIN_GAIN of clearance. ``distance`` is the heightmap's distance from edges
    (qz_drake.planning.capability_mdp.edge_distances; None: a map without edges). [m]"""
    if distance is None or max_shift <= 0.0 or not heightmap.contains(x, y):
        return x, y
    res = heightmap.resolution
    n = int(math.floor(max_shift / res + 1e-9))
    offsets = np.arange(-n, n + 1) * res
    dx, dy = (a.ravel() for a in np.meshgrid(offsets, offsets))
    within = np.hypot(dx, dy) <= max_shift + 1e-9
    dx, dy = dx[within], dy[within]
    on_map = heightmap.contains(x + dx, y + dy)
    dx, dy = dx[on_map], dy[on_map]
    ix, iy = heightmap.index(x + dx, y + dy)
    cx, cy = heightmap.index(x, y)
    level = np.abs(heightmap.heights[iy, ix] - heightmap.heights[cy, cx]) <= edge_height
    clearance = np.where(level, np.minimum(distance[iy, ix], TARGET_CLEARANCE), -np.inf)
    best = float(clearance.max())
    if best - min(float(distance[cy, cx]), TARGET_CLEARANCE) < TARGET_MIN_GAIN - 1e-9:
        return x, y
    candidates = np.flatnonzero(clearance >= best - 1e-9)
    pick = candidates[np.argmin(np.hypot(dx[candidates], dy[candidates]))]
    return x + float(dx[pick]), y + float(dy[pick])


def place_targets(missions, heightmap, distance, max_shift: float, edge_height: float,
                  keep_last: bool = False) -> list:
    """``missions`` with each target (but a back-out's, and the last's with ``keep_last``: a
    goal) moved to :func:`placed_target` of it, the heading kept. A robot standing at a cell's
    centre a few centimetres from a box's side (the grid is anchored at the start, so centres
    fall anywhere) is refused there by the BLC or turns with a leg against the box; the
    point beside it clear of the box is in the same cell: the same state of the map's grid."""
    for i, m in enumerate(missions):
        if m.back_out or (keep_last and i == len(missions) - 1):
            continue
        x, y, yaw = m.target
        m.target = (*placed_target(heightmap, distance, x, y, max_shift, edge_height), yaw)
    return missions


def route_ahead(missions, distance: float) -> list[tuple[float, float]]:
    """The cell centres (x, y) a route of GuidedMissions crosses within its first ``distance``
    of travel, in order (a turn in place adds none): what two routes from one state are
    compared on. [m]"""
    cells, travelled = [], 0.0
    for m in missions:
        for x, y in m.polyline():
            point = (round(float(x), 6), round(float(y), 6))
            if cells and point == cells[-1]:
                continue
            if cells:
                travelled += math.dist(cells[-1], point)
                if travelled > distance + 1e-9:
                    return cells
            cells.append(point)
    return cells
