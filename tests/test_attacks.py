"""Attacks on the live twin replayed through real processes on loopback (issues "A secure online twin" and
"Who is the twin").

* Forged samples: the test plays a light curtain on its physical key (as the cell's devices would,
  through the bridge or an emulator), and between its samples what someone with a foothold on the cell
  network sent: a sample stamped a million seconds ahead, a 400 kB nested payload, and time stamps and
  sequence numbers of 400 digits. The twin must keep believing the real curtain, fail safe on what it
  cannot read, recover, and never stop.
* A rogue twin: with the twin killed, a process holding the observer's certificate serves on the twin's
  port and commands the welder to work. Nobody connects to it; the devices get their safe commands.
* A listener through ``--config``: refused before anything starts, as ``--listen`` would be.
* Forged command frames with the twin lost: refused by the device from the first one; nothing is released.
"""

from __future__ import annotations

import json
import threading
import time

import pytest
from conftest import ONE_AT_A_TIME

from cellsim.codec import encode_fields
from cellsim.blackbox import BlackBox

from live_processes import (ROOT, ChannelWatch, CommandFrames, can_server, free_port, observer, processes, rogue_router,
                            start_emulator, start_twin_and_bridge, wait_alive)

pytestmark = [pytest.mark.slow, ONE_AT_A_TIME]  # processes on loopback: skip locally with -m "not slow"

WELDING_CELL = str(ROOT / "scenarios" / "welding_cell.yaml")
CURTAIN = "cellsim/welding_cell/physical/light_barrier"


class Curtain:
    """The real curtain: its samples at 25 Hz on a thread, broken as ``broken`` says, counting its sequence."""

    def __init__(self, publisher):
        self.publisher, self.broken, self.seq = publisher, True, 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._lock = threading.Lock()
        self._thread.start()

    def next_seq(self) -> int:
        with self._lock:
            self.seq += 1
            return self.seq

    def _run(self) -> None:
        while not self._stop.is_set():
            self.publisher.put(encode_fields(time.time(), self.next_seq(), {"broken": self.broken}))
            self._stop.wait(0.04)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)


def test_forged_future_stamps_and_oversized_payloads_neither_fool_nor_stop_the_twin(tmp_path):
    port = free_port()
    with processes() as start:
        twin = start(["live", WELDING_CELL, "--out", str(tmp_path / "twin"), "--listen", f"tls/127.0.0.1:{port}",
                      "--quiet", "--set", "light_barrier.twin.mode=shadow", "--wait-physical", "0"], tmp_path / "twin.log")
        # the attacker holds the bridge's certificate: a foothold on a legitimate sender of samples
        with observer(port) as session, observer(port, role="bridge") as attacker:
            wait_alive(session, "cellsim/welding_cell/alive/twin")
            broken = ChannelWatch(session, "cellsim/welding_cell/twin/light_barrier/broken")
            link = ChannelWatch(session, "cellsim/welding_cell/twin/light_barrier/physical_link")
            publisher = attacker.declare_publisher(CURTAIN)
            curtain = Curtain(publisher)
            try:
                link.wait_for("ok", 30)
                broken.wait_for(True, 5)  # the real curtain: broken (someone is in the beams)

                # 1. a sample stamped a million seconds ahead saying "clear": refused, and it does not
                #    make the later real samples look old
                publisher.put(encode_fields(time.time() + 1e6, curtain.next_seq(), {"broken": False}))
                seen = len(broken.values)
                threading.Event().wait(1.0)  # a second of real samples after it (25 of them)
                assert broken.values[seen:] == [] and broken.values[-1] is True, broken.values
                assert link.values[-1] == "ok", link.values

                # 2. what cannot be read: the twin reads its link corrupt (fails safe), then trusts the real
                #    samples again; it does not stop
                for payload in (b"[" * 200_000 + b"]" * 200_000,
                                json.dumps({"t": 10 ** 400, "seq": curtain.next_seq(), "fields": {"broken": False}}).encode(),
                                json.dumps({"t": time.time(), "seq": 10 ** 400, "fields": {"broken": False}}).encode()):
                    publisher.put(payload)
                    link.wait_for("corrupt", 5)
                    link.wait_for("ok", 5)
                assert broken.values[-1] is True and False not in broken.values[seen:]
                assert twin.popen.poll() is None, twin.output()  # still running
            finally:
                curtain.stop()
                broken.close()
                link.close()
        twin.stop()
        assert twin.popen.returncode == 130, twin.output()
    with BlackBox(tmp_path / "twin" / "blackbox.sqlite") as bb:
        metadata = bb.metadata()
        assert metadata["status"] == "stopped"
        assert metadata["live"]["rejected_samples"]["light_barrier"] >= 4  # each forged or unreadable one counted
        # the real curtain said broken throughout, and so did the twin: never clear, whatever was forged
        assert bb.series("light_barrier.broken").values == [True]
    assert "refused a message" in (tmp_path / "twin.log").read_text()  # and said so, with its key


