"""The one link-trust rule (cellsim.link): watchdog, sequence, recover-after, and its state as numbers."""

from __future__ import annotations

from cellsim.link import Fault, LinkTrust
from cellsim.vocabulary import PhysicalLink


def test_trust_comes_after_recover_after_good_messages_and_goes_at_the_first_fault():
    link = LinkTrust(timeout=0.1, recover_after=3, faults=tuple(Fault))
    assert link.link is PhysicalLink.STALE  # at start
    assert [link.good(t).trusted for t in (0.0, 0.01, 0.02)] == [False, False, True]
    assert link.fail(Fault.CRC).fault is Fault.CRC and link.link is PhysicalLink.CORRUPT
    assert link.good(0.03).recovering and link.link is PhysicalLink.RECOVERING
    assert link.watchdog(0.5).fault is Fault.TIMEOUT and link.link is PhysicalLink.STALE
    assert link.watchdog(0.55) is None  # counted once per timeout period
    assert link.counts["crc"] == 1 and link.counts["timeout"] == 1


def test_sequence_numbers_refuse_repeats_fail_jumps_and_restart_after_silence():
    link = LinkTrust(timeout=0.1, recover_after=1, max_gap=2)
    assert link.sequence(10, 0.0) is None
    link.good(0.0)
    assert link.sequence(10, 0.01) is Fault.REPEATED and link.link is PhysicalLink.OK  # refused, not failed
    assert link.sequence(9, 0.02) is Fault.REPEATED
    assert link.sequence(12, 0.03) is None  # one lost on the way
    assert link.sequence(20, 0.04) is Fault.COUNTER
    link.watchdog(1.0)
    assert link.sequence(1, 1.0) is None  # silent, stale: a restarted sender starts afresh


def test_a_frozen_sender_stays_refused_after_the_link_went_stale_and_a_restarted_one_is_heard():
    """The restart rule takes any number once the link is stale and silent, but not the very message last heard
    again: a stream frozen on one message (its number and content) stays refused, stale, however long it lasts
    (before, it was taken once every timeout, and a link with recover_after 1 trusted it again each time)."""
    link = LinkTrust(timeout=0.1, recover_after=1)
    assert link.receive(0.0, 7, content=70.0).trusted
    t = 0.0
    while t < 1.0:  # the same package every 2 ms for a second
        t += 0.002
        judgement = link.receive(t, 7, content=70.0)
        assert not judgement.good and judgement.fault in (Fault.REPEATED, None)
        link.watchdog(t)
    assert link.link is PhysicalLink.STALE and link.counts["repeated"] > 400
    assert link.receive(t + 0.002, 7, content=71.0).trusted  # the same number, new content: a restarted sender
    link.watchdog(t + 0.5)
    assert link.receive(t + 0.5, 0, content=1.0).trusted  # stale again, then a restarted count from 0


def test_a_wrapping_counter_counts_modulo():
    link = LinkTrust(timeout=0.1, modulo=16, max_gap=2)
    assert link.sequence(15, 0.0) is None
    link.good(0.0)
    assert link.sequence(0, 0.01) is None  # 15 -> 0
    assert link.sequence(0, 0.02) is Fault.REPEATED
    assert link.sequence(5, 0.03) is Fault.COUNTER


def test_stamps_beyond_the_skew_are_refused_and_old_ones_are_late():
    link = LinkTrust(timeout=0.1, future_skew=0.5)
    assert link.stamp(1000.4, now_wall=1000.0) is None
    assert link.stamp(1000.6, now_wall=1000.0) is Fault.FUTURE
    assert link.fail(Fault.FUTURE).fault is Fault.FUTURE and link.counts["future"] == 1  # counted, not failed
    assert link.stamp(float("inf"), now_wall=1000.0) is Fault.FUTURE
    assert link.stamp(999.8, now_wall=1000.0) is Fault.LATE


def test_its_state_survives_a_round_trip_through_numbers():
    link = LinkTrust(timeout=0.1, recover_after=3)
    link.sequence(7, 0.0)
    link.good(0.0)
    copy = LinkTrust(timeout=0.1, recover_after=3).restore(link.state())
    assert (copy.link, copy.good_in_a_row, copy.last_good, copy.last_seq) == (link.link, 1, 0.0, 7)
    assert LinkTrust(timeout=0.1).restore(LinkTrust(timeout=0.1).state()).last_good is None


