"""The link watchdog on its own: freshness, sequence, clock, malformed messages, reset."""

from qz_drake.hardware.watchdog import LinkState, WatchdogLimits, reset_watchdog, step_watchdog

H = 0.002
LIMITS = WatchdogLimits(timeout=2.5 * H, max_missed=2, clock_tolerance=0.02)


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
    assert state.counters() == {"received": 50, "rejected": 0, "stale": 0, "missed": 0, "sequence_jumps": 0,
                                "duplicates": 0, "clock_jumps": 0, "safe_stops": 0}


def test_silence_latches_on_the_third_missing_message():
    state, _ = run(regular(10) + [None] * 5)
    assert state.latched and state.counters()["stale"] == 1 and state.counters()["safe_stops"] == 1
    # The last message came at period 9; periods 10 and 11 pass, period 12 latches.
    assert abs(state.latched_time - 12 * H) < 1e-12
    assert state.reason.startswith("no message")


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
    assert state.reason == "duplicated sequence number"


def test_a_jump_of_the_senders_clock_is_detected():
    messages = [(u + (1_000_000 if k >= 10 else 0), s, p) for k, (u, s, p) in enumerate(regular(20))]
    state, _ = run(messages)
    assert state.latched and state.counters()["clock_jumps"] == 1 and "clock jumped by +1.0" in state.reason
    backwards = [(u - (5000 if k >= 10 else 0), s, p) for k, (u, s, p) in enumerate(regular(20))]
    assert run(backwards)[0].counters()["clock_jumps"] == 1


def test_lost_messages_within_the_bound_are_counted_beyond_it_latch():
    few = regular(10) + [(int(12 * H * 1e6), 12, "")]  # sequences 11 lost: gap 2, one missed
    state, _ = run(few)
    assert not state.latched and state.counters()["missed"] == 1
    many = regular(10) + [(int(15 * H * 1e6), 15, "")]
    state, _ = run(many)
    assert state.latched and state.counters()["sequence_jumps"] == 1


def test_reset_unlatches_and_rearms_on_the_next_message():
    state, _ = run(regular(10) + [None] * 5)
    state = reset_watchdog(state)
    assert not state.latched and not state.armed
    # A driver restart: sequence numbers start again at 1; after a reset that is fine.
    state, _ = run([None] * 15 + regular(5), state)
    assert state.armed and not state.latched and state.counters()["safe_stops"] == 1
