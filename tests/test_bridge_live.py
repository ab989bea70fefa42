"""The twin, the bridge daemon and the emulated cell speaking CAN and Zenoh: processes on loopback.

A python-can-remote server carries the CAN bus between processes; every process
is started and stopped by the test, by its PID.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time

import can
import pytest
from conftest import ONE_AT_A_TIME

from cellsim.blackbox import BlackBox

from live_processes import (ROOT, assert_supervised, can_server, free_port, observer, offset_of, processes,
                            sim_time_reached, start_emulator, start_twin_and_bridge, wait_alive, wait_for, CommandFrames)


pytestmark = [pytest.mark.slow, ONE_AT_A_TIME]  # processes on loopback: skip locally with -m "not slow"
WELDING_CELL = str(ROOT / "scenarios" / "welding_cell.yaml")
BRIDGE = str(ROOT / "bridges" / "welding_cell.yaml")
ENTITIES = ("robot", "welder", "light_barrier", "range_detector", "operator")
ALL_SHADOW = [arg for e in ENTITIES for arg in ("--set", f"{e}.twin.mode=shadow")]
TWIN_SUPERVISES = ["--set", "robot.twin.mode=twin", "--set", "welder.twin.mode=twin",
                   *[arg for e in ("light_barrier", "range_detector", "operator") for arg in ("--set", f"{e}.twin.mode=shadow")]]
TWIN_PERIOD = {"light_barrier": 0.04, "range_detector": 0.04, "welder": 0.04, "robot": 0.02}
DEVICE = {  # entity: (cycle time, watchdog) as bridges/welding_cell.yaml sets them
    "light_barrier": (0.02, 0.1), "range_detector": (0.04, 0.2), "welder": (0.04, 0.2), "robot": (0.002, 0.05),
}
# every bus fault, and two of the robot controller's link, each in a window of emulator time
FAULTS = [
    ("light_barrier", "drop", 1.5, 2.5), ("light_barrier", "length", 3.5, 4.5),
    ("range_detector", "crc", 1.5, 2.5), ("range_detector", "flood", 3.5, 4.5),
    ("welder", "replay", 1.5, 2.5), ("welder", "delay", 3.5, 4.5),
    ("robot", "freeze", 1.5, 2.5), ("robot", "delay", 3.5, 4.5),
]
# what the twin shows of each entity: (channel, its value in the emulated cell then, its fail-safe value)
SHOWN = {
    "light_barrier": ("light_barrier.broken", False, True),
    "range_detector": ("range_detector.range", "far", "close"),
    "welder": ("welder.safety_mode", "normal", "unknown"),
    "robot": ("robot.physical_link", "ok", {"freeze": "stale", "delay": "stale"}),  # a frozen stream goes stale
}
# a repeated counter or seq (a replayed frame, a frozen state) is refused and counted: its stream then goes stale
COUNTED = {"drop": "timeout", "length": "length", "crc": "crc", "flood": "timeout", "replay": "repeated",
           "delay": "timeout", "freeze": "repeated"}
ROBOT_DELAY_COUNTED = "late"


_offset = offset_of


class Diagnostics:
    """The latest diagnostics of each device, as the daemon publishes them."""

    def __init__(self, session):
        self.latest: dict[str, dict] = {}
        self.heard: dict[str, int] = {}
        self.subscriber = session.declare_subscriber("cellsim/welding_cell/diagnostics/*", self._on_status)

    def _on_status(self, sample) -> None:
        device = str(sample.key_expr).rsplit("/", 1)[1]
        self.latest[device] = json.loads(sample.payload.to_bytes())
        self.heard[device] = self.heard.get(device, 0) + 1


_start_twin_and_bridge, _start_emulator = start_twin_and_bridge, start_emulator


def test_each_bus_fault_drives_its_entity_to_fail_safe_within_its_watchdog_and_back(tmp_path):
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    faults = [arg for entity, kind, t0, t1 in FAULTS for arg in ("--fault", f"{entity}={kind}@{t0}-{t1}")]
    with processes() as start:
        bus = can_server(start, tmp_path / "can.log")
        twin, bridge = _start_twin_and_bridge(start, tmp_path, ALL_SHADOW, bus, endpoint, port)
        with observer(port) as session:
            diagnostics = Diagnostics(session)
            emulator = _start_emulator(start, tmp_path, ["--duration", "6.5", *faults], bus, endpoint)
            assert emulator.wait(timeout=120) == 0, emulator.output()
            twin.stop()  # SIGINT: the twin closes its black box cleanly
            assert bridge.popen.poll() is None, bridge.output()  # nothing on the bus stopped the daemon
            latest = dict(diagnostics.latest)
            diagnostics.subscriber.undeclare()
        bridge.stop()
        assert bridge.popen.returncode == 130, bridge.output()
    with BlackBox(tmp_path / "twin" / "blackbox.sqlite") as twin, BlackBox(tmp_path / "emulator" / "blackbox.sqlite") as emu:
        offset = _offset(twin, emu)
        for entity, kind, t0, t1 in FAULTS:
            channel, normal, safe = SHOWN[entity]
            safe = safe[kind] if isinstance(safe, dict) else safe
            cycle, watchdog = DEVICE[entity]
            series = twin.series(channel)
            assert series.value_at(t0 + offset - 0.1) == normal, (entity, kind)
            # failed safe within the device's watchdog plus one twin update period (and the way of a frame)
            failed = t0 + offset + watchdog + cycle + TWIN_PERIOD[entity] + 0.1
            during = {v for t, v in zip(series.times, series.values) if t0 + offset < t <= failed}
            assert safe in during and series.value_at(failed) == safe, (entity, kind, series.value_at(failed))
            # trusted again once recover_after good frames came in a row
            recovered = t1 + offset + 5 * cycle + TWIN_PERIOD[entity] + 0.15
            assert series.value_at(recovered) == normal, (entity, kind, series.value_at(recovered))
    # the daemon counted each fault, by kind, in its diagnostics
    for entity, kind, *_ in FAULTS:
        counted = ROBOT_DELAY_COUNTED if (entity, kind) == ("robot", "delay") else COUNTED[kind]
        assert latest[entity]["counts"][counted] >= 1, (entity, kind, latest[entity])
        assert latest[entity]["level"] in ("OK", "STALE")  # recovered, or stale once the emulator ended
    assert latest["bridge"]["unknown_frames"] >= 20 * 10  # the flood: counted, dropped, survived


def test_with_authenticated_frames_a_forger_on_the_bus_fails_the_curtain_safe_from_his_first_frame(tmp_path):
    """Issue 22's forged 'curtain clear' frames (CRC and next counter computed from the DBC), against the
    authenticated curtain: the emulated device's frames, signed with the cell's CAN key, are taken end to
    end; while the forger sends three frames after each real one the twin's curtain link is failed and the
    curtain reads broken (its fail-safe), from the first forgery to the last; then it recovers."""
    import random

    from cantools.autosar.end_to_end import compute_profile2_crc

    from cellsim.bridges.config import load_bridge
    from cellsim.bridges.e2e import data_id
    from live_processes import ChannelWatch

    curtain = load_bridge(BRIDGE).database.get_message_by_name("LightCurtainStateAuthenticated")
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    with processes() as start:
        bus = can_server(start, tmp_path / "can.log")
        twin, bridge = _start_twin_and_bridge(start, tmp_path, ALL_SHADOW, bus, endpoint, port, BRIDGE)
        with observer(port) as session:
            diagnostics = Diagnostics(session)
            link = ChannelWatch(session, "cellsim/welding_cell/twin/light_barrier/physical_link")
            broken = ChannelWatch(session, "cellsim/welding_cell/twin/light_barrier/broken")
            emulator = _start_emulator(start, tmp_path, ["--duration", "120", "--bridge", BRIDGE], bus, endpoint)
            link.wait_for("ok", 90)  # the real curtain's authenticated frames are taken
            forger = can.Bus(interface="remote", channel=bus)
            sent, rng = 0, random.Random(22)
            try:
                deadline = time.monotonic() + 3.0
                while time.monotonic() < deadline:
                    frame = forger.recv(timeout=1.0)
                    if frame is None or frame.arbitration_id != curtain.frame_id:
                        continue
                    for k in range(1, 4):  # the counters that come next, Broken 0, a guessed MAC
                        counter = (frame.data[1] + k) & 0x0F
                        data = bytearray(curtain.encode({"Crc": 0, "Counter": counter, "Broken": 0, "Freshness": frame.data[4],
                                                         "Mac": rng.getrandbits(24)}))
                        data[0] = compute_profile2_crc(bytes(data), data_id(curtain.frame_id, counter))
                        forger.send(can.Message(arbitration_id=curtain.frame_id, data=bytes(data), is_extended_id=False))
                        sent += 1
                    if sent == 3:
                        link.wait_for("corrupt", 5)  # failed at the first forgeries
                        failed_from, broken_from = len(link.values) - 1, len(broken.values)
                attack = link.values[failed_from:]
                assert attack and "ok" not in attack, link.values  # never trusted while the forger sends
                assert False not in broken.values[broken_from:] and broken.values[-1] is True, broken.values
            finally:
                forger.shutdown()
            link.wait_for("ok", 10)  # the forger gone: the real curtain trusted again
            wait_for(lambda: diagnostics.latest.get("light_barrier", {}).get("counts", {}).get("auth", 0) >= sent * 0.9,
                     5, "the forgeries counted in the daemon's diagnostics")
            link.close()
            broken.close()
            diagnostics.subscriber.undeclare()
        emulator.stop()
        twin.stop()
        bridge.stop()
    assert sent >= 3 * 100  # 3 s of the curtain's 50 Hz, three forgeries each


def test_the_twin_supervises_the_emulated_cell_through_the_bus(tmp_path):
    """The live issue's supervision test, with the welder's commands and states as CAN frames and the
    robot's through its controller's stream: the same outcomes."""
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    reached, on_status = sim_time_reached(30.0)

    with processes() as start:
        bus = can_server(start, tmp_path / "can.log")
        twin, bridge = _start_twin_and_bridge(start, tmp_path, TWIN_SUPERVISES, bus, endpoint, port)
        with observer(port) as session:
            status = session.declare_subscriber("cellsim/welding_cell/status/twin", on_status)
            emulator = _start_emulator(start, tmp_path, ["--duration", "36", "--commanded-by-twin"], bus, endpoint)
            assert reached.wait(90), twin.output()
            status.undeclare()
        twin.stop()  # after the scenario's 30 s, while the emulated cell still runs
        assert emulator.wait(timeout=60) == 0, emulator.output()
        bridge.stop()
    with BlackBox(tmp_path / "twin" / "blackbox.sqlite") as twin, BlackBox(tmp_path / "emulator" / "blackbox.sqlite") as emu:
        # the twin's ssmon request reaches the emulated robot through the daemon and its controller link
        offset = assert_supervised(twin, emu, within=0.35)
        # the welder's requests came as CAN frames: the emulated welder stops when the twin's controller says so
        demand = twin.series("safety_controller.safmod")
        stop = next(t for t, v in zip(demand.times, demand.values) if v == "stopped" and t > offset + 5.0)
        resume = next(t for t, v in zip(demand.times, demand.values) if v != "stopped" and t > stop)
        welder = emu.series("welder.safety_mode")
        stopped = next(t for t, v in zip(welder.times, welder.values) if v == "stopped" and t > stop - offset - 0.5)
        assert 0 < stopped - (stop - offset) < 0.25  # twin's update, the daemon at once, the welder's update
        assert welder.value_at(resume - offset + 0.25) == "normal" and emu.series("welder.activity").value_at(stopped + 0.1) == "off"
    proc = subprocess.run([sys.executable, "-m", "cellsim", "check", str(tmp_path / "twin"), "--json"],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    verdicts = json.loads(proc.stdout)
    assert proc.returncode == 0 and verdicts["holds"] and verdicts["complete"], verdicts["violations"]
    assert len(verdicts["verdicts"]) == 16  # the 14 of the cell and NoHarm, NoClamping


def test_a_killed_twin_gets_every_commanded_device_its_safe_command_within_the_watchdog(tmp_path, cell_keys):
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    with processes() as start:
        bus = can_server(start, tmp_path / "can.log")
        requests = CommandFrames(bus, ["SafetyModeRequestAuthenticated"], cell_keys)
        try:
            twin, bridge = _start_twin_and_bridge(start, tmp_path, TWIN_SUPERVISES, bus, endpoint, port)
            emulator = _start_emulator(start, tmp_path, ["--commanded-by-twin"], bus, endpoint)

            def next_request(deadline: float) -> tuple[float, str]:
                at, _, values = requests.next(deadline)
                return at, values["SafetyMode"]

            deadline = time.monotonic() + 90
            normal_in_a_row = 0
            while normal_in_a_row < 25:  # a second of the twin supervising, the welder free to work
                normal_in_a_row = normal_in_a_row + 1 if next_request(deadline)[1] == "normal" else 0
            twin.stop(signal.SIGKILL)
            killed = time.monotonic()
            seen = []
            while not seen or seen[-1][1] != "stopped":
                seen.append(next_request(killed + 5))
            # the commands' watchdog (0.5 s) and a frame's cycle, whichever sees it first
            assert seen[-1][0] - killed <= 0.5 + 0.04 + 0.1, seen
            for _ in range(10):  # and it stays safe
                assert next_request(killed + 10)[1] == "stopped"
            assert bridge.popen.poll() is None  # the daemon outlives the twin
        finally:
            requests.close()
        emulator.stop()
        bridge.stop()
    with BlackBox(tmp_path / "emulator" / "blackbox.sqlite") as emu:
        assert emu.series("welder.safety_mode").values[-1] == "stopped"  # the device did as the safe command said


def test_under_the_twins_access_control_the_daemon_feeds_the_twin_and_observers_see_its_diagnostics(tmp_path):
    """The daemon with the bridge's certificate: a robot controller's states (the robot adapter's
    certificate) reach the twin as the robot's samples through it; an observer sees its diagnostics
    but cannot feed the controller stream."""
    import zenoh

    from cellsim.live.session import session_config

    from live_processes import ChannelWatch

    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"

    def session(role: str):
        return zenoh.open(session_config(role=role, connect=[endpoint]))

    def stream(publisher, seq0: int, until, timeout: float) -> int:
        """Robot controller states at about 500 Hz until ``until()`` holds."""
        deadline, pause, seq = time.monotonic() + timeout, threading.Event(), seq0
        while not until():
            assert time.monotonic() < deadline, "not within the deadline"
            seq += 1
            publisher.put(json.dumps({"t": time.time(), "seq": seq, "position": [0.1, -1.2, 1.0, 0.0, 1.5, 0.0],
                                      "velocity": [0.0] * 6, "safety_mode": "normal", "activity": "exchWrkp",
                                      "reached_pose": "moving"}))
            pause.wait(0.002)
        return seq

    with processes() as start:
        twin = start(["live", WELDING_CELL, "--out", str(tmp_path / "twin"), "--listen", endpoint, "--quiet",
                      "--set", "robot.twin.mode=shadow", "--wait-physical", "0"],
                     tmp_path / "twin.log")
        observer_session = session("observer")
        try:
            wait_alive(observer_session, "cellsim/welding_cell/alive/twin")
            bridge = start(["bridge", BRIDGE, "--can", "virtual:acl", "--connect", endpoint], tmp_path / "bridge.log")
            wait_alive(observer_session, "cellsim/welding_cell/alive/bridge")
            diagnostics = Diagnostics(observer_session)
            link = ChannelWatch(observer_session, "cellsim/welding_cell/twin/robot/physical_link")
            # the observer's controller states do not count
            forged = observer_session.declare_publisher("cellsim/welding_cell/controller/robot/state")
            stream(forged, 0, lambda: diagnostics.heard.get("robot", 0) >= 3, 30)  # two diagnostics periods of it
            assert diagnostics.latest["robot"]["received"] == 0 and diagnostics.latest["robot"]["level"] == "STALE"
            controller_session = session("robot")
            try:
                controller = controller_session.declare_publisher("cellsim/welding_cell/controller/robot/state")
                stream(controller, 0, lambda: link.values[-1:] == ["ok"], 60)
            finally:
                controller_session.close()
            link.close()
            # the daemon's diagnostics say so (their next status may still be on its way)
            wait_for(lambda: diagnostics.latest["robot"]["received"] > 0, 5, "the robot's states in the diagnostics")
            diagnostics.subscriber.undeclare()
        finally:
            observer_session.close()
        twin.stop()
        bridge.stop()
