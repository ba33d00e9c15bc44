"""Geometry and mass properties of the hexapod Qingzhui (paper 002, section 2.1).

The published numbers are the trunk size (about 1.2 m x 0.8 m), the mass (about 60 kg, up to
20 kg payload), the leg mass (about 5.8 kg, 80 % of it in the drive units at the hip) and the
leg mechanism: j0 abducts the leg plane, j1 swings the thigh and j2, through a parallelogram,
sets the *absolute* angle of the shank (Eq. 1-3). Link lengths and joint limits are not
published; the values below are our choice, made so that

* the nominal standing height (base origin above flat ground) is 0.55 m,
* each foot stands 0.20 m radially outside its hip, so that the knee can point outwards or
  inwards (the two bend directions the topologies of paper 000 use) with room on both sides,
* a foot can be placed 0.20 m higher than the others (stepping onto a 0.2 m stair) and 0.15 m
  lower without leaving the workspace (tests check both).

Frames. The base frame B sits at the trunk's geometric centre, x forward, z up. Each leg has a
leg frame L at its hip: x radially outwards (the axis of j0), y down, z = x cross y. In L the
foot centre is (paper 002 Eq. 1-3, motor angles m0, m1, m2 with m2 absolute)::

    x = l1 cos m1 + l2 cos m2
    y = (l1 sin m1 + l2 sin m2) cos m0
    z = (l1 sin m1 + l2 sin m2) sin m0

The URDF models the parallelogram as a serial chain whose knee angle is relative:
q0 = m0, q1 = m1, q2 = m2 - m1.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

LEG_NAMES: tuple[str, ...] = ("MF", "RF", "RB", "MB", "LB", "LF")
"""Leg order used everywhere (ids 0..5)."""

TRIPOD_A: tuple[int, ...] = (0, 2, 4)
"""Tripod group A: MF, RB, LB (paper 002, Fig. 10)."""

TRIPOD_B: tuple[int, ...] = (3, 1, 5)
"""Tripod group B: MB, RF, LF."""

JOINTS_PER_LEG = 3
NUM_LEGS = 6
NUM_JOINTS = NUM_LEGS * JOINTS_PER_LEG


def leg_index(leg: int | str) -> int:
    """Returns the id 0..5 of a leg given as an id or a name (case-insensitive)."""
    from qz_drake.errors import KinematicsError, bad_value

    if isinstance(leg, (int, np.integer)) and not isinstance(leg, bool):
        if 0 <= int(leg) < NUM_LEGS:
            return int(leg)
    elif isinstance(leg, str) and leg.upper() in LEG_NAMES:
        return LEG_NAMES.index(leg.upper())
    raise bad_value("leg", leg, f"expected an id 0..5 or one of {', '.join(LEG_NAMES)}",
                    KinematicsError)


@dataclasses.dataclass(frozen=True)
class QingzhuiParams:
    """Qingzhui's geometry, masses, limits and actuators. Defaults are the robot we model."""

    # Hip (j0 axis origin) positions in the base frame, in LEG_NAMES order. [m]
    # A non-regular hexagon, MF and MB on the centreline (paper 002, section 3.1).
    hip_positions: tuple[tuple[float, float, float], ...] = (
        (0.55, 0.0, 0.0),
        (0.27, -0.38, 0.0),
        (-0.27, -0.38, 0.0),
        (-0.55, 0.0, 0.0),
        (-0.27, 0.38, 0.0),
        (0.27, 0.38, 0.0),
    )
    # Yaw of each leg frame's x axis (radially outwards) in the base frame. [rad]
    hip_yaws: tuple[float, ...] = (
        0.0, -math.pi / 3, -2 * math.pi / 3, math.pi, 2 * math.pi / 3, math.pi / 3)
    # Thigh length l1, hip axis to knee. [m]
    thigh_length: float = 0.36
    # Shank length l2, knee to foot-sphere centre. [m]
    shank_length: float = 0.42
    # Foot sphere radius. [m]
    foot_radius: float = 0.03
    # Trunk collision box (length, width, height); hips sit inside its outline. [m]
    trunk_size: tuple[float, float, float] = (1.20, 0.80, 0.16)
    # Nominal height of the base origin above flat ground when standing. [m]
    standing_height: float = 0.55
    # Nominal foothold: radial distance of the foot centre from its hip, ground projection. [m]
    nominal_radial_offset: float = 0.20

    # Masses. Total = trunk + 6 * leg = 25.2 + 34.8 = 60 kg (paper 002: about 60 kg). [kg]
    trunk_mass: float = 25.2
    # Leg: 80 % of 5.8 kg in the drive units at the hip. [kg]
    hip_mass: float = 4.64
    thigh_mass: float = 0.66
    shank_mass: float = 0.44
    foot_mass: float = 0.06
    # Extra mass rigidly carried on the trunk (paper 002 tests with 5 kg; up to 20 kg). [kg]
    payload_mass: float = 0.0

    # Joint limits in URDF coordinates (q0 = m0, q1 = m1, q2 = m2 - m1). [rad]
    q0_limits: tuple[float, float] = (-0.70, 0.70)
    q1_limits: tuple[float, float] = (-0.80, 2.80)
    q2_limits: tuple[float, float] = (-2.90, 2.90)
    # Actuator effort limit. [N*m]
    effort_limit: float = 250.0
    # Joint velocity limit. [rad/s]
    velocity_limit: float = 12.0
    # Reducer ratio and motor rotor inertia: reflected inertia = rotor_inertia * gear_ratio^2
    # (0.02 kg*m^2) makes the light links well conditioned for a 1-2 ms simulation step.
    gear_ratio: float = 50.0
    rotor_inertia: float = 8.0e-6  # [kg*m^2]
    # Viscous joint damping of the drive units. [N*m*s/rad]
    joint_damping: float = 0.5

    @property
    def leg_mass(self) -> float:
        return self.hip_mass + self.thigh_mass + self.shank_mass + self.foot_mass

    @property
    def total_mass(self) -> float:
        return self.trunk_mass + self.payload_mass + NUM_LEGS * self.leg_mass

    def hip_position(self, leg: int | str) -> np.ndarray:
        return np.array(self.hip_positions[leg_index(leg)], dtype=float)

    def R_BL(self, leg: int | str) -> np.ndarray:
        """Rotation from leg frame L to base frame B (columns: L's axes in B)."""
        psi = self.hip_yaws[leg_index(leg)]
        c, s = math.cos(psi), math.sin(psi)
        return np.array([[c, 0.0, -s], [s, 0.0, c], [0.0, -1.0, 0.0]])

    def nominal_foothold(self, leg: int | str) -> np.ndarray:
        """Foot-sphere centre in B when standing at the nominal height on flat ground."""
        i = leg_index(leg)
        psi = self.hip_yaws[i]
        hip = self.hip_position(i)
        d = self.nominal_radial_offset
        z = -self.standing_height + self.foot_radius
        return np.array([hip[0] + d * math.cos(psi), hip[1] + d * math.sin(psi), z])

    def joint_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper limits (3,) of one leg's URDF joints."""
        lower = np.array([self.q0_limits[0], self.q1_limits[0], self.q2_limits[0]])
        upper = np.array([self.q0_limits[1], self.q1_limits[1], self.q2_limits[1]])
        return lower, upper


DEFAULT_PARAMS = QingzhuiParams()