TWIN_SUPERVISES = ["--set", "robot.twin.mode=twin", "--set", "welder.twin.mode=twin",
                   *[arg for e in ("light_barrier", "range_detector", "operator") for arg in ("--set", f"{e}.twin.mode=shadow")]]
COMMAND_WATCHDOG = 0.5
"""bridges/welding_cell.yaml: the twin's commands older than this count as lost (s)."""


def _supervised_cell(start, tmp_path, cell_keys):
    """The twin supervising the emulated welding cell through the bridge daemon on a CAN server, until its
    welder has been asked for normal work for a second; returns (port, bus, twin, bridge, emulator, requests)."""
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    bus = can_server(start, tmp_path / "can.log")
    requests = CommandFrames(bus, ["SafetyModeRequestAuthenticated", "WelderCommandAuthenticated"], cell_keys)
    twin, bridge = start_twin_and_bridge(start, tmp_path, TWIN_SUPERVISES, bus, endpoint, port)
    emulator = start_emulator(start, tmp_path, ["--commanded-by-twin"], bus, endpoint)
    deadline, normal_in_a_row = time.monotonic() + 90, 0
    while normal_in_a_row < 25:  # a second of the twin supervising, the welder free to work
        _, name, values = requests.next(deadline)
        if name == "SafetyModeRequestAuthenticated":
            normal_in_a_row = normal_in_a_row + 1 if values["SafetyMode"] == "normal" else 0
    return port, bus, twin, bridge, emulator, requests


