"""Gaits and contact schedules (paper 000 Eq. 3).

A contact schedule gives each foot an alternating sequence of phase durations that starts and
ends in stance: ``[stance, swing, stance, ..., stance]``; the sum of every foot's durations is
the task's duration (the total-duration part of Eq. 3 holds by construction). A gait is a
cyclic order of *swing groups*: feet that lift together. The schedule stands on all feet for
``stand_duration`` at both ends (as TOWR's gaits do) and fills the time between with swing
slots of equal length, one group per slot.

Gaits:

* ``tripod``: the alternating tripod of paper 002, group A = MF, RB, LB then group B = MB, RF, LF;
* ``tetrapod``: two feet at a time, opposite through the centre: (RF, LB), (RB, LF), (MF, MB);
* ``wave``: one foot at a time, alternating sides: MB, RF, LB, MF, RB, LF;
* ``trot``: quadrupeds, diagonal pairs (LF, RH) then (RF, LH) (TOWR's leg order LF, RF, LH, RH);
* ``crawl``: quadrupeds, one foot at a time in paper 003's order LF, RH, RF, LH.
"""

from __future__ import annotations

import bisect
import dataclasses

import numpy as np

from qz_drake.errors import ConfigError, bad_value

# Swing groups per gait, as leg ids in the robot's leg order.
GAIT_GROUPS: dict[str, tuple[tuple[int, ...], ...]] = {
    "tripod": ((0, 2, 4), (3, 1, 5)),
    "tetrapod": ((1, 4), (2, 5), (0, 3)),
    "wave": ((3,), (1,), (4,), (0,), (2,), (5,)),
    "trot": ((0, 3), (1, 2)),
    "crawl": ((0,), (3,), (1,), (2,)),
}
GAIT_LEGS = {"tripod": 6, "tetrapod": 6, "wave": 6, "trot": 4, "crawl": 4}
# Nominal swing duration of each gait. [s]
DEFAULT_SWING_DURATION = {"tripod": 0.3, "tetrapod": 0.25, "wave": 0.2, "trot": 0.3, "crawl": 0.25}
GAIT_NAMES = tuple(GAIT_GROUPS)


@dataclasses.dataclass(frozen=True)
class ContactSchedule:
    """Per foot, the durations of its alternating stance and swing phases."""

    # phase_durations[leg] = (stance, swing, stance, ..., stance). [s]
    phase_durations: tuple[tuple[float, ...], ...]
    gait: str = "custom"

    def __post_init__(self):
        totals = [sum(d) for d in self.phase_durations]
        for leg, d in enumerate(self.phase_durations):
            if len(d) % 2 != 1:
                raise bad_value(f"schedule.phase_durations[{leg}]", d,
                                "must start and end in stance (an odd number of phases)")
            if min(d) <= 0:
                raise bad_value(f"schedule.phase_durations[{leg}]", d, "durations must be positive")
            if abs(totals[leg] - totals[0]) > 1e-9:
                raise bad_value(f"schedule.phase_durations[{leg}]", d,
                                f"sums to {totals[leg]}, not {totals[0]} like foot 0")

    @property
    def num_legs(self) -> int:
        return len(self.phase_durations)

    @property
    def duration(self) -> float:
        return float(sum(self.phase_durations[0]))

    def phase_boundaries(self, leg: int) -> np.ndarray:
        """Times at which foot ``leg``'s phases start and end, (num_phases + 1,). [s]"""
        return self._boundaries()[leg].copy()

    def _boundaries(self) -> list[np.ndarray]:
        # Computed once per schedule (it is immutable): trackers ask for them at every update.
        cached = self.__dict__.get("_cached_boundaries")
        if cached is None:
            cached = []
            for durations in self.phase_durations:
                b = np.concatenate([[0.0], np.cumsum(durations)])
                b[-1] = self.duration  # exact end, free of summation round-off
                b.flags.writeable = False
                cached.append(b)
            object.__setattr__(self, "_cached_boundaries", cached)
        return cached

    def _boundary_lists(self) -> list[list[float]]:
        # The boundaries as Python floats, for the scalar queries below (once per schedule).
        cached = self.__dict__.get("_cached_boundary_lists")
        if cached is None:
            cached = [b.tolist() for b in self._boundaries()]
            object.__setattr__(self, "_cached_boundary_lists", cached)
        return cached

    def stance_intervals(self, leg: int) -> list[tuple[float, float]]:
        b = self._boundary_lists()[leg]
        return [(b[i], b[i + 1]) for i in range(0, len(b) - 1, 2)]

    def swing_intervals(self, leg: int) -> list[tuple[float, float]]:
        b = self._boundary_lists()[leg]
        return [(b[i], b[i + 1]) for i in range(1, len(b) - 1, 2)]

    def in_contact(self, t) -> np.ndarray:
        """(n, L) contact flags at times t; a foot is in stance on [touchdown, liftoff)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        out = np.zeros((len(t), self.num_legs), dtype=bool)
        for leg, b in enumerate(self._boundaries()):
            phase = np.clip(np.searchsorted(b, t, side="right") - 1, 0, len(b) - 2)
            out[:, leg] = phase % 2 == 0
        return out

    def contact_at(self, t: float) -> np.ndarray:
        """(L,) contact flags at one time t: in_contact(t)[0] without numpy's array machinery
        (a tracker asks at every update)."""
        t = float(t)
        out = np.empty(self.num_legs, dtype=bool)
        for leg, b in enumerate(self._boundary_lists()):
            out[leg] = min(max(bisect.bisect_right(b, t) - 1, 0), len(b) - 2) % 2 == 0
        return out


def make_gait(name: str, num_legs: int, duration: float, *, swing_duration: float | None = None,
              stand_duration: float = 0.2) -> ContactSchedule:
    """The contact schedule of a named gait over ``duration`` seconds.

    Args:
        name: one of GAIT_NAMES.
        num_legs: the robot's leg count (must match the gait).
        duration: total time T. [s]
        swing_duration: nominal swing time; the slots are stretched so that they fill T. [s]
        stand_duration: time on all feet at the start and at the end. [s]
    """
    if name not in GAIT_GROUPS:
        raise bad_value("gait", name, f"expected one of {', '.join(GAIT_NAMES)}", ConfigError)
    if GAIT_LEGS[name] != num_legs:
        raise bad_value("gait", name, f"is a gait for {GAIT_LEGS[name]} legs; the robot has "
                        f"{num_legs}", ConfigError)
    swing = DEFAULT_SWING_DURATION[name] if swing_duration is None else float(swing_duration)
    if not swing > 0:
        raise bad_value("gait.swing_duration", swing_duration, "must be positive", ConfigError)
    if not stand_duration > 0:
        raise bad_value("gait.stand_duration", stand_duration, "must be positive", ConfigError)
    middle = duration - 2 * stand_duration
    if middle < 0.5 * swing:
        raise bad_value("duration", duration,
                        f"leaves no time to step after standing {stand_duration} s at each end",
                        ConfigError)
    groups = GAIT_GROUPS[name]
    num_slots = max(1, int(round(middle / swing)))
    slot = middle / num_slots
    # Per leg: which slots it swings in.
    swings = [[k for k in range(num_slots) if leg in groups[k % len(groups)]]
              for leg in range(num_legs)]
    durations = []
    for leg in range(num_legs):
        phases, t = [], 0.0
        for k in swings[leg]:
            start = stand_duration + k * slot
            phases += [start - t, slot]
            t = start + slot
        phases.append(duration - t)
        durations.append(tuple(float(d) for d in phases))
    return ContactSchedule(tuple(durations), gait=name)
