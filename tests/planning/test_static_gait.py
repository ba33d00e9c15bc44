"""Static-gait search of paper 003 section 3: unit cases and the depth claim of Fig. 10."""

import math

import numpy as np
import pytest

from qz_drake.errors import ConfigError
from qz_drake.planning.static_gait import (LEG_ORDER, LEGS, QuadrupedGeometry, StaticGaitConfig,
                                           body_projection, cuboid_terrain, search_gait, support_margin)


def test_support_margin_hand_checked():
    triangle = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    # Nearest edges x = 0 and y = 0 at 0.2; the hypotenuse at (1 - 0.4) / sqrt 2 = 0.424.
    assert support_margin([0.2, 0.2], triangle) == pytest.approx(0.2)
    assert support_margin([0.45, 0.45], triangle) == pytest.approx(0.1 / math.sqrt(2))
    assert support_margin([-0.1, 0.5], triangle) == pytest.approx(-0.1)  # outside
    assert support_margin([0.2, 0.2], triangle[::-1]) == pytest.approx(0.2)  # either winding


def test_body_projection_eq21_lies_between_crossing_and_side():
    feet = np.array([[0.1, 0.075], [0.1, -0.075], [-0.1, 0.075], [-0.1, -0.075]])  # LEGS order
    # LF swings: towards the right pair's midpoint (0, -0.075) from the centre.
    assert body_projection(feet, "LF", 0.5) == pytest.approx([0.0, -0.0375])
    assert body_projection(feet, "RB", 0.4) == pytest.approx([0.0, 0.03])
    stand = [LEGS.index(leg) for leg in LEGS if leg != "LF"]
    assert support_margin(body_projection(feet, "LF", 0.5), feet[stand]) > 0


def test_unreachable_foothold_rejected():
    geometry = QuadrupedGeometry()
    hip = geometry.hip_B("LF")
    below = hip + np.array([0.0, geometry.shoulder, -0.12])
    assert geometry.reachable("LF", below)
    assert not geometry.reachable("LF", hip + np.array([0.0, geometry.shoulder, -0.5]))  # too far
    assert not geometry.reachable("LF", hip + np.array([0.15, geometry.shoulder, -0.05]))  # too far ahead
    assert not geometry.reachable("LF", hip + np.array([0.0, geometry.shoulder, 0.05]))  # above the hip


def test_flat_ground_walks_the_standard_order():
    result = search_gait(cuboid_terrain(0, max_height=0.0), (0.0, 0.0), 0.0, steps=8, depth=2)
    assert result.success and result.reason == "found"
    assert [s.leg for s in result.states] == list(LEG_ORDER) * 2
    # Two cycles move every foot two strides forward.
    moved = result.states[-1].feet[:, 0] - result.states[0].feet[:, 0]
    assert moved[LEGS.index("LF")] == pytest.approx(StaticGaitConfig().stride, abs=0.011)


def test_a_wall_is_a_dead_end():
    terrain = cuboid_terrain(0, max_height=0.0)
    terrain.heights[:, terrain.x_coords > 0.15] = 0.3
    result = search_gait(terrain, (0.0, 0.0), 0.0, steps=8, depth=2)
    assert not result.success and "dead end" in result.reason


@pytest.mark.parametrize("kwargs, field", [({"steps": 0}, "steps"), ({"depth": 0}, "depth")])
def test_bad_arguments_name_the_field(kwargs, field):
    args = {"steps": 4, "depth": 1, **kwargs}
    with pytest.raises(ConfigError, match=field):
        search_gait(cuboid_terrain(0, max_height=0.0), (0.0, 0.0), 0.0, **args)


def test_deeper_search_succeeds_more_often_on_cuboids():
    """Fig. 10: looking four steps ahead avoids dead ends that a greedy (depth 1) search hits."""
    successes = {1: 0, 4: 0}
    for seed in range(24):
        terrain = cuboid_terrain(seed, max_height=0.025)
        for depth in successes:
            successes[depth] += search_gait(terrain, (0.0, 0.0), 0.0, steps=8, depth=depth).success
    assert successes[4] > successes[1]
    assert 0 < successes[1] < 24  # the terrain is neither trivial nor impossible
