"""The bridge daemon's CAN side: checked device frames become the twin's physical samples."""

from __future__ import annotations

import json
import queue
import re
import time
from pathlib import Path

import can
import pytest
import zenoh

from cellsim.bridges.config import load_bridge
from cellsim.bridges.daemon import Bridge
from cellsim.bridges.e2e import DeviceChecker, protect
from cellsim.channels import BOOL, enum_type, number_type
from cellsim.config.typed_yaml import ConfigError
from cellsim.codec import FAILURES, FieldCodec
from cellsim.live.session import session_config
from cellsim.vocabulary import Range, TwinMode

from conftest import ROOT
from live_processes import free_port, wait_for

SHIPPED = ROOT / "bridges" / "welding_cell.yaml"


def config_text() -> str:
    """The welding cell's bridge configuration, naming its scenario by an absolute path (to be copied)."""
    return SHIPPED.read_text().replace("scenario: ../scenarios/welding_cell.yaml",
                                       f"scenario: {ROOT / 'scenarios' / 'welding_cell.yaml'}")


def e2e_only_text() -> str:
    """The welding cell's bridge with every message end-to-end protected only (the DBC's plain messages),
    each by the explicit choice a device that cannot compute a MAC needs: the E2E checks in isolation."""
    text = config_text().replace("dbc: welding_cell.dbc", f"dbc: {ROOT / 'bridges' / 'welding_cell.dbc'}")
    return re.sub(r"^( *)(- )?message: (\w+)Authenticated$",
                  lambda m: f"{m[1]}{m[2] or ''}message: {m[3]}\n{m[1]}{'  ' if m[2] else ''}e2e_only: a test of the E2E checks",
                  text, flags=re.M)


@pytest.fixture(scope="module")
def e2e_config(tmp_path_factory) -> Path:
    """The E2E-only configuration the daemon-logic tests load."""
    path = tmp_path_factory.mktemp("e2e-only") / "bridge.yaml"
    path.write_text(e2e_only_text())
    return path


@pytest.fixture
def sessions():
    """A hub with the daemon's session, and a second session that plays the twin, a watcher or a controller:
    the daemon's logic, with no access control between them (test_security.py tests the roles)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    hub = zenoh.open(session_config(role="bridge", insecure=True, listen=[endpoint], listen_by_default=True))
    watcher = zenoh.open(session_config(role="twin", insecure=True, connect=[endpoint]))
    try:
        yield hub, watcher
    finally:
        watcher.close()
        hub.close()


def test_checked_frames_become_samples_and_any_failure_a_link_failure_at_once(sessions, e2e_config):
    """The daemon forwards each frame's outcome at once (the twin applies recover-after, once): a good
    frame as the entity's sample, a bad one or silence as a failure, so the twin fails safe as its kind says."""
    hub, watcher = sessions
    received: queue.Queue = queue.Queue()
    subscriber = watcher.declare_subscriber("cellsim/welding_cell/physical/**",
                                            lambda s: received.put((str(s.key_expr), s.payload.to_bytes())))
    loaded = load_bridge(e2e_config)
    bridge = Bridge(loaded, hub)
    curtain = loaded.database.get_message_by_name("LightCurtainState")
    device = can.Bus(interface="virtual", channel="bridge-test", receive_own_messages=False)
    bus = can.Bus(interface="virtual", channel="bridge-test")

    def next_sample(timeout: float = 5.0):
        key, payload = received.get(timeout=timeout)
        return key, json.loads(payload)

    def send(data: bytes, frame_id: int = curtain.frame_id):
        device.send(can.Message(arbitration_id=frame_id, data=data, is_extended_id=False))
        frame = bus.recv(timeout=1.0)
        return bridge.handle(frame.arbitration_id, bytes(frame.data), now=0.02 * counter[0])

    counter = [0]
    try:
        # the subscription reaches the hub asynchronously: until the first sample is heard, resend
        for _ in range(250):
            send(protect(curtain, {"Broken": 0}, counter[0]))
            counter[0] += 1
            try:
                first = next_sample(timeout=0.02)
                break
            except queue.Empty:
                continue
        assert first[0] == "cellsim/welding_cell/physical/light_barrier"
        sample = first[1]
        assert sample["fields"] == {"broken": False}  # the very first good frame: forwarded at once
        assert abs(sample["t"] - time.time()) < 5  # stamped with the daemon's wall clock
        # the twin's light barrier reads the payload as any sample
        message = FieldCodec(("broken",), (BOOL,)).decode(json.dumps(sample).encode())
        assert message.codes == [0.0] and message.seq >= 1
        # a corrupt CRC: a link failure at once, and the fault counted
        bad = bytearray(protect(curtain, {"Broken": 0}, counter[0]))
        bad[0] ^= 0xFF
        counter[0] += 1
        assert send(bytes(bad)).fault.value == "crc"
        assert next_sample()[1]["failed"] == "crc"  # forwarded by the fault its check found
        # the same frame twice (a repeated counter): refused and counted, nothing published
        frame = protect(curtain, {"Broken": 1}, counter[0])
        counter[0] += 1
        assert send(frame).good and next_sample()[1]["fields"] == {"broken": True}
        assert send(frame).fault.value == "repeated"
        with pytest.raises(queue.Empty):
            next_sample(timeout=0.2)
        assert bridge.devices[curtain.frame_id].checker.counts["crc"] == 1
        # an unknown frame is counted and dropped
        assert send(b"\x00\x01", frame_id=0x7FF) is None and bridge.unknown_frames == 1
        # silence: the watchdog says stale
        bridge.check_watchdogs(now=0.02 * counter[0] + 1.0)
        assert next_sample()[1]["failed"] == "timeout"
        assert bridge.devices[curtain.frame_id].checker.counts["repeated"] == 1
    finally:
        subscriber.undeclare()
        device.shutdown()
        bus.shutdown()


