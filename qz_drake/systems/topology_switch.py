"""Topology switching on the robot (paper 000 II-D and Fig. 8: Qingzhui changes its topology
before tough terrain).

A ``TopologySwitchPlan`` takes the standing robot from one topology to another tripod by
tripod while the body stands still on the other tripod: each leg of the moving tripod lifts
its foot straight up, moves in joint space to the new knee bend above its new nominal
foothold, and puts the foot down there. A knee cannot flip through a bent-down leg (the
straight leg is longer than the hip is high), so a flip passes through two high waypoints in
motor angles (paper 002 Eq. 1-3: m1 the thigh, m2 the shank's absolute angle below the leg
plane's horizontal): a near-horizontal straight leg (m1 = m2 = 0.3 rad) and a high knee-in pose
(m1 = 1.2, m2 = -0.2 rad), in that order for out -> in and reversed for in -> out. A change of
footholds alone (split_up) only lifts and places.

The plan has the tracker's BodyFeetTrajectory interface, plus ``joint_override(t)`` (the
joint references of legs in their joint-space move, NaN elsewhere) and ``topology_at(t)``
(each leg's bend at t), which InverseKinematicsTracker uses when a plan offers them. It is
not a mission (``is_mission = False``): route sequencers do not count it.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.math import RollPitchYaw

from qz_drake.errors import ConfigError, bad_value
from qz_drake.robot import kinematics
from qz_drake.robot.params import DEFAULT_PARAMS, LEG_NAMES, NUM_LEGS, TRIPOD_A, TRIPOD_B, QingzhuiParams
from qz_drake.robot.topology import Topology
from qz_drake.robot.urdf import LINK_COLLISION_RADIUS, SHANK_COLLISION_END_INSET, THIGH_COLLISION_START
from qz_drake.trajopt.leg_clearance import raw_ground, sphere_clearance
from qz_drake.trajopt.terrain import as_terrain

GRAVITY = 9.81
# Motor-angle waypoints of a knee flip (m1, m2). [rad]
_STRAIGHT_HIGH = (0.3, 0.3)
_KNEE_IN_HIGH = (1.2, -0.2)


@dataclasses.dataclass(frozen=True)
class SwitchTiming:
    """Durations of one tripod's move and the foot lift."""

    # Lifting the foot straight up, and putting it down. [s]
    lift: float = 0.4
    # The joint-space move (a knee flip's three segments share it). [s]
    move: float = 1.2
    # Height the foot is lifted above where it stood. [m]
    lift_height: float = 0.12
    # Standing still on all six feet before and after each tripod's move. [s]
    settle: float = 0.3


def _min_jerk(s):
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (10 - 15 * s + 6 * s**2)


def _is_bent_out(m) -> bool:
    return m[1] < m[2]


# Least clearance of a leg link above the raw terrain during a switch. [m]
LINK_CLEARANCE = 0.01
# Points along the collision capsules (robot/urdf.py) checked during a switch: every 1.5 cm of
# the thigh's (from the hip drive to the knee) and of the shank's (from the knee to 9 cm above
# the foot), as fractions of each link.
_THIGH = np.linspace(THIGH_COLLISION_START, DEFAULT_PARAMS.thigh_length, 19) / DEFAULT_PARAMS.thigh_length
_SHANK = np.linspace(0.0, DEFAULT_PARAMS.shank_length - SHANK_COLLISION_END_INSET, 23)[1:] / DEFAULT_PARAMS.shank_length
_THIGH_POINTS = len(_THIGH)
_LINK_FRACTIONS = np.concatenate([_THIGH, _SHANK])
_LINK_IS_THIGH = np.arange(len(_LINK_FRACTIONS)) < _THIGH_POINTS

# Foot lifts a switch tries, lowest first: a foot whose joint-space move would graze the terrain
# (a ridge or a slope under the moving leg) may clear it lifted higher; above 0.2 m the lifted
# foot leaves Qingzhui's reach. [m]
LIFT_HEIGHTS = (0.12, 0.16, 0.2)