def test_a_corrupt_link_stays_corrupt_while_faulty_messages_come_and_goes_stale_when_they_stop():
    link = LinkTrust(timeout=0.1, recover_after=1)
    link.good(0.0)
    for t in (0.05, 0.10, 0.15, 0.20):  # a stream of malformed messages, past the watchdog
        link.fail(Fault.CORRUPT, t)
        assert link.watchdog(t + 0.01) is None and link.link is PhysicalLink.CORRUPT
    assert link.watchdog(0.5).fault is Fault.TIMEOUT and link.link is PhysicalLink.STALE  # they stopped


def test_a_forger_jumping_the_sequence_again_and_again_is_a_masquerade_not_a_takeover():
    """On Zenoh, a forger sending seq + 1000 after each real message makes each real one a step back with
    other content, and each forged one a jump: anomalies, and three latch the link corrupt."""
    link = LinkTrust(timeout=0.5, recover_after=1, max_gap=1_000_000, clear_after=5)
    t, faults = 0.0, []
    for seq in range(1, 10):
        t += 0.04
        for sent, content in ((seq, seq), (seq + 1000, -seq)):  # the real message, then the forged one
            fault = link.sequence(sent, t, content=content)
            faults.append(fault)
            link.fail(fault, t) if fault is not None else link.good(t)
    assert Fault.MASQUERADE in faults and link.masquerade and link.link is PhysicalLink.CORRUPT
    for seq in range(10, 30):  # the forger gone: the real run in order clears it
        t += 0.04
        fault = link.sequence(seq, t, content=seq)
        if fault is None:
            break
    assert not link.masquerade and fault is None and seq - 10 >= 4  # a stable run of clear_after first


def test_stamps_are_judged_at_their_exact_boundaries():
    """A stamp exactly the watchdog old is still fresh and one a hair older is late; exactly the skew ahead is
    taken and a hair more is refused (binary fractions: no rounding decides these)."""
    import math

    link = LinkTrust(timeout=0.25, future_skew=0.5)
    assert link.stamp(999.75, now_wall=1000.0) is None
    assert link.stamp(math.nextafter(999.75, 0.0), now_wall=1000.0) is Fault.LATE
    assert link.stamp(1000.5, now_wall=1000.0) is None
    assert link.stamp(math.nextafter(1000.5, math.inf), now_wall=1000.0) is Fault.FUTURE
    assert link.stamp(math.nan, now_wall=1000.0) is Fault.FUTURE


def test_the_watchdog_fires_only_past_its_timeout():
    import math

    link = LinkTrust(timeout=0.25, recover_after=1)
    link.good(1.0)
    assert link.watchdog(1.25) is None  # exactly the timeout since the last good message
    assert link.watchdog(math.nextafter(1.25, math.inf)).fault is Fault.TIMEOUT


def test_an_old_sequence_number_right_after_a_late_message_is_a_replay_not_a_restart():
    """A late message makes the link stale, but its sender was heard just now: an old sequence number that
    follows is refused (a replay). Only a sender silent for longer than the watchdog starts afresh."""
    import math

    link = LinkTrust(timeout=0.25, recover_after=1)
    assert link.sequence(7, 0.0) is None
    link.good(0.0)
    link.fail(Fault.LATE, 0.125)
    assert link.link is PhysicalLink.STALE
    assert link.sequence(5, 0.125) is Fault.REPEATED
    assert link.sequence(7, 0.25) is Fault.REPEATED  # exactly the watchdog since the last good one: not silent
    assert link.sequence(3, math.nextafter(0.25, math.inf)) is None  # silent past it: a restarted sender


def _take(link: LinkTrust, seq: int, t: float, content: float | None = None) -> Fault | None:
    """One message through the rule, as a receiver takes it: judged, then good or failed."""
    fault = link.sequence(seq, t, content)
    link.fail(fault, t) if fault is not None else link.good(t)
    return fault


