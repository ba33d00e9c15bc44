"""Single-rigid-body robot models for the BLC (paper 000, section II-A, Eq. 1-2).

The BLC sees a robot as one rigid body (mass, rotational inertia about the centre of mass) and
any number of point feet, each confined to a box around a nominal foothold in the body frame
(Eq. 1) and able to push with at most ``max_normal_force``. The body frame B of this module has
its origin at the centre of mass and its axes parallel to the base link's; ``com_B`` is where
that point sits in the base link frame, so a tracker converts with
``p_W_base = p_W_body - R_WB @ com_B``.

Presets: Qingzhui in each of its six topologies (from the Drake plant), a HyQ-sized quadruped
with TOWR's numbers (``towr/models/examples/hyq_model.h``) so that we can be compared with TOWR
on its own tasks, and the small quadruped of paper 003 (LittleDog-like).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from qz_drake.errors import ConfigError, bad_value

GRAVITY = 9.81  # [m/s^2]


@dataclasses.dataclass(frozen=True)
class LegLinks:
    """A leg's thigh and shank, for keeping them off the terrain (trajopt/legs.py): the knee
    follows from the hip, the foot and the bend in the plane of j0's axis (paper 002 Eq. 1-6)."""

    # Hip to knee and knee to foot-sphere centre. [m]
    thigh_length: float
    shank_length: float
    # +1: the knee radially outside the hip-foot line, -1: inside (the topology's bend).
    knee_bend: int
    # j0's axis (the leg plane's radial direction) in the body frame, unit.
    radial_axis: tuple[float, float, float]


@dataclasses.dataclass(frozen=True)
class LegModel:
    """One leg as the BLC sees it: a point foot in a box around its nominal foothold."""

    name: str
    # Nominal foot (sphere centre) position in the body frame B (origin at the CoM). [m]
    nominal_foothold: tuple[float, float, float]
    # Half-size of the kinematic box around the nominal foothold, along B's axes. [m]
    box_half_size: tuple[float, float, float]
    # Largest force the leg can push along the terrain normal. [N]
    max_normal_force: float
    # Hip position in the body frame (informative; the box encodes the reach). [m]
    hip_position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # Leg mass, already included in the robot's total mass (informative). [kg]
    mass: float = 0.0
    # Thigh and shank (None: a point foot on an unmodelled leg; no link clearance).
    links: LegLinks | None = None


@dataclasses.dataclass(frozen=True)
class RobotModel:
    """A legged robot as a single rigid body with point feet."""

    name: str
    # Total mass. [kg]
    mass: float
    # Rotational inertia about the CoM in the body frame, row-major 3x3. [kg*m^2]
    inertia: tuple[tuple[float, float, float], ...]
    legs: tuple[LegModel, ...]
    # Foot sphere radius: the foot centre stays this far above the terrain in stance. [m]
    foot_radius: float = 0.0
    # CoM position in the base link frame. [m]
    com_B: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # Gravity acceleration magnitude. [m/s^2]
    gravity: float = GRAVITY
    # Gaits this robot can use; the first is its default.
    gaits: tuple[str, ...] = ("trot",)
    # Radius of the legs' link tubes (their collision capsules), for the link clearance. [m]
    link_radius: float = 0.0
    # How far along the thigh (from the hip) and the shank (from the knee) the links can touch
    # anything: the collision capsules' extent. [m]
    thigh_collision: tuple[float, float] = (0.0, 0.0)
    shank_collision: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self):
        if not (math.isfinite(self.mass) and self.mass > 0):
            raise bad_value("robot.mass", self.mass, "must be positive")
        inertia = np.asarray(self.inertia, dtype=float)
        if inertia.shape != (3, 3) or not np.allclose(inertia, inertia.T) or \
                np.linalg.eigvalsh(inertia).min() <= 0:
            raise bad_value("robot.inertia", self.inertia, "must be a symmetric positive definite 3x3")
        if len(self.legs) < 1:
            raise bad_value("robot.legs", self.legs, "a robot needs at least one leg")
        for leg in self.legs:
            if min(leg.box_half_size) <= 0:
                raise bad_value(f"robot.legs[{leg.name}].box_half_size", leg.box_half_size,
                                "must be positive")
            if not leg.max_normal_force > 0:
                raise bad_value(f"robot.legs[{leg.name}].max_normal_force", leg.max_normal_force,
                                "must be positive")

    @property
    def num_legs(self) -> int:
        return len(self.legs)

    @property
    def leg_names(self) -> tuple[str, ...]:
        return tuple(leg.name for leg in self.legs)

    @property
    def inertia_matrix(self) -> np.ndarray:
        return np.asarray(self.inertia, dtype=float)

    @property
    def nominal_footholds(self) -> np.ndarray:
        """(L, 3) nominal feet in the body frame. [m]"""
        return np.array([leg.nominal_foothold for leg in self.legs], dtype=float)

    @property
    def box_half_sizes(self) -> np.ndarray:
        """(L, 3) kinematic box half sizes. [m]"""
        return np.array([leg.box_half_size for leg in self.legs], dtype=float)

    @property
    def max_normal_forces(self) -> np.ndarray:
        """(L,) force limits along the normal. [N]"""
        return np.array([leg.max_normal_force for leg in self.legs], dtype=float)

    @property
    def weight(self) -> float:
        """m g, the unit of the optimiser's forces. [N]"""
        return self.mass * self.gravity

    @property
    def nominal_height(self) -> float:
        """Height of the CoM above flat ground when every foot is on its nominal foothold. [m]"""
        return float(self.foot_radius - self.nominal_footholds[:, 2].mean())


