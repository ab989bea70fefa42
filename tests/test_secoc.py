"""Authenticated CAN frames (cellsim/bridges/secoc.py): a forger who has the DBC but not the key fails the link
at his first frame; replays and stale frames are never taken."""

from __future__ import annotations

import json
import math
import os
import queue
import shutil
import subprocess
import sys

import can
import cantools
import pytest
from cantools.autosar.end_to_end import check_profile2_crc, compute_profile2_crc
from cryptography.hazmat.primitives.ciphers import algorithms
from cryptography.hazmat.primitives.cmac import CMAC
from cryptography.hazmat.primitives.kdf.kbkdf import KBKDFCMAC, CounterLocation, Mode

from cellsim.bridges.config import load_bridge
from cellsim.bridges.e2e import DeviceChecker, data_id, protect
from cellsim.bridges.secoc import Authenticator, message_key
from cellsim.config.typed_yaml import ConfigError
from cellsim.link import Fault
from cellsim.live import pki
from cellsim.vocabulary import PhysicalLink, TwinMode

from conftest import ROOT

AUTHENTICATED = ROOT / "bridges" / "welding_cell.yaml"  # every message authenticated
DBC = cantools.database.load_file(str(ROOT / "bridges" / "welding_cell.dbc"))
CURTAIN = DBC.get_message_by_name("LightCurtainStateAuthenticated")
TICK = 0.01
CAN_KEY = bytes(range(16))
T0 = 1_800_000_000.0  # a wall-clock time (s since the epoch)


class Clock:
    def __init__(self, t: float = T0):
        self.t = t

    def __call__(self) -> float:
        return self.t


def device(clock: Clock, key: bytes = CAN_KEY) -> Authenticator:
    return Authenticator(CURTAIN, message_key(key, CURTAIN.frame_id), TICK, clock)


def checker(clock: Clock) -> DeviceChecker:
    return DeviceChecker(message=CURTAIN, timeout=0.1, authenticator=device(clock))


def test_a_frame_carries_the_documented_cmac_and_freshness_and_any_dbc_tool_decodes_it():
    """The layout of docs/security.md, recomputed here from the standard primitives, not cellsim.bridges.secoc."""
    clock = Clock(T0 + 0.123)
    frame = protect(CURTAIN, {"Broken": 1}, 7, device(clock))
    kdf = KBKDFCMAC(algorithms.AES, Mode.CounterMode, 16, 4, 4, CounterLocation.BeforeFixed, b"cellsim SecOC",
                    CURTAIN.frame_id.to_bytes(4, "big"), None)
    key = kdf.derive(CAN_KEY)
    freshness = math.floor((T0 + 0.123) / TICK)
    assert frame[4] == freshness % 256  # byte 4: the freshness value's low 8 bits
    covered = bytes([0, frame[1], frame[2], frame[3], 0, 0, 0, 0])  # Crc, Freshness and Mac zeroed
    cmac = CMAC(algorithms.AES(key))
    cmac.update(CURTAIN.frame_id.to_bytes(2, "big") + covered + freshness.to_bytes(8, "big"))
    assert frame[5:8] == cmac.finalize()[:3]  # bytes 5-7: the CMAC's first 24 bits
    assert check_profile2_crc(frame, data_id(CURTAIN.frame_id, 7))  # the CRC last, over the secured frame
    decoded = DBC.decode_message(CURTAIN.frame_id, frame)
    assert decoded["Broken"] == 1 and decoded["Counter"] == 7
    # each message has its own key
    assert message_key(CAN_KEY, 273) != message_key(CAN_KEY, 513) and len(message_key(CAN_KEY, 273)) == 16


