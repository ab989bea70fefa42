"""The welding cell's DBC and the black-channel checks on its frames (AUTOSAR E2E profile 2)."""

from __future__ import annotations

import can
import cantools
import pytest
from cantools.autosar.end_to_end import check_profile2_crc

from cellsim.bridges.e2e import DeviceChecker, Fault, data_id, protect

from conftest import ROOT

DBC = cantools.database.load_file(str(ROOT / "bridges" / "welding_cell.dbc"))
SCANNER = DBC.get_message_by_name("ScannerState")


def frames(n: int, start: int = 0, **values):
    values = {"Range": 1, "Distance": 1.5, **values}
    return [protect(SCANNER, values, start + i) for i in range(n)]


def test_frames_are_profile_2_protected_and_decode_with_any_dbc_tool():
    frame = protect(SCANNER, {"Range": "close", "Distance": 0.75}, counter=5)
    assert len(frame) == SCANNER.length and frame[1] & 0x0F == 5
    assert check_profile2_crc(frame, data_id(SCANNER.frame_id, 5))  # cantools' own check agrees
    decoded = DBC.decode_message(SCANNER.frame_id, frame)
    assert decoded["Range"] == "close" and decoded["Distance"] == pytest.approx(0.75)
    # every message of the cell carries the protection
    for message in DBC.messages:
        assert {"Crc", "Counter"} <= {s.name for s in message.signals}, message.name


def test_a_device_is_trusted_only_after_three_good_frames_in_a_row():
    checker = DeviceChecker(message=SCANNER, timeout=0.1)
    verdicts = [checker.check(f, t * 0.04) for t, f in enumerate(frames(4))]
    assert [v.trusted for v in verdicts] == [False, False, True, True]
    assert verdicts[0].recovering and verdicts[2].values == {"Range": 1, "Distance": pytest.approx(1.5)}


@pytest.mark.parametrize(
    "spoil, fault",
    [
        (lambda f: bytes([f[0] ^ 0x01]) + f[1:], Fault.CRC),  # corrupt CRC
        (lambda f: f[:-1], Fault.LENGTH),  # wrong length
        (lambda f: bytes([f[0]]) + bytes([f[1] ^ 0x40]) + f[2:], Fault.CRC),  # a flipped data bit
    ],
)
def test_a_spoiled_frame_fails_the_device_at_once(spoil, fault):
    checker = DeviceChecker(message=SCANNER, timeout=0.1)
    good = frames(5)
    for t, f in enumerate(good[:3]):
        checker.check(f, t * 0.04)
    verdict = checker.check(spoil(good[3]), 0.12)
    assert not verdict.trusted and verdict.fault is fault and checker.counts[fault.value] == 1


def test_a_repeated_counter_is_refused_an_old_one_fails_and_recovery_needs_good_frames_again():
    checker = DeviceChecker(message=SCANNER, timeout=0.1)
    good = frames(8)
    for t, f in enumerate(good[:4]):
        assert checker.check(f, t * 0.04).trusted == (t >= 2)
    repeated = checker.check(good[3], 0.16)  # the same frame again: refused, the device still trusted
    assert repeated.fault is Fault.REPEATED and not repeated.trusted and not checker.failed
    assert checker.check(good[1], 0.20).fault is Fault.COUNTER  # an old one: the counter jumps 14 ahead
    # the stream goes on from counter 2 (resynchronised): good frames, but not trusted at once
    later = frames(4, start=2)
    assert [checker.check(f, 0.24 + i * 0.04).trusted for i, f in enumerate(later[1:])] == [False, False, True]
    assert checker.counts["counter"] == 1 and checker.counts["repeated"] == 1


def test_a_value_outside_its_range_or_choices_is_refused():
    checker = DeviceChecker(message=SCANNER, timeout=0.1)
    for t, f in enumerate(frames(3)):
        checker.check(f, t * 0.04)
    # range code 3 is no reading (the DBC names 0 far, 1 near, 2 close): encode it around cantools' checks
    frame = bytearray(protect(SCANNER, {"Range": 2, "Distance": 1.0}, 3))
    frame[1] |= 0x30  # Range bits 12..13 -> 3
    from cantools.autosar.end_to_end import compute_profile2_crc

    frame[0] = compute_profile2_crc(bytes(frame), data_id(SCANNER.frame_id, 3))
    assert checker.check(bytes(frame), 0.12).fault is Fault.RANGE