def test_a_rogue_twin_holding_the_observers_certificate_gets_no_session_and_the_devices_their_safe_commands(
        tmp_path, cell_keys):
    """Issue 32, attack 1: the twin killed, a process with only the observer's certificate binds its port,
    declares itself alive as the twin and commands the welder to normal work. The daemon, the emulator and
    twin-mode refuse its certificate (it names no host and may not serve TLS): it hears nothing, and the
    daemon sends the welder its safe command within the watchdog and keeps to it."""
    import os
    import signal
    import subprocess
    import sys

    heard: list[str] = []
    with processes() as start:
        port, bus, twin, bridge, emulator, requests = _supervised_cell(start, tmp_path, cell_keys)
        try:
            twin.stop(signal.SIGKILL)
            killed = time.monotonic()
            rogue = rogue_router(cell_keys, "observer", port)
            try:
                for sent_by_others in ("physical", "status", "diagnostics", "controller"):  # all but its own
                    rogue.declare_subscriber(f"cellsim/welding_cell/{sent_by_others}/**",
                                             lambda sample: heard.append(str(sample.key_expr)))
                token = rogue.liveliness().declare_token("cellsim/welding_cell/alive/twin")
                mode = rogue.declare_publisher("cellsim/welding_cell/twin/welder/twin_mode")
                order = rogue.declare_publisher("cellsim/welding_cell/command/welder")
                stop, seq = threading.Event(), [0]

                def command_the_welder():
                    while not stop.is_set():
                        seq[0] += 1
                        mode.put(json.dumps({"t": time.time(), "sim_time": 60.0, "value": "twin"}))
                        order.put(json.dumps({"t": time.time(), "seq": seq[0], "fields": {
                            "safety_mode_request": "normal", "activity_request": "welding", "command": 1.0}}))
                        stop.wait(0.04)

                rogue_thread = threading.Thread(target=command_the_welder, daemon=True)
                rogue_thread.start()
                switch = None
                try:
                    # twin-mode (the engineer's certificate) tries the rogue for the twin while the daemon is watched
                    switch = subprocess.Popen([sys.executable, "-m", "cellsim", "twin-mode", "light_barrier", "model",
                                               "--connect", f"tls/127.0.0.1:{port}", "--timeout", "2"],
                                              stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                              text=True, cwd=ROOT)
                    # every request the daemon sends after the watchdog is the safe one, for 6 s of the rogue
                    safe_from = killed + COMMAND_WATCHDOG + 0.04 + 0.1
                    seen = []
                    while time.monotonic() < killed + 6.0:
                        seen.append(requests.next(killed + 10))
                    late = [(name, values) for at, name, values in seen if at > safe_from]
                    assert {name for name, _ in late} == {"SafetyModeRequestAuthenticated", "WelderCommandAuthenticated"}
                    assert all(values in ({"SafetyMode": "stopped"}, {"ActivityRequest": "off", "Weld": 0})
                               for _, values in late), seen
                    # and twin-mode did not take the rogue for the twin either
                    _, err = switch.communicate(timeout=60)
                    assert switch.returncode == 2 and "no running twin reachable" in err, err
                finally:
                    if switch is not None and switch.poll() is None:
                        os.kill(switch.pid, signal.SIGKILL)  # stopped by its PID, whatever happened above
                        switch.communicate()
                    stop.set()
                    rogue_thread.join(5)
                    token.undeclare()
            finally:
                rogue.close()
            assert seq[0] > 100 and bridge.popen.poll() is None and emulator.popen.poll() is None
        finally:
            requests.close()
        emulator.stop()
        bridge.stop()
    assert heard == []  # no physical sample, no status, nothing: nobody's session reached the rogue
    with BlackBox(tmp_path / "emulator" / "blackbox.sqlite") as emu:
        assert emu.series("welder.safety_mode").values[-1] == "stopped"


def test_a_listener_the_command_line_refuses_is_refused_from_a_config_file_too(tmp_path):
    """Issue 32, attack 2: ``--insecure --listen tcp/0.0.0.0:P`` is refused; the same listener in a ``--config``
    file (given to the twin, or named by a bridge configuration) is refused as well, in one line, exit 2, with
    no run folder and nothing listening."""
    import socket
    import subprocess
    import sys

    port = free_port()
    config = tmp_path / "zenoh.json5"
    config.write_text(f'{{ listen: {{ endpoints: ["tcp/0.0.0.0:{port}"] }} }}')
    bridge_config = tmp_path / "bridge.yaml"
    bridge_config.write_text(f"base: {ROOT / 'bridges' / 'welding_cell.yaml'}\nscenario: {WELDING_CELL}\n"
                             f"dbc: {ROOT / 'bridges' / 'welding_cell.dbc'}\nzenoh: {{config: {config}}}\n")
    for args in (["live", WELDING_CELL, "--insecure", "--config", str(config), "--out", str(tmp_path / "run")],
                 ["live", WELDING_CELL, "--config", str(config), "--out", str(tmp_path / "run")],
                 ["bridge", str(bridge_config), "--insecure", "--can", "virtual:config-attack"]):
        done = subprocess.run([sys.executable, "-m", "cellsim", *args], capture_output=True, text=True, timeout=120,
                              cwd=ROOT)
        assert done.returncode == 2, done.stderr
        assert done.stderr.count("\n") == 1 and f"{config}: listen/endpoints 'tcp/0.0.0.0:{port}'" in done.stderr, done.stderr
        assert not (tmp_path / "run").exists()
        with pytest.raises(OSError):
            socket.create_connection(("127.0.0.1", port), timeout=1.0).close()