@pytest.mark.skipif(shutil.which("openssl") is None, reason="the openssl command recomputes the MAC")
def test_openssl_derives_the_same_message_key_and_verifies_the_frames_mac(tmp_path):
    """A second implementation (OpenSSL's KBKDF and CMAC, from the keys folder's can.key) agrees."""
    pki.init_keys(tmp_path / "keys")
    can_key = pki.can_key(tmp_path / "keys")
    clock = Clock(T0 + 42.0)
    frame = protect(CURTAIN, {"Broken": 0}, 3, Authenticator(CURTAIN, message_key(can_key, CURTAIN.frame_id), TICK, clock))

    def openssl(*args: str, data: bytes | None = None) -> str:
        done = subprocess.run(["openssl", *args], input=data, capture_output=True, timeout=30)
        assert done.returncode == 0, done.stderr
        return done.stdout.decode().strip().replace(":", "").lower()

    key = openssl("kdf", "-keylen", "16", "-kdfopt", "mac:CMAC", "-kdfopt", "cipher:AES-128-CBC",
                  "-kdfopt", f"hexkey:{(tmp_path / 'keys' / 'can.key').read_text().strip()}",
                  "-kdfopt", f"hexsalt:{b'cellsim SecOC'.hex()}", "-kdfopt", f"hexinfo:{CURTAIN.frame_id:08x}", "KBKDF")
    freshness = math.floor((T0 + 42.0) / TICK)
    covered = bytes([0, frame[1], frame[2], frame[3], 0, 0, 0, 0])
    mac = openssl("mac", "-cipher", "AES-128-CBC", "-macopt", f"hexkey:{key}", "CMAC",
                  data=CURTAIN.frame_id.to_bytes(2, "big") + covered + freshness.to_bytes(8, "big"))
    assert frame[5:8].hex() == mac[:6]


def test_a_forger_with_the_dbc_but_not_the_key_fails_the_link_at_his_first_frame_and_keeps_it_failed():
    """Issue 22's attack on an authenticated curtain: three forged 'clear' frames (CRC and next counter
    computed from the DBC, a guessed MAC) after each real 'broken' one. E2E alone let the first forgeries
    through until the masquerade latched; here not one is taken, and the link stays failed throughout."""
    clock = Clock()
    real, receiver = device(clock), checker(clock)
    forger = device(clock, key=os.urandom(16))
    for counter in range(3):
        clock.t += 0.02
        receiver.check(protect(CURTAIN, {"Broken": 1}, counter, real), clock.t)
    assert receiver.link is PhysicalLink.OK
    taken_forged, links = 0, []
    for counter in range(3, 3 + 100):  # 2 s at 20 ms; the forger sends the counters that come next
        clock.t += 0.02
        judged = receiver.check(protect(CURTAIN, {"Broken": 1}, counter, real), clock.t)
        assert judged.good and (judged.trusted == (counter == 3))  # the real frames: authentic, but after the
        for k in range(1, 4):                                      # first forgery only recovering
            forged = receiver.check(protect(CURTAIN, {"Broken": 0}, counter + k, forger), clock.t + 0.001 * k)
            assert forged.fault is Fault.AUTH
            taken_forged += forged.trusted
            links.append(receiver.link)
    assert taken_forged == 0 and receiver.counts["auth"] == 300 and receiver.counts["counter"] == 0
    assert set(links) == {PhysicalLink.CORRUPT}  # failed from the first forgery while the attack lasts
    # the forger gone: the real device is trusted again after recover_after good frames
    for counter in range(103, 106):
        clock.t += 0.02
        last = receiver.check(protect(CURTAIN, {"Broken": 1}, counter, real), clock.t)
    assert last.trusted and receiver.link is PhysicalLink.OK


def test_a_tampered_frame_with_its_crc_recomputed_fails_authentication():
    clock = Clock()
    receiver = checker(clock)
    frame = bytearray(protect(CURTAIN, {"Broken": 1}, 0, device(clock)))
    frame[1] &= ~0x10  # Broken (bit 12) cleared
    frame[0] = compute_profile2_crc(bytes(frame), data_id(CURTAIN.frame_id, 0))
    assert check_profile2_crc(bytes(frame), data_id(CURTAIN.frame_id, 0))
    assert receiver.check(bytes(frame), 0.0).fault is Fault.AUTH
    assert receiver.link is PhysicalLink.CORRUPT