def test_the_watchdog_fails_a_silent_device_once_per_timeout():
    checker = DeviceChecker(message=SCANNER, timeout=0.1)
    for t, f in enumerate(frames(3)):
        checker.check(f, t * 0.04)
    assert checker.watchdog(0.15) is None
    assert checker.watchdog(0.25).fault is Fault.TIMEOUT
    assert checker.watchdog(0.30) is None and checker.watchdog(0.36).fault is Fault.TIMEOUT
    assert checker.counts["timeout"] == 2


def test_protected_frames_cross_a_python_can_bus_intact():
    sender = can.Bus(interface="virtual", channel="e2e-test", receive_own_messages=False)
    receiver = can.Bus(interface="virtual", channel="e2e-test")
    try:
        checker = DeviceChecker(message=SCANNER, timeout=0.1)
        for t, data in enumerate(frames(3, Range=2, Distance=0.4)):
            sender.send(can.Message(arbitration_id=SCANNER.frame_id, data=data, is_extended_id=False))
            received = receiver.recv(timeout=1.0)
            assert received is not None and received.arbitration_id == SCANNER.frame_id
            verdict = checker.check(bytes(received.data), t * 0.04)
        assert verdict.trusted and verdict.values["Range"] == 2
    finally:
        sender.shutdown()
        receiver.shutdown()


def test_a_forger_interleaving_good_frames_latches_a_masquerade_until_one_sender_runs_alone():
    """Issue 22: three forged 'clear' frames (CRC and next counter computed from the DBC) after each real
    'broken' one used to be trusted 3 times out of 4. Two senders on one identifier show in the counter."""
    curtain = DBC.get_message_by_name("LightCurtainState")
    checker = DeviceChecker(message=curtain, timeout=0.1, recover_after=3)
    t, clear_after_latch, latched_at = 0.0, 0, None
    for real in range(40):  # 40 real frames at 20 ms, each followed by three forged ones
        t += 0.02
        judged = checker.check(protect(curtain, {"Broken": 1}, real), t)
        if checker.masquerade and latched_at is None:
            latched_at = real
        for k in range(1, 4):
            forged = checker.check(protect(curtain, {"Broken": 0}, real + k), t + 0.001 * k)
            clear_after_latch += forged.trusted and latched_at is not None
    assert latched_at is not None and latched_at <= 3  # the third real frame's step back latched it
    assert checker.masquerade and checker.counts["masquerade"] >= 1 and clear_after_latch == 0
    assert not judged.trusted and judged.fault.value == "masquerade"
    # the forger stops: the real curtain alone, in order, clears it after a stable run, then recover_after
    trusted = []
    for real in range(40, 80):
        t += 0.02
        trusted.append(checker.check(protect(curtain, {"Broken": 1}, real), t).trusted)
    first = trusted.index(True)
    assert not checker.masquerade and 16 <= first <= 16 + 3 and all(trusted[first:])


def test_a_retransmitted_frame_is_no_masquerade():
    checker = DeviceChecker(message=SCANNER, timeout=0.1, recover_after=1)
    good = frames(10)
    for t, f in enumerate(good):
        checker.check(f, t * 0.04)
        assert checker.check(f, t * 0.04 + 0.001).fault is Fault.REPEATED  # the same frame twice: refused
    assert not checker.masquerade and checker.check(frames(1, start=10)[0], 0.5).trusted


# Known-good frames of ScannerState, written out byte for byte: computed once with cantools' own
# AUTOSAR profile 2 (cantools.autosar.end_to_end.compute_profile2_crc, polynomial 0x2F) over bytes 1..5
# and the data ID (base + counter) mod 256, the base 0xd2 that same CRC over the frame id's bytes 01 20, not
# with cellsim.bridges.e2e.
KNOWN_GOOD = [
    (5, {"Range": "near", "Distance": 1.5}, "c915dc050000"),  # data ID 0xd7
    (15, {"Range": "close", "Distance": 60.0}, "1e2f60ea0000"),  # data ID 0xe1; Distance at its DBC maximum
]


