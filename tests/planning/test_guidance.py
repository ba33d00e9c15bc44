"""Guidance path -> BLC missions: merged within the BLC's reach and a success threshold, a
topology change on its own."""

import math

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
