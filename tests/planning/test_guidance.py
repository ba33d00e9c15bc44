"""Guidance path -> BLC missions: merged within the BLC's reach and a success threshold, a
topology change on its own."""

import math

import numpy as np
import pytest

from qz_drake.errors import QzError
from qz_drake.planning.capability_mdp import PathStep
from qz_drake.planning.guidance import MissionSplitConfig, split_missions


def _path(actions, x=0.0, y=0.0, k=0, topology="nominal"):
    """PathSteps of (motion, action topology, success) from (x, y, k)."""
    steps = []
    for motion, action_topology, p in actions:
        steps.append(PathStep(x, y, k, topology, action_topology, motion, p))
        if motion == "forward":
            dx, dy = [(1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1)][k]
            x, y = x + dx, y + dy
        else:
            k = (k + (1 if motion == "turn_left" else -1)) % 8
        topology = action_topology
    return steps


def test_straight_moves_merge_up_to_the_blc_reach():
    missions = split_missions(_path([("forward", "nominal", 0.99)] * 5))
    assert [m.target[:2] for m in missions] == [(2.0, 0.0), (4.0, 0.0), (5.0, 0.0)]
    assert [len(m.steps) for m in missions] == [2, 2, 1]
    assert missions[0].success == pytest.approx(0.99 ** 2)


def test_a_risky_move_is_a_mission_of_its_own_and_a_topology_change_starts_one():
    steps = _path([("forward", "nominal", 0.99), ("forward", "nominal", 0.6), ("forward", "nominal", 0.99),
                   ("forward", "hind_bend", 0.95), ("forward", "hind_bend", 0.95)])
    missions = split_missions(steps)
    assert [(len(m.steps), m.topology) for m in missions] == [(1, "nominal"), (1, "nominal"), (1, "nominal"),
                                                           (2, "hind_bend")]
    assert missions[-1].target == (5.0, 0.0, 0.0)


def test_turns_merge_with_moves_and_yaws_unwrap():
    steps = _path([("turn_right", "nominal", 1.0), ("turn_right", "nominal", 1.0), ("forward", "nominal", 1.0),
                   ("turn_right", "nominal", 1.0), ("turn_right", "nominal", 1.0), ("forward", "nominal", 1.0)])
    missions = split_missions(steps, start_yaw=0.0)
    # 90 deg of turning per mission at most: [R, R, F] then [R, R, F].
    assert [len(m.steps) for m in missions] == [3, 3]
    assert missions[0].target == pytest.approx((0.0, -1.0, -math.pi / 2))
    assert missions[1].target == pytest.approx((-1.0, -1.0, -math.pi))  # not +pi


def test_a_diagonal_move_counts_its_length():
    missions = split_missions(_path([("forward", "nominal", 1.0)] * 2, k=1))
    assert [len(m.steps) for m in missions] == [1, 1]  # 2.83 m > 2 m
    assert missions[0].length == pytest.approx(math.sqrt(2))


def test_turns_with_moves_never_leaves_a_turn_in_place_alone():
    # Two turns and a move whose product falls below the threshold, then a risky move.
    steps = _path([("turn_left", "nominal", 0.97), ("turn_left", "nominal", 0.97), ("forward", "nominal", 0.97),
                   ("forward", "nominal", 0.5), ("turn_right", "nominal", 0.97)])
    alone = MissionSplitConfig(min_success=0.95, turns_with_moves=False)
    assert [len(m.steps) for m in split_missions(steps, alone)] == [1, 1, 1, 1, 1]
    config = MissionSplitConfig(min_success=0.95)
    assert config.turns_with_moves  # the default
    missions = split_missions(steps, config)
    # The turns go with the move after them; the risky move stays alone; a turn with no move
    # after it (the route's end) is still a turn in place.
    assert [len(m.steps) for m in missions] == [3, 1, 1]
    assert missions[0].target == pytest.approx((0.0, 1.0, math.pi / 2))
    assert missions[0].success == pytest.approx(0.97 ** 3)
    # Not across a topology change, nor past the BLC's reach of turning.
    switch = _path([("turn_left", "nominal", 0.97), ("forward", "hind_bend", 0.97)])
    assert [len(m.steps) for m in split_missions(switch, config)] == [1, 1]
    about = _path([("turn_left", "nominal", 0.97)] * 3 + [("forward", "nominal", 0.97)])
    assert [len(m.steps) for m in split_missions(about, config)] == [2, 2]


