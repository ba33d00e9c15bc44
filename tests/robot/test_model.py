"""The URDF, the plant built from it, and the topologies."""

import itertools

import numpy as np
import pytest

from qz_drake.errors import KinematicsError
from qz_drake.robot import kinematics as kin
from qz_drake.robot.model import QINGZHUI_URDF, standing_rigid_body
from qz_drake.robot.params import DEFAULT_PARAMS, QingzhuiParams
from qz_drake.robot.topology import TOPOLOGY_NAMES, all_topologies, get_topology
from qz_drake.robot.urdf import make_urdf


def test_committed_urdf_is_generated_from_params():
    assert QINGZHUI_URDF.read_text() == make_urdf(DEFAULT_PARAMS), (
        "models/qingzhui.urdf is stale: run scripts/make_urdf.py")


def test_mass_properties_match_the_paper():
    mass, inertia, com = standing_rigid_body("nominal")
    assert mass == pytest.approx(60.0, abs=0.5)
    assert DEFAULT_PARAMS.leg_mass == pytest.approx(5.8)
    assert DEFAULT_PARAMS.hip_mass / DEFAULT_PARAMS.leg_mass == pytest.approx(0.8, abs=0.01)
    np.testing.assert_allclose(inertia, inertia.T)
    assert np.all(np.linalg.eigvalsh(inertia) > 0)
    # A long, wide, flat body: roll < pitch < yaw inertia.
    assert inertia[0, 0] < inertia[1, 1] < inertia[2, 2]
    assert abs(com[0]) < 1e-9 and abs(com[1]) < 1e-9
    heavy, _, _ = standing_rigid_body("nominal", QingzhuiParams(payload_mass=20.0))
    assert heavy == pytest.approx(80.0, abs=0.5)


@pytest.mark.parametrize("name", TOPOLOGY_NAMES)
def test_topology_standing_pose_and_kinematic_box_are_reachable(name):
    topology = get_topology(name)
    q = topology.standing_pose()
    feet = kin.all_foot_positions(q)
    np.testing.assert_allclose(feet, topology.footholds_B, atol=1e-10)
    # Feet stand on flat ground at the nominal height.
    np.testing.assert_allclose(feet[:, 2], -DEFAULT_PARAMS.standing_height + DEFAULT_PARAMS.foot_radius)
    for i in range(6):
        corners = topology.footholds_B[i] + np.array(
            list(itertools.product([-1, 1], repeat=3))) * topology.box_half_size
        _, ok = kin.leg_inverse_kinematics(i, corners, topology.bends[i])
        assert ok.all(), f"{name}: leg {i} box corner out of reach"
        # Stepping 0.2 m up onto a stair.
        up = topology.footholds_B[i] + np.array([0.0, 0.0, 0.20])
        assert kin.leg_inverse_kinematics(i, up, topology.bends[i])[1]


def test_topologies_differ_as_their_names_say():
    by_name = {t.name: t for t in all_topologies()}
    assert by_name["nominal"].bends == (1,) * 6
    assert [i for i, b in enumerate(by_name["hind_bend"].bends) if b < 0] == [2, 3, 4]
    assert [i for i, b in enumerate(by_name["front_bend"].bends) if b < 0] == [0, 1, 5]
    assert [i for i, b in enumerate(by_name["hind_1_bend"].bends) if b < 0] == [3]
    assert [i for i, b in enumerate(by_name["front_1_bend"].bends) if b < 0] == [0]
    spread = by_name["split_up"].footholds_B[0, 0] - by_name["split_up"].footholds_B[3, 0]
    nominal = by_name["nominal"].footholds_B[0, 0] - by_name["nominal"].footholds_B[3, 0]
    assert spread > nominal + 0.1


def test_unknown_topology_names_the_field():
    with pytest.raises(KinematicsError, match="topology = 'tripod'"):
        get_topology("tripod")