@pytest.mark.parametrize("delay, restarted, fault, link", [
    (0.0, False, Fault.REPEATED, PhysicalLink.OK),  # at once: the same freshness again, refused
    (1.0, False, Fault.REPEATED, PhysicalLink.OK),  # later: still not after the last one taken
    (1.0, True, Fault.LATE, PhysicalLink.STALE),  # to a restarted daemon: authentic, older than the watchdog
    (5.0, True, Fault.AUTH, PhysicalLink.CORRUPT),  # beyond the low bits' reach: its freshness rebuilt wrong
])
def test_a_replayed_authentic_frame_is_never_taken(delay, restarted, fault, link):
    clock = Clock()
    sender, receiver = device(clock), checker(clock)
    for counter in range(3):
        clock.t += 0.02
        captured = protect(CURTAIN, {"Broken": 0}, counter, sender)
        receiver.check(captured, clock.t)
    clock.t += delay
    if restarted:
        receiver = checker(clock)
    judged = receiver.check(captured, clock.t)
    assert not judged.trusted and judged.fault is fault and receiver.link is link


def test_frames_stamped_ahead_of_the_receivers_clock_are_refused_and_clocks_within_the_skew_agree():
    sender_clock, receiver_clock = Clock(T0 + 0.8), Clock(T0)
    receiver = checker(receiver_clock)
    assert receiver.check(protect(CURTAIN, {"Broken": 0}, 0, device(sender_clock)), 0.0).fault is Fault.FUTURE
    sender_clock.t = T0 + 0.3  # within the link's 0.5 s skew: taken
    assert receiver.check(protect(CURTAIN, {"Broken": 0}, 1, device(sender_clock)), 0.02).good


def test_the_sender_never_repeats_a_freshness_value_even_when_the_clock_stands_still():
    clock = Clock()
    sender, receiver = device(clock), checker(clock)
    frames = [protect(CURTAIN, {"Broken": 1}, c, sender) for c in range(4)]  # all within one tick
    assert len({f[4] for f in frames}) == 4
    clock.t += 0.05  # the receiver's clock has moved past them by then
    assert all(receiver.check(f, 0.001 * i).good for i, f in enumerate(frames))


@pytest.mark.parametrize("edit, key, expected", [
    ("freshness_tick: 0.05", "freshness_tick", "longer than the cycle time of LightCurtainStateAuthenticated"),
    ("freshness_tick: 0.001", "devices.light_barrier.message", "rebuilds only within +-0.128 s"),
])
def test_a_freshness_value_that_cannot_span_its_window_is_refused_at_load(tmp_path, edit, key, expected):
    (tmp_path / "bridge.yaml").write_text(
        f"base: {AUTHENTICATED}\nscenario: {ROOT / 'scenarios' / 'welding_cell.yaml'}\ndbc: {ROOT / 'bridges' / 'welding_cell.dbc'}\n{edit}\n")
    with pytest.raises(ConfigError) as e:
        load_bridge(tmp_path / "bridge.yaml")
    assert e.value.key == key and expected in str(e.value)


def test_a_message_with_a_freshness_value_but_no_mac_is_refused_at_load(tmp_path):
    dbc = (ROOT / "bridges" / "welding_cell.dbc").read_text()
    dbc = dbc.replace(' SG_ Mac : 47|24@0+ (1,0) [0|16777215] "" Bridge\n', "")
    (tmp_path / "cell.dbc").write_text(dbc)
    (tmp_path / "bridge.yaml").write_text(
        f"base: {AUTHENTICATED}\nscenario: {ROOT / 'scenarios' / 'welding_cell.yaml'}\ndbc: cell.dbc\n")
    with pytest.raises(ConfigError) as e:
        load_bridge(tmp_path / "bridge.yaml")
    assert e.value.key == "devices.light_barrier.message" and "an authenticated message has both" in str(e.value)