@pytest.mark.parametrize("counter, values, frame", KNOWN_GOOD)
def test_frames_match_known_good_bytes_and_only_their_own_counters_data_id_checks(counter, values, frame):
    """The data ID follows the counter: the same bytes checked with another counter's ID (the frame id's
    alone, say) fail; so does a CRC one above or one below the right one."""
    from cantools.autosar.end_to_end import compute_profile2_crc

    expected = bytes.fromhex(frame)
    assert protect(SCANNER, values, counter) == expected
    assert compute_profile2_crc(expected, SCANNER.frame_id % 256) != expected[0]  # the counter-blind ID: another CRC
    checker = DeviceChecker(message=SCANNER, timeout=0.1, recover_after=1)
    assert checker.check(expected, 0.0).trusted
    for delta in (+1, -1):
        spoiled = bytes([(expected[0] + delta) % 256]) + expected[1:]
        assert DeviceChecker(message=SCANNER, timeout=0.1).check(spoiled, 0.0).fault is Fault.CRC, delta


def test_a_frame_longer_or_shorter_than_its_message_is_a_length_fault():
    good = bytes.fromhex(KNOWN_GOOD[0][2])
    for data in (good + b"\x00", good[:-1], good + good):
        assert DeviceChecker(message=SCANNER, timeout=0.1).check(data, 0.0).fault is Fault.LENGTH, data.hex()


def test_a_value_is_judged_against_its_dbc_range_at_the_boundary():
    """Distance: 16 bits of 1 mm can carry 65.535 m; the DBC allows [0, 60]. Exactly 60 m is good, one step
    more is out of range (a frame with a right CRC and counter, made around cantools' own range check)."""
    from cantools.autosar.end_to_end import compute_profile2_crc

    def frame(raw_mm: int, counter: int) -> bytes:
        data = bytearray(protect(SCANNER, {"Range": "far", "Distance": 0.0}, counter))
        data[2:4] = raw_mm.to_bytes(2, "little")
        data[0] = compute_profile2_crc(bytes(data), data_id(SCANNER.frame_id, counter))
        return bytes(data)

    for raw, fault in ((60_000, None), (60_001, Fault.RANGE), (65_000, Fault.RANGE), (65_535, Fault.RANGE)):
        checker = DeviceChecker(message=SCANNER, timeout=0.1, recover_after=1)
        assert checker.check(frame(raw, 3), 0.0).fault is fault, raw


def test_a_value_outside_its_signal_is_never_encoded_into_a_frame():
    """protect refuses what the DBC does not allow (cantools' strict encoding), plain or authenticated: a frame is
    never made of a value clamped or wrapped on the way."""
    import cantools.database

    from cellsim.bridges.secoc import Authenticator, message_key

    for values in ({"Range": "far", "Distance": 60.5}, {"Range": 3, "Distance": 1.0}):
        with pytest.raises(cantools.database.EncodeError):
            protect(SCANNER, values, 0)
    authenticated = DBC.get_message_by_name("ScannerStateAuthenticated")
    signer = Authenticator(authenticated, message_key(bytes(16), authenticated.frame_id), 0.01, lambda: 1.8e9)
    with pytest.raises(cantools.database.EncodeError):
        protect(authenticated, {"Range": "far", "Distance": 60.5}, 0, signer)


def test_a_checker_counts_the_faults_its_kind_of_message_can_have():
    from cellsim.bridges.e2e import AUTHENTICATED_FAULTS, E2E_FAULTS
    from cellsim.bridges.secoc import Authenticator, message_key

    plain = DeviceChecker(message=SCANNER, timeout=0.1)
    assert list(plain.counts) == [f.value for f in E2E_FAULTS]
    authenticated = DBC.get_message_by_name("ScannerStateAuthenticated")
    signer = Authenticator(authenticated, message_key(bytes(16), authenticated.frame_id), 0.01)
    checked = DeviceChecker(message=authenticated, timeout=0.1, authenticator=signer)
    assert list(checked.counts) == [f.value for f in AUTHENTICATED_FAULTS]
    chosen = DeviceChecker(message=authenticated, timeout=0.1, authenticator=signer, faults=(Fault.CRC,))
    assert list(chosen.counts) == ["crc"]  # a caller's own choice stands


