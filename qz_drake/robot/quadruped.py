"""The quadruped of paper 003 (section 4.1, Fig. 8): URDF, leg kinematics (FK and IK).

The paper's robot has three revolute joints per leg, abduction, hip and knee, on a body of half
length ``l``, half width ``w`` with a shoulder offset ``d``; its Tables 3-6 (DH parameters, joint
ranges, constants) lost their numbers in extraction. We take the LittleDog-like dimensions of
:class:`~qz_drake.planning.static_gait.QuadrupedGeometry` (the gait search's model), so the
robot that walks in Drake is the one the search reasons about:

==========================  ===========================================================
hips (body frame)           (+-0.10, +-0.045, 0) m: ``half_length``, ``half_width``
shoulder (leg plane offset)  0.03 m outwards from the hip
thigh, shank                 0.08 m, 0.09 m
body box                     0.26 x 0.12 x 0.05 m, 2.0 kg
leg                          0.06 kg hip + 0.08 kg thigh + 0.05 kg shank + 0.01 kg foot
foot                         sphere of radius 0.012 m (``StaticGaitConfig.foot_radius``)
total mass                   2.8 kg (LittleDog: about 2.9 kg)
==========================  ===========================================================

Frames and joints (names as Qingzhui's: links ``base``, ``<LEG>_hip``, ``<LEG>_thigh``,
``<LEG>_shank``, ``<LEG>_foot``; joints ``<LEG>_j0`` .. ``<LEG>_j2``), legs LF, RF, LB, RB:

* ``j0``, abduction, at the hip about the body's x axis for left legs and -x for right legs, so
  a positive angle swings every foot outwards. The leg plane sits ``shoulder`` outwards of it.
* ``j1``, hip, about the body's y axis (after abduction): positive swings the thigh backwards.
* ``j2``, knee, about the same axis; knees point backwards (q2 <= 0), one IK branch for all legs.

With s = +1 for left and -1 for right legs, R_x the rotation about x, the foot centre is::

    p_BF = p_BH + R_x(s q0) [x, s d, z],   x = -l1 sin q1 - l2 sin(q1 + q2),
                                            z = -l1 cos q1 - l2 cos(q1 + q2)

The gait search's footholds are sole points on the ground; the foot frame is the sphere's centre,
``foot_radius`` above the sole.
"""

# No `from __future__ import annotations`: pydrake's typed YAML reads QuadrupedGeometry's field
# types, which that would turn into strings (static-gait scenarios nest it).
import dataclasses
import math
from pathlib import Path

import numpy as np

from qz_drake.errors import KinematicsError, bad_value
from qz_drake.robot.urdf import _f, _inertial, _joint, _transmission, _vec

LEGS = ("LF", "RF", "LB", "RB")
"""Index order of feet in arrays."""
_SIGN = {"LF": (1, 1), "RF": (1, -1), "LB": (-1, 1), "RB": (-1, -1)}


@dataclasses.dataclass
class QuadrupedGeometry:
    """LittleDog-like leg geometry (Boston Dynamics LittleDog: 0.2 m hip-to-hip body, 0.08 m
    thigh and shank); the paper's Table 6 lost its numbers."""

    # Hip x from the body centre (the paper's half body length). [m]
    half_length: float = 0.10
    # Hip y from the body centre (half body width). [m]
    half_width: float = 0.045
    # Lateral offset of the leg plane from the hip (shoulder width). [m]
    shoulder: float = 0.03
    # Thigh length. [m]
    thigh: float = 0.08
    # Shank length. [m]
    shank: float = 0.09
    # Body box (length, width, height) for collisions. [m]
    body_size: list[float] = dataclasses.field(default_factory=lambda: [0.26, 0.12, 0.05])
    # Largest abduction angle of the leg plane from vertical. [rad]
    max_abduction: float = 0.6
    # Largest hip swing angle of the hip-to-foot line from vertical in the leg plane. [rad]
    max_hip_swing: float = 0.9
    # Reach limits as fractions of thigh + shank: a straight leg is singular, a folded one weak.
    min_reach: float = 0.45
    max_reach: float = 0.95

    def hip_B(self, leg: str) -> np.ndarray:
        sx, sy = _SIGN[leg]
        return np.array([sx * self.half_length, sy * self.half_width, 0.0])

    def default_foothold_B(self, leg: str) -> np.ndarray:
        """Nominal foothold (x, y) in the body frame: under the hip, out by the shoulder. [m]"""
        sx, sy = _SIGN[leg]
        return np.array([sx * self.half_length, sy * (self.half_width + self.shoulder)])

    def reachable(self, leg: str, p_BF: np.ndarray) -> bool:
        """Whether the foot at p_BF (body frame) is in the leg's workspace."""
        x, y, z = np.asarray(p_BF, dtype=float) - self.hip_B(leg)
        y *= _SIGN[leg][1]  # outward positive
        if z >= 0.0:
            return False
        r_yz2 = y * y + z * z
        d = self.shoulder
        if r_yz2 < d * d:
            return False
        down = math.sqrt(r_yz2 - d * d)  # foot below the hip in the leg plane
        # The leg plane's tilt from vertical: direction (y, z) minus the shoulder offset.
        abduction = math.atan2(y, -z) - math.atan2(d, down)
        if abs(abduction) > self.max_abduction:
            return False
        if abs(math.atan2(x, down)) > self.max_hip_swing:
            return False
        reach = math.hypot(x, down)
        total = self.thigh + self.shank
        return self.min_reach * total <= reach <= self.max_reach * total


