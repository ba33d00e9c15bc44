"""Where a route source backs out of a dead end to (qz_drake.planning.back_out)."""

from qz_drake.planning.back_out import BACK_OUT_MIN, BackOut
from qz_drake.systems.mission_sequencer import RecoveryLog


def _log(plan, walks):
    """A RecoveryLog of walked missions: (start (x, y), end (x, y)) each, one second apiece."""
    log = RecoveryLog()
    for i, (start, end) in enumerate(walks):
        log.plans.append(plan(start, end, float(i), float(i + 1)))
        log.targets.append((*end, 0.0, "nominal"))
    return log


def test_backs_out_to_the_start_of_the_last_mission_that_moved_the_robot(straight_plan):
    # Walked east 1 m, then turned in place: the turn's start is where the robot stands, so
    # the way out is to where the move started.
    log = _log(straight_plan, [((0.0, 0.0), (1.0, 0.0)), ((1.0, 0.0), (1.0, 0.0))])
    back = BackOut()
    assert back.target(log, (1.0, 0.0)) == (0.0, 0.0, 0.0) and len(back) == 1
    # Once the way back is walked, backing out again from its end is refused: no backing and
    # forth between two stances.
    log.plans.append(straight_plan((1.0, 0.0), (0.0, 0.0), 2.0, 3.0))
    log.targets.append((0.0, 0.0, 0.0, "nominal"))
    assert back.target(log, (0.0, 0.0)) is None


def test_no_way_back_without_a_walked_move_or_with_a_mission_not_yet_planned(straight_plan):
    back = BackOut()
    assert back.target(RecoveryLog(), (0.0, 0.0)) is None
    turned = _log(straight_plan, [((0.0, 0.0), (0.0, 0.5 * BACK_OUT_MIN))])
    assert back.target(turned, (0.0, 0.5 * BACK_OUT_MIN)) is None
    planned = _log(straight_plan, [((0.0, 0.0), (1.0, 0.0))])
    planned.plans.append(straight_plan((1.0, 0.0), (2.0, 0.0), 1.0, 2.0))  # a plan whose target is not logged
    assert back.target(planned, (2.0, 0.0)) is None
