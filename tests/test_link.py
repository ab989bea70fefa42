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
