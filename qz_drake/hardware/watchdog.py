"""The link watchdog of both ends of the LCM protocol: freshness, sequence and clock checks.

A pure function of the previous ``LinkState`` and the newest message's key, so that the
interface (watching qz_status) and the driver (watching qz_command) share it and it is tested
without a diagram. A receiver sees only the newest message of a channel (Drake's
LcmSubscriberSystem keeps one), so a new message is one whose (utime, sequence) differs from
the last one seen; an exact repeat is indistinguishable from silence and ends as stale.
"""

from __future__ import annotations

import dataclasses
import math

# Counter names, in the order reports print them.
COUNTERS = ("received", "rejected", "stale", "missed", "sequence_jumps", "duplicates",
            "clock_jumps", "safe_stops")


@dataclasses.dataclass(frozen=True)
class WatchdogLimits:
    # Age of the newest message that latches a safe stop. [s]
    timeout: float
    # Largest number of lost messages between two consecutive ones that is tolerated.
    max_missed: int
    # Largest difference between the sender's and the receiver's clock advance. [s]
    clock_tolerance: float


@dataclasses.dataclass(frozen=True)
class LinkState:
    """What one end knows about its incoming link; immutable (kept in a Drake abstract state)."""

    # A valid message has been accepted since the start (or the last reset).
    armed: bool = False
    # A safe stop is latched; ``reason`` says why (the first cause).
    latched: bool = False
    reason: str = ""
    # When the safe stop latched (receiver time). [s]
    latched_time: float = math.nan
    # Key (utime, sequence) of the newest message seen, valid or not.
    last_key: tuple[int, int] = (0, 0)
    # The newest accepted message: its sequence, sender time [us], receiver time [s].
    sequence: int = 0
    utime: int = 0
    received_time: float = -math.inf
    # The link is currently stale (counted once per outage).
    stale_now: bool = False
    counts: tuple[int, ...] = (0,) * len(COUNTERS)

    def __deepcopy__(self, memo):  # immutable: Drake's state copies may share it
        return self

    def counters(self) -> dict[str, int]:
        return dict(zip(COUNTERS, self.counts))


def _count(state: LinkState, **increments) -> tuple[int, ...]:
    counts = list(state.counts)
    for name, k in increments.items():
        counts[COUNTERS.index(name)] += k
    return tuple(counts)


def _latch(state: LinkState, reason: str, t: float) -> LinkState:
    if state.latched:
        return state
    return dataclasses.replace(state, latched=True, reason=reason, latched_time=t,
                               counts=_count(state, safe_stops=1))


def step_watchdog(state: LinkState, key: tuple[int, int], problem: str, t: float,
                  limits: WatchdogLimits) -> tuple[LinkState, bool]:
    """Advances the watchdog to time t with the newest message's key; returns (state, accepted).

    ``key`` is (utime [us], sequence) of the newest message on the channel, (0, 0) if none has
    come; ``problem`` is empty when that message passed the receiver's content checks, else
    what is wrong with it. A message is accepted (its content may be used) when it is new and
    valid, even while latched: the estimate stays fresh during a stop. Every fault latches;
    only ``reset_watchdog`` unlatches.
    """
    if key == state.last_key or key == (0, 0):
        if state.armed and not state.stale_now and t - state.received_time > limits.timeout:
            state = dataclasses.replace(state, stale_now=True, counts=_count(state, stale=1))
            return _latch(state, f"no message for {t - state.received_time:.4f} s", t), False
        return state, False
    if problem:
        state = dataclasses.replace(state, last_key=key, counts=_count(state, received=1, rejected=1))
        return (_latch(state, f"malformed message: {problem}", t) if state.armed else state), False
    utime, sequence = key
    faults = {}
    reason = ""
    if state.armed:
        gap = sequence - state.sequence
        if gap == 0:
            state = dataclasses.replace(state, last_key=key, counts=_count(state, received=1, duplicates=1))
            return _latch(state, "duplicated sequence number", t), False
        if gap < 0 or gap > 1 + limits.max_missed:
            faults["sequence_jumps"] = 1
            reason = f"sequence jump {state.sequence} -> {sequence}"
        elif gap > 1:
            faults["missed"] = gap - 1
        sender_dt = (utime - state.utime) * 1e-6
        receiver_dt = t - state.received_time
        if sender_dt <= 0.0 or abs(sender_dt - receiver_dt) > limits.clock_tolerance:
            faults["clock_jumps"] = 1
            reason = reason or f"sender clock jumped by {sender_dt - receiver_dt:+.4f} s"
    state = dataclasses.replace(state, armed=True, last_key=key, sequence=sequence, utime=utime, received_time=t,
                                stale_now=False, counts=_count(state, received=1, **faults))
    return (_latch(state, reason, t) if reason else state), True


def reset_watchdog(state: LinkState) -> LinkState:
    """Unlatches; the next valid message re-arms the watchdog (no continuity check against the
    messages before the reset). Counters are kept."""
    return dataclasses.replace(state, armed=False, latched=False, reason="", latched_time=math.nan,
                               stale_now=False)