def test_keys_init_writes_the_can_key_privately_and_a_bad_one_is_said_as_such(tmp_path):
    pki.init_keys(tmp_path / "keys")
    path = tmp_path / "keys" / "can.key"
    assert path.stat().st_mode & 0o777 == 0o600
    assert len(bytes.fromhex(path.read_text().strip())) == 16 == len(pki.can_key(tmp_path / "keys"))
    assert any(line.startswith("can ") for line in pki.describe(tmp_path / "keys"))
    pki.init_keys(tmp_path / "other")
    assert pki.can_key(tmp_path / "other") != pki.can_key(tmp_path / "keys")  # random, per cell
    path.write_text("not hex\n")
    with pytest.raises(pki.KeysError, match="not a 128-bit key"):
        pki.can_key(tmp_path / "keys")
    path.unlink()
    with pytest.raises(pki.KeysError, match="no can.key"):
        pki.can_key(tmp_path / "keys")


def test_the_daemon_without_the_can_key_refuses_to_start_in_one_line_exit_2(tmp_path):
    pki.init_keys(tmp_path / "keys")
    (tmp_path / "keys" / "can.key").unlink()
    proc = subprocess.run([sys.executable, "-m", "cellsim", "bridge", str(AUTHENTICATED), "--keys", str(tmp_path / "keys"),
                           "--can", "virtual:secoc-test"], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert ("LightCurtainStateAuthenticated, ScannerStateAuthenticated, WelderStatusAuthenticated, "
            "SafetyModeRequestAuthenticated, WelderCommandAuthenticated are authenticated") in proc.stderr
    assert "no can.key" in proc.stderr


def test_the_daemon_and_the_emulated_devices_authenticate_each_others_frames(tmp_path):
    """In-process, on a virtual bus: the emulated curtain's frames become samples at the daemon, a forged one a
    link failure; the daemon's authenticated safety-mode requests reach the emulated welder, a forged one
    gets its safe command."""
    from types import SimpleNamespace

    import zenoh

    from cellsim.bridges.daemon import Bridge
    from cellsim.bridges.devices import EmulatedDevices
    from cellsim.channels import number_type
    from cellsim.live.session import session_config

    from live_processes import free_port, wait_for

    loaded = load_bridge(AUTHENTICATED)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    hub = zenoh.open(session_config(role="bridge", insecure=True, listen=[endpoint], listen_by_default=True))
    watcher = zenoh.open(session_config(role="twin", insecure=True, connect=[endpoint]))
    samples: queue.Queue = queue.Queue()
    subscriber = watcher.declare_subscriber("cellsim/welding_cell/physical/light_barrier",
                                            lambda s: samples.put(json.loads(s.payload.to_bytes())))
    cell_bus = can.Bus(interface="virtual", channel="secoc-cell")
    daemon_bus = can.Bus(interface="virtual", channel="secoc-cell")
    forger_bus = can.Bus(interface="virtual", channel="secoc-cell")
    bridge = Bridge(loaded, hub, bus=daemon_bus, can_key=CAN_KEY)
    devices = EmulatedDevices(loaded, cell_bus, session=None, can_key=CAN_KEY)
    delivered: queue.Queue = queue.Queue()
    enum = SimpleNamespace(kind="enum")
    source = SimpleNamespace(inputs=["safety_mode_request", "activity_request", "command"],
                             codec=SimpleNamespace(types=[enum, enum, number_type(None)]),
                             deliver=lambda payload: delivered.put(json.loads(payload)["fields"]))
    try:
        # the curtain: the emulated device's frames, checked by the daemon
        curtain = devices.outlet("light_barrier", None)
        curtain_id = CURTAIN.frame_id

        def deliver_one() -> object:
            frame = daemon_bus.recv(timeout=5)
            return bridge.handle(frame.arbitration_id, bytes(frame.data))

        first = None
        for _ in range(250):  # until the watcher's subscription has reached the hub
            curtain.send({"broken": True}, None, 0.0)
            assert deliver_one().good
            try:
                first = samples.get(timeout=0.02)
                break
            except queue.Empty:
                continue
        assert first is not None and first["fields"] == {"broken": True}
        forged = protect(CURTAIN, {"Broken": 0}, curtain.counter,
                         Authenticator(CURTAIN, os.urandom(16), loaded.config.freshness_tick))
        forger_bus.send(can.Message(arbitration_id=curtain_id, data=forged, is_extended_id=False))
        assert deliver_one().fault is Fault.AUTH
        wait_for(lambda: not samples.empty() and samples.queue[-1].get("failed") == "auth", 5, "a link failure")
        assert bridge.devices[curtain_id].checker.counts["auth"] == 1
        # the welder: the daemon's authenticated requests in twin mode, checked by the emulated device
        assert devices.feed_commands(SimpleNamespace(module="welder"), source)
        bridge._modes["welder"], bridge._twin_alive = TwinMode.TWIN, True
        bridge._commands["welder"] = {"safety_mode_request": "ssmon", "activity_request": None, "command": 0.0}
        bridge._command_links["welder"].good(bridge.clock())
        for _ in range(3):  # trusted after three good frames in a row
            bridge.send_commands(only="welder")
        fields = [delivered.get(timeout=5) for _ in range(6)][-1]  # two frames per round
        assert fields["safety_mode_request"] == "ssmon"
        request = loaded.database.get_message_by_name("SafetyModeRequestAuthenticated")
        forged = protect(request, {"SafetyMode": "normal"}, bridge._counters[request.name],
                         Authenticator(request, os.urandom(16), loaded.config.freshness_tick))
        forger_bus.send(can.Message(arbitration_id=request.frame_id, data=forged, is_extended_id=False))
        assert delivered.get(timeout=5)["safety_mode_request"] == "stopped"  # the forgery: the safe command
    finally:
        devices.close()
        bridge.close()
        subscriber.undeclare()
        for bus in (cell_bus, daemon_bus, forger_bus):
            bus.shutdown()
        watcher.close()
        hub.close()


class _Publishers:
    """A stand-in for the daemon's Zenoh session: what it would publish, per key."""

    def __init__(self):
        self.published: dict[str, list] = {}

    def declare_publisher(self, key, **kwargs):
        outer = self

        class Publisher:
            def put(self, payload):
                outer.published.setdefault(key, []).append(json.loads(payload))

        return Publisher()

    def declare_subscriber(self, *args, **kwargs):
        return self

    def liveliness(self):
        return self

    def declare_token(self, key):
        return self

    def undeclare(self):
        pass


def _forged(message, values: dict, counter: int) -> bytes:
    """What a forger with the DBC but not the key sends: the right CRC and counter, a MAC of another key."""
    return protect(message, values, counter, Authenticator(message, os.urandom(16), 0.01))


def test_every_reading_of_the_shipped_cell_refuses_a_forgery_from_its_first_frame():
    """Issue 32: the shipped configuration authenticates every device; a forged frame (CRC and counter right)
    is never a sample, whether it comes first or after the device's own good frames."""
    from cellsim.bridges.daemon import Bridge

    loaded = load_bridge(AUTHENTICATED)
    assert loaded.e2e_only() == []
    values = {"light_barrier": {"Broken": 0}, "range_detector": {"Range": "far", "Distance": 5.0},
              "welder": {"SafetyMode": "normal", "Activity": "welding"}}
    assert set(values) == set(loaded.config.devices)
    for first in (True, False):
        session = _Publishers()
        bridge = Bridge(loaded, session, can_key=CAN_KEY)
        for entity, mapping in loaded.config.devices.items():
            message = loaded.database.get_message_by_name(mapping.message)
            key = f"cellsim/welding_cell/physical/{entity}"
            real = Authenticator(message, message_key(CAN_KEY, message.frame_id), loaded.config.freshness_tick)
            counter = 0
            if not first:
                for counter in range(3):  # the device's own frames: samples
                    assert bridge.handle(message.frame_id, protect(message, values[entity], counter, real)).good
                counter += 1
            judgement = bridge.handle(message.frame_id, _forged(message, values[entity], counter))
            assert judgement.fault is Fault.AUTH, (entity, judgement)
            assert session.published[key][-1]["failed"] == "auth", entity  # a failure by its fault, at once
            forged_samples = session.published[key][3 if not first else 0:]
            assert all("fields" not in p for p in forged_samples), (entity, forged_samples)


def test_every_command_of_the_shipped_cell_refuses_a_forgery_from_its_first_frame():
    """The emulated welder checks the daemon's frames as the real one must: a forged request or command (CRC and
    counter right) gets the kind's safe values, never what it asks, first or after good frames."""
    from types import SimpleNamespace

    from cellsim.bridges.devices import EmulatedDevices
    from cellsim.channels import number_type

    loaded = load_bridge(AUTHENTICATED)
    enum = SimpleNamespace(kind="enum")
    unsafe = {"SafetyModeRequestAuthenticated": {"SafetyMode": "normal"},
              "WelderCommandAuthenticated": {"ActivityRequest": "welding", "Weld": 1}}
    assert {m.message for m in loaded.config.commands["welder"]} == set(unsafe)
    for first in (True, False):
        for mapping in loaded.config.commands["welder"]:
            delivered: queue.Queue = queue.Queue()
            source = SimpleNamespace(inputs=["safety_mode_request", "activity_request", "command"],
                                     codec=SimpleNamespace(types=[enum, enum, number_type(None)]),
                                     deliver=lambda payload: delivered.put(json.loads(payload)["fields"]))
            channel = f"secoc-commands-{mapping.message}-{first}"
            cell_bus, daemon_bus = (can.Bus(interface="virtual", channel=channel) for _ in range(2))
            devices = EmulatedDevices(loaded, cell_bus, session=None, can_key=CAN_KEY)
            message = loaded.database.get_message_by_name(mapping.message)
            real = Authenticator(message, message_key(CAN_KEY, message.frame_id), loaded.config.freshness_tick)
            send = lambda data: daemon_bus.send(can.Message(arbitration_id=message.frame_id, data=data,  # noqa: E731
                                                            is_extended_id=False))
            try:
                assert devices.feed_commands(SimpleNamespace(module="welder"), source)
                counter = 0
                if not first:
                    for counter in range(3):  # the daemon's own frames: trusted after three
                        send(protect(message, unsafe[mapping.message], counter, real))
                        fields = delivered.get(timeout=5)
                    asked = {"safety_mode_request": "normal"} if "SafetyMode" in mapping.fields else \
                        {"activity_request": "welding", "command": 1.0}
                    assert fields == loaded.safe["welder"] | asked, fields  # the real frames were taken
                    counter += 1
                send(_forged(message, unsafe[mapping.message], counter))
                assert delivered.get(timeout=5) == loaded.safe["welder"], mapping.message  # the safe values
            finally:
                devices.close()
                cell_bus.shutdown()
                daemon_bus.shutdown()


# Known-good authenticated frames, written out byte for byte (key bytes 0..15, wall clock T0 + 0.123 s, 0.01 s
# ticks): the curtain's was checked against the standard primitives above (KBKDF-CMAC, AES-CMAC, cantools'
# profile 2 CRC), the welder command's likewise when it was written down. Byte 0, the CRC, was computed again
# with cantools' profile 2 CRC when the data IDs took every bit of the frame id (base: that CRC over its 2 bytes).
KNOWN_FRAMES = [
    ("LightCurtainStateAuthenticated", {"Broken": 1}, 7, "901700000c45217e"),
    ("WelderCommandAuthenticated", {"ActivityRequest": "welding", "Weld": 1}, 12, "b75c00000c00f52f"),
]


@pytest.mark.parametrize("name, values, counter, frame", KNOWN_FRAMES)
def test_authenticated_frames_match_known_good_bytes_and_any_changed_mac_bit_is_refused(name, values, counter, frame):
    message = DBC.get_message_by_name(name)
    key = message_key(CAN_KEY, message.frame_id)
    expected = bytes.fromhex(frame)
    assert protect(message, values, counter, Authenticator(message, key, TICK, Clock(T0 + 0.123))) == expected

    def receiver() -> DeviceChecker:
        return DeviceChecker(message=message, timeout=0.5, recover_after=1,
                             authenticator=Authenticator(message, key, TICK, Clock(T0 + 0.125)))

    assert receiver().check(expected, 0.0).trusted
    for bit in range(24):  # bytes 5-7 hold the MAC: each of its bits changed, the CRC made right again
        spoiled = bytearray(expected)
        spoiled[5 + bit // 8] ^= 1 << (bit % 8)
        spoiled[0] = compute_profile2_crc(bytes(spoiled), data_id(message.frame_id, counter))
        assert receiver().check(bytes(spoiled), 0.0).fault is Fault.AUTH, bit
    other_key = DeviceChecker(message=message, timeout=0.5, recover_after=1,
                              authenticator=Authenticator(message, message_key(bytes(16), message.frame_id), TICK,
                                                          Clock(T0 + 0.125)))
    assert other_key.check(expected, 0.0).fault is Fault.AUTH


def test_a_message_is_authenticated_only_with_both_a_freshness_value_and_a_mac():
    from cellsim.bridges.secoc import is_authenticated

    assert is_authenticated(CURTAIN)
    half = cantools.database.load_string(
        'VERSION ""\nBU_: N\nBO_ 5 Half: 2 N\n SG_ Crc : 0|8@1+ (1,0) [0|255] "" N\n'
        ' SG_ Freshness : 8|8@1+ (1,0) [0|255] "" N\n', "dbc").get_message_by_name("Half")
    assert not is_authenticated(half)


def test_the_freshness_window_is_refused_when_it_only_just_fails_to_span_watchdog_and_skew():
    """Binary fractions: ticks of 2^-7 s give 8 low bits a reach of +-1.0 s exactly; a watchdog and skew that add
    up to it are refused (they must be less), a hair less is taken."""
    from cellsim.bridges.secoc import window_problem

    tick = 2.0 ** -7
    problem = window_problem(CURTAIN, tick, 0.5, 0.5)
    assert problem == ("its 8-bit freshness value at 0.0078125 s ticks rebuilds only within +-1 s, which must exceed the "
                       "watchdog (0.5 s) plus the clock skew allowed (0.5 s): widen the Freshness signal or lengthen "
                       "freshness_tick")
    assert window_problem(CURTAIN, tick, 0.5 - 2.0 ** -20, 0.5) is None


def test_freshness_values_sent_within_one_tick_follow_one_another():
    clock = Clock(T0 + 0.123)
    sender = device(clock)
    values = [sender.next_freshness() for _ in range(4)]
    first = math.floor((T0 + 0.123) / TICK)
    assert values == [first, first + 1, first + 2, first + 3]
    clock.t += 1.0  # the clock moves on: its own count again
    assert sender.next_freshness() == math.floor((T0 + 1.123) / TICK)


def test_a_frame_exactly_half_the_counters_range_old_is_rebuilt_as_old_and_is_late():
    """The receiver rebuilds the full value nearest its own count; exactly half the range (128 ticks) away is read
    as past, so an authentic frame that old verifies and is late, not taken as one from the future."""
    sent = protect(CURTAIN, {"Broken": 1}, 3, device(Clock(T0)))
    receiver = DeviceChecker(message=CURTAIN, timeout=0.1, recover_after=1,
                             authenticator=device(Clock(T0 + 128 * TICK)))
    assert receiver.check(sent, 0.0).fault is Fault.LATE
    ahead = DeviceChecker(message=CURTAIN, timeout=0.1, recover_after=1,
                          authenticator=device(Clock(T0 + 127 * TICK)))
    assert ahead.check(sent, 0.0).fault is Fault.LATE  # nearer: the same value, late