def test_a_stream_of_forged_frames_keeps_the_device_corrupt_not_stale():
    """While forged authenticated frames keep coming, the device stays failed as corrupt (someone is sending),
    past its watchdog; when they stop it goes stale."""
    from cellsim.bridges.secoc import Authenticator, message_key

    message = DBC.get_message_by_name("ScannerStateAuthenticated")
    key, clock = message_key(bytes(16), message.frame_id), (lambda: 1.8e9)
    checker = DeviceChecker(message=message, timeout=0.1, recover_after=1,
                            authenticator=Authenticator(message, key, 0.01, clock))
    device = Authenticator(message, key, 0.01, clock)
    forger = Authenticator(message, message_key(bytes([1] * 16), message.frame_id), 0.01, clock)
    assert checker.check(protect(message, {"Range": "far", "Distance": 2.0}, 0, device), 0.0).trusted
    for i in range(1, 8):  # every 40 ms for 0.28 s: past the 0.1 s watchdog
        assert checker.check(protect(message, {"Range": "far", "Distance": 9.0}, i, forger), 0.04 * i).fault is Fault.AUTH
        assert checker.watchdog(0.04 * i + 0.01) is None and checker.link.value == "corrupt", i
    assert checker.watchdog(0.28 + 0.2).fault is Fault.TIMEOUT and checker.link.value == "stale"


def test_a_repeated_counter_carrying_other_data_is_a_second_sender_not_a_retransmission():
    checker = DeviceChecker(message=SCANNER, timeout=1.0, recover_after=1)
    first = protect(SCANNER, {"Range": "near", "Distance": 1.5}, 4)
    assert checker.check(first, 0.0).trusted
    assert checker.check(first, 0.01).fault is Fault.REPEATED  # the same bytes: a retransmission, refused
    other = protect(SCANNER, {"Range": "far", "Distance": 5.0}, 4)
    assert checker.check(other, 0.02).fault is Fault.COUNTER and checker.anomalies == 1


SIGNED_DBC = """VERSION ""
BU_: Node
BO_ 100 Probe: 3 Node
 SG_ Crc : 0|8@1+ (1,0) [0|255] "" Node
 SG_ Counter : 8|4@1+ (1,0) [0|15] "" Node
 SG_ Mode : 12|2@1+ (1,0) [0|3] "" Node
 SG_ Level : 16|8@1+ (1,0) [10|200] "" Node
VAL_ 100 Mode 0 "off" 1 "on" 2 "fault" ;
"""


def test_an_enumeration_takes_only_its_named_values_and_a_number_its_range_from_both_ends():
    """Mode's two bits could carry 3, which its DBC range allows but no name has; Level's byte carries 0..255,
    its range is [10, 200]: each checked at both ends, exactly."""
    from cantools.autosar.end_to_end import compute_profile2_crc

    probe = cantools.database.load_string(SIGNED_DBC, "dbc").get_message_by_name("Probe")

    def frame(mode: int, level: int, counter: int = 1) -> bytes:
        data = bytearray(3)
        data[1] = counter | (mode << 4)
        data[2] = level
        data[0] = compute_profile2_crc(bytes(data), data_id(probe.frame_id, counter))
        return bytes(data)

    def judged(mode: int, level: int):
        return DeviceChecker(message=probe, timeout=1.0, recover_after=1).check(frame(mode, level), 0.0).fault

    assert judged(2, 100) is None and judged(3, 100) is Fault.RANGE
    assert judged(0, 10) is None and judged(0, 9) is Fault.RANGE
    assert judged(0, 200) is None and judged(0, 201) is Fault.RANGE


def test_a_stream_of_corrupt_frames_keeps_the_device_corrupt_until_it_stops():
    """Frames keep coming, each with a bad CRC (a damaged transceiver): the device is corrupt, not stale, for as
    long as they come (its diagnostics say so); silence after them makes it stale."""
    checker = DeviceChecker(message=SCANNER, timeout=0.1, recover_after=1)
    good = frames(8)
    assert checker.check(good[0], 0.0).trusted
    for i in range(1, 8):
        bad = bytes([good[i][0] ^ 0xFF]) + good[i][1:]
        assert checker.check(bad, 0.04 * i).fault is Fault.CRC
        assert checker.watchdog(0.04 * i + 0.01) is None and checker.link.value == "corrupt", i
    assert checker.watchdog(0.28 + 0.2).fault is Fault.TIMEOUT and checker.link.value == "stale"