MODELS_DIR = Path(__file__).resolve().parents[2] / "models"
QUADRUPED_URDF = MODELS_DIR / "quadruped.urdf"

# Left legs +1, right legs -1.
_SIDE = {"LF": 1.0, "RF": -1.0, "LB": 1.0, "RB": -1.0}
_LINK_RADIUS = 0.008  # [m] visual radius of thigh and shank


@dataclasses.dataclass(frozen=True)
class QuadrupedParams:
    """Mass, joint and actuator properties of the quadruped; lengths come from ``geometry``."""

    geometry: QuadrupedGeometry = dataclasses.field(default_factory=QuadrupedGeometry)
    # Body (trunk) mass, spread over ``geometry.body_size``. [kg]
    body_mass: float = 2.0
    # Hip drive (a sphere at the hip), thigh, shank and foot masses. [kg]
    hip_mass: float = 0.06
    thigh_mass: float = 0.08
    shank_mass: float = 0.05
    foot_mass: float = 0.01
    # Foot sphere radius; matches StaticGaitConfig.foot_radius. [m]
    foot_radius: float = 0.012
    # Joint ranges (lower, upper) of abduction, hip and knee. [rad]
    abduction_limits: tuple[float, float] = (-0.6, 0.6)
    hip_limits: tuple[float, float] = (-1.2, 2.4)
    knee_limits: tuple[float, float] = (-2.7, 0.0)
    # Torque limit of each joint: about three times the heaviest static load. [N*m]
    effort_limit: float = 4.0
    # Speed limit of each joint. [rad/s]
    velocity_limit: float = 12.0
    # Viscous joint damping. [N*m*s/rad]
    joint_damping: float = 0.01
    # Motor rotor inertia and gear ratio: the drives' reflected inertia (2.7e-3 kg*m^2) is
    # larger than a link's, as in geared small robots, and keeps stiff PD gains well behaved.
    rotor_inertia: float = 3.0e-6
    gear_ratio: float = 30.0

    def joint_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) of the three joints of a leg. [rad]"""
        lims = np.array([self.abduction_limits, self.hip_limits, self.knee_limits])
        return lims[:, 0], lims[:, 1]

    @property
    def total_mass(self) -> float:
        return self.body_mass + 4 * (self.hip_mass + self.thigh_mass + self.shank_mass + self.foot_mass)


DEFAULT_QUADRUPED = QuadrupedParams()


def joint_names() -> list[str]:
    """The 12 joints in leg-major order, legs as ``static_gait.LEGS`` (LF, RF, LB, RB)."""
    return [f"{leg}_j{j}" for leg in LEGS for j in range(3)]


def foot_frame_names() -> list[str]:
    return [f"{leg}_foot" for leg in LEGS]


def _check_leg(leg: str) -> float:
    if leg not in _SIDE:
        raise bad_value("leg", leg, f"expected one of {', '.join(LEGS)}", KinematicsError)
    return _SIDE[leg]


def leg_fk(leg: str, q, geometry: QuadrupedGeometry | None = None) -> np.ndarray:
    """Foot centre in the body frame for joint angles q (..., 3) of ``leg``. [m]"""
    g = geometry or QuadrupedGeometry()
    s = _check_leg(leg)
    q = np.asarray(q, dtype=float)
    q0, q1, q2 = q[..., 0], q[..., 1], q[..., 2]
    x = -g.thigh * np.sin(q1) - g.shank * np.sin(q1 + q2)
    z = -g.thigh * np.cos(q1) - g.shank * np.cos(q1 + q2)
    y = s * g.shoulder
    a = s * q0
    c, sn = np.cos(a), np.sin(a)
    p = np.stack([x, c * y - sn * z, sn * y + c * z], axis=-1)
    return p + g.hip_B(leg)


def leg_ik(leg: str, p_BF, geometry: QuadrupedGeometry | None = None, *, strict: bool = True) -> np.ndarray:
    """Joint angles (..., 3) putting the foot centre of ``leg`` at p_BF (..., 3), body frame.

    The knee-backwards branch (q2 <= 0). A point out of reach raises KinematicsError, or gives
    NaN rows with ``strict=False``.
    """
    g = geometry or QuadrupedGeometry()
    s = _check_leg(leg)
    r = np.asarray(p_BF, dtype=float) - g.hip_B(leg)
    x, y_out, z = r[..., 0], s * r[..., 1], r[..., 2]
    d, l1, l2 = g.shoulder, g.thigh, g.shank
    # In the abduction plane (y, z): the leg plane is a line at distance d from the hip; the
    # foot lies ``down`` below the hip along it.
    down2 = y_out**2 + z**2 - d * d
    down = np.sqrt(np.maximum(down2, 0.0))
    q0 = np.arctan2(y_out, -z) - np.arctan2(d, down)
    # In the leg plane: a two-link arm from the hip to (x, -down).
    reach2 = x**2 + down**2
    cos_knee = (reach2 - l1 * l1 - l2 * l2) / (2 * l1 * l2)
    ok = (down2 >= 0) & (np.abs(cos_knee) <= 1.0) & (down > 0)
    q2 = -np.arccos(np.clip(cos_knee, -1.0, 1.0))
    q1 = np.arctan2(-x, down) - np.arctan2(l2 * np.sin(q2), l1 + l2 * np.cos(q2))
    q = np.stack([q0, q1, q2], axis=-1)
    if not np.all(ok):
        if strict:
            bad = np.asarray(p_BF, dtype=float).reshape(-1, 3)[~np.atleast_1d(ok).ravel()][0]
            raise bad_value(f"{leg} foot", bad.round(4).tolist(), "out of the leg's reach", KinematicsError)
        q = np.where(ok[..., None], q, np.nan)
    return q


def body_ik(p_WB, R_WB, feet_W, geometry: QuadrupedGeometry | None = None, *,
            strict: bool = True) -> np.ndarray:
    """The 12 joint angles (leg-major, LEGS order) placing the four foot centres feet_W (4, 3)
    for a body at position p_WB (3,) with rotation R_WB (3, 3)."""
    feet_W = np.asarray(feet_W, dtype=float).reshape(4, 3)
    p_BF = (feet_W - np.asarray(p_WB, dtype=float)) @ np.asarray(R_WB, dtype=float)
    return np.concatenate([leg_ik(leg, p_BF[i], geometry, strict=strict) for i, leg in enumerate(LEGS)])


# -- URDF -----------------------------------------------------------------------------------------
def _down_link(name: str, mass: float, length: float, rgba: str) -> str:
    """A link whose mass is a uniform rod along its -z axis, from 0 to -length."""
    ixx = mass * (3 * _LINK_RADIUS**2 + length**2) / 12.0
    izz = 0.5 * mass * _LINK_RADIUS**2
    return (f'  <link name="{name}">\n'
            + _inertial(mass, (0, 0, -length / 2), ixx, ixx, izz)
            + f'    <visual>\n      <origin xyz="0 0 {_f(-length / 2)}" rpy="0 0 0"/>\n'
            f'      <geometry><cylinder radius="{_f(_LINK_RADIUS)}" length="{_f(length)}"/></geometry>\n'
            f'      <material name="{name}_color"><color rgba="{rgba}"/></material>\n'
            f'    </visual>\n  </link>\n')


def _sphere_link(name: str, mass: float, radius: float, rgba: str, collision: bool) -> str:
    i = 0.4 * mass * radius**2
    text = (f'  <link name="{name}">\n' + _inertial(mass, (0, 0, 0), i, i, i)
            + f'    <visual>\n      <geometry><sphere radius="{_f(radius)}"/></geometry>\n'
            f'      <material name="{name}_color"><color rgba="{rgba}"/></material>\n    </visual>\n')
    if collision:
        text += (f'    <collision name="{name}_collision">\n'
                 f'      <geometry><sphere radius="{_f(radius)}"/></geometry>\n    </collision>\n')
    return text + "  </link>\n"


def make_quadruped_urdf(params: QuadrupedParams = DEFAULT_QUADRUPED) -> str:
    """Returns the URDF text of the quadruped. Collision geometry: the body box (so that a body
    touching the terrain shows in the contact results) and the foot spheres; legs have none, as
    the gait search checks only the feet's box paths and the body."""
    g = params.geometry
    lx, ly, lz = g.body_size
    m = params.body_mass
    lower, upper = params.joint_limits()
    parts = [
        '<?xml version="1.0"?>\n',
        "<!-- Generated by scripts/make_quadruped_urdf.py from qz_drake/robot/quadruped.py. Do not edit. -->\n",
        '<robot name="quadruped" xmlns:drake="http://drake.mit.edu">\n',
        '  <link name="base">\n',
        _inertial(m, (0, 0, 0), m * (ly**2 + lz**2) / 12, m * (lx**2 + lz**2) / 12, m * (lx**2 + ly**2) / 12),
        f'    <visual>\n      <geometry><box size="{_vec(g.body_size)}"/></geometry>\n'
        '      <material name="body_color"><color rgba="0.2 0.45 0.75 1"/></material>\n    </visual>\n',
        f'    <collision name="body_collision">\n      <geometry><box size="{_vec(g.body_size)}"/></geometry>\n'
        '    </collision>\n  </link>\n',
    ]
    for leg in LEGS:
        s = _SIDE[leg]
        parts.append(_sphere_link(f"{leg}_hip", params.hip_mass, 0.015, "0.15 0.15 0.15 1", False))
        parts.append(_down_link(f"{leg}_thigh", params.thigh_mass, g.thigh, "0.3 0.3 0.35 1"))
        parts.append(_down_link(f"{leg}_shank", params.shank_mass, g.shank, "0.5 0.5 0.55 1"))
        parts.append(_sphere_link(f"{leg}_foot", params.foot_mass, params.foot_radius, "0.1 0.1 0.1 1", True))
        parts.append(_joint(f"{leg}_j0", "base", f"{leg}_hip", g.hip_B(leg), (0, 0, 0), (s, 0, 0),
                            lower[0], upper[0], params))
        parts.append(_joint(f"{leg}_j1", f"{leg}_hip", f"{leg}_thigh", (0, s * g.shoulder, 0), (0, 0, 0),
                            (0, 1, 0), lower[1], upper[1], params))
        parts.append(_joint(f"{leg}_j2", f"{leg}_thigh", f"{leg}_shank", (0, 0, -g.thigh), (0, 0, 0),
                            (0, 1, 0), lower[2], upper[2], params))
        parts.append(f'  <joint name="{leg}_foot_joint" type="fixed">\n'
                     f'    <parent link="{leg}_shank"/>\n    <child link="{leg}_foot"/>\n'
                     f'    <origin xyz="0 0 {_f(-g.shank)}" rpy="0 0 0"/>\n  </joint>\n')
        for j in range(3):
            parts.append(_transmission(f"{leg}_j{j}", params))
    parts.append("</robot>\n")
    return "".join(parts)


def add_quadruped(plant, params: QuadrupedParams = DEFAULT_QUADRUPED, name: str = "quadruped"):
    """Adds the quadruped (floating base) to an unfinalized MultibodyPlant; returns its model
    instance. With the default parameters the text equals ``models/quadruped.urdf``."""
    from pydrake.multibody.parsing import Parser

    parser = Parser(plant)
    parser.SetAutoRenaming(True)
    (instance,) = parser.AddModelsFromString(make_quadruped_urdf(params), "urdf")
    if name != "quadruped":
        plant.RenameModelInstance(instance, name)
    return instance