def test_bad_settings_name_the_field():
    with pytest.raises(QzError, match="missions.max_length"):
        split_missions([], MissionSplitConfig(max_length=1.0))
    with pytest.raises(QzError, match="missions.min_success"):
        split_missions([], MissionSplitConfig(min_success=1.5))


def _box_field(box, height=0.3, stairs=False):
    """4 m x 4 m of 0.05 m cells centred on the origin, flat but for a box (xmin, xmax, ymin,
    ymax) of ``height``, or, with ``stairs``, steps of ``height`` every 0.4 m along x."""
    from qz_drake.terrain import HeightMap

    res = 0.05
    c = -2.0 + res / 2 + res * np.arange(80)
    gx, gy = np.meshgrid(c, c)
    if stairs:
        heights = height * np.floor((gx + 2.0) / 0.4)
    else:
        xmin, xmax, ymin, ymax = box
        heights = np.where((gx >= xmin) & (gx < xmax) & (gy >= ymin) & (gy < ymax), height, 0.0)
    return HeightMap(heights, res, (float(c[0]), float(c[0])))


def test_a_target_beside_a_box_moves_clear_of_it_on_its_own_level_and_a_clear_one_stays():
    """Issue 54, obstacles-hard: a cell's centre a few centimetres from a box's side (the grid is
    anchored at the start) is where the BLC refused moves and turns went against the box."""
    from qz_drake.planning.capability_mdp import edge_distances
    from qz_drake.planning.guidance import TARGET_CLEARANCE, placed_target

    heightmap = _box_field((-0.5, 0.5, 0.05, 1.5))  # a 0.3 m box whose south side is 5 cm north of (0, 0)
    distance = edge_distances(heightmap, 0.05)
    x, y = placed_target(heightmap, distance, 0.0, 0.0, 0.3, 0.05)
    assert math.hypot(x, y) <= 0.3 + 1e-9 and y < -0.2  # away from the box, not onto it
    assert heightmap.height(x, y) == pytest.approx(0.0)
    ix, iy = heightmap.index(x, y)
    assert distance[iy, ix] >= 0.3
    # Clear of edges already (or as clear as TARGET_CLEARANCE): it stays.
    assert placed_target(heightmap, distance, 0.0, -1.0, 0.3, 0.05) == (0.0, -1.0)
    assert TARGET_CLEARANCE <= 0.5
    # On the box itself, near its side: it moves further onto the box, never off it.
    x, y = placed_target(heightmap, distance, 0.0, 0.1, 0.3, 0.05)
    assert y > 0.3 and heightmap.height(x, y) == pytest.approx(0.3)
    # No edges: nothing moves; no shift: nothing moves.
    assert placed_target(heightmap, None, 0.0, 0.0, 0.3, 0.05) == (0.0, 0.0)
    assert placed_target(heightmap, distance, 0.0, 0.0, 0.0, 0.05) == (0.0, 0.0)


def test_a_target_on_a_stairs_run_stays_where_no_point_nearby_gains_enough_clearance():
    from qz_drake.planning.capability_mdp import edge_distances
    from qz_drake.planning.guidance import placed_target

    heightmap = _box_field(None, 0.12, stairs=True)
    distance = edge_distances(heightmap, 0.05)
    for x in (0.1, 0.2, 0.3):
        assert placed_target(heightmap, distance, x, 0.0, 0.3, 0.05) == (x, 0.0)


def test_place_targets_keeps_the_goal_back_outs_and_headings():
    from qz_drake.planning.capability_mdp import edge_distances
    from qz_drake.planning.guidance import GuidedMission, place_targets

    heightmap = _box_field((-0.5, 0.5, 0.05, 1.5))
    missions = [GuidedMission((0.0, 0.0, 0.7), "nominal", [], 0.9),
                GuidedMission((0.0, 0.0, 0.7), "nominal", [], 1.0, back_out=True),
                GuidedMission((0.0, 0.0, 0.7), "nominal", [], 0.9)]
    place_targets(missions, heightmap, edge_distances(heightmap, 0.05), 0.3, 0.05, keep_last=True)
    assert missions[0].target[1] < -0.2 and missions[0].target[2] == 0.7
    assert missions[1].target == missions[2].target == (0.0, 0.0, 0.7)


@pytest.mark.parametrize("value", [-0.1, 0.5, "far", None, float("nan"), False])
def test_a_bad_target_shift_names_the_field(value):
    from qz_drake.planning.guidance import check_target_shift

    with pytest.raises(QzError, match="--target-shift"):
        check_target_shift(value, "--target-shift")