@pytest.mark.parametrize("spoil", ["short", "range", "jump"])
def test_a_stream_of_any_faulty_frames_keeps_the_device_corrupt_while_it_comes(spoil):
    """Short frames, values out of range, counters jumping (a second sender): each arrival of a faulty frame counts
    as the device heard, so its link stays corrupt past the watchdog, then goes stale when they stop."""
    from cantools.autosar.end_to_end import compute_profile2_crc

    checker = DeviceChecker(message=SCANNER, timeout=0.1, recover_after=1)
    good = frames(16)
    assert checker.check(good[0], 0.0).trusted

    def faulty(i: int) -> bytes:
        if spoil == "short":
            return good[i][:-1]
        if spoil == "range":
            data = bytearray(good[i])
            data[2:4] = (65_000).to_bytes(2, "little")
            data[0] = compute_profile2_crc(bytes(data), data_id(SCANNER.frame_id, i))
            return bytes(data)
        return good[(i * 5) % 16]  # counters jumping by 5: anomalies, then a masquerade

    for i in range(1, 8):
        assert checker.check(faulty(i), 0.04 * i).fault is not None
        assert checker.watchdog(0.04 * i + 0.01) is None and checker.link.value == "corrupt", (spoil, i)
    assert checker.watchdog(0.5).fault is Fault.TIMEOUT


def test_messages_whose_ids_differ_only_above_the_low_byte_never_check_as_each_other():
    """The data ID's base takes every bit of the 11-bit id: an audit found 0x110 (the light curtain) and 0x210 (a
    welder command), both 4 bytes, sharing every data ID, so a command frame passed as 'curtain clear'."""
    curtain, command = DBC.get_message_by_name("LightCurtainState"), DBC.get_message_by_name("WelderCommand")
    assert curtain.frame_id % 256 == command.frame_id % 256 and curtain.length == command.length
    frame = protect(command, {name: 0 for name in (s.name for s in command.signals) if name not in ("Crc", "Counter")}, 2)
    assert DeviceChecker(message=curtain, timeout=0.1).check(frame, 0.0).fault is Fault.CRC
    from cellsim.bridges.e2e import sharing_data_ids

    assert sharing_data_ids(DBC.messages) is None  # the cell's DBC has no two sharing


def test_a_bridge_whose_dbc_gives_two_messages_one_data_id_list_is_refused(tmp_path):
    """A DBC where two mapped messages of one length share their data IDs: the loader names them."""
    import re
    import shutil

    from cellsim.bridges.config import load_bridge
    from cellsim.bridges.e2e import data_id_base
    from cellsim.config.typed_yaml import ConfigError
    from cellsim.scenario import load_scenario

    curtain = DBC.get_message_by_name("LightCurtainStateAuthenticated")  # (messages the shipped bridge maps)
    welder = DBC.get_message_by_name("WelderCommandAuthenticated")
    twin = next(i for i in range(0x300, 0x800) if data_id_base(i) == data_id_base(curtain.frame_id))
    for name in ("welding_cell.yaml", "welding_cell.dbc"):
        shutil.copy(ROOT / "bridges" / name, tmp_path / name)
    dbc = tmp_path / "welding_cell.dbc"
    dbc.write_text(re.sub(rf"\b{welder.frame_id}\b", str(twin), dbc.read_text()))
    said = f"has the data IDs of 'LightCurtainStateAuthenticated' (0x{curtain.frame_id:x})"
    with pytest.raises(ConfigError, match=re.escape(said)):
        load_bridge(tmp_path / "welding_cell.yaml", load_scenario(ROOT / "scenarios" / "welding_cell.yaml"))


def test_a_watchdog_the_alive_counter_can_outrun_unseen_is_refused():
    from cellsim.bridges.config import DeviceMapping
    from cellsim.config.typed_yaml import FieldError

    with pytest.raises(FieldError, match="shorter than 14 cycles"):
        DeviceMapping(message="ScannerState", fields={}, cycle_time=0.01, watchdog=0.2)


def test_an_extended_id_has_data_ids_and_a_command_watchdog_the_counter_outruns_is_refused():
    from cellsim.bridges.config import CommandMapping
    from cellsim.bridges.e2e import data_id_base
    from cellsim.config.typed_yaml import FieldError

    assert 0 <= data_id_base(0x18FF1234) < 256 and data_id_base(0x18FF1234) != data_id_base(0x1234)
    with pytest.raises(FieldError, match="shorter than 14 cycles"):
        CommandMapping(message="WelderCommand", fields={}, cycle_time=0.02, watchdog=0.5)