def _masquerade(link: LinkTrust, t: float = 0.0) -> float:
    """Latch ``link``'s masquerade: in-order numbers, then three anomalies within a second (a step back with
    other content, a jump forward, a step back); returns the time."""
    for seq in (10, 11):
        t += 0.01
        assert _take(link, seq, t, content=float(seq)) is None
    for seq in (5, 11 + link.max_gap + 1, 5):
        t += 0.01
        _take(link, seq, t, content=-float(seq) - t)
    assert link.masquerade
    return t


def test_a_masquerade_clears_after_exactly_clear_after_messages_in_strict_order():
    link = LinkTrust(timeout=10.0, recover_after=1, clear_after=4)
    t = _masquerade(link)
    for k, seq in enumerate((6, 7, 8)):  # three in order: not yet
        t += 0.01
        assert _take(link, seq, t, content=float(seq)) is Fault.MASQUERADE and link.masquerade, k
    assert _take(link, 8, t + 0.005, content=8.0) is Fault.REPEATED  # a byte-for-byte repeat restarts the count
    for seq in (9, 10, 11):
        t += 0.01
        assert _take(link, seq, t, content=float(seq)) is Fault.MASQUERADE
    t += 0.01
    assert _take(link, 12, t, content=12.0) is None and not link.masquerade  # the fourth in a row: cleared
    assert link.anomalies == 0 and link.anomaly_since is None
    for seq in (2, 12):  # two anomalies after clearing: not a masquerade yet (three are)
        t += 0.01
        _take(link, seq, t, content=-float(seq))
    assert not link.masquerade
    t += 0.01
    _take(link, 3, t, content=-3.0)
    assert link.masquerade


def test_a_jump_of_exactly_max_gap_is_no_anomaly_and_one_more_is():
    link = LinkTrust(timeout=10.0, recover_after=1, max_gap=2)
    seq, t = 0, 0.0
    assert _take(link, seq, t) is None
    for _ in range(5):  # five jumps of exactly max_gap within a second: lost frames, no second sender
        seq, t = seq + 2, t + 0.01
        assert _take(link, seq, t) is None
    assert link.anomalies == 0 and not link.masquerade
    assert _take(link, seq + 3, t + 0.01) is Fault.COUNTER and link.anomalies == 1


def test_anomalies_count_within_a_sliding_window_exactly():
    """Three anomalies within any masquerade_window (1 s, both ends included) latch, wherever the window starts: an
    anomaly counts with those of the last second before it. At times far from zero, as a live clock's are. (An
    audit found the window anchored at its first anomaly: 0.90, 1.05, 1.10 s after it never latched.)"""
    def jumps(times):
        link = LinkTrust(timeout=100.0, recover_after=1, max_gap=2, masquerade_window=1.0)
        seq = 0
        _take(link, seq, times[0] - 0.5)
        for t in times:
            seq += 10  # a jump: an anomaly
            _take(link, seq, t)
        return link

    assert jumps([1000.0, 1000.5, 1001.0]).masquerade  # the last exactly the window after the first: within
    late = jumps([1000.0, 1000.5, 1001.25])
    assert not late.masquerade and late.anomalies == 2 and late.anomaly_since == 1000.5  # the first fell out
    assert not jumps([1000.0, 1002.0, 1002.5]).masquerade  # two within a second are not three
    assert jumps([1000.0, 1002.0, 1002.5, 1002.75]).masquerade
    assert jumps([1000.0, 1000.9, 1001.05, 1001.1]).masquerade  # three in 0.2 s across the first one's second


def test_a_refused_message_is_not_trusted_and_changes_nothing_else():
    link = LinkTrust(timeout=0.25, recover_after=1)
    link.good(0.0)
    for fault in (Fault.REPEATED, Fault.FUTURE):
        judgement = link.fail(fault, 0.1)
        assert judgement.trusted is False and judgement.fault is fault and judgement.values is None
        assert link.link is PhysicalLink.OK and link.good_in_a_row == 1 and link.last_heard is None
    assert link.good(0.2).trusted is True


