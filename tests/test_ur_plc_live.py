"""The emulated UR controller read and commanded by ur-rtde, and the twin beside it and the emulated PLC
through the daemon.

ur-rtde's clients dial port 30004 and nothing else (the port is fixed in the
library), so these tests serve RTDE on 127.0.0.1:30004 and run one at a time.
Every process is started and stopped by the test, by its PID.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import threading
import time

import pytest
from conftest import ONE_AT_A_TIME

from cellsim.blackbox import BlackBox

from live_processes import (ROOT, assert_supervised, can_server, free_port, observer, processes, sim_time_reached,
                            wait_alive, wait_listening)

pytestmark = [pytest.mark.slow, ONE_AT_A_TIME]
WELDING_CELL = str(ROOT / "scenarios" / "welding_cell.yaml")
UR_BRIDGE = str(ROOT / "bridges" / "welding_cell_ur_plc.yaml")
RTDE_PORT = 30004
TWIN_SUPERVISES = ["--set", "robot.twin.mode=twin", "--set", "welder.twin.mode=twin",
                   *[arg for e in ("light_barrier", "range_detector", "operator") for arg in ("--set", f"{e}.twin.mode=shadow")]]


def until(predicate, timeout: float, what: str):
    """Poll ``predicate`` (a getter of ur-rtde's) every 10 ms until it is truthy, with a deadline."""
    deadline = time.monotonic() + timeout
    tick = threading.Event()
    while True:
        value = predicate()
        if value:
            return value
        assert time.monotonic() < deadline, f"{what} within {timeout} s"
        tick.wait(0.01)


def start_twin(start, tmp_path, port: int, args=()):
    endpoint = f"tls/127.0.0.1:{port}"
    twin = start(["live", WELDING_CELL, "--out", str(tmp_path / "twin"), "--listen", endpoint, "--quiet", *args],
                 tmp_path / "twin.log")
    with observer(port) as session:
        wait_alive(session, "cellsim/welding_cell/alive/twin")
    return twin, endpoint


def test_ur_rtde_reads_the_emulated_controller_and_its_speed_slider_slows_the_emulated_arm(tmp_path):
    import rtde_io
    import rtde_receive

    with processes() as start:
        twin, endpoint = start_twin(start, tmp_path, free_port())
        emulator = start(["emulate", WELDING_CELL, "--bridge", UR_BRIDGE, "--rtde", str(RTDE_PORT), "--duration", "10",
                          "--out", str(tmp_path / "emulator"), "--connect", endpoint, "--quiet"], tmp_path / "emulator.log")
        wait_listening(emulator, RTDE_PORT, 60, "the emulated UR controller")
        receive = rtde_receive.RTDEReceiveInterface("127.0.0.1")
        until(lambda: receive.getTimestamp() > 2.0, 20, "the controller streams")
        read = [(receive.getTimestamp(), list(receive.getActualQ()), receive.getSafetyMode(), receive.getRobotMode())
                for _ in range(5)]
        io = rtde_io.RTDEIOInterface("127.0.0.1")
        assert io.setSpeedSlider(0.2)
        until(lambda: receive.getSpeedScaling() == pytest.approx(0.2), 5, "the slider reaches the controller")
        slowed_at = receive.getTimestamp()
        until(lambda: receive.getTimestamp() > slowed_at + 2.0, 10, "two more seconds")
        io.disconnect()
        receive.disconnect()
        assert emulator.wait(timeout=60) == 0, emulator.output()
        twin.stop()
    with BlackBox(tmp_path / "emulator" / "blackbox.sqlite") as emu:
        joints, speed = emu.series("robot.joint_positions"), emu.series("robot.tool_speed")
        for t, q, safety_mode, robot_mode in read:
            # the joints ur-rtde read are the emulated arm's at the controller's timestamp (its simulated time)
            assert max(abs(a - b) for a, b in zip(q, joints.value_at(t))) < 0.03
            assert safety_mode == 1 and robot_mode == 7  # NORMAL, RUNNING: the welding cell's arm before anyone comes
        before = [v for t, v in zip(speed.times, speed.values) if t < slowed_at]
        after = [v for t, v in zip(speed.times, speed.values) if slowed_at + 0.6 < t]  # braked within braking_time
        assert max(before) > 0.5  # at full speed, normal's cap 1 m/s
        assert after and max(after) <= 0.2 * 1.0 + 0.02  # the slider's fifth of it


def bridge_on_a_shared_host(tmp_path) -> str:
    """The shipped UR and PLC bridge configuration with the robot's watchdog at 0.25 s instead of 0.05 s.

    The emulated controller is a Python process pacing a simulation in real time beside the twin, the
    daemon, the CAN server and another test's worker on two cores: a stall of 50 ms there (a real
    controller's 25 missed cycles) is the host's, and failing the link for it is the rule working, not a
    fault of the path under test. A watchdog five times the shipped one keeps this test about the path."""
    path = tmp_path / "bridge.yaml"
    path.write_text(f"base: {UR_BRIDGE}\nrobots:\n  robot:\n    watchdog: 0.25\n")
    return str(path)


def plc_command(port: int, node: str) -> int:
    """A command node of the emulated PLC, read as the bridge (its OPC UA certificate, signed and encrypted)."""
    import asyncio
    import os
    from pathlib import Path

    from asyncua import Client
    from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
    from asyncua.crypto.uacrypto import CertProperties

    keys = Path(os.environ["CELLSIM_KEYS"])

    async def read() -> int:
        client = Client(f"opc.tcp://127.0.0.1:{port}", timeout=5)
        client.application_uri = "urn:cellsim:bridge"
        await client.set_security(SecurityPolicyBasic256Sha256, CertProperties(str(keys / "opcua-bridge.pem"), "pem"),
                                  CertProperties(str(keys / "opcua-bridge.key"), "pem"),
                                  server_certificate=CertProperties(str(keys / "opcua-plc.pem"), "pem"))
        async with client:
            return await client.get_node(node).read_value()

    return asyncio.run(read())


def test_the_twin_commands_the_emulated_ur_controller_and_plc_through_the_daemon_and_losing_it_makes_them_safe(tmp_path):
    """The bridge issue's supervision test beside a UR cell with a PLC: the shipped
    bridges/welding_cell_ur_plc.yaml, the robot's controller over RTDE, the light curtain and the welder on
    the PLC over OPC UA (signed and encrypted), the scanner on a python-can-remote bus."""
    import rtde_receive

    port, opcua = free_port(), free_port()
    reached, on_status = sim_time_reached(30.0)
    with processes() as start:
        bus = can_server(start, tmp_path / "can.log")
        twin, endpoint = start_twin(start, tmp_path, port, TWIN_SUPERVISES)
        bridge = start(["bridge", bridge_on_a_shared_host(tmp_path), "--can", f"remote:{bus}", "--opcua", f"opc.tcp://127.0.0.1:{opcua}",
                        "--connect", endpoint], tmp_path / "bridge.log")
        with observer(port) as session:
            wait_alive(session, "cellsim/welding_cell/alive/bridge")
            status = session.declare_subscriber("cellsim/welding_cell/status/twin", on_status)
            emulator = start(["emulate", WELDING_CELL, "--bridge", UR_BRIDGE, "--can", f"remote:{bus}", "--duration", "40",
                              "--opcua", str(opcua),
                              "--commanded-by-twin", "--out", str(tmp_path / "emulator"), "--connect", endpoint, "--quiet"],
                             tmp_path / "emulator.log")
            wait_listening(emulator, RTDE_PORT, 60, "the emulated UR controller")
            receive = rtde_receive.RTDEReceiveInterface("127.0.0.1")
            assert reached.wait(90), twin.output()
            status.undeclare()
        # the twin supervising: the slider at the requested mode's cap, the welder's request not a stop
        assert receive.getTargetSpeedFraction() > 0.0
        assert plc_command(opcua, "ns=2;s=Welder.SafetyModeRequest") != 5
        twin.stop()  # the twin lost (its liveliness token goes with it)
        lost = time.monotonic()
        until(lambda: receive.getTargetSpeedFraction() == 0.0, 5, "the slider at 0")
        assert time.monotonic() - lost <= 0.5 + 0.02 + 0.1  # the command watchdog and a command cycle
        until(lambda: plc_command(opcua, "ns=2;s=Welder.SafetyModeRequest") == 5, 5, "the welder's stop in the PLC")
        assert time.monotonic() - lost <= 0.5 + 0.04 + 0.3  # the watchdog, a command cycle, a read of the node
        assert plc_command(opcua, "ns=2;s=Welder.ActivityRequest") == 2  # off: the welder kind's safe command
        # the emulated program took the stop: the arm reports it in its safety-mode register (stopped's code 5)
        until(lambda: receive.getOutputIntRegister(18) == 5, 5, "the arm stopped")
        receive.disconnect()
        assert emulator.wait(timeout=60) == 0, emulator.output()
        bridge.stop()
        assert "robot: RTDE controller at 127.0.0.1:30004 streaming" in bridge.output()
        assert f"PLC at opc.tcp://127.0.0.1:{opcua}: subscribed to 4 nodes every 0.02 s (signed and encrypted)" in bridge.output()
    with BlackBox(tmp_path / "twin" / "blackbox.sqlite") as twin_box, \
            BlackBox(tmp_path / "emulator" / "blackbox.sqlite") as emu:
        # the twin's ssmon request reaches the emulated arm through the daemon and the RTDE registers
        assert_supervised(twin_box, emu, within=0.35)
        for entity in ("robot", "welder", "light_barrier", "range_detector"):  # RTDE, OPC UA, CAN: every link held
            link = twin_box.series(f"{entity}.physical_link")
            ok_from = next(t for t, v in zip(link.times, link.values) if v == "ok")
            held = all(v == "ok" for t, v in zip(link.times, link.values) if ok_from <= t < 29.0)
            assert ok_from < 12.0 and held, (entity, [(round(float(t), 3), v) for t, v in zip(link.times, link.values)][:20])
    proc = subprocess.run([sys.executable, "-m", "cellsim", "check", str(tmp_path / "twin"), "--json"],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    verdicts = json.loads(proc.stdout)
    assert proc.returncode == 0 and verdicts["holds"] and verdicts["complete"], verdicts["violations"]