def test_enumerations_go_out_by_name(e2e_config):
    loaded = load_bridge(e2e_config)

    class Recorder:
        def __init__(self):
            self.payloads = []

        def declare_publisher(self, key, **kwargs):
            return self

        def declare_subscriber(self, *args, **kwargs):
            return self

        def declare_token(self, key):
            return self

        def liveliness(self):
            return self

        def put(self, payload):
            self.payloads.append(payload)

    out = Recorder()
    bridge = Bridge(loaded, out)
    scanner = loaded.database.get_message_by_name("ScannerState")
    for c in range(3):
        bridge.handle(scanner.frame_id, protect(scanner, {"Range": "near", "Distance": 1.25}, c), now=0.04 * c)
    codes = FieldCodec(("range", "distance"), (enum_type(Range), number_type("m"))).decode(out.payloads[-1]).codes
    assert codes == [float(Range.NEAR.code), pytest.approx(1.25)]


@pytest.mark.parametrize(
    "old, new, key, expected",
    [
        ("message: LightCurtainStateAuthenticated", "message: LightCurtain", "devices.light_barrier.message", "no message 'LightCurtain'"),
        # a message without a MAC only by an explicit, reasoned choice; and only where it has none
        ("message: ScannerStateAuthenticated", "message: ScannerState", "devices.range_detector.message",
         "'ScannerState' is not authenticated (no Freshness and Mac signals)"),
        ("    - message: WelderCommandAuthenticated\n", "    - message: WelderCommand\n      e2e_only: ' '\n",
         "commands.welder.1.message", "'WelderCommand' is not authenticated"),
        ("    message: WelderStatusAuthenticated\n", "    message: WelderStatusAuthenticated\n    e2e_only: no MAC here\n",
         "devices.welder.e2e_only", "'WelderStatusAuthenticated' is authenticated: e2e_only does not apply"),
        ("fields: {broken: Broken}", "fields: {broken: Brokn}", "devices.light_barrier.fields.broken", "no signal 'Brokn'"),
        ("dbc: welding_cell.dbc", "dbc: welding.dbc", "dbc", "file not found: welding.dbc"),
        ("scenario: SCENARIO", "scenario: nowhere.yaml", "scenario", "file not found: nowhere.yaml"),
        ("    watchdog: 0.1", "    watchdog: 0.01", "devices.light_barrier.watchdog", "longer than the cycle time"),
        ("wrist_2_joint, wrist_3_joint]", "wrist_2_joint]", "robots.robot.joints", "six joints"),
        ("    watchdog: 0.05", "    watchdog: 0.001", "robots.robot.watchdog", "longer than the cycle time"),
        ("ros_namespace: /welding_cell", "ros_namespace: /welding cell", "robots.robot.ros_namespace", "not a ROS 2 name"),
        # loaded with the scenario: the devices are its entities, with its kinds' fields and values
        ("  light_barrier:\n", "  light_curtain:\n", "devices.light_curtain", "no entity named 'light_curtain'"),
        ("fields: {range: Range, distance: Distance}", "fields: {range: Range}", "devices.range_detector.fields",
         "map each physical-sample field of range_detector exactly once: range, distance"),
        ("fields: {safety_mode: SafetyMode, activity: Activity}", "fields: {safety_mode: SafetyMode, activity: SafetyMode}",
         "devices.welder.fields.activity", "signal SafetyMode can carry normal, hguid"),
        ("    - message: WelderCommandAuthenticated\n      fields: {ActivityRequest: activity_request, Weld: command}",
         "    - message: SafetyModeRequestAuthenticated\n      fields: {SafetyMode: safety_mode_request}",
         "commands.welder.1.message", "'SafetyModeRequestAuthenticated' is already the frame of commands.welder.0"),
        ("fields: {SafetyMode: safety_mode_request}", "fields: {SafetyMode: mode_request}",
         "commands.welder.0.fields.SafetyMode", "'mode_request' is not a command field of welder"),
        ("fields: {ActivityRequest: activity_request, Weld: command}", "fields: {ActivityRequest: safety_mode_request, Weld: command}",
         "commands.welder.1.fields.ActivityRequest", "welder's safe command safety_mode_request = stopped is not a value"),
    ],
)
def test_a_configuration_that_does_not_match_its_dbc_or_scenario_is_one_error_naming_the_key(tmp_path, old, new, key, expected):
    text = config_text()
    old = old.replace("SCENARIO", str(ROOT / "scenarios" / "welding_cell.yaml"))
    assert old in text
    (tmp_path / "welding_cell.dbc").write_text((ROOT / "bridges" / "welding_cell.dbc").read_text())
    path = tmp_path / "bridge.yaml"
    path.write_text(text.replace(old, new, 1))
    with pytest.raises(ConfigError) as e:
        load_bridge(path)
    assert e.value.key == key and expected in str(e.value) and e.value.line is not None, (e.value.key, str(e.value))


def test_what_a_device_is_told_when_the_twin_is_lost_is_its_kinds_safe_command(e2e_config):
    loaded = load_bridge(e2e_config)
    assert loaded.safe["welder"] == {"safety_mode_request": "stopped", "activity_request": "off", "command": 0.0}
    assert [loaded.signals(m).safe_signals() for m in loaded.config.commands["welder"]] == [
        {"SafetyMode": "stopped"}, {"ActivityRequest": "off", "Weld": 0.0}]
    assert loaded.safe["robot"]["safety_mode_request"] == "stopped"