def _quad_legs(x, y, z, box, f_max, hip_y=None):
    # TOWR's order: LF, RF, LH, RH.
    hip_y = y if hip_y is None else hip_y
    signs = (("LF", 1, 1), ("RF", 1, -1), ("LH", -1, 1), ("RH", -1, -1))
    return tuple(LegModel(name, (sx * x, sy * y, z), box, f_max, (sx * x, sy * hip_y, 0.0))
                 for name, sx, sy in signs)


def hyq() -> RobotModel:
    """HyQ as TOWR models it: 83 kg, diag inertia (4.26, 8.97, 9.88) kg m^2, nominal stance
    (+-0.31, +-0.29, -0.58) m, box +-(0.25, 0.20, 0.10) m, 1000 N per leg; point feet."""
    # TOWR's products of inertia (Ixy, Ixz, Iyz) = (-0.0063, 0.193, 0.0126).
    inertia = ((4.26, -0.0063, 0.193), (-0.0063, 8.97, 0.0126), (0.193, 0.0126, 9.88))
    return RobotModel(name="hyq", mass=83.0, inertia=inertia,
                      legs=_quad_legs(0.31, 0.29, -0.58, (0.25, 0.20, 0.10), 1000.0),
                      foot_radius=0.0, gaits=("trot", "crawl"))


def quadruped() -> RobotModel:
    """The small static-gait quadruped of paper 003, LittleDog-sized (our numbers: the paper
    gives none): 2.9 kg, 0.30 m x 0.18 m trunk, hips at (+-0.10, +-0.07), standing 0.16 m."""
    mass = 2.9
    # A 0.30 x 0.18 x 0.06 m box of the trunk's mass plus the hip-mounted motors. [kg*m^2]
    inertia = ((0.0095, 0.0, 0.0), (0.0, 0.0250, 0.0), (0.0, 0.0, 0.0310))
    legs = _quad_legs(0.10, 0.11, -0.145, (0.06, 0.04, 0.04), 40.0, hip_y=0.07)
    return RobotModel(name="quadruped", mass=mass, inertia=inertia, legs=legs,
                      foot_radius=0.01, gaits=("crawl", "trot"))


# Largest normal force of one Qingzhui leg: 250 N*m at the hip over a ~0.4 m lever. [N]
QINGZHUI_MAX_NORMAL_FORCE = 600.0


def qingzhui(topology: str = "nominal") -> RobotModel:
    """Qingzhui standing in one of its six topologies: mass and inertia of the whole robot in
    that pose (from the Drake plant), nominal footholds and kinematic boxes of the topology."""
    from qz_drake.robot.model import standing_rigid_body
    from qz_drake.robot.params import DEFAULT_PARAMS, LEG_NAMES
    from qz_drake.robot.topology import get_topology
    from qz_drake.robot.urdf import (LINK_COLLISION_RADIUS, SHANK_COLLISION_END_INSET,
                                     THIGH_COLLISION_START)

    topo = get_topology(topology)
    mass, inertia, com_B = standing_rigid_body(topology)
    params = DEFAULT_PARAMS
    footholds = topo.footholds_B - com_B
    legs = tuple(
        LegModel(name, tuple(float(v) for v in footholds[i]),
                 tuple(float(v) for v in topo.box_half_size), QINGZHUI_MAX_NORMAL_FORCE,
                 tuple(float(v) for v in params.hip_position(i) - com_B), params.leg_mass,
                 LegLinks(params.thigh_length, params.shank_length, int(topo.bends[i]),
                          tuple(float(v) for v in params.R_BL(i)[:, 0])))
        for i, name in enumerate(LEG_NAMES))
    inertia = 0.5 * (inertia + inertia.T)
    return RobotModel(name=f"qingzhui/{topology}", mass=float(mass),
                      inertia=tuple(tuple(float(v) for v in row) for row in inertia),
                      legs=legs, foot_radius=params.foot_radius,
                      com_B=tuple(float(v) for v in com_B),
                      gaits=("tripod", "tetrapod", "wave"),
                      link_radius=LINK_COLLISION_RADIUS,
                      thigh_collision=(THIGH_COLLISION_START, params.thigh_length),
                      shank_collision=(0.0, params.shank_length - SHANK_COLLISION_END_INSET))


ROBOT_NAMES = ("qingzhui", "hyq", "quadruped")


def make_robot(name: str, topology: str = "nominal") -> RobotModel:
    """Returns a preset by name (``topology`` only applies to Qingzhui)."""
    if name == "qingzhui":
        return qingzhui(topology)
    if name == "hyq":
        return hyq()
    if name == "quadruped":
        return quadruped()
    raise bad_value("robot", name, f"expected one of {', '.join(ROBOT_NAMES)}", ConfigError)
