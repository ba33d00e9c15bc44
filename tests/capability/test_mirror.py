"""The mirror augmentation of the capability networks' inputs (patches.mirror_inputs): it is
only sound if the robot, its topologies and its gait are symmetric about the sagittal plane
and if the mirrored inputs are what the planner would sample on the mirrored terrain."""

import numpy as np
import pytest

from qz_drake.capability import patches as P
from qz_drake.robot.params import DEFAULT_PARAMS, LEG_NAMES
from qz_drake.robot.topology import TOPOLOGY_NAMES, get_topology
from qz_drake.terrain.heightmap import HeightMap
from qz_drake.trajopt.gait import GAIT_GROUPS
from qz_drake.errors import QzError


def test_mirror_legs_pairs_the_sides_and_keeps_the_centreline():
    perm = P.mirror_legs()
    names = {LEG_NAMES[i]: LEG_NAMES[j] for i, j in enumerate(perm)}
    assert names == {"MF": "MF", "MB": "MB", "RF": "LF", "LF": "RF", "RB": "LB", "LB": "RB"}
    assert np.array_equal(perm[perm], np.arange(6))


def test_mirror_legs_refuses_an_asymmetric_robot():
    import dataclasses

    hips = list(DEFAULT_PARAMS.hip_positions)
    hips[1] = (0.27, -0.40, 0.0)
    with pytest.raises(QzError, match="hip_positions"):
        P.mirror_legs(dataclasses.replace(DEFAULT_PARAMS, hip_positions=tuple(hips)))


@pytest.mark.parametrize("name", TOPOLOGY_NAMES)
def test_every_topology_is_its_own_mirror_image(name):
    topology = get_topology(name)
    perm = P.mirror_legs()
    assert tuple(np.asarray(topology.bends)[perm]) == tuple(topology.bends)
    mirrored = topology.footholds_B[perm] * np.array([1.0, -1.0, 1.0])
    # The kinematic boxes are centred on the footholds with one size for every leg.
    np.testing.assert_allclose(mirrored, topology.footholds_B, atol=1e-12)


def test_the_tripod_swings_mirror_symmetric_groups():
    perm = P.mirror_legs()
    for group in GAIT_GROUPS["tripod"]:
        assert {int(perm[i]) for i in group} == set(group)


@pytest.mark.parametrize("kind,heading", [("orthogonal", 0), ("diagonal", 1), ("orthogonal", 2), ("turn", 3)])
def test_mirrored_inputs_are_the_inputs_sampled_on_the_mirrored_terrain(kind, heading):
    rng = np.random.default_rng(4)
    heights = rng.uniform(0.0, 0.3, (81, 81))
    terrain = HeightMap(heights, 0.05, origin=(-2.0, -2.0))
    mirrored = HeightMap(heights[::-1, :].copy(), 0.05, origin=(-2.0, -2.0))  # y -> -y about y = 0
    x, y = 0.1, 0.0
    yaw = float(P.heading_yaw(heading))
    patch = P.sample_patches(terrain, x, y, yaw, kind)
    feet_W = P.nominal_feet_W(terrain, x, y, yaw, get_topology("front_bend"), DEFAULT_PARAMS.foot_radius)
    feet = P.feet_in_heading_frame(feet_W, x, y, yaw, P.ground_reference(terrain, x, y))
    direction = np.int8(P.TURN_LEFT) if kind == "turn" else None

    m_patch, m_feet, m_direction = P.mirror_inputs(patch, feet, direction, kind)

    # The planner's inputs for the mirrored robot (heading -yaw) on the mirrored terrain.
    patch_on_mirror = P.sample_patches(mirrored, x, -y, -yaw, kind)
    feet_W_on_mirror = P.nominal_feet_W(mirrored, x, -y, -yaw, get_topology("front_bend"), DEFAULT_PARAMS.foot_radius)
    feet_on_mirror = P.feet_in_heading_frame(feet_W_on_mirror, x, -y, -yaw, P.ground_reference(mirrored, x, -y))
    np.testing.assert_allclose(m_patch, patch_on_mirror, atol=1e-5)
    np.testing.assert_allclose(m_feet, feet_on_mirror, atol=1e-5)
    if kind == "turn":
        assert m_direction == P.TURN_RIGHT
    assert not np.allclose(m_patch, patch)  # the terrain is not symmetric: the test sees the flip


def test_mirroring_twice_is_the_identity_and_keeps_dtypes():
    rng = np.random.default_rng(0)
    patches = rng.normal(size=(5, 20, 20)).astype(np.float32)
    feet = rng.normal(size=(5, 6, 3)).astype(np.float32)
    direction = np.array([0, 1, 1, 0, 1], dtype=np.int8)
    once = P.mirror_inputs(patches, feet, direction, "turn")
    twice = P.mirror_inputs(*once, "turn")
    for a, b in zip((patches, feet, direction), twice):
        assert a.dtype == b.dtype and np.array_equal(a, b)
    assert np.array_equal(once[2], 1 - direction)
    # Moves keep their direction entry (-1 in the dataset).
    assert np.array_equal(P.mirror_inputs(patches, feet, np.full(5, -1, np.int8), "orthogonal")[2], np.full(5, -1))