def test_forged_command_frames_after_the_twin_is_lost_release_no_device(tmp_path, cell_keys):
    """Issue 32, attack 3: the twin killed, a node on the bus answers the daemon's safe frames with the next
    three counters and right CRCs, asking the welder for normal work and a weld (a guessed MAC), in rounds
    spaced so that end-to-end checks alone would take each round. The emulated
    welder refuses each from the first: it stops within the watchdog and stays stopped and off while they come."""
    import random
    import signal

    import can
    from cantools.autosar.end_to_end import compute_profile2_crc

    from cellsim.bridges.config import load_bridge
    from cellsim.bridges.e2e import data_id

    database = load_bridge(ROOT / "bridges" / "welding_cell.yaml").database
    asks = {"SafetyModeRequestAuthenticated": {"SafetyMode": "normal"},
            "WelderCommandAuthenticated": {"ActivityRequest": "welding", "Weld": 1}}
    messages = {database.get_message_by_name(name).frame_id: database.get_message_by_name(name) for name in asks}
    forged, rng = 0, random.Random(32)
    with processes() as start:
        port, bus, twin, bridge, emulator, requests = _supervised_cell(start, tmp_path, cell_keys)
        requests.close()
        forger = can.Bus(interface="remote", channel=bus)
        try:
            twin.stop(signal.SIGKILL)
            killed_wall, killed = time.time(), time.monotonic()
            next_round = {}  # frame id -> when its next round may go
            while time.monotonic() < killed + 5.0:
                frame = forger.recv(timeout=1.0)
                message = messages.get(frame.arbitration_id) if frame is not None else None
                if message is None or time.monotonic() < next_round.get(message.frame_id, 0.0):
                    continue
                # a round every 0.6 s: each is one counter anomaly for the device, two in any second, too few
                # for its masquerade rule to latch, so without authentication every round would be taken
                next_round[message.frame_id] = time.monotonic() + 0.6
                for k in range(1, 4):  # the daemon's next counters, sent before it does
                    counter = (frame.data[1] + k) & 0x0F
                    data = bytearray(message.encode({**asks[message.name], "Crc": 0, "Counter": counter,
                                                     "Freshness": (frame.data[4] + k) & 0xFF, "Mac": rng.getrandbits(24)}))
                    data[0] = compute_profile2_crc(bytes(data), data_id(message.frame_id, counter))
                    forger.send(can.Message(arbitration_id=message.frame_id, data=bytes(data), is_extended_id=False))
                    forged += 1
        finally:
            forger.shutdown()
        assert bridge.popen.poll() is None and emulator.popen.poll() is None
        emulator.stop()
        bridge.stop()
    assert forged >= 3 * 2 * 7  # three frames a round, both messages, a round every 0.6 s for 5 s
    with BlackBox(tmp_path / "emulator" / "blackbox.sqlite") as emu:
        killed_at = killed_wall - emu.metadata()["live"]["wall_at_zero"]  # the kill on the emulator's clock
        safe_from = killed_at + COMMAND_WATCHDOG + 0.04 + 0.1 + 0.04  # the watchdog, a frame, the welder's update
        mode, activity = emu.series("welder.safety_mode"), emu.series("welder.activity")
        assert mode.value_at(safe_from) == "stopped" and activity.value_at(safe_from) == "off"
        assert all(v == "stopped" for t, v in zip(mode.times, mode.values) if t > safe_from), mode.values
        assert all(v == "off" for t, v in zip(activity.times, activity.values) if t > safe_from), activity.values
        assert emu.metadata()["recorded_until"] > killed_at + 4.0  # recorded through the attack
