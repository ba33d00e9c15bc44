"""A robot of one's own with the BLC, the way docs/own_robot.md describes it (issue 39).

The robot is none of the three shipped ones: a 'stilt' quadruped written here as a URDF, with
HyQ-like legs (abduction about the body's x axis, hip and knee about y) of other dimensions
and masses than any model in the package. ``UrdfRobot`` reads it standing; a RobotModel is
built from that as the guide shows, and the BLC plans a flat 1 m walk with it. The same reader
on Qingzhui's URDF gives exactly the package's own Qingzhui model: the hand check of the reader.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from pydrake.math import RollPitchYaw

from qz_drake.errors import KinematicsError
from qz_drake.robot.description import UrdfRobot
from qz_drake.robot.model import QINGZHUI_URDF
from qz_drake.robot.params import LEG_NAMES
from qz_drake.robot.topology import get_topology
from qz_drake.robot.urdf import joint_names
from qz_drake.trajopt.robot_model import LegLinks, LegModel, RobotModel, qingzhui
from qz_drake.trajopt.solver import BlcTask, solve_blc
from qz_drake.config import TerrainConfig
from qz_drake.station import make_heightmap

REPO = Path(__file__).resolve().parents[1]
GUIDE = REPO / "docs" / "own_robot.md"
STILT_URDF = REPO / "docs" / "own_robot" / "stilt.urdf"
# The stilt quadruped: a 0.7 x 0.4 x 0.12 m, 16 kg trunk; hips at (+-0.3, +-0.17); thigh 0.30 m,
# shank 0.32 m, 1.5 kg per leg; feet spheres of 0.025 m at the shank's end.
HALF_LENGTH, HALF_WIDTH = 0.30, 0.17
THIGH, SHANK, FOOT_RADIUS = 0.30, 0.32, 0.025
LEGS = {"LF": (1, 1), "RF": (1, -1), "LH": (-1, 1), "RH": (-1, -1)}  # the trot gait's order
# Standing: hip 0.5 rad, knee -1.0 rad: each foot 0.544 m below its hip and 1 cm ahead, the knee
# behind (a positive angle about y swings a link hanging down backwards).
STANDING = {**{f"{leg}_hfe": 0.5 for leg in LEGS}, **{f"{leg}_kfe": -1.0 for leg in LEGS}}


def _link(name: str, mass: float, length: float) -> str:
    # A thin rod along z (its axial moment small but physical: no larger than the other two).
    inertia = mass * length ** 2 / 12 + 1e-5
    return (f'  <link name="{name}">\n    <inertial>\n      <origin xyz="0 0 {-length / 2:g}"/>\n'
            f'      <mass value="{mass:g}"/>\n'
            f'      <inertia ixx="{inertia:.6g}" iyy="{inertia:.6g}" izz="1e-05" ixy="0" ixz="0" iyz="0"/>\n'
            '    </inertial>\n  </link>\n')


def _joint(name: str, parent: str, child: str, xyz, axis: str, lower: float, upper: float) -> str:
    return (f'  <joint name="{name}" type="revolute">\n    <parent link="{parent}"/>\n    <child link="{child}"/>\n'
            f'    <origin xyz="{xyz[0]:g} {xyz[1]:g} {xyz[2]:g}"/>\n    <axis xyz="{axis}"/>\n'
            f'    <limit lower="{lower:g}" upper="{upper:g}" effort="150" velocity="10"/>\n  </joint>\n')


def stilt_urdf() -> str:
    """The text of docs/own_robot/stilt.urdf."""
    parts = ['<?xml version="1.0"?>\n',
             "<!-- The stilt quadruped of docs/own_robot.md, written by tests/test_own_robot.py:stilt_urdf. -->\n",
             '<robot name="stilt">\n',
             '  <link name="trunk">\n    <inertial>\n      <mass value="16"/>\n'
             '      <inertia ixx="0.23" iyy="0.67" izz="0.87" ixy="0" ixz="0" iyz="0"/>\n    </inertial>\n  </link>\n']
    for leg, (sx, sy) in LEGS.items():
        parts += [_link(f"{leg}_hip", 0.8, 0.01), _link(f"{leg}_thigh", 0.4, THIGH), _link(f"{leg}_shank", 0.25, SHANK),
                  f'  <link name="{leg}_foot">\n    <inertial>\n      <mass value="0.05"/>\n'
                  '      <inertia ixx="1e-05" iyy="1e-05" izz="1e-05" ixy="0" ixz="0" iyz="0"/>\n'
                  '    </inertial>\n  </link>\n',
                  _joint(f"{leg}_haa", "trunk", f"{leg}_hip", (sx * HALF_LENGTH, sy * HALF_WIDTH, 0), "1 0 0", -0.6, 0.6),
                  _joint(f"{leg}_hfe", f"{leg}_hip", f"{leg}_thigh", (0, 0, 0), "0 1 0", -1.2, 1.6),
                  _joint(f"{leg}_kfe", f"{leg}_thigh", f"{leg}_shank", (0, 0, -THIGH), "0 1 0", -2.6, -0.2),
                  f'  <joint name="{leg}_foot_fixed" type="fixed">\n    <parent link="{leg}_shank"/>\n'
                  f'    <child link="{leg}_foot"/>\n    <origin xyz="0 0 {-SHANK:g}"/>\n  </joint>\n']
    return "".join(parts) + "</robot>\n"


def test_committed_stilt_urdf_is_the_tests():
    assert STILT_URDF.read_text() == stilt_urdf(), "docs/own_robot/stilt.urdf is stale: write stilt_urdf() to it"


def test_the_guides_code_runs():
    """docs/own_robot.md's Python blocks, run in order from the repository's root as a user would."""
    text = GUIDE.read_text()
    blocks = [block.split("```", 1)[0] for block in text.split("```python\n")[1:]]
    assert len(blocks) >= 3
    namespace = {}
    cwd = os.getcwd()
    os.chdir(REPO)
    try:
        exec(compile("\n".join(blocks), str(GUIDE), "exec"), namespace)
    finally:
        os.chdir(cwd)
    assert namespace["solution"].success, namespace["solution"].reason
    assert namespace["robot"].name == "stilt" and namespace["robot"].num_legs == 4


@pytest.fixture(scope="module")
def stilt() -> UrdfRobot:
    return UrdfRobot(STILT_URDF, feet={leg: f"{leg}_foot" for leg in LEGS}, standing=STANDING)


def stilt_model(stilt: UrdfRobot) -> RobotModel:
    """The RobotModel of docs/own_robot.md, step 3, for the stilt quadruped."""
    legs = []
    for i, name in enumerate(stilt.leg_names):
        chain = stilt.leg_chain(i)
        box = stilt.largest_box(i, (0.15, 0.10, 0.08))
        legs.append(LegModel(name, tuple(stilt.footholds_B[i]), tuple(box), max_normal_force=400.0,
                             hip_position=tuple(stilt.hips_B[i]), mass=float(stilt.leg_masses[i]),
                             links=LegLinks(chain.thigh_length, chain.shank_length, chain.knee_bend,
                                            chain.radial_axis)))
    return RobotModel(name="stilt", mass=stilt.mass, inertia=tuple(map(tuple, stilt.inertia)), legs=tuple(legs),
                      foot_radius=FOOT_RADIUS, com_B=tuple(stilt.com_B), gaits=("trot", "crawl"),
                      link_radius=0.02, thigh_collision=(0.05, THIGH), shank_collision=(0.0, SHANK - 0.03))


def test_stilt_mass_properties_and_stance_are_its_urdf(stilt):
    assert stilt.leg_names == tuple(LEGS)
    assert stilt.mass == pytest.approx(16 + 4 * (0.8 + 0.4 + 0.25 + 0.05))
    np.testing.assert_allclose(stilt.leg_masses, 1.5)
    # Symmetric left-right and front-hind: the CoM on the trunk's centre line, below the hips
    # (the legs hang down).
    assert abs(stilt.com_B[1]) < 1e-12 and stilt.com_B[2] < 0
    # By hand: the foot below its hip by l1 cos 0.5 + l2 cos(0.5 - 1.0) and ahead of it by
    # -l1 sin 0.5 - l2 sin(0.5 - 1.0).
    drop = THIGH * np.cos(0.5) + SHANK * np.cos(-0.5)
    ahead = -THIGH * np.sin(0.5) - SHANK * np.sin(-0.5)
    assert drop == pytest.approx(0.544, abs=1e-3) and ahead == pytest.approx(0.0096, abs=1e-4)
    feet = stilt.footholds_B + stilt.com_B
    np.testing.assert_allclose(feet[:, 2], -drop, atol=1e-12)
    np.testing.assert_allclose(feet[:, 0], [sx * HALF_LENGTH + ahead for sx, _ in LEGS.values()], atol=1e-12)
    np.testing.assert_allclose(stilt.hips_B + stilt.com_B,
                               [[sx * HALF_LENGTH, sy * HALF_WIDTH, 0] for sx, sy in LEGS.values()], atol=1e-12)
    assert np.all(np.linalg.eigvalsh(stilt.inertia) > 0)


def test_stilt_legs_are_planar_two_link_legs(stilt):
    for i in range(stilt.num_legs):
        chain = stilt.leg_chain(i)
        assert chain.thigh_length == pytest.approx(THIGH) and chain.shank_length == pytest.approx(SHANK)
        np.testing.assert_allclose(chain.radial_axis, (1, 0, 0), atol=1e-12)
        # The knee lies behind the hip-foot line: on the side j0's axis (+x) does not point to.
        assert chain.knee_bend == -1


def test_stilt_boxes_are_reachable_and_no_larger(stilt):
    box = stilt.largest_box(0, (0.15, 0.10, 0.08))
    assert 0.02 < box[0] <= 0.15
    assert stilt.unreachable_corners(0, box) == []
    assert stilt.unreachable_corners(0, 1.1 * box) != []
    # Beyond the stretched leg (0.62 m) nothing is reachable.
    assert len(stilt.unreachable_corners(0, (0.05, 0.05, 0.2))) >= 4


def test_stilt_walks_a_flat_metre_with_the_blc(stilt):
    robot = stilt_model(stilt)
    flat = make_heightmap(TerrainConfig(kind="flat"))
    solution = solve_blc(BlcTask(target=(1.0, 0.0, 0.0), duration=3.0), robot, flat)
    assert solution.success, solution.reason
    samples = solution.sample(50.0)
    end = samples["base_pos"][-1]
    assert end[:2] == pytest.approx([1.0, 0.0], abs=0.02)
    # The CoM at the robot's standing height: its legs, not Qingzhui's, carry it.
    assert end[2] == pytest.approx(robot.nominal_height, abs=0.05)
    # Every stance foot in its box around the nominal foothold, in the body frame.
    for k in range(len(samples["t"])):
        R_WB = RollPitchYaw(samples["base_rpy"][k]).ToRotationMatrix().matrix()
        p_B = (samples["foot_pos"][k] - samples["base_pos"][k]) @ R_WB
        inside = np.abs(p_B - robot.nominal_footholds) <= robot.box_half_sizes + 1e-3
        assert np.all(inside[samples["contact"][k]]), (samples["t"][k], p_B)
    # The feet stepped: each moved about the metre the body did.
    moved = samples["foot_pos"][-1, :, 0] - samples["foot_pos"][0, :, 0]
    np.testing.assert_allclose(moved, 1.0, atol=0.15)


def test_qingzhui_read_from_its_urdf_is_the_packages_model():
    """The hand check: the reader on models/qingzhui.urdf in the hind_bend pose gives what
    trajopt.robot_model.qingzhui builds from the parameters."""
    q = get_topology("hind_bend").standing_pose()
    robot = UrdfRobot(QINGZHUI_URDF, feet={leg: f"{leg}_foot" for leg in LEG_NAMES},
                      standing=dict(zip(joint_names(), q)))
    model = qingzhui("hind_bend")
    assert robot.mass == pytest.approx(model.mass)
    np.testing.assert_allclose(robot.inertia, model.inertia_matrix, atol=1e-9)
    np.testing.assert_allclose(robot.com_B, model.com_B, atol=1e-9)
    np.testing.assert_allclose(robot.footholds_B, model.nominal_footholds, atol=1e-9)
    np.testing.assert_allclose(robot.hips_B, [leg.hip_position for leg in model.legs], atol=1e-9)
    for i, leg in enumerate(model.legs):
        chain = robot.leg_chain(i)
        assert (chain.thigh_length, chain.shank_length, chain.knee_bend) == pytest.approx(
            (leg.links.thigh_length, leg.links.shank_length, leg.links.knee_bend))
        np.testing.assert_allclose(chain.radial_axis, leg.links.radial_axis, atol=1e-12)
        assert robot.leg_masses[i] == pytest.approx(leg.mass)
        assert robot.unreachable_corners(i, leg.box_half_size) == []


# -- what the reader refuses, naming the field and the value --------------------------------------
@pytest.mark.parametrize("kwargs, named", [
    (dict(feet={"LF": "LF_toe"}), "feet[LF] = 'LF_toe'"),
    (dict(feet={"LF": "trunk"}), "feet[LF] = 'trunk'"),
    (dict(feet={}), "feet = {}"),
    (dict(standing={"LF_knee": -1.0}), "standing = 'LF_knee'"),
    (dict(standing={"LF_kfe": 0.5}), "standing[LF_kfe] = 0.5"),
    (dict(standing=STANDING | {"LF_hfe": 0.9}), "standing = {"),
    (dict(standing={"LF_hfe": 0.5}), "standing[LF_kfe] = 0.0"),
    (dict(base="body"), "base = 'body'"),
    (dict(urdf="no/such/robot.urdf"), "urdf = 'no/such/robot.urdf'"),
], ids=["unknown_frame", "foot_on_base", "no_feet", "unknown_joint", "outside_limits", "not_level", "unnamed_outside_limits",
        "unknown_base", "missing_file"])
def test_bad_descriptions_are_refused(kwargs, named):
    arguments = dict(urdf=stilt_urdf(), feet={leg: f"{leg}_foot" for leg in LEGS}, standing=STANDING) | kwargs
    with pytest.raises(KinematicsError) as error:
        UrdfRobot(arguments.pop("urdf"), **arguments)
    assert str(error.value).startswith(named), str(error.value)


def test_a_leg_off_its_plane_has_no_two_link_model():
    # The knee moved 3 cm sideways: thigh and shank no longer in a plane through j0's axis.
    urdf = stilt_urdf().replace(f'<origin xyz="0 0 {-THIGH:g}"/>', f'<origin xyz="0 0.03 {-THIGH:g}"/>', 1)
    assert urdf != stilt_urdf()
    robot = UrdfRobot(urdf, feet={leg: f"{leg}_foot" for leg in LEGS}, standing=STANDING)
    with pytest.raises(KinematicsError, match=r"^feet\[LF\] = 'LF_foot': its knee lies [0-9.]+ mm off"):
        robot.leg_chain(0)
    assert robot.leg_chain(1).knee_bend == -1
    with pytest.raises(KinematicsError, match=r"^half_size = \[0.1, -0.1, 0.1\]"):
        robot.unreachable_corners(1, (0.1, -0.1, 0.1))


def test_a_standing_pose_on_a_joint_limit_has_no_box():
    # Knees at their upper limit (-0.2 rad, nearly straight): no foot can move down from there.
    at_limit = {**{f"{leg}_hfe": 0.1 for leg in LEGS}, **{f"{leg}_kfe": -0.2 for leg in LEGS}}
    robot = UrdfRobot(STILT_URDF, feet={leg: f"{leg}_foot" for leg in LEGS}, standing=at_limit)
    with pytest.raises(KinematicsError, match=r"^feet\[RF\] = 'RF_foot': cannot move from its standing foothold"):
        robot.largest_box(1, (0.1, 0.1, 0.1))
