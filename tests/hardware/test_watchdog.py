"""The link watchdog on its own: lost messages ridden through, freshness, sequence, clock,
malformed messages, reset."""

import pytest

from qz_drake.hardware.watchdog import LinkState, WatchdogLimits, reset_watchdog, step_watchdog

H = 0.002
LIMITS = WatchdogLimits(timeout=2.5 * H, clock_tolerance=0.02, message="status")


def run(messages, start=LinkState()):
    """Steps the watchdog once per period k with messages[k] = (utime, sequence, problem) or None."""
    state = start
    accepted = []
    key = (0, 0)
    for k, message in enumerate(messages):
        problem = ""
        if message is not None:
            key, problem = message[:2], message[2]
        state, ok = step_watchdog(state, key, problem, k * H, LIMITS)
        accepted.append(ok)
    return state, accepted


def regular(n, first=1):
    return [(int((k + first) * H * 1e6), k + first, "") for k in range(n)]


def test_regular_messages_are_accepted_without_faults():
    state, accepted = run(regular(50))
    assert all(accepted) and not state.latched
    assert state.counters() == {"received": 50, "rejected": 0, "stale": 0, "missed": 0, "gaps": 0,
                                "sequence_jumps": 0, "duplicates": 0, "clock_jumps": 0, "safe_stops": 0,
                                "longest_gap": 0, "longest_silence_s": pytest.approx(H)}


def test_silence_latches_on_the_third_missing_message():
    state, _ = run(regular(10) + [None] * 5)
    assert state.latched and state.counters()["stale"] == 1 and state.counters()["safe_stops"] == 1
    # The last message came at period 9; periods 10 and 11 pass, period 12 latches.
    assert abs(state.latched_time - 12 * H) < 1e-12
    # The cause with the age it had reached and the budget it broke.
    assert state.reason == "status stale for 6.0 ms (timeout 5.0 ms)"


def test_before_the_first_message_nothing_is_stale():
    state, _ = run([None] * 20)
    assert not state.armed and not state.latched and state.counters()["stale"] == 0


def test_a_malformed_message_is_rejected_counted_and_latches():
    messages = regular(20)
    messages[10] = messages[10][:2] + ("joint_position[3] = nan",)
    state, accepted = run(messages)
    assert accepted[10] is False and accepted[11] is True
    assert state.latched and "joint_position[3] = nan" in state.reason
    assert state.counters()["rejected"] == 1 and state.counters()["received"] == 20
    # The next message skips the rejected one's sequence number: no jump, one missed.
    assert state.counters()["missed"] == 1 and state.counters()["sequence_jumps"] == 0


def test_a_duplicated_sequence_number_is_detected():
    messages = regular(20)
    messages[10] = (messages[10][0], messages[9][1], "")
    state, _ = run(messages)
    assert state.latched and state.counters()["duplicates"] == 1 and state.counters()["missed"] == 1
    assert state.reason == "status sequence number 10 repeated"


def test_a_jump_of_the_senders_clock_is_detected():
    messages = [(u + (1_000_000 if k >= 10 else 0), s, p) for k, (u, s, p) in enumerate(regular(20))]
    state, _ = run(messages)
    assert state.latched and state.counters()["clock_jumps"] == 1 and "clock jumped by +1.0" in state.reason
    backwards = [(u - (5000 if k >= 10 else 0), s, p) for k, (u, s, p) in enumerate(regular(20))]
    assert run(backwards)[0].counters()["clock_jumps"] == 1


def test_lost_messages_are_counted_and_ridden_through_while_the_link_is_fresh():
    # UDP lost 11 and 12 (nothing new for two periods); later the receiver ran late, found
    # 20 to 24 waiting and kept the newest: a gap of two, then one of four.
    sequences = list(range(1, 11)) + [None, None] + list(range(13, 20)) + list(range(24, 31))
    state, accepted = run([None if s is None else (int(s * H * 1e6), s, "") for s in sequences])
    assert not state.latched and accepted.count(True) == len(sequences) - 2
    counters = state.counters()
    assert counters["missed"] == 6 and counters["gaps"] == 2 and counters["longest_gap"] == 4
    assert abs(counters["longest_silence_s"] - 3 * H) < 1e-12
    assert counters["safe_stops"] == 0 and counters["stale"] == 0 and counters["sequence_jumps"] == 0


def test_a_burst_of_lost_messages_longer_than_the_budget_is_a_stale_link():
    # Sequences 11 to 15 lost and nothing else arriving: stale at the third empty period, and
    # the message after the outage is accepted and counted as a gap of five.
    state, accepted = run(regular(10) + [None] * 5 + [(int(16 * H * 1e6), 16, "")])
    assert state.latched and state.reason == "status stale for 6.0 ms (timeout 5.0 ms)"
    assert accepted[-1] and state.counters()["missed"] == 5 and state.counters()["stale"] == 1


def test_a_sequence_going_backwards_latches():
    messages = regular(20)
    messages[15] = (messages[15][0], 3, "")
    state, _ = run(messages)
    assert state.latched and state.reason == "status sequence went back from 15 to 3"
    assert state.counters()["sequence_jumps"] == 1


def test_reset_unlatches_and_rearms_on_the_next_message():
    state, _ = run(regular(10) + [None] * 5)
    state = reset_watchdog(state)
    assert not state.latched and not state.armed
    # A driver restart: sequence numbers start again at 1; after a reset that is fine.
    state, _ = run([None] * 15 + regular(5), state)
    assert state.armed and not state.latched and state.counters()["safe_stops"] == 1
