"""Backing out of a dead end: a stance from which the BLC refuses every way on.

Both recovering route sources (CapPlanner's TLC, qz_drake.planning.capability_planner, and the
A* baseline's, qz_drake.experiments.astar_recovery) go round a mission the BLC could not plan.
Sometimes the stance the robot stands in is the trouble, not the way: the BLC, started from
feet spread across a stair edge or astride a box, refuses whatever it is given within its
iteration budget, and going round from there finds nothing (CapPlanner's moves and turns in
place from the robot's cell all refused; session 38 validation walks). Then the route source
hands out one more mission: back to where the robot stood when the last walked mission that
moved it started (a turn in place leaves it where it is), a stance the BLC planned from, and
plans on from there with the refused ways closed.

It is a helper of both route sources rather than a part of their shared base
(systems.mission_sequencer.RecoveringSequencer), whose module the capability dataset's
fingerprint covers (its "controller"): the trials never go round anything, and a change there
would ask for the dataset to be certified again.
"""

from __future__ import annotations

import math

# Least distance to a stance worth backing out to: closer, the robot already stands there. [m]
BACK_OUT_MIN = 0.2


class BackOut:
    """Where to back out to, for a RecoveringSequencer (its ``log``: the plans and targets
    handed out). One per walk, as its sequencer."""

    def __init__(self):
        # Targets of the ways back out already handed out.
        self._targets: set = set()

    def target(self, log, here) -> tuple[float, float, float] | None:
        """(x, y, yaw) where the robot stood when the last walked mission that moved it (by
        BACK_OUT_MIN at least: a turn in place leaves it where it is) started; None without
        one, or when a way back out was walked since (no backing and forth between two
        stances)."""
        plans = log.plans
        if len(log.targets) < len(plans):
            return None
        for i in range(len(plans) - 1, -1, -1):
            if _key(log.targets[i]) in self._targets:
                return None
            plan = plans[i]
            p = plan.base_position(plan.start_time)
            if math.hypot(float(p[0]) - here[0], float(p[1]) - here[1]) >= BACK_OUT_MIN:
                target = (float(p[0]), float(p[1]), float(plan.base_rpy(plan.start_time)[2]))
                self._targets.add(_key(target))
                return target
        return None

    def __len__(self) -> int:
        return len(self._targets)


def _key(target) -> tuple[float, float]:
    """A target's place, to the millimetre (its yaw may be unwrapped by whole turns)."""
    return round(float(target[0]), 3), round(float(target[1]), 3)


__all__ = ["BACK_OUT_MIN", "BackOut"]
