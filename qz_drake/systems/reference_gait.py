"""A kinematic alternating-tripod walking plan: the heuristic the BLC's optimisation improves on.

Body: minimum-jerk motion from start to goal (position and yaw), at the standing height above
the mean ground under its nominal footholds. Feet: tripod A (MF, RB, LB) and B (MB, RF, LF)
swing in alternate phases of equal length; each foot lands on the nominal foothold of the body
pose half a stance later (a Raibert-style placement that keeps the foot centred in its
kinematic box), at the terrain's height, and swings over the ground between with a fixed apex
clearance. Stance feet share the body weight equally. It is a BodyFeetTrajectory for the
InverseKinematicsTracker, a fallback when an optimisation fails, and an initial guess.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from qz_drake.config import MissionTiming
from qz_drake.errors import ConfigError, bad_value
from qz_drake.robot.params import DEFAULT_PARAMS, NUM_LEGS, TRIPOD_A, TRIPOD_B, QingzhuiParams
from qz_drake.robot.topology import Topology

GRAVITY = 9.81
# Fraction of a swing in which the foot covers its horizontal distance.
SWING_HORIZONTAL_FRACTION = 0.75
# Foothold selection: search radius around the nominal foothold [m] (inside the kinematic
# box), grid step [m], clearance radius a safe point needs [m], and the height variation
# tolerated within it [m].
FOOTHOLD_SEARCH = 0.15
FOOTHOLD_GRID = 0.02
FOOTHOLD_CLEARANCE = 0.045
FOOTHOLD_STEP = 0.02
# A level spot is still no foothold when it is the floor of a narrow gap: ground higher by
# more than FOOTHOLD_PIT_DEPTH on both sides within FOOTHOLD_PIT_RADIUS would catch the shank on
# the edge (paper 000 Fig. 2). [m]
FOOTHOLD_PIT_RADIUS = 0.2
FOOTHOLD_PIT_DEPTH = 0.05


def _offsets() -> np.ndarray:
    g = np.arange(-FOOTHOLD_SEARCH, FOOTHOLD_SEARCH + 1e-9, FOOTHOLD_GRID)
    d = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    d = d[np.linalg.norm(d, axis=1) <= FOOTHOLD_SEARCH + 1e-9]
    return d[np.argsort(np.linalg.norm(d, axis=1), kind="stable")]


_FOOTHOLD_OFFSETS = _offsets()
_RING = np.array([[FOOTHOLD_CLEARANCE * np.cos(a), FOOTHOLD_CLEARANCE * np.sin(a)]
                  for a in np.linspace(0, 2 * np.pi, 12, endpoint=False)] + [[0.0, 0.0]])
# Four opposite pairs of directions at FOOTHOLD_PIT_RADIUS: [pair, side, xy].
_PIT_PAIRS = np.array([[[FOOTHOLD_PIT_RADIUS * np.cos(a), FOOTHOLD_PIT_RADIUS * np.sin(a)],
                        [-FOOTHOLD_PIT_RADIUS * np.cos(a), -FOOTHOLD_PIT_RADIUS * np.sin(a)]]
                       for a in np.linspace(0, np.pi, 4, endpoint=False)])


def _min_jerk(s):
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (10 - 15 * s + 6 * s**2)


@dataclasses.dataclass
class TripodGaitPlan:
    """Body and feet of an alternating tripod walk; satisfies BodyFeetTrajectory."""

    heightmap: object
    topology: Topology
    start_xy_yaw: tuple[float, float, float]
    goal_xy_yaw: tuple[float, float, float]
    start_time: float
    duration: float
    # Duration of one swing (= one stance) phase. [s]
    phase_duration: float = MissionTiming.phase_duration
    # Swing apex above the higher of lift-off, landing and the ground in between. [m]
    swing_clearance: float = 0.08
    params: QingzhuiParams = DEFAULT_PARAMS
    # Measured foot-sphere centres at the start (6, 3); None: nominal footholds on the ground.
    start_feet_W: np.ndarray | None = None

    def __post_init__(self):
        if not self.duration > 0:
            raise bad_value("duration", self.duration, "must be positive", ConfigError)
        if not self.phase_duration > 0:
            raise bad_value("phase_duration", self.phase_duration, "must be positive", ConfigError)
        self.num_phases = max(2, int(math.ceil(self.duration / self.phase_duration)))
        self.end_time = self.start_time + self.num_phases * self.phase_duration + self.phase_duration
        # Foot placements: for each leg, a list of (land_time, position) with the first at start.
        self._holds: list[list[tuple[float, np.ndarray]]] = []
        for leg in range(NUM_LEGS):
            first_swing = 0 if leg in TRIPOD_A else 1
            first = (self._foothold(leg, self.start_time) if self.start_feet_W is None
                     else np.asarray(self.start_feet_W[leg], dtype=float))
            holds = [(self.start_time, first)]
            for k in range(first_swing, self.num_phases, 2):
                land = self.start_time + (k + 1) * self.phase_duration
                holds.append((land, self._foothold(leg, min(land + self.phase_duration / 2,
                                                            self.start_time + self.duration))))
            self._holds.append(holds)

    # -- body -----------------------------------------------------------------------------
    def _pose_2d(self, t: float) -> tuple[float, float, float]:
        s = float(_min_jerk((t - self.start_time) / self.duration))
        x0, y0, yaw0 = self.start_xy_yaw
        x1, y1, yaw1 = self.goal_xy_yaw
        dyaw = math.atan2(math.sin(yaw1 - yaw0), math.cos(yaw1 - yaw0))
        return x0 + s * (x1 - x0), y0 + s * (y1 - y0), yaw0 + s * dyaw

    def _nominal_world(self, t: float) -> np.ndarray:
        return self._nominal_world_at(*self._pose_2d(t))

    def base_position(self, t: float) -> np.ndarray:
        x, y, _ = self._pose_2d(t)
        xy = self._nominal_world(t)
        ground = float(np.mean(self.heightmap.height(xy[:, 0], xy[:, 1])))
        return np.array([x, y, ground + self.params.standing_height])

    def base_positions_many(self, times) -> np.ndarray:
        """base_position at each of ``times`` (n, 3), the same numbers, the ground queried once
        for all of them (the tracker reads a mission's references at hundreds of times)."""
        ts = np.asarray(times, dtype=float).reshape(-1)
        poses = [self._pose_2d(float(t)) for t in ts]
        xy = np.stack([self._nominal_world_at(*pose) for pose in poses]) if poses else np.zeros((0, NUM_LEGS, 2))
        ground = np.mean(self.heightmap.height(xy[..., 0], xy[..., 1]), axis=1)
        out = np.empty((ts.size, 3))
        out[:, 0] = [pose[0] for pose in poses]
        out[:, 1] = [pose[1] for pose in poses]
        out[:, 2] = ground + self.params.standing_height
        return out

    def _nominal_world_at(self, x: float, y: float, yaw: float) -> np.ndarray:
        c, s = math.cos(yaw), math.sin(yaw)
        p = self.topology.footholds_B[:, :2]
        return np.stack([x + c * p[:, 0] - s * p[:, 1], y + s * p[:, 0] + c * p[:, 1]], axis=1)

    def base_rpy(self, t: float) -> np.ndarray:
        return np.array([0.0, 0.0, self._pose_2d(t)[2]])

    # -- feet -----------------------------------------------------------------------------
    def _foothold(self, leg: int, t: float) -> np.ndarray:
        """The safe point nearest the nominal foothold, within FOOTHOLD_SEARCH of it: a point is
        safe when the ground within FOOTHOLD_CLEARANCE of it is level to FOOTHOLD_STEP (not on
        an edge) and it is not the floor of a narrow gap (see FOOTHOLD_PIT_RADIUS); if none
        is, the least uneven point outside a gap."""
        xy = self._nominal_world(t)[leg]
        offsets = _FOOTHOLD_OFFSETS
        candidates = xy[None, :] + offsets
        centre = self.heightmap.height(candidates[:, 0], candidates[:, 1])
        ring = candidates[:, None, :] + _RING[None, :, :]
        around = self.heightmap.height(ring[..., 0], ring[..., 1])
        unevenness = np.max(np.abs(around - centre[:, None]), axis=1)
        pairs = candidates[:, None, None, :] + _PIT_PAIRS[None]
        sides = self.heightmap.height(pairs[..., 0], pairs[..., 1]) - centre[:, None, None]
        in_pit = np.any(np.all(sides > FOOTHOLD_PIT_DEPTH, axis=2), axis=1)
        # The nearest safe point; with none, the least uneven point outside a gap (offsets are
        # sorted by distance, and argmin takes the first of equals).
        badness = np.where(unevenness <= FOOTHOLD_STEP, 0.0, unevenness) + np.where(in_pit, 10.0, 0.0)
        xy = candidates[int(np.argmin(badness))]
        return np.array([xy[0], xy[1], float(self.heightmap.height(xy[0], xy[1])) + self.params.foot_radius])

    def _swing(self, leg: int, t: float):
        """(lift, land, s) if the leg swings at t, else None."""
        holds = self._holds[leg]
        for k in range(1, len(holds)):
            land = holds[k][0]
            lift = land - self.phase_duration
            if lift <= t < land:
                return holds[k - 1][1], holds[k][1], (t - lift) / self.phase_duration
        return None

    def foot_positions(self, t: float) -> np.ndarray:
        out = np.zeros((NUM_LEGS, 3))
        for leg in range(NUM_LEGS):
            swing = self._swing(leg, t)
            if swing is None:
                out[leg] = [p for land, p in self._holds[leg] if land <= t + 1e-12][-1] \
                    if t >= self._holds[leg][0][0] else self._holds[leg][0][1]
                continue
            a, b, s = swing
            out[leg] = self._swing_point(a, b, self._swing_apex(a, b), s)
        return out

    def foot_positions_many(self, times) -> np.ndarray:
        """foot_positions at each of ``times`` (n, 6, 3), the same numbers: a swing's clearance
        over the ground between its footholds depends on the swing alone, so the ground is
        queried once a swing instead of once a time."""
        ts = np.asarray(times, dtype=float).reshape(-1)
        out = np.empty((ts.size, NUM_LEGS, 3))
        for leg in range(NUM_LEGS):
            holds = self._holds[leg]
            lands = np.array([land for land, _ in holds])
            points = np.stack([p for _, p in holds])
            # Standing: the newest foothold landed by t (the first before the plan starts).
            newest = np.searchsorted(lands, ts + 1e-12, side="right") - 1
            out[:, leg] = points[np.where(ts >= lands[0], newest, 0)]
            # Swinging: the first swing whose [lift, land) holds t, as _swing finds it.
            swing = np.zeros(ts.size, dtype=int)
            for k in range(len(holds) - 1, 0, -1):
                lift = lands[k] - self.phase_duration
                swing[(lift <= ts) & (ts < lands[k])] = k
            for k in np.unique(swing[swing > 0]):
                rows = np.flatnonzero(swing == k)
                a, b = holds[k - 1][1], holds[k][1]
                apex = self._swing_apex(a, b)
                lift = lands[k] - self.phase_duration
                for r in rows:
                    out[r, leg] = self._swing_point(a, b, apex, (ts[r] - lift) / self.phase_duration)
        return out

    def _swing_apex(self, a: np.ndarray, b: np.ndarray) -> float:
        """The apex height of the swing from foothold a to b."""
        line = a[None, :2] + np.linspace(0, 1, 9)[:, None] * (b - a)[None, :2]
        ground = float(np.max(self.heightmap.height(line[:, 0], line[:, 1]))) + self.params.foot_radius
        return max(a[2], b[2], ground) + self.swing_clearance

    @staticmethod
    def _swing_point(a: np.ndarray, b: np.ndarray, apex: float, s: float) -> np.ndarray:
        """The foot at phase s of its swing from a to b."""
        # The foot reaches its landing point over the ground before it descends the last
        # part: a foot that lags its target and touches down early would drag and shove.
        blend = float(_min_jerk(s / SWING_HORIZONTAL_FRACTION))
        p = a + blend * (b - a)
        base = a[2] + blend * (b[2] - a[2])
        p[2] = base + (apex - min(a[2], b[2])) * math.sin(math.pi * s) if s < 1 else b[2]
        return p

    def __deepcopy__(self, memo):
        # A plan is immutable once made; Drake copies abstract values (state, outputs) often,
        # and a deep copy would copy the heightmap each time.
        return self

    def stance_start(self, leg: int, t: float) -> float | None:
        """When the stance of `leg` in force at t began; None while it swings."""
        if self._swing(leg, t) is not None:
            return None
        lands = [land for land, _ in self._holds[leg] if land <= t + 1e-12]
        return lands[-1] if lands else self._holds[leg][0][0]

    def contact(self, t: float) -> np.ndarray:
        return np.array([self._swing(leg, t) is None for leg in range(NUM_LEGS)])

    def foot_forces(self, t: float) -> np.ndarray:
        stance = self.contact(t)
        f = np.zeros((NUM_LEGS, 3))
        f[stance, 2] = self.params.total_mass * GRAVITY / max(int(stance.sum()), 1)
        return f


__all__ = ["TripodGaitPlan", "TRIPOD_A", "TRIPOD_B"]