def plan_topology_switch(*, lift_heights=LIFT_HEIGHTS, timing: "SwitchTiming | None" = None,
                         **kwargs) -> "TopologySwitchPlan":
    """The first TopologySwitchPlan (same arguments) whose feet clear the terrain, trying the
    foot lifts in order; ConfigError (the lowest lift's reason) when none does."""
    timing = timing or SwitchTiming()
    first = None
    for height in lift_heights:
        try:
            return TopologySwitchPlan(timing=dataclasses.replace(timing, lift_height=float(height)),
                                      **kwargs)
        except ConfigError as e:
            first = first or e
    if len(lift_heights) > 1:
        raise ConfigError(f"{first} (and with foot lifts up to {max(lift_heights):.2f} m)")
    raise first


class TopologySwitchPlan:
    """The switch from ``from_topology`` to ``to_topology`` of a robot standing at ``start``
    (a MissionStart: base pose and feet), beginning at ``start_time``.

    Raises ConfigError when a new foothold is out of reach, a foot's path would pass within
    ``min_clearance`` of the terrain, or a leg's thigh or shank (standing, lifting, flipping
    or placing) would come within ``link_clearance`` of it: such a switch is refused before
    it starts (issue 34: four of CapPlanner's Fig. 9 walks failed in a switch whose leg hit
    the ground).
    """

    is_mission = False

    def __init__(self, *, heightmap, start, from_topology: Topology, to_topology: Topology,
                 start_time: float, params: QingzhuiParams = DEFAULT_PARAMS,
                 timing: SwitchTiming = SwitchTiming(), min_clearance: float = 0.02,
                 link_clearance: float = LINK_CLEARANCE):
        self.from_topology, self.topology = from_topology, to_topology
        self.params, self.timing = params, timing
        self.start_time = float(start_time)
        x, y, yaw = start.xy_yaw
        roll, pitch = start.roll_pitch
        feet0 = np.asarray(start.feet_W, dtype=float)
        base_z = start.base_z if start.base_z is not None else (
            float(np.mean(feet0[:, 2])) - params.foot_radius + params.standing_height)
        self._p_base = np.array([x, y, base_z])
        self._rpy = np.array([roll, pitch, yaw])
        self._R = RollPitchYaw(self._rpy).ToRotationMatrix().matrix()
        # New footholds: the new topology's nominal ones around the standing base, on the ground.
        p_B = to_topology.footholds_B
        c, s = np.cos(yaw), np.sin(yaw)
        fx = x + c * p_B[:, 0] - s * p_B[:, 1]
        fy = y + s * p_B[:, 0] + c * p_B[:, 1]
        feet1 = np.column_stack([fx, fy, heightmap.height(fx, fy) + params.foot_radius])
        self._feet0, self._feet1 = feet0, feet1
        self._heightmap = heightmap
        # Which legs move: a new bend or a foothold more than 1 cm away.
        self._moves = [i for i in range(NUM_LEGS)
                       if from_topology.bends[i] != to_topology.bends[i]
                       or np.linalg.norm(feet1[i, :2] - feet0[i, :2]) > 0.01]
        self._groups = [tuple(i for i in group if i in self._moves) for group in (TRIPOD_A, TRIPOD_B)]
        self._groups = [g for g in self._groups if g]
        t = self.start_time + timing.settle
        self._windows = {}  # leg -> (lift start, move start, place start, place end)
        for group in self._groups:
            for i in group:
                self._windows[i] = (t, t + timing.lift, t + timing.lift + timing.move,
                                    t + 2 * timing.lift + timing.move)
            t += 2 * timing.lift + timing.move + timing.settle
        self.end_time = t if self._groups else self.start_time + timing.settle
        self._waypoints = {i: self._joint_waypoints(i) for i in self._moves}
        self._check_clearance(min_clearance)
        self._check_links(link_clearance)

    # -- construction ----------------------------------------------------------------------
    def _ik(self, leg: int, p_W, bend) -> np.ndarray:
        p_BF = self._R.T @ (np.asarray(p_W) - self._p_base)
        q, ok = kinematics.leg_inverse_kinematics(leg, p_BF, bend, self.params)
        if not ok:
            raise bad_value(f"topology switch leg {leg}", np.round(p_W, 3).tolist(),
                            "foot position out of reach", ConfigError)
        return np.asarray(q, dtype=float)

    def _joint_waypoints(self, leg: int) -> list[np.ndarray]:
        """Motor-angle waypoints (m0, m1, m2) of a leg's joint-space move."""
        h = np.array([0.0, 0.0, self.timing.lift_height])
        old = kinematics.urdf_to_motor(self._ik(leg, self._feet0[leg] + h, self.from_topology.bends[leg]))
        new = kinematics.urdf_to_motor(self._ik(leg, self._feet1[leg] + h, self.topology.bends[leg]))
        if self.from_topology.bends[leg] == self.topology.bends[leg]:
            return [old, new]
        m0 = 0.5 * (old[0] + new[0])
        straight = np.array([m0, *_STRAIGHT_HIGH])
        knee_in = np.array([m0, *_KNEE_IN_HIGH])
        middle = [straight, knee_in] if _is_bent_out(old) else [knee_in, straight]
        return [old, *middle, new]

    def _check_clearance(self, min_clearance: float) -> None:
        for t in np.linspace(self.start_time, self.end_time, 400):
            feet = self.foot_positions(t)
            ground = self._heightmap.height(feet[:, 0], feet[:, 1]) + self.params.foot_radius
            moving = ~self.contact(t)
            low = moving & (feet[:, 2] - ground < min_clearance)
            # Lifting off and touching down start and end on the ground: judge the moves only.
            for i in np.flatnonzero(low):
                lift, move, place, _ = self._windows[i]
                if move <= t <= place:
                    raise ConfigError(
                        f"topology switch leg {i} ({LEG_NAMES[i]}): the foot would pass "
                        f"{100 * (feet[i, 2] - ground[i]):.1f} cm over the terrain "
                        f"{t - self.start_time:.2f} s into the switch (at least "
                        f"{100 * min_clearance:.1f} cm needed)")

    def _check_links(self, min_clearance: float) -> None:
        """Every leg's link capsules over the raw heightmap at 400 samples of the switch."""
        ground = raw_ground(as_terrain(self._heightmap))
        times = np.linspace(self.start_time, self.end_time, 400)
        # A leg standing still has the same links at most of the samples: each leg's distinct
        # joint references are taken once (the same numbers as link_points at every sample).
        legs = {}
        points = np.stack([self.link_points(t, legs) for t in times])  # (n, 6, J, 3)
        clearance = sphere_clearance(points, LINK_COLLISION_RADIUS, ground)
        # The robot stands as it stands: a link only counts where it is lower than at the start.
        allowed = np.minimum(min_clearance, clearance[0] - 0.005)
        excess = allowed[None] - clearance
        if excess.max() > 0:
            k, leg, j = np.unravel_index(int(np.argmax(excess)), excess.shape)
            link = "thigh" if j < _THIGH_POINTS else "shank"
            raise ConfigError(
                f"topology switch leg {leg} ({LEG_NAMES[leg]}): its {link} would pass "
                f"{100 * clearance[k, leg, j]:.1f} cm over the terrain {times[k] - self.start_time:.2f} s "
                f"into the switch (at least {100 * min_clearance:.1f} cm needed)")

    def link_points(self, t: float, cache: dict | None = None) -> np.ndarray:
        """(6, J, 3) points every 1.5 cm along each leg's thigh and shank collision capsules,
        world, at t (the legs' joint references: a flip's joint-space move, else the IK of
        the foot with the leg's bend at t). ``cache``: a dict kept across calls on one plan,
        holding each leg's points by its inputs (a reference, or a foot and bend)."""
        override = self.joint_override(t).reshape(NUM_LEGS, 3)
        feet = self.foot_positions(t)
        bends = self.topology_at(t).bends
        out = np.empty((NUM_LEGS, len(_LINK_FRACTIONS), 3))
        for i in range(NUM_LEGS):
            flip = bool(np.all(np.isfinite(override[i])))
            key = (i, True, override[i].tobytes()) if flip else (i, False, feet[i].tobytes(), bends[i])
            points = None if cache is None else cache.get(key)
            if points is None:
                points = self._leg_link_points(i, override[i] if flip else self._ik(i, feet[i], bends[i]))
                if cache is not None:
                    cache[key] = points
            out[i] = points
        return out

    def _leg_link_points(self, i: int, q: np.ndarray) -> np.ndarray:
        """(J, 3) world points along leg i's thigh and shank capsules at URDF angles q."""
        m = kinematics.urdf_to_motor(q)
        l1 = self.params.thigh_length
        knee = l1 * np.array([np.cos(m[1]), np.sin(m[1]) * np.cos(m[0]), np.sin(m[1]) * np.sin(m[0])])
        foot = kinematics.foot_position_leg_frame(m, self.params)
        hip = np.zeros(3)
        starts = np.where(_LINK_IS_THIGH[:, None], hip, knee)
        ends = np.where(_LINK_IS_THIGH[:, None], knee, foot)
        p_L = starts + _LINK_FRACTIONS[:, None] * (ends - starts)
        p_B = p_L @ self.params.R_BL(i).T + self.params.hip_position(i)
        return self._p_base + p_B @ self._R.T

    # -- sampling ----------------------------------------------------------------------------
    def _phase(self, leg: int, t: float) -> tuple[str, float]:
        if leg not in self._windows:
            return "stand", 0.0
        lift, move, place, end = self._windows[leg]
        if t < lift:
            return "before", 0.0
        if t < move:
            return "lift", (t - lift) / (move - lift)
        if t < place:
            return "move", (t - move) / (place - move)
        if t < end:
            return "place", (t - place) / (end - place)
        return "after", 1.0

    def _move_q(self, leg: int, s: float) -> np.ndarray:
        """URDF joint angles along a leg's joint-space move at fraction s in [0, 1]."""
        points = self._waypoints[leg]
        segments = len(points) - 1
        k = min(int(s * segments), segments - 1)
        u = _min_jerk(s * segments - k)
        m = points[k] + u * (points[k + 1] - points[k])
        return kinematics.motor_to_urdf(m)

    def base_position(self, t: float) -> np.ndarray:
        return self._p_base.copy()

    def base_rpy(self, t: float) -> np.ndarray:
        return self._rpy.copy()

    def foot_positions(self, t: float) -> np.ndarray:
        h = self.timing.lift_height
        out = np.empty((NUM_LEGS, 3))
        for i in range(NUM_LEGS):
            phase, s = self._phase(i, t)
            if phase in ("stand", "before"):
                out[i] = self._feet0[i]
            elif phase == "after":
                out[i] = self._feet1[i]
            elif phase == "lift":
                out[i] = self._feet0[i] + [0.0, 0.0, h * _min_jerk(s)]
            elif phase == "place":
                out[i] = self._feet1[i] + [0.0, 0.0, h * (1.0 - _min_jerk(s))]
            else:
                p_B = kinematics.foot_position(i, self._move_q(i, s), self.params)
                out[i] = self._p_base + self._R @ p_B
        return out

    def contact(self, t: float) -> np.ndarray:
        return np.array([self._phase(i, t)[0] in ("stand", "before", "after") for i in range(NUM_LEGS)])

    def foot_forces(self, t: float) -> np.ndarray:
        contact = self.contact(t)
        forces = np.zeros((NUM_LEGS, 3))
        forces[contact, 2] = self.params.total_mass * GRAVITY / max(int(contact.sum()), 1)
        return forces

    def stance_start(self, leg: int, t: float) -> float | None:
        phase, _ = self._phase(leg, t)
        if phase in ("stand", "before"):
            return self.start_time
        if phase == "after":
            return self._windows[leg][3]
        return None

    def joint_override(self, t: float) -> np.ndarray:
        """(18,) URDF joint references of legs in their joint-space move; NaN elsewhere."""
        q = np.full((NUM_LEGS, 3), np.nan)
        for i in self._moves:
            phase, s = self._phase(i, t)
            if phase == "move":
                q[i] = self._move_q(i, s)
        return q.reshape(-1)

    def topology_at(self, t: float) -> Topology:
        """The topology whose bends the IK uses at t: each leg's new bend once its move began."""
        bends = tuple(self.topology.bends[i] if self._phase(i, t)[0] in ("move", "place", "after")
                      else self.from_topology.bends[i] for i in range(NUM_LEGS))
        return dataclasses.replace(self.topology, bends=bends)

    def __deepcopy__(self, memo):
        return self  # immutable; Drake copies abstract values often
