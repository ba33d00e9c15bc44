"""Any legged robot's URDF, standing, read as the BLC's single rigid body needs it (paper 000
section II-A, Eq. 1-2; docs/own_robot.md is the guide).

The BLC's ``RobotModel`` (``qz_drake/trajopt/robot_model.py``) is a rigid body with point feet:
mass, rotational inertia about the centre of mass, nominal footholds, a kinematic box per foot
and, for keeping the legs off the terrain, each leg's thigh and shank. Qingzhui's model takes
these from its own parameters; ``UrdfRobot`` takes them from a Drake plant of any URDF (or SDF)
given the frames of the feet and the joint angles of a standing pose, so that a robot of one's
own is described by measurement, not by hand. Frames are the RobotModel's: the body frame B has
the base link's axes and its origin at the whole robot's centre of mass in that pose.

Kinematic boxes are a choice (how far a foot may stray from its nominal foothold), so they are
not derived; ``unreachable_corners`` and ``largest_box`` check one against the leg's reach by
inverse kinematics within the URDF's joint limits, the test Qingzhui's boxes pass
(``tests/robot/test_model.py``).
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import JacobianWrtVariable, RevoluteJoint

from qz_drake.errors import KinematicsError, bad_value

# Feet of a standing pose may differ in height by this much (rounding in a URDF's numbers);
# more is not a stance on flat ground, which the nominal footholds are. [m]
LEVEL_TOLERANCE = 0.005
# How far the thigh may start off j0's axis, and the URDF's knee may lie from where the
# two-link model of the legs' clearance puts it, for that model to hold. [m]
PLANAR_TOLERANCE = 0.001
# A box corner counts as reached when the foot's inverse kinematics ends this close to it. [m]
REACH_TOLERANCE = 1e-4
# Damped least squares: damping [m] and iterations. From the standing pose a 3-DoF leg reaches
# a corner 0.2 m away in 10-20 iterations; 100 leave room for steps clipped at a joint limit.
_IK_DAMPING = 1e-3
_IK_ITERATIONS = 100


@dataclasses.dataclass(frozen=True)
class LegChain:
    """A leg as a two-link chain in a plane through j0's axis (the model of the legs' clearance,
    ``trajopt/legs.py``): what ``LegLinks`` holds."""

    # Hip (where the thigh starts: j1's axis) to knee (j2's axis), knee to foot frame. [m]
    thigh_length: float
    shank_length: float
    # +1: the knee on the side of the hip-foot line that j0's axis points to, -1: the other.
    knee_bend: int
    # j0's axis in the body frame, unit.
    radial_axis: tuple[float, float, float]


class UrdfRobot:
    """A legged robot's URDF in a standing pose: mass properties, feet, hips and legs in the
    BLC's body frame B, and the legs' reach.

    Args:
        urdf: path of a URDF or SDF file, or URDF text (starting with ``<``).
        feet: leg name -> the frame at that foot's centre (a foot sphere's centre), in the
            order the BLC's gaits number the legs (docs/own_robot.md).
        standing: joint name -> angle [rad] of the standing pose; joints not named are at 0.
            Every foot must end at the same height (flat ground).
        base: the floating base link; default the root of the model's tree.
    """

    def __init__(self, urdf: str | Path, *, feet: Mapping[str, str], standing: Mapping[str, float],
                 base: str | None = None):
        plant = MultibodyPlant(0.0)
        parser = Parser(plant)
        if isinstance(urdf, str) and urdf.lstrip().startswith("<"):
            (instance,) = parser.AddModelsFromString(urdf, "urdf")
        else:
            path = Path(urdf)
            if not path.is_file():
                raise bad_value("urdf", str(urdf), "no such file", KinematicsError)
            (instance,) = parser.AddModels(str(path))
        joints = [plant.get_joint(j) for j in plant.GetJointIndices(instance)]
        base_body = plant.GetBodyByName(base, instance) if base and plant.HasBodyNamed(base, instance) \
            else None
        if base and base_body is None:
            raise bad_value("base", base, "no such link in the model", KinematicsError)
        if base_body is None:
            children = {j.child_body().index() for j in joints}
            roots = [plant.get_body(b) for b in plant.GetBodyIndices(instance) if b not in children]
            if len(roots) != 1:
                raise bad_value("base", base, f"the model has {len(roots)} root links "
                                f"({', '.join(b.name() for b in roots)}): name one", KinematicsError)
            base_body = roots[0]
        # The base welded to the world: B's axes are the world's, and the legs' joints are all
        # of q.
        plant.WeldFrames(plant.world_frame(), base_body.body_frame())
        plant.Finalize()
        self._plant = plant
        self._context = plant.CreateDefaultContext()
        self._base = base_body.body_frame()
        if not feet:
            raise bad_value("feet", dict(feet), "name at least one foot frame", KinematicsError)
        self.leg_names = tuple(feet)
        self._feet = []
        for leg, frame in feet.items():
            if not plant.HasFrameNamed(frame, instance):
                raise bad_value(f"feet[{leg}]", frame, "no such frame in the model", KinematicsError)
            self._feet.append(plant.GetFrameByName(frame, instance))
        self._chains = [self._chain(leg, foot, joints) for leg, foot in zip(self.leg_names, self._feet)]

        q = np.zeros(plant.num_positions())
        names = {j.name(): j for j in joints if j.num_positions() == 1}
        for name, angle in standing.items():
            if name not in names:
                raise bad_value("standing", name, "not a one-degree-of-freedom joint of the model",
                                KinematicsError)
            q[names[name].position_start()] = angle
        for name, joint in names.items():
            low, high = joint.position_lower_limits()[0], joint.position_upper_limits()[0]
            angle = q[joint.position_start()]
            if not low <= angle <= high:
                unnamed = "" if name in standing else " (a joint standing does not name is at 0)"
                raise bad_value(f"standing[{name}]", float(angle),
                                f"outside the joint's limits [{low:g}, {high:g}]{unnamed}", KinematicsError)
        self.standing_q = q
        plant.SetPositions(self._context, q)

        spatial = plant.CalcSpatialInertia(self._context, self._base, plant.GetBodyIndices(instance))
        self.mass = float(spatial.get_mass())
        # CoM in the base link frame, and the inertia about it (the I of Eq. 2). [m, kg*m^2]
        self.com_B = np.array(spatial.get_com())
        self.inertia = np.array(spatial.Shift(self.com_B).CalcRotationalInertia().CopyToFullMatrix3())
        self.inertia = 0.5 * (self.inertia + self.inertia.T)
        feet_base = np.array([self._in_base(foot) for foot in self._feet])
        spread = float(np.ptp(feet_base[:, 2]))
        if spread > LEVEL_TOLERANCE:
            raise bad_value("standing", dict(standing), f"puts the feet at heights {spread:.3f} m apart; a standing "
                            f"pose has every foot on flat ground (within {LEVEL_TOLERANCE} m)", KinematicsError)
        # Nominal footholds and hips relative to the CoM: the RobotModel's nominal_foothold and
        # hip_position. [m]
        self.footholds_B = feet_base - self.com_B
        self.hips_B = np.array([self._in_base(chain[1].frame_on_child()) if len(chain) == 3
                                else self._in_base(chain[0].frame_on_child()) for chain in self._chains]) - self.com_B
        # Each leg's mass: the bodies its joints move. [kg]
        self.leg_masses = np.array([sum(plant.get_body(b).get_mass(self._context)
                                        for b in plant.GetBodiesKinematicallyAffectedBy([chain[0].index()]))
                                    for chain in self._chains])

    def _chain(self, leg: str, foot, joints) -> list:
        """The joints with a degree of freedom from the base out to the frame ``foot`` (fixed
        ones skipped)."""
        body = foot.body()
        by_child = {j.child_body().index(): j for j in joints}
        chain = []
        while body.index() != self._base.body().index():
            joint = by_child.get(body.index())
            if joint is None:
                raise bad_value(f"feet[{leg}]", foot.name(), "is not on a leg of the base link",
                                KinematicsError)
            if joint.num_positions() > 1:
                raise bad_value(f"feet[{leg}]", foot.name(),
                                f"hangs on joint {joint.name()} of {joint.num_positions()} degrees of freedom; "
                                "a leg's joints are revolute or prismatic", KinematicsError)
            if joint.num_positions() == 1:
                chain.append(joint)
            body = joint.parent_body()
        if not chain:
            raise bad_value(f"feet[{leg}]", foot.name(), "is fixed to the base: no joint moves it",
                            KinematicsError)
        return chain[::-1]

    def _in_base(self, frame) -> np.ndarray:
        return frame.CalcPose(self._context, self._base).translation().copy()

    @property
    def num_legs(self) -> int:
        return len(self.leg_names)

    def leg_chain(self, leg: int) -> LegChain:
        """Leg ``leg`` (an index into ``leg_names``) as the legs' clearance models it. Raises
        KinematicsError when it is not such a leg: three revolute joints, j1's axis through j0's,
        thigh and shank in a plane through j0's axis."""
        name = self.leg_names[leg]
        chain = self._chains[leg]
        if len(chain) != 3 or not all(isinstance(j, RevoluteJoint) for j in chain):
            raise bad_value(f"feet[{name}]", self._feet[leg].name(),
                            f"moves with {len(chain)} joints ({', '.join(j.type_name() for j in chain)}); "
                            "the legs' clearance models three revolute ones", KinematicsError)
        j0, j1, j2 = chain
        origin = self._in_base(j0.frame_on_child())
        R_BF = j0.frame_on_parent().CalcPose(self._context, self._base).rotation().matrix()
        axis = R_BF @ j0.revolute_axis()
        hip = self._in_base(j1.frame_on_child())
        knee = self._in_base(j2.frame_on_child())
        foot = self._in_base(self._feet[leg])
        off_axis = np.linalg.norm(np.cross(hip - origin, axis))
        if off_axis > PLANAR_TOLERANCE:
            raise bad_value(f"feet[{name}]", self._feet[leg].name(),
                            f"its thigh starts {off_axis * 1000:.1f} mm off {j0.name()}'s axis; the legs' "
                            "clearance models a thigh that starts on it", KinematicsError)
        thigh, shank = np.linalg.norm(knee - hip), np.linalg.norm(foot - knee)
        # The knee where the two-link model puts it, on either side (trajopt/legs.py).
        d = foot - hip
        dist = np.linalg.norm(d)
        u = d / dist
        along = 0.5 * ((thigh ** 2 - shank ** 2) / dist + dist)
        w = axis - (axis @ u) * u
        w /= np.linalg.norm(w)
        offset = np.sqrt(max(thigh ** 2 - along ** 2, 0.0))
        bend = 1 if (knee - hip - along * u) @ w >= 0 else -1
        miss = np.linalg.norm(hip + along * u + bend * offset * w - knee)
        if miss > PLANAR_TOLERANCE:
            raise bad_value(f"feet[{name}]", self._feet[leg].name(),
                            f"its knee lies {miss * 1000:.1f} mm off the plane of the hip-foot line and "
                            f"{j0.name()}'s axis; the legs' clearance models a planar leg in that plane",
                            KinematicsError)
        return LegChain(float(thigh), float(shank), bend, tuple(float(v) for v in axis))

    def reach(self, leg: int, p_B) -> tuple[np.ndarray, bool]:
        """Inverse kinematics of one leg from the standing pose: the joint positions (the whole
        q, the other legs standing) that bring foot ``leg`` nearest to ``p_B`` (body frame B,
        like the footholds) within the joint limits, and whether it got there."""
        plant, context = self._plant, self._context
        target = np.asarray(p_B, dtype=float) + self.com_B
        joints = self._chains[leg]
        index = np.array([j.position_start() for j in joints])
        v_index = np.array([j.velocity_start() for j in joints])
        low = np.array([j.position_lower_limits()[0] for j in joints])
        high = np.array([j.position_upper_limits()[0] for j in joints])
        q = self.standing_q.copy()
        foot = self._feet[leg]
        error = np.inf
        for _ in range(_IK_ITERATIONS):
            plant.SetPositions(context, q)
            residual = target - self._in_base(foot)
            error = float(np.linalg.norm(residual))
            if error < 0.1 * REACH_TOLERANCE:
                break
            J = plant.CalcJacobianTranslationalVelocity(context, JacobianWrtVariable.kQDot, foot, np.zeros(3),
                                                        self._base, self._base)[:, v_index]
            step = J.T @ np.linalg.solve(J @ J.T + _IK_DAMPING ** 2 * np.eye(3), residual)
            q[index] = np.clip(q[index] + step, low, high)
        plant.SetPositions(context, self.standing_q)
        return q, error < REACH_TOLERANCE

    def unreachable_corners(self, leg: int, half_size) -> list[tuple[float, float, float]]:
        """The corners of the box of ``half_size`` (x, y, z half widths [m], body axes) around
        leg ``leg``'s nominal foothold that its foot cannot reach within the joint limits, or
        that it reaches only with the knee on the other side (a box that crosses the stretched
        leg: the legs' clearance would model the wrong knee). Empty: the box is good."""
        half_size = np.asarray(half_size, dtype=float)
        if half_size.shape != (3,) or not np.all(np.isfinite(half_size)) or half_size.min() <= 0:
            raise bad_value("half_size", half_size.tolist(), "expected three positive half widths [m]",
                            KinematicsError)
        try:
            bend = self.leg_chain(leg).knee_bend
        except KinematicsError:
            bend = None  # no two-link model: reach alone decides
        missed = []
        for signs in itertools.product((-1.0, 1.0), repeat=3):
            corner = self.footholds_B[leg] + np.array(signs) * half_size
            q, reached = self.reach(leg, corner)
            if reached and bend is not None:
                self._plant.SetPositions(self._context, q)
                reached = self.leg_chain(leg).knee_bend == bend
                self._plant.SetPositions(self._context, self.standing_q)
            if not reached:
                missed.append(tuple(float(v) for v in corner))
        return missed

    def largest_box(self, leg: int, shape, steps: int = 12) -> np.ndarray:
        """The largest box of the given proportions (x, y, z half widths [m]; a scale of 1 gives
        ``shape`` itself) whose corners foot ``leg`` reaches, by bisection on the scale in
        (0, 1]. Raises KinematicsError when even a millimetre's box is out of reach (the
        standing pose sits on a joint limit)."""
        shape = np.asarray(shape, dtype=float)
        if not self.unreachable_corners(leg, shape):
            return shape
        low, high = 0.0, 1.0
        for _ in range(steps):
            middle = 0.5 * (low + high)
            if self.unreachable_corners(leg, middle * shape):
                high = middle
            else:
                low = middle
        if low * shape.min() < 1e-3:
            raise bad_value(f"feet[{self.leg_names[leg]}]", self._feet[leg].name(),
                            "cannot move from its standing foothold: a joint is at its limit there",
                            KinematicsError)
        return low * shape
