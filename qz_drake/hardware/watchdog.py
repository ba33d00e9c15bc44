"""The link watchdog of both ends of the LCM protocol: freshness, sequence and clock checks.

A pure function of the previous ``LinkState`` and the newest message's key, so that the
interface (watching qz_status) and the driver (watching qz_command) share it and it is tested
without a diagram. A receiver sees only the newest message of a channel (Drake's
LcmSubscriberSystem keeps one), so a new message is one whose (utime, sequence) differs from
the last one seen; an exact repeat is indistinguishable from silence and ends as stale.

A link that loses messages is not broken: UDP drops a datagram now and then, and a receiver
that runs a little late finds two messages where it expected one and keeps the newer. A gap in
the sequence numbers is therefore counted (``missed`` messages in ``gaps`` gaps) and ridden
through, the receiver holding the last good message. What latches a safe stop is a stale link
(the last good message older than the time budget ``timeout``: checked every period, so a
burst of losses longer than the budget is caught as it happens, and there is no separate
limit on lost messages), a malformed message, a repeated or backwards sequence number, or a
sender clock that advances differently from the receiver's (which is also what a receiver
sees that fell behind and caught up: the sender's clock ran on while its own stood still).
"""

from __future__ import annotations

import dataclasses
import math

# How long before a receiver reads its newest message the simulator takes a step, as a
# fraction of the control period (see declare_message_intake).
INTAKE_LEAD = 1.0 / 16.0

# Counter names, in the order reports print them.
COUNTERS = ("received", "rejected", "stale", "missed", "gaps", "sequence_jumps", "duplicates",
            "clock_jumps", "safe_stops")


@dataclasses.dataclass(frozen=True)
class WatchdogLimits:
    # Age of the newest good message that latches a safe stop. [s]
    timeout: float
    # Largest difference between the sender's and the receiver's clock advance. [s]
    clock_tolerance: float
    # What the link carries, for the reason of a safe stop ("status", "command").
    message: str = "message"


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
    # The most messages lost in one gap, and the longest receiver time between two accepted
    # messages [s]: what a timeout must cover on this link.
    longest_gap: int = 0
    longest_silence: float = 0.0

    def __deepcopy__(self, memo):  # immutable: Drake's state copies may share it
        return self

    def counters(self) -> dict:
        return {**dict(zip(COUNTERS, self.counts)), "longest_gap": self.longest_gap,
                "longest_silence_s": self.longest_silence}


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


def _ms(seconds: float) -> str:
    return f"{seconds * 1e3:.1f} ms"


def step_watchdog(state: LinkState, key: tuple[int, int], problem: str, t: float,
                  limits: WatchdogLimits) -> tuple[LinkState, bool]:
    """Advances the watchdog to time t with the newest message's key; returns (state, accepted).

    ``key`` is (utime [us], sequence) of the newest message on the channel, (0, 0) if none has
    come; ``problem`` is empty when that message passed the receiver's content checks, else
    what is wrong with it. A message is accepted (its content may be used) when it is new and
    valid, even while latched: the estimate stays fresh during a stop. Every fault latches;
    only ``reset_watchdog`` unlatches.
    """
    name = limits.message
    if key == state.last_key or key == (0, 0):
        age = t - state.received_time
        if state.armed and not state.stale_now and age > limits.timeout:
            state = dataclasses.replace(state, stale_now=True, counts=_count(state, stale=1))
            return _latch(state, f"{name} stale for {_ms(age)} (timeout {_ms(limits.timeout)})", t), False
        return state, False
    if problem:
        state = dataclasses.replace(state, last_key=key, counts=_count(state, received=1, rejected=1))
        return (_latch(state, f"malformed {name}: {problem}", t) if state.armed else state), False
    utime, sequence = key
    faults = {}
    reason = ""
    extremes = {}
    if state.armed:
        gap = sequence - state.sequence
        if gap == 0:
            state = dataclasses.replace(state, last_key=key, counts=_count(state, received=1, duplicates=1))
            return _latch(state, f"{name} sequence number {sequence} repeated", t), False
        if gap < 0:
            faults["sequence_jumps"] = 1
            reason = f"{name} sequence went back from {state.sequence} to {sequence}"
        elif gap > 1:
            faults.update(missed=gap - 1, gaps=1)
        sender_dt = (utime - state.utime) * 1e-6
        receiver_dt = t - state.received_time
        if sender_dt <= 0.0 or abs(sender_dt - receiver_dt) > limits.clock_tolerance:
            faults["clock_jumps"] = 1
            reason = reason or (f"{name} clock jumped by {sender_dt - receiver_dt:+.4f} s: sent {_ms(sender_dt)} "
                                f"after the last good one, taken in {_ms(receiver_dt)} after it "
                                f"(tolerance {_ms(limits.clock_tolerance)})")
        extremes = dict(longest_gap=max(state.longest_gap, gap - 1),
                        longest_silence=max(state.longest_silence, receiver_dt))
    state = dataclasses.replace(state, armed=True, last_key=key, sequence=sequence, utime=utime, received_time=t,
                                stale_now=False, counts=_count(state, received=1, **faults), **extremes)
    return (_latch(state, reason, t) if reason else state), True


def latch_watchdog(state: LinkState, reason: str, t: float) -> LinkState:
    """Latches a safe stop for a cause the link itself did not show (the first cause stays)."""
    return _latch(state, reason, t)


def reset_watchdog(state: LinkState) -> LinkState:
    """Unlatches; the next valid message re-arms the watchdog (no continuity check against the
    messages before the reset). Counters are kept."""
    return dataclasses.replace(state, armed=False, latched=False, reason="", latched_time=math.nan,
                               stale_now=False)


def declare_message_intake(system, period: float, read_phase: float) -> None:
    """Gives ``system``, which reads its newest LCM message at ``read_phase`` of each period, a
    simulator step just before that read, so that the read sees what arrived until then.

    Drake's LcmInterfaceSystem takes in the messages that have arrived at the start of each
    simulator step, and a paced simulator sleeps inside the step before an event. Without a
    step shortly before the read, a message that arrives during the last sleep would wait a
    whole period (the interface: 3/4 of a period late, the driver: 5/8), and a feedback loop
    over two processes would run 1.4 periods behind the lockstep one. In the lockstep
    ``memq://`` diagram every message is in before this step, and the step changes nothing.
    """
    from pydrake.systems.framework import EventStatus

    system.DeclarePeriodicPublishEvent(period, (read_phase - INTAKE_LEAD) * period,
                                       lambda context: EventStatus.DidNothing())