def test_only_a_corrupting_fault_keeps_a_link_from_going_stale_while_messages_come():
    """A late message (stale) does not count as heard for the watchdog of a corrupt link; a corrupt one does."""
    link = LinkTrust(timeout=0.1, recover_after=1)
    link.good(0.0)
    link.fail(Fault.CORRUPT, 0.5)
    link.fail(Fault.LATE, 0.55)  # stale now: the watchdog judges from the last good message
    assert link.link is PhysicalLink.STALE and link.last_heard == 0.5
    assert link.watchdog(0.58).fault is Fault.TIMEOUT and link.counts["timeout"] == 1
    fresh = LinkTrust(timeout=0.1, recover_after=1)
    fresh.good(0.0)
    fresh.fail(Fault.LATE, 0.05)
    assert fresh.last_heard is None  # a stale fault is no sign of a live corrupt sender


def test_silence_is_judged_at_any_time_of_a_live_clock():
    link = LinkTrust(timeout=0.25, recover_after=1)
    assert link.sequence(7, 1000.0) is None
    link.good(1000.0)
    assert link.sequence(6, 1000.25) is Fault.REPEATED  # heard 0.25 s ago: not silent
    link.watchdog(1000.5)
    assert link.sequence(1, 1000.5) is None  # silent, stale: a restarted sender


def test_a_message_after_a_silence_longer_than_the_timeout_starts_a_recovery_whenever_the_watchdog_is_called():
    """The twin judges its inbox, then calls the watchdog: a gap of more than the timeout between two messages was
    never seen, and the message after it trusted at once (an audit). It is judged on arrival now."""
    link = LinkTrust(timeout=0.5, recover_after=3)
    for k in range(4):
        link.good(k * 0.04)
    assert link.link is PhysicalLink.OK
    after = link.receive(0.12 + 0.52, 4)  # 0.52 s of silence, no watchdog call in it
    assert after.trusted is False and after.recovering and link.counts["timeout"] == 1
    assert [link.receive(0.64 + 0.04 * k, 5 + k).trusted for k in range(1, 3)] == [False, True]


def test_every_field_of_the_rule_survives_a_round_trip_through_its_state():
    fields = ("link", "good_in_a_row", "last_good", "last_seq", "timed_out_at", "last_heard", "anomalies",
              "anomaly_since", "anomaly_times", "masquerade", "clean_run", "last_content")
    fresh = LinkTrust(timeout=0.1)
    copy = LinkTrust(timeout=0.1).restore(fresh.state())
    assert {f: getattr(copy, f) for f in fields} == {f: getattr(fresh, f) for f in fields}
    assert copy.last_seq is None and copy.last_heard is None and copy.anomaly_since is None
    assert copy.timed_out_at is None and copy.last_content is None and copy.masquerade is False
    busy = LinkTrust(timeout=0.1, recover_after=3, clear_after=20)
    t = _masquerade(busy, 5.0)
    busy.fail(Fault.CORRUPT, t + 0.01)
    busy.watchdog(t + 0.5)
    busy.last_seq, busy.last_content, busy.clean_run = 0, 123.0, 2
    copy = LinkTrust(timeout=0.1, recover_after=3, clear_after=20).restore(busy.state())
    assert {f: getattr(copy, f) for f in fields} == {f: getattr(busy, f) for f in fields}
    assert copy.last_seq == 0 and copy.masquerade is True and copy.timed_out_at == t + 0.5
    # a link that took a number without content, restored: the same number again is a plain repeat
    plain = LinkTrust(timeout=1.0, recover_after=1)
    plain.sequence(7, 0.0)
    plain.good(0.0)
    again = LinkTrust(timeout=1.0, recover_after=1).restore(plain.state())
    assert again.sequence(7, 0.1, content=5.0) is Fault.REPEATED and again.anomalies == 0


def test_a_late_message_at_a_live_clocks_time_does_not_open_the_sequence_to_replays():
    """As at t near zero, so at a live clock's times: stale by a late message, not silent, an old number is refused."""
    link = LinkTrust(timeout=0.25, recover_after=1)
    assert _take(link, 7, 1000.0) is None
    link.fail(Fault.LATE, 1000.125)
    assert link.link is PhysicalLink.STALE and link.sequence(5, 1000.125) is Fault.REPEATED