def test_commands_reach_the_bus_only_in_twin_mode_and_the_safe_ones_when_the_supervisor_is_lost(sessions, e2e_config):
    import threading
    import time

    hub, twin = sessions  # the hub plays the network; the second session plays the twin
    loaded = load_bridge(e2e_config)
    bus = can.Bus(interface="virtual", channel="bridge-commands", receive_own_messages=False)
    welder = can.Bus(interface="virtual", channel="bridge-commands")
    request = loaded.database.get_message_by_name("SafetyModeRequest")
    checker = DeviceChecker(message=request, timeout=1.0, recover_after=1)
    bridge = Bridge(loaded, hub, bus=bus)
    token = None
    mode = twin.declare_publisher("cellsim/welding_cell/twin/welder/twin_mode")
    command = twin.declare_publisher("cellsim/welding_cell/command/welder")

    def frames_now(now: float) -> list:
        bridge.send_commands(now)
        out = []
        while (frame := welder.recv(timeout=0.0)) is not None:
            if frame.arbitration_id == request.frame_id:
                verdict = checker.check(bytes(frame.data), now)
                assert verdict.trusted, verdict  # protected: CRC and counter good
                out.append(request.decode(bytes(frame.data))["SafetyMode"])
        return [str(v) for v in out]

    def until(condition, what: str):
        """Take in what the network delivered until ``condition`` holds, polling with a deadline."""
        deadline, pause = time.monotonic() + 10, threading.Event()
        while True:
            bridge.take_inbox()
            if condition():
                return
            assert time.monotonic() < deadline, what
            pause.wait(0.01)

    try:
        token = twin.liveliness().declare_token("cellsim/welding_cell/alive/twin")
        until(lambda: bridge._twin_alive, "the twin's token")  # its modes are taken only from a living twin
        # shadow mode: nothing goes to the bus, whatever the twin says
        mode.put(json.dumps({"t": time.time(), "sim_time": 0.0, "value": "shadow"}))
        until(lambda: bridge.twin_mode("welder") is TwinMode.SHADOW, "shadow mode heard")
        assert frames_now(time.monotonic()) == []
        # twin mode: the twin's request goes out
        mode.put(json.dumps({"t": time.time(), "sim_time": 0.1, "value": "twin"}))
        command.put(json.dumps({"t": time.time(), "seq": 1, "fields": {"safety_mode_request": "ssmon", "activity_request": None, "command": 1.0}}))
        until(lambda: "welder" in bridge._commands and bridge._twin_alive and bridge.twin_mode("welder") is TwinMode.TWIN,
              "command heard")
        assert set(frames_now(time.monotonic())) == {"ssmon"}
        # its commands stop for longer than the watchdog: the safe request, stopped
        assert frames_now(time.monotonic() + 0.6) == ["stopped"]
        # a fresh command again; then the twin goes: stopped
        command.put(json.dumps({"t": time.time(), "seq": 2, "fields": {"safety_mode_request": "normal", "activity_request": None, "command": 0.0}}))
        until(lambda: bridge._commands["welder"]["safety_mode_request"] == "normal", "second command")
        # a changed command went out at once, as it was taken in; and again on the cycle
        assert frames_now(time.monotonic()) == ["normal", "normal"]
        token.undeclare()
        token = None
        until(lambda: not bridge._twin_alive, "the twin's token gone")
        assert frames_now(time.monotonic()) == ["stopped"]
        assert bridge.safe_frames_sent >= 2 * 2  # both the request and the welder command each time
    finally:
        if token is not None:
            token.undeclare()
        bridge.close()
        bus.shutdown()
        welder.shutdown()


def test_the_daemon_loop_publishes_device_frames_until_stopped(sessions, e2e_config):
    import threading

    from cellsim.bridges.daemon import run_bridge

    hub, watcher = sessions
    loaded = load_bridge(e2e_config)
    bus = can.Bus(interface="virtual", channel="bridge-loop")
    device = can.Bus(interface="virtual", channel="bridge-loop")
    heard = threading.Event()
    subscriber = watcher.declare_subscriber(
        "cellsim/welding_cell/physical/range_detector",
        lambda s: heard.set() if json.loads(s.payload.to_bytes())["fields"] == {"range": "near", "distance": 1.25} else None,
    )
    bridge = Bridge(loaded, hub, bus=bus)
    stop = threading.Event()
    loop = threading.Thread(target=run_bridge, args=(bridge, bus, stop), daemon=True)
    loop.start()
    scanner = loaded.database.get_message_by_name("ScannerState")
    try:
        counter = 0
        while not heard.is_set():  # the device sends every 40 ms until the twin's side hears it
            assert counter < 500, "no sample heard"
            device.send(can.Message(arbitration_id=scanner.frame_id, is_extended_id=False,
                                    data=protect(scanner, {"Range": "near", "Distance": 1.25}, counter)))
            counter += 1
            heard.wait(0.04)
        # junk on the bus (an unknown identifier, an FD frame too long for any device) does not stop the loop
        device.send(can.Message(arbitration_id=0x7FF, data=bytes(range(48)), is_extended_id=False, is_fd=True))
        device.send(can.Message(arbitration_id=scanner.frame_id, data=b"\x00", is_extended_id=False))
        for _ in range(4):  # each good frame after them is still heard
            published = bridge.devices[scanner.frame_id].published
            device.send(can.Message(arbitration_id=scanner.frame_id, is_extended_id=False,
                                    data=protect(scanner, {"Range": "near", "Distance": 1.25}, counter)))
            counter += 1
            wait_for(lambda: bridge.devices[scanner.frame_id].published > published or not loop.is_alive(), 5,
                     "the loop hearing a frame")
            assert loop.is_alive()
    finally:
        stop.set()
        loop.join(5)
        subscriber.undeclare()
        bridge.close()
        bus.shutdown()
        device.shutdown()
    assert not loop.is_alive()  # it ends when asked
    assert bridge.unknown_frames == 1 and bridge.devices[scanner.frame_id].checker.counts["length"] == 1


