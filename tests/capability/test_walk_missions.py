"""The missions of a whole walk, told apart from the BLC's logs (capability/walk_missions.py)."""

import math
from types import SimpleNamespace


from qz_drake.capability.walk_missions import mission_timeline


def _solve(t, success, target=(0.0, 0.0, 0.0), topology="nominal"):
    return SimpleNamespace(start_time=t, success=success, target=target, topology=topology, reason="" if success else
                           "BLC: Ipopt: Max iteration exceeded")


def _plan(t0, t1):
    return SimpleNamespace(start_time=t0, end_time=t1)


def _switch(t0, t1, before="split_up"):
    return SimpleNamespace(start_time=t0, end_time=t1, from_topology=before)


def test_a_switch_belongs_to_the_mission_it_was_made_for_even_when_that_one_is_refused():
    """CapPlanner's walk of obstacles-hard 501 (session 36): a turn planned 41.95-43.15; a
    forward move in front_bend needed a switch (43.2-48.1), then the BLC refused it; the TLC went
    round with a turn, solved from the same end state (48.1-49.3). The switch is the refused
    move's, so the turn's stretch starts at 48.1 and is judged on its own, and the first turn's
    ends where the switch began (before: the turn was judged over the switch and 'missed' its
    heading by 45 deg)."""
    first, turn = _plan(41.95, 43.15), _plan(48.1, 49.3)
    switch = _switch(43.2, 48.1)
    solves = [_solve(41.95, True), _solve(48.1, False, (1.0, 0.0, 0.0), "front_bend"), _solve(48.1, True)]
    timeline = mission_timeline([first, turn], solves, [], [switch], end=60.0)
    assert [(e["planned"], e["begin"], e["t0"]) for e in timeline] == [
        (True, 41.95, 41.95), (False, 43.2, 48.1), (True, 48.1, 48.1)]
    assert timeline[0]["t1"] == 43.2 and timeline[2]["t1"] == 60.0
    assert timeline[1]["switch"] is switch and timeline[2]["switch"] is None
    assert timeline[0]["plan"] is first and timeline[2]["plan"] is turn


def test_a_mission_refused_while_the_plan_before_it_ran_cuts_nothing_short():
    """With plan-ahead the next mission is solved from the current plan's expected end while the
    robot walks; a refusal then starts no stretch (the robot walks its plan to the end), and a
    retried solve is one mission."""
    a, b = _plan(0.0, 3.0), _plan(3.5, 6.0)
    solves = [_solve(0.0, True), _solve(3.0, False), _solve(3.0, False), _solve(3.5, True)]
    timeline = mission_timeline([a, b], solves, [1], [], end=8.0)
    assert [(e["planned"], e["t0"]) for e in timeline] == [(True, 0.0), (False, 3.0), (True, 3.5)]
    assert timeline[0]["t1"] == 3.5 and timeline[2]["t1"] == 8.0


def test_a_switch_before_a_planned_mission_starts_its_stretch():
    a, b = _plan(0.0, 3.0), _plan(8.0, 10.0)
    switch = _switch(3.1, 8.0)
    timeline = mission_timeline([a, b], [_solve(0.0, True), _solve(8.0, True)], [], [switch, _switch(9, math.nan)],
                                end=12.0)
    assert [(e["begin"], e["t0"], e["t1"]) for e in timeline] == [(0.0, 0.0, 3.1), (3.1, 8.0, 12.0)]
    assert timeline[1]["switch"] is switch