def test_cellsim_bridge_refuses_a_bad_configuration_in_one_line(tmp_path, e2e_config):
    import subprocess
    import sys

    path = tmp_path / "bridge.yaml"
    path.write_text(config_text().replace("dbc: welding_cell.dbc", "dbc: missing.dbc"))
    proc = subprocess.run([sys.executable, "-m", "cellsim", "bridge", str(path)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1 and "file not found: missing.dbc" in proc.stderr
    proc = subprocess.run([sys.executable, "-m", "cellsim", "bridge", str(e2e_config), "--can", "socketcan"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "expected INTERFACE:CHANNEL" in proc.stderr


def test_a_command_frame_without_end_to_end_protection_is_refused_at_load(tmp_path):
    dbc = (ROOT / "bridges" / "welding_cell.dbc").read_text()
    dbc = dbc.replace('''BO_ 513 SafetyModeRequestAuthenticated: 8 Bridge
 SG_ Crc : 0|8@1+ (1,0) [0|255] "" Welder
 SG_ Counter : 8|4@1+ (1,0) [0|15] "" Welder
''', "BO_ 513 SafetyModeRequestAuthenticated: 8 Bridge\n")
    (tmp_path / "welding_cell.dbc").write_text(dbc)
    path = tmp_path / "bridge.yaml"
    path.write_text(config_text())
    with pytest.raises(ConfigError) as e:
        load_bridge(path)
    assert e.value.key == "commands.welder.0.message" and "not end-to-end protected" in str(e.value)


def _state(seq: int, t: float, q0: float = 0.5, **over) -> bytes:
    state = {"t": t, "seq": seq, "position": [q0, -1.0, 1.2, 0.0, 1.57, 0.0], "velocity": [0.1, 0, 0, 0, 0, 0],
             "safety_mode": "normal", "activity": "moving", "reached_pose": None, **over}
    return json.dumps(state).encode()


def test_the_robot_controllers_state_becomes_the_robots_sample_and_a_ros_joint_state(sessions, e2e_config):
    """States at 500 Hz over Zenoh: checked, published as the robot's physical sample and as a CDR
    sensor_msgs/JointState on the key zenoh-bridge-ros2dds maps to /welding_cell/joint_states."""
    import threading
    import time

    from cellsim.bridges.daemon import run_bridge
    from cellsim.bridges.ros import decode_joint_state

    hub, controller = sessions
    samples: queue.Queue = queue.Queue()
    joint_states: queue.Queue = queue.Queue()
    statuses: queue.Queue = queue.Queue()
    subscribers = [
        controller.declare_subscriber("cellsim/welding_cell/physical/robot", lambda s: samples.put(json.loads(s.payload.to_bytes()))),
        controller.declare_subscriber("welding_cell/joint_states", lambda s: joint_states.put((s.payload.to_bytes(), str(s.encoding)))),
        controller.declare_subscriber("cellsim/welding_cell/diagnostics/robot", lambda s: statuses.put(json.loads(s.payload.to_bytes()))),
    ]
    state = controller.declare_publisher("cellsim/welding_cell/controller/robot/state")
    bridge = Bridge(load_bridge(e2e_config), hub)
    stop, cycled = threading.Event(), threading.Event()  # cycled: set by every turn of the daemon's loop
    loop = threading.Thread(target=run_bridge, args=(bridge, None, stop), kwargs={"on_cycle": cycled.set}, daemon=True)
    loop.start()
    seq = [0]

    last = [b""]

    def send(**over) -> None:
        seq[0] += 1
        last[0] = _state(seq[0], time.time(), **over)
        state.put(last[0])

    def next_sample() -> dict:
        return samples.get(timeout=5)

    STALE = ("timeout", "late")  # what a loaded machine may publish meanwhile: the watchdog, a late copy

    try:
        deadline = time.monotonic() + 10
        while True:  # until the daemon's subscription is in place (a good state is forwarded at once)
            assert time.monotonic() < deadline, "no robot sample"
            send(q0=0.5)
            try:
                sample = samples.get(timeout=0.002)
            except queue.Empty:
                continue
            if "fields" in sample:
                break
            assert sample["failed"] in FAILURES, sample  # not yet trusted (a link failure, by its fault)
        assert sample["fields"] == {"q0": 0.5, "q1": -1.0, "q2": 1.2, "q3": 0.0, "q4": 1.57, "q5": 0.0,
                                    "safety_mode": "normal", "activity": "moving", "reached_pose": None}
        payload, encoding = joint_states.get(timeout=5)
        message = decode_joint_state(payload)  # a ROS 2 tool reads it as sensor_msgs/msg/JointState
        assert message.name == ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
                                "wrist_2_joint", "wrist_3_joint"]
        assert list(message.position) == [0.5, -1.0, 1.2, 0.0, 1.57, 0.0] and message.velocity[0] == 0.1
        assert abs(message.header.stamp.sec + message.header.stamp.nanosec * 1e-9 - time.time()) < 5
        assert payload[:4] == b"\x00\x01\x00\x00" and "cdr" in encoding.lower()  # CDR little endian, as ROS 2 sends
        # the last state again, byte for byte (a retransmission): refused and counted, nothing published for it
        # (the 50 ms watchdog may publish "timeout" meanwhile: only forwarded states are counted here)
        link = bridge.robots["robot"]
        for _ in range(50):
            # the daemon's loop has taken in every state sent so far (states still in its inbox would be forwarded
            # after the count below is read)
            send()
            wait_for(lambda: link.checker.last_seq == seq[0], 5, "every state sent taken in", poll=cycled)
            with link._lock:
                forwarded, received = link.published - link.failures_published, link.received
            state.put(last[0])
            wait_for(lambda: link.received > received, 5, "the retransmission taken in", poll=cycled)
            with link._lock:  # (held while a message is judged: the judgement is complete)
                refused = link.checker.counts["repeated"] == 1
                assert not refused or link.published - link.failures_published == forwarded
            if refused:
                break
            # else 50 ms passed between the two (a loaded machine): the copy is late (its stamp is judged first),
            # or the watchdog went off and after silence any state starts the sequence afresh (a restarted
            # sender), as the link rule says; try again
        else:
            pytest.fail("the retransmission was never judged a repeat")
        # its seq again with other content (a replay, or a second sender): the failure at once
        state.put(_state(seq[0], time.time(), q0=0.25))
        while (sample := next_sample()).get("failed") != "counter":
            assert "fields" in sample or sample["failed"] in STALE, sample
        while "fields" not in next_sample():  # forwarded again with the next good state
            send()
        # one out of range, one late: the failure at once, each counted
        for over, failure in (({"q0": 9.0}, "range"), ({"late": True}, "late")):
            if over.get("late"):
                seq[0] += 1
                state.put(_state(seq[0], time.time() - 1.0))
            else:
                send(**over)
            # (samples of good states still on their way come first; the watchdog may time out before)
            while (sample := next_sample()).get("failed") != failure:
                assert "fields" in sample or sample["failed"] in STALE, sample
            assert sample == {"t": pytest.approx(time.time(), abs=2), "seq": pytest.approx(0, abs=10**9), "failed": failure}
            while "fields" not in next_sample():  # forwarded again with the next good state
                send()
        # silence: the watchdog (50 ms) says stale
        while "fields" in (sample := next_sample()):
            pass
        assert sample["failed"] == "timeout"
        counts = bridge.robots["robot"].checker.counts
        assert (counts["repeated"], counts["counter"], counts["range"]) == (1, 1, 1)
        assert counts["late"] >= 1  # (a good state the loaded machine delivered 50 ms late is late too)
        assert counts["timeout"] >= 1
        # its diagnostics went stale, and said so
        deadline = time.monotonic() + 5
        while (status := statuses.get(timeout=5))["counts"]["range"] < 1 or status["counts"]["late"] < 1 or status["level"] != "STALE":
            assert time.monotonic() < deadline
        assert status["entity"] == "robot" and status["counts"]["range"] == 1 and status["received"] >= 5
    finally:
        stop.set()
        loop.join(5)
        for subscriber in subscribers:
            subscriber.undeclare()
        bridge.close()
    assert not loop.is_alive()


def test_robot_requests_go_to_the_controller_in_twin_mode_and_a_stop_when_the_twin_is_lost(sessions, e2e_config):
    import time

    hub, twin = sessions
    requests: queue.Queue = queue.Queue()
    subscriber = twin.declare_subscriber("cellsim/welding_cell/controller/robot/request",
                                         lambda s: requests.put(json.loads(s.payload.to_bytes())))
    bridge = Bridge(load_bridge(e2e_config), hub)
    mode = twin.declare_publisher("cellsim/welding_cell/twin/robot/twin_mode")
    command = twin.declare_publisher("cellsim/welding_cell/command/robot")
    token = twin.liveliness().declare_token("cellsim/welding_cell/alive/twin")
    fields = {"safety_mode_request": "ssmon", "activity": "welding", "target_pose": 2.0, "speed_limit": 0.3}  # a pose's index

    def take_until(condition) -> None:
        deadline = time.monotonic() + 10
        while not condition():
            assert time.monotonic() < deadline
            try:
                bridge.take(bridge.inbox.get(timeout=0.05))
            except queue.Empty:
                pass

    try:
        take_until(lambda: bridge._twin_alive)  # its modes are taken only from a living twin
        mode.put(json.dumps({"t": time.time(), "sim_time": 0.0, "value": "shadow"}))
        take_until(lambda: bridge.twin_mode("robot") is TwinMode.SHADOW)
        bridge.send_commands()
        assert bridge.robots["robot"].requests_sent == 0  # shadow: the controller answers to its own program
        mode.put(json.dumps({"t": time.time(), "sim_time": 0.1, "value": "twin"}))
        take_until(lambda: bridge.twin_mode("robot") is TwinMode.TWIN)
        command.put(json.dumps({"t": time.time(), "seq": 1, "fields": fields}))
        take_until(lambda: "robot" in bridge._commands)  # a changed command goes out at once
        assert requests.get(timeout=5)["fields"] == fields
        token.undeclare()
        token = None
        take_until(lambda: not bridge._twin_alive)
        bridge.send_commands()
        # the robot kind's safe command: stop, idle, hold where it is, no speed allowed
        assert requests.get(timeout=5)["fields"] == {"safety_mode_request": "stopped", "activity": "idle", "target_pose": -1.0,
                                                     "speed_limit": 0.0}
    finally:
        if token is not None:
            token.undeclare()
        subscriber.undeclare()
        bridge.close()


@pytest.fixture
def emulated_welder(e2e_config, request):
    """The welder's emulated CAN device fed by a daemon's bus (python-can's virtual interface, in this process): (the
    loaded bridge, the devices, the daemon's bus, the queue of the commands the device hands over). Closed after."""
    from types import SimpleNamespace

    from cellsim.bridges.devices import EmulatedDevices

    loaded = load_bridge(e2e_config)
    channel = f"emulated-welder-{request.node.name}"
    bus = can.Bus(interface="virtual", channel=channel)
    daemon = can.Bus(interface="virtual", channel=channel)
    delivered: queue.Queue = queue.Queue()
    enum, number = SimpleNamespace(kind="enum"), number_type(None)
    source = SimpleNamespace(inputs=["safety_mode_request", "activity_request", "command"],
                             codec=SimpleNamespace(types=[enum, enum, number]),
                             deliver=lambda payload: delivered.put(json.loads(payload)["fields"]))
    devices = EmulatedDevices(loaded, bus, session=None)
    try:
        assert devices.feed_commands(SimpleNamespace(module="welder"), source)
        yield loaded, devices, daemon, delivered
    finally:
        devices.close()
        bus.shutdown()
        daemon.shutdown()


def test_an_emulated_device_fails_safe_on_a_bad_command_frame_as_the_real_one_would(emulated_welder):
    loaded, devices, daemon, delivered = emulated_welder
    request = loaded.database.get_message_by_name("SafetyModeRequest")
    frame = lambda data: can.Message(arbitration_id=request.frame_id, data=data, is_extended_id=False)  # noqa: E731
    for counter in range(3):  # trusted after three good frames in a row
        daemon.send(frame(protect(request, {"SafetyMode": "ssmon"}, counter)))
        fields = delivered.get(timeout=5)
    assert fields == {"safety_mode_request": "ssmon", "activity_request": "off", "command": 0.0}
    bad = bytearray(protect(request, {"SafetyMode": "normal"}, 3))
    bad[0] ^= 0x01  # a corrupted CRC: the frame's safe values, not what it says
    daemon.send(frame(bytes(bad)))
    assert delivered.get(timeout=5)["safety_mode_request"] == "stopped"
    daemon.send(frame(protect(request, {"SafetyMode": "normal"}, 4)))
    assert delivered.get(timeout=5)["safety_mode_request"] == "stopped"  # recovering: still safe


def test_an_emulated_device_whose_one_command_message_stops_takes_that_messages_safe_values(emulated_welder):
    """The welder's safety mode and its weld command come in two messages, each with its own watchdog: while the
    weld commands keep coming, a safety mode request silent for longer than its watchdog is not the last one heard
    but its safe value (the devices' clock is the test's: no waiting)."""
    loaded, devices, daemon, delivered = emulated_welder
    now = [0.0]
    devices.clock = lambda: now[0]
    request = loaded.database.get_message_by_name("SafetyModeRequest")
    command = loaded.database.get_message_by_name("WelderCommand")
    watchdog = next(m.watchdog for m in loaded.config.commands["welder"] if m.message == "SafetyModeRequest")

    def send(message, values, counter):
        daemon.send(can.Message(arbitration_id=message.frame_id, data=protect(message, values, counter),
                                is_extended_id=False))
        return delivered.get(timeout=5)

    for counter in range(3):  # both trusted after three good frames in a row
        send(request, {"SafetyMode": "normal"}, counter)
        fields = send(command, {"ActivityRequest": "none", "Weld": 1}, counter)
    assert fields["safety_mode_request"] == "normal" and fields["command"] == 1.0
    now[0] = 0.9 * watchdog  # the request still within its watchdog: as last heard
    assert send(command, {"ActivityRequest": "none", "Weld": 1}, 3)["safety_mode_request"] == "normal"
    now[0] = 1.1 * watchdog  # silent for longer than its watchdog: its safe value, the weld command as sent
    fields = send(command, {"ActivityRequest": "none", "Weld": 1}, 4)
    assert fields["safety_mode_request"] == "stopped" and fields["command"] == 1.0
    for counter in range(5, 7):  # it comes back: safe until recover_after good frames in a row
        now[0] += 0.01
        assert send(request, {"SafetyMode": "normal"}, counter)["safety_mode_request"] == "stopped"
    assert send(request, {"SafetyMode": "normal"}, 7)["safety_mode_request"] == "normal"
    # a frozen stream: the same frame again and again is refused, not good, and its watchdog runs out (a review
    # found the repeats themselves keeping the last request trusted for ever)
    now[0] += 0.5 * watchdog
    assert send(request, {"SafetyMode": "normal"}, 7)["safety_mode_request"] == "normal"
    now[0] += 0.6 * watchdog
    assert send(request, {"SafetyMode": "normal"}, 7)["safety_mode_request"] == "stopped"


@pytest.mark.parametrize("args, expected", [
    (["--can", "virtual:x", "--fault", "welder=freeze"], "welder is a CAN device; its faults: drop, crc"),
    (["--can", "virtual:x", "--fault", "robot=crc"], "robot is on Zenoh; its faults: silence"),
    (["--fault", "welder=flood"], "a bus fault needs --can"),
    (["--bridge", "bridges/welding_cell.yaml"], "--bridge is for --can"),
    (["--can", "virtual:x", "--bridge", "nowhere.yaml"], "nowhere.yaml"),
    (["--can", "virtual"], "expected INTERFACE:CHANNEL"),
])
def test_bad_emulate_can_arguments_are_one_line_exit_2(tmp_path, args, expected):
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "cellsim", "emulate", str(ROOT / "scenarios" / "welding_cell.yaml"),
                           "--out", str(tmp_path / "out"), "--connect", f"tls/127.0.0.1:{free_port()}", *args],
                          capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1 and expected in proc.stderr, proc.stderr
    assert not (tmp_path / "out").exists()


def test_the_packed_joint_state_is_byte_for_byte_what_rosbags_serialises():
    import numpy as np

    from cellsim.bridges.ros import JOINT_STATE, JointStateEncoder, typestore

    store = typestore()
    joints = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
    encoder = JointStateEncoder(joints)
    rng = np.random.default_rng(7)
    JointState, Header, Time = (store.types[t] for t in (JOINT_STATE, "std_msgs/msg/Header", "builtin_interfaces/msg/Time"))
    for t in (0.0, 1795000000.25, 1795000123.999999):
        q, qd = rng.uniform(-6, 6, 6), rng.uniform(-3, 3, 6)
        sec = int(t // 1)
        expected = store.serialize_cdr(JointState(
            header=Header(stamp=Time(sec=sec, nanosec=min(round((t - sec) * 1e9), 999_999_999)), frame_id=""),
            name=joints, position=q, velocity=qd, effort=np.array([], dtype=np.float64)), JOINT_STATE)
        assert encoder.encode(t, q, qd) == bytes(expected)


def test_a_bus_that_refuses_a_frame_does_not_stop_the_daemons_loop(sessions, e2e_config):
    import threading

    from cellsim.bridges.daemon import run_bridge

    hub, twin = sessions

    class FullBus:
        """A bus whose transmit buffer is full: every send fails, as python-can says it."""

        sends = 0

        def send(self, message, timeout=None):
            FullBus.sends += 1
            raise can.CanOperationError("transmit buffer full")

    bridge = Bridge(load_bridge(e2e_config), hub, bus=FullBus())
    bridge._twin_alive, bridge._modes = True, {"welder": TwinMode.TWIN}  # commands are due every cycle
    stop, cycles = threading.Event(), [0]

    def on_cycle():
        cycles[0] += 1
        if cycles[0] >= 5:
            stop.set()

    loop = threading.Thread(target=run_bridge, args=(bridge, None, stop, on_cycle), daemon=True)
    loop.start()
    loop.join(10)
    bridge.close()
    # it kept going after the first refusal, and tried again on a later cycle (frames are due every 40 ms)
    assert not loop.is_alive() and cycles[0] >= 5 and FullBus.sends >= 2


def test_a_future_stamped_command_does_not_keep_a_lost_twin_in_charge(sessions, e2e_config):
    """Issue 22: a twin command stamped far ahead used to count as fresh for ever; now freshness is the
    daemon's own clock, so when the twin's commands stop, the safe command goes out after the watchdog."""
    import time

    hub, twin = sessions
    loaded = load_bridge(e2e_config)
    bus = can.Bus(interface="virtual", channel="bridge-future", receive_own_messages=False)
    welder = can.Bus(interface="virtual", channel="bridge-future")
    request = loaded.database.get_message_by_name("SafetyModeRequest")
    bridge = Bridge(loaded, hub, bus=bus)
    token = twin.liveliness().declare_token("cellsim/welding_cell/alive/twin")
    mode = twin.declare_publisher("cellsim/welding_cell/twin/welder/twin_mode")
    command = twin.declare_publisher("cellsim/welding_cell/command/welder")
    fields = {"safety_mode_request": "normal", "activity_request": "welding", "command": 1.0}

    def sent(now: float) -> list[str]:
        bridge.send_commands(now)
        out = []
        while (frame := welder.recv(timeout=0.0)) is not None:
            if frame.arbitration_id == request.frame_id:
                out.append(str(request.decode(bytes(frame.data))["SafetyMode"]))
        return out

    try:
        wait_for(lambda: bridge.take_inbox() or bridge._twin_alive, 10, "the twin's token")  # modes: a living twin's
        mode.put(json.dumps({"t": time.time(), "sim_time": 0.0, "value": "twin"}))
        command.put(json.dumps({"t": time.time(), "seq": 1, "fields": fields}))
        wait_for(lambda: bridge.take_inbox() or bridge._commands.get("welder") == fields and bridge._twin_alive, 10,
                 "the twin's command")
        assert set(sent(time.monotonic())) == {"normal"}
        # the forgery: the same command stamped a million seconds ahead, the next in sequence
        command.put(json.dumps({"t": time.time() + 1e6, "seq": 2, "fields": fields}))
        wait_for(lambda: bridge.take_inbox() or bridge.refused_messages == 1, 10, "the forgery refused")
        # the twin's commands stop (its token stays: a frozen twin): after the watchdog, the safe command
        assert sent(time.monotonic() + 0.6) == ["stopped"]
    finally:
        token.undeclare()
        bridge.close()
        bus.shutdown()
        welder.shutdown()


def test_a_future_stamped_controller_state_is_refused_and_the_robot_goes_stale_when_states_stop(sessions, e2e_config):
    import time

    hub, _ = sessions
    bridge = Bridge(load_bridge(e2e_config), hub)
    link = bridge.robots["robot"]
    try:
        now = time.monotonic()
        for seq in (1, 2, 3):
            assert bridge.handle_robot("robot", _state(seq, time.time()), now + seq * 0.002).good
        forged = bridge.handle_robot("robot", _state(4, time.time() + 1e6), now + 0.008)
        assert forged.fault.value == "future" and link.checker.counts["future"] == 1
        assert link.checker.link.value == "ok"  # refused, the link as it was
        link.check_watchdog(now + 0.008 + 1.0)  # no state since: stale, the forgery notwithstanding
        assert link.checker.link.value == "stale"
    finally:
        bridge.close()


def test_the_daemon_says_at_start_which_messages_go_without_authentication(tmp_path, e2e_config):
    """An E2E-only message is the configuration's explicit choice, and the daemon says so, with the reason, at
    every start (here against a loopback hub; the process is stopped by its PID)."""
    import signal

    from live_processes import processes

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    hub = zenoh.open(session_config(role="twin", insecure=True, listen=[endpoint], listen_by_default=True))
    try:
        with processes() as start:
            daemon = start(["bridge", str(e2e_config), "--can", "virtual:e2e-only-start", "--insecure", "--connect", endpoint],
                           tmp_path / "bridge.log")
            wait_for(lambda: "cellsim bridge: welding_cell on" in daemon.output() or daemon.popen.poll() is not None, 60,
                     "the daemon started")
            assert daemon.stop(signal.SIGINT) == 130, daemon.output()
    finally:
        hub.close()
    warnings = [line for line in daemon.output().splitlines() if "not authenticated, E2E only" in line]
    assert [w.rsplit(": ", 2)[1] for w in warnings] == [
        "LightCurtainState from light_barrier", "ScannerState from range_detector", "WelderStatus from welder",
        "SafetyModeRequest to welder", "WelderCommand to welder"]
    assert all(w.endswith(": a test of the E2E checks") for w in warnings)
    shipped = load_bridge(SHIPPED)
    assert shipped.e2e_only() == [] and len(shipped.authenticated()) == 5  # the shipped cell: every message


def test_a_twin_mode_that_is_not_one_is_refused_and_the_mode_stays_as_it_was(sessions, e2e_config):
    from cellsim import codec

    hub, _ = sessions
    bridge = Bridge(load_bridge(e2e_config), hub)
    try:
        bridge.take(("alive", None, True, 0.0))  # modes are taken from a living twin only (test_ur)
        bridge.take(("mode", "welder", codec.encode_value(1.0, 0.5, "twin"), 0.0))
        assert bridge.twin_mode("welder") is TwinMode.TWIN and bridge.refused_messages == 0
        for bad in (codec.encode_value(1.0, 0.6, "flying"), codec.encode_value(1.0, 0.7, 3), b"{not json"):
            bridge.take(("mode", "welder", bad, 0.0))
        assert bridge.twin_mode("welder") is TwinMode.TWIN and bridge.refused_messages == 3
        assert bridge.twin_mode("robot") is None  # never heard: no command goes out for it
    finally:
        bridge.close()


def test_a_configuration_on_a_base_elsewhere_finds_the_bases_scenario_and_dbc_beside_the_base(tmp_path):
    """Paths are relative to the file that wrote them: a cell's own file in another folder, on the shipped base."""
    own = tmp_path / "site" / "bridge.yaml"
    own.parent.mkdir()
    own.write_text(f"base: {SHIPPED}\nrecover_after: 5\n")
    loaded = load_bridge(own)
    assert loaded.cell == "welding_cell" and loaded.config.recover_after == 5 and loaded.database.messages


def test_the_bridges_ros_key_is_one_the_access_control_grants_and_no_cellsim_key_is():
    """The grant was **/joint_states, which matches cellsim/<cell>/command/joint_states (only the twin may publish
    command/**). It is joint_states under at most one namespace, and the loader refuses a ROS key outside it."""
    from cellsim.bridges.config import RobotLinkConfig, _key_matches
    from cellsim.config.typed_yaml import FieldError
    from cellsim.live.access import ROS_JOINT_STATE_KEYS

    for key in ("cellsim/welding_cell/command/joint_states", "cellsim/x/twin/robot/joint_states"):
        assert not any(_key_matches(p, key) for p in ROS_JOINT_STATE_KEYS)
    assert any(_key_matches(p, "welding_cell/joint_states") for p in ROS_JOINT_STATE_KEYS)
    with pytest.raises(FieldError, match="not one the twin's access control lets a bridge publish"):
        RobotLinkConfig(joints=[f"j{i}" for i in range(6)], ros_topic="/command/joint_states", ros_namespace="/cellsim/x")


def test_a_frame_is_judged_and_stamped_at_its_arrival_not_when_the_daemon_takes_it(tmp_path):
    """A frame held 0.3 s in the daemon's inbox (its thread busy): judged at the daemon-clock time it arrived and
    stamped with the wall time it arrived, so the twin's late check sees its age (an audit found it judged and
    stamped fresh when taken, past the watchdog)."""
    import time
    from types import SimpleNamespace

    from cellsim.bridges.daemon import Bridge
    from cellsim.bridges.e2e import protect

    text = (ROOT / "bridges" / "welding_cell.yaml").read_text()
    text = text.replace("scenario: ../scenarios/welding_cell.yaml", f"scenario: {ROOT / 'scenarios' / 'welding_cell.yaml'}")
    text = text.replace("dbc: welding_cell.dbc", f"dbc: {ROOT / 'bridges' / 'welding_cell.dbc'}")
    text = text.replace("    message: ScannerStateAuthenticated\n", "    message: ScannerState\n    e2e_only: test\n")
    config = tmp_path / "bridge.yaml"
    config.write_text(text)
    loaded = load_bridge(config)
    published: dict[str, list] = {}

    class Session:  # what the daemon asks of a Zenoh session, recorded
        def declare_publisher(self, key, **_):
            published[key] = []
            return SimpleNamespace(put=published[key].append)

        def declare_subscriber(self, *_, **__):
            return SimpleNamespace(undeclare=lambda: None)

        def liveliness(self):
            return SimpleNamespace(declare_token=lambda key: SimpleNamespace(undeclare=lambda: None),
                                   declare_subscriber=lambda *_, **__: SimpleNamespace(undeclare=lambda: None))

    clock, wall = [1000.0], [2.0e9]
    bridge = Bridge(loaded, Session(), clock=lambda: clock[0], wall_clock=lambda: wall[0], can_key=bytes(16))
    scanner = loaded.database.get_message_by_name("ScannerState")
    frame = SimpleNamespace(arbitration_id=scanner.frame_id, data=protect(scanner, {"Range": "far", "Distance": 5.0}, 0))
    bridge.inbox.put(("frame", None, frame, time.perf_counter() - 0.3))  # arrived 0.3 s before it is taken
    bridge.take_inbox()
    checker = bridge.devices[scanner.frame_id].checker
    assert checker.last_good == pytest.approx(1000.0 - 0.3, abs=0.05)
    (key,) = [k for k in published if k.endswith("physical/range_detector")]
    stamp = json.loads(published[key][-1])["t"]
    assert stamp == pytest.approx(2.0e9 - 0.3, abs=0.05)
