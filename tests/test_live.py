"""The live twin on Zenoh against the emulated physical cell: processes on loopback, stopped by PID."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest
from conftest import ONE_AT_A_TIME

from cellsim.blackbox import BlackBox

from live_processes import (ROOT, ChannelWatch, assert_supervised, free_port, observer, offset_of, processes,
                            sim_time_reached, wait_alive)


pytestmark = [pytest.mark.slow, ONE_AT_A_TIME]  # processes on loopback: skip locally with -m "not slow"
WELDING_CELL = str(ROOT / "scenarios" / "welding_cell.yaml")
ENTITIES = ("robot", "welder", "light_barrier", "range_detector", "operator")
ALL_SHADOW = [arg for e in ENTITIES for arg in ("--set", f"{e}.twin.mode=shadow")]
FOLLOWED = {  # channel: its publisher's update period (s)
    "light_barrier.broken": 0.04,
    "range_detector.range": 0.04,
    "robot.safety_mode": 0.02,
    "robot.reached_pose": 0.02,
    "welder.activity": 0.04,
}


_offset = offset_of


@pytest.fixture(scope="module")
def shadow_run(tmp_path_factory):
    """The twin with every entity in shadow mode beside the standalone emulator, 12 s."""
    tmp = tmp_path_factory.mktemp("shadow")
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    with processes() as start:
        twin = start(["live", WELDING_CELL, "--out", str(tmp / "twin"), "--listen", endpoint, "--quiet", *ALL_SHADOW],
                     tmp / "twin.log")
        with observer(port) as session:  # opening waits for the twin to listen
            wait_alive(session, "cellsim/welding_cell/alive/twin")
        emulator = start(["emulate", WELDING_CELL, "--out", str(tmp / "emulator"), "--duration", "12",
                          "--connect", endpoint, "--quiet"], tmp / "emulator.log")
        assert emulator.wait(timeout=120) == 0, emulator.output()
        twin.stop()  # SIGINT: the twin closes its black box cleanly
        assert twin.popen.returncode == 130, twin.output()
    return tmp


def test_a_shadow_twin_follows_the_emulated_cell(shadow_run):
    with BlackBox(shadow_run / "twin" / "blackbox.sqlite") as twin, BlackBox(shadow_run / "emulator" / "blackbox.sqlite") as emu:
        offset = _offset(twin, emu)
        assert twin.metadata()["status"] == "stopped"  # a live run ends on request: its record is complete
        for channel, period in FOLLOWED.items():
            followed = twin.series(channel)
            changes = [(t, v) for t, v in zip(emu.series(channel).times, emu.series(channel).values) if t > 0]
            assert changes or channel != "light_barrier.broken"
            for t, value in changes:
                if t + offset + 0.5 > emu.metadata()["duration"] + offset:  # too near the emulator's end
                    continue
                # the twin shows each transition within two update periods plus 50 ms
                window = [v for tt, v in zip(followed.times, followed.values) if t + offset - 1e-6 <= tt <= t + offset + 2 * period + 0.05]
                assert value in window or followed.value_at(t + offset + 2 * period + 0.05) == value, (channel, t, value)


def test_the_shadowed_robots_joints_follow_within_a_bound(shadow_run):
    """The twin's arm moves as the physical one did, a steady delay later (the sample's way and the joint
    controller's tracking of it), and never differs from it by what the robot kind calls a difference, even
    where a sample came late on a loaded host."""
    from cellsim.kinds.robot.kind import RobotKind

    with BlackBox(shadow_run / "twin" / "blackbox.sqlite") as twin, BlackBox(shadow_run / "emulator" / "blackbox.sqlite") as emu:
        offset = _offset(twin, emu)
        q_emu, q_twin = emu.series("robot.joint_positions"), twin.series("robot.joint_positions")
        physical = [(t, np.array(q)) for t, q in zip(q_emu.times, q_emu.values) if 1.0 < t < 11.0]
        assert np.ptp([q for _, q in physical], axis=0).max() > 0.5  # the physical arm moved: there is something to follow

        def errors(delay: float) -> np.ndarray:
            return np.array([np.max(np.abs(np.array(q_twin.value_at(t + offset + delay)) - q)) for t, q in physical])

        delays = np.round(np.arange(0.0, 0.405, 0.01), 2)
        typical = [float(np.median(errors(d))) for d in delays]
        delay = delays[int(np.argmin(typical))]
        assert min(typical) < 0.01, typical  # the same motion ...
        assert delay <= 0.25, delay  # ... a steady delay later
        assert errors(delay).max() < RobotKind.comparison.tolerance, errors(delay).max()


def test_the_live_twins_run_is_checked_as_any_run(shadow_run):
    proc = subprocess.run([sys.executable, "-m", "cellsim", "check", str(shadow_run / "twin"), "--json"],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    verdicts = json.loads(proc.stdout)
    assert proc.returncode in (0, 1) and verdicts  # readable evidence, whatever it says
    with BlackBox(shadow_run / "twin" / "blackbox.sqlite") as twin:
        live = twin.metadata()["live"]
        pacing = live["pacing_lag_s"]  # its figures, whatever the host's load (the target is bench_live's to measure)
        assert live["process"] == "twin" and pacing["p50"] <= pacing["p99"] <= pacing["max"] < 12.0
        # the twin's own reaction to its shadowed entities' changed samples, measured, beside what is assumed
        reaction = live["reaction_s"]
        assert reaction["robot"]["count"] > 0 and reaction["light_barrier"]["count"] > 0
        assert reaction["light_barrier"]["assumed"] == 0.06 and 0.0 < reaction["light_barrier"]["p50"] <= reaction["light_barrier"]["max"]
        links = twin.series("robot.physical_link").values
        # not trusted at the start (no emulator yet, or fewer than recover_after of its samples), then its samples
        assert links[0] in ("stale", "recovering") and "ok" in links


def _twin_mode(endpoint: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cellsim", "twin-mode", *args, "--connect", endpoint],
                          capture_output=True, text=True, timeout=60, cwd=ROOT)


def _twin_mode_started(endpoint: str, *args: str) -> subprocess.Popen:
    """``_twin_mode`` started, not waited for: collect it with ``_twin_mode_ended``."""
    return subprocess.Popen([sys.executable, "-m", "cellsim", "twin-mode", *args, "--connect", endpoint],
                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)


def _twin_mode_ended(process: subprocess.Popen, timeout: float = 60) -> subprocess.CompletedProcess:
    """Its result, waiting at most ``timeout`` s; stopped by its PID if it has not ended by then."""
    try:
        out, err = process.communicate(timeout=timeout)
    finally:
        if process.poll() is None:
            os.kill(process.pid, signal.SIGKILL)
            process.communicate()
    return subprocess.CompletedProcess(process.args, process.returncode, out, err)


def test_twin_modes_switch_at_run_time_on_request_and_bad_requests_are_refused(tmp_path):
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    with processes() as start:
        twin = start(["live", WELDING_CELL, "--out", str(tmp_path / "twin"), "--listen", endpoint, "--quiet"], tmp_path / "twin.log")
        with observer(port) as session:
            mode = ChannelWatch(session, "cellsim/welding_cell/twin/light_barrier/twin_mode")
            start(["emulate", WELDING_CELL, "--out", str(tmp_path / "emulator"), "--connect", endpoint, "--quiet"], tmp_path / "emu.log")
            wait_alive(session, "cellsim/welding_cell/alive/twin")
            wait_alive(session, "cellsim/welding_cell/alive/emulator")
            mode.wait_for("model", 30)
            for wanted in ("shadow", "twin", "model"):
                done = _twin_mode(endpoint, "light_barrier", wanted)
                assert done.returncode == 0 and done.stdout.startswith("accepted"), done.stdout + done.stderr
                mode.wait_for(wanted, 10)
            for args, reason in ((("lightbarrier", "shadow"), "no entity named 'lightbarrier'"),
                                 (("light_barrier", "shdow"), "'shdow' is not a twin mode")):
                refused = _twin_mode(endpoint, *args)
                assert refused.returncode == 2 and refused.stdout.startswith("refused") and reason in refused.stdout
            mode.close()
        twin.stop()
    assert mode.values == ["model", "shadow", "twin", "model"]
    with BlackBox(tmp_path / "twin" / "blackbox.sqlite") as bb:
        assert bb.series("light_barrier.twin_mode").values == ["model", "shadow", "twin", "model"]
        requests = bb.metadata()["live"]["twin_mode_requests"]
        assert [r["mode"] for r in requests] == ["shadow", "twin", "model"]
        assert all(r["entity"] == "light_barrier" and r["by"].startswith("cellsim twin-mode") for r in requests)
        # nothing else changed
        assert bb.series("range_detector.twin_mode").values == ["model"]


def test_twin_mode_with_no_twin_running_says_so(tmp_path):
    done = _twin_mode(f"tls/127.0.0.1:{free_port()}", "light_barrier", "shadow", "--timeout", "1")
    assert done.returncode == 2 and "no running twin reachable within 1 s" in done.stderr


FAULTS = {  # entity: (fault injected, the link state it must cause, a channel and its fail-safe value)
    "light_barrier": ("silence", "stale", "light_barrier.broken", True),
    "range_detector": ("corrupt", "corrupt", "range_detector.range", "close"),
    "robot": ("freeze", "stale", "robot.safety_mode", "unknown"),
    "welder": ("replay", "stale", "welder.activity", "welding"),
    "operator": ("delay", "stale", None, None),
}


def test_each_injected_fault_drives_its_entity_to_fail_safe_and_back(tmp_path):
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    faults = [arg for e, (kind, *_) in FAULTS.items() for arg in ("--fault", f"{e}={kind}@3-5")]
    with processes() as start:
        twin = start(["live", WELDING_CELL, "--out", str(tmp_path / "twin"), "--listen", endpoint, "--quiet", *ALL_SHADOW],
                     tmp_path / "twin.log")
        with observer(port) as session:
            wait_alive(session, "cellsim/welding_cell/alive/twin")
        emulator = start(["emulate", WELDING_CELL, "--out", str(tmp_path / "emulator"), "--duration", "7.5",
                          "--connect", endpoint, "--quiet", *faults], tmp_path / "emulator.log")
        assert emulator.wait(timeout=120) == 0, emulator.output()
        twin.stop()
    with BlackBox(tmp_path / "twin" / "blackbox.sqlite") as twin, BlackBox(tmp_path / "emulator" / "blackbox.sqlite") as emu:
        offset = _offset(twin, emu)
        for entity, (kind, link_state, channel, safe) in FAULTS.items():
            period = 0.02 if entity == "robot" else 0.04
            link = twin.series(f"{entity}.physical_link")
            assert link.value_at(2.5 + offset) == "ok", entity
            # failing safe within stale_after plus one update period (and the way of a sample)
            failed = 3.0 + offset + (0.5 if link_state == "stale" else 0.0) + period + 0.06
            assert link.value_at(failed) == link_state, (entity, kind, link.value_at(failed))
            if channel is not None:
                assert twin.series(channel).value_at(failed) == safe, (entity, channel)
            # back once recover_after good samples came in a row
            assert link.value_at(5.0 + offset + 4 * period + 0.06) == "ok", entity
            # (by way of recovering: looked for after it failed, not after 5.0 s + the two clocks' estimated offset, a
            # window the suite on a loaded host once found only 'ok' in)
            assert "recovering" in [v for t, v in zip(link.times, link.values) if t > failed]
        assert emu.metadata()["live"]["faults"][0] == {"entity": "light_barrier", "kind": "silence", "at": 3.0, "until": 5.0}


def test_a_killed_emulator_makes_the_shadow_fail_safe_and_a_restarted_one_recovers_it(tmp_path):
    import signal

    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    emulator_args = ["emulate", WELDING_CELL, "--connect", endpoint, "--quiet"]
    with processes() as start:
        twin = start(["live", WELDING_CELL, "--out", str(tmp_path / "twin"), "--listen", endpoint, "--quiet", *ALL_SHADOW],
                     tmp_path / "twin.log")
        with observer(port) as session:
            link = ChannelWatch(session, "cellsim/welding_cell/twin/robot/physical_link")
            wait_alive(session, "cellsim/welding_cell/alive/twin")
            first = start([*emulator_args, "--out", str(tmp_path / "emu1")], tmp_path / "emu1.log")
            link.wait_for("ok", 60)
            first.stop(signal.SIGKILL)
            link.wait_for("stale", 2.0)  # stale_after 0.5 s, one period, and the twin's publishing
            start([*emulator_args, "--out", str(tmp_path / "emu2")], tmp_path / "emu2.log")
            link.wait_for("ok", 60)
            link.close()
        twin.stop()
    assert link.values[0] in ("stale", "recovering")  # not trusted before recover_after samples came
    killed = link.values[link.values.index("ok"):]
    assert "recovering" in killed[killed.index("stale"):]  # the restarted emulator: recovering, then ok
    # the killed emulator's black box is still readable: what it committed is kept
    with BlackBox(tmp_path / "emu1" / "blackbox.sqlite") as killed:
        assert killed.metadata()["status"] == "running" and killed.channels()


TWIN_SUPERVISES = ["--set", "robot.twin.mode=twin", "--set", "welder.twin.mode=twin",
                   *[arg for e in ("light_barrier", "range_detector", "operator") for arg in ("--set", f"{e}.twin.mode=shadow")]]


def test_the_twins_safety_controller_supervises_the_emulated_cell(tmp_path):
    """The published twin test: the welding cell's full 30 s, the twin supervising the emulated cell, whose robot is
    emulated as a UR controller at 500 Hz (``--rate robot=500``: it works, not only publishes, every 2 ms)."""
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    reached, on_status = sim_time_reached(30.0)

    with processes() as start:
        twin = start(["live", WELDING_CELL, "--out", str(tmp_path / "twin"), "--listen", endpoint, "--quiet", *TWIN_SUPERVISES],
                     tmp_path / "twin.log")
        with observer(port) as session:
            wait_alive(session, "cellsim/welding_cell/alive/twin")
            status = session.declare_subscriber("cellsim/welding_cell/status/twin", on_status)
            emulator = start(["emulate", WELDING_CELL, "--out", str(tmp_path / "emulator"), "--duration", "36",
                              "--commanded-by-twin", "--rate", "robot=500", "--connect", endpoint, "--quiet"],
                             tmp_path / "emulator.log")
            assert reached.wait(90), twin.output()
            status.undeclare()
        twin.stop()  # after the scenario's 30 s, while the emulated cell still runs
        assert emulator.wait(timeout=60) == 0, emulator.output()
    with BlackBox(tmp_path / "twin" / "blackbox.sqlite") as twin, BlackBox(tmp_path / "emulator" / "blackbox.sqlite") as emu:
        # the operator walks into the emulated cell; the twin detects HS from the emulated scanner and
        # its ssmon request reaches the emulated robot (twin's update, the command's way, the robot's update)
        assert_supervised(twin, emu, within=0.3)
        # the emulated robot took its modes at its own 2 ms cycles, off the 20 ms grid of the scenario's robot,
        # and the run says so in its overrides
        assert "robot.period=0.002" in emu.metadata()["overrides"]
        modes = emu.series("robot.safety_mode")
        assert any(round(t / 0.002) % 10 for t in modes.times[1:]), modes.times
    proc = subprocess.run([sys.executable, "-m", "cellsim", "check", str(tmp_path / "twin"), "--json"],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    verdicts = json.loads(proc.stdout)
    assert proc.returncode == 0 and verdicts["holds"] and verdicts["complete"], verdicts["violations"]
    assert len(verdicts["verdicts"]) == 16  # all 16 conditions (NoHarm, NoClamping too) hold on the twin's record


def test_only_the_roles_certificates_allow_may_publish_samples_or_switch_modes(tmp_path, cell_keys):
    """Mutual TLS and the twin's access control by certificate name: an observer may watch but neither
    feed a physical sample nor switch a mode; a session with no certificate, or with one from another
    CA, cannot connect at all; the engineer may switch modes, and the bridge feed samples."""
    import threading
    import time

    import zenoh

    from cellsim.live import pki
    from cellsim.live.session import session_config

    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"

    def session(role: str):
        return zenoh.open(session_config(role=role, connect=[endpoint]))

    links: list[tuple[float, str]] = []
    sim_time = [0.0]
    heard = threading.Event()

    def on_link(sample) -> None:
        message = json.loads(sample.payload.to_bytes())
        links.append((message["sim_time"], message["value"]))
        heard.set()

    def on_status(sample) -> None:
        sim_time[0] = json.loads(sample.payload.to_bytes())["sim_time"]
        heard.set()

    def publish_until(publisher, done, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        seq = 0
        while not done():
            assert time.monotonic() < deadline, links
            seq += 1
            publisher.put(json.dumps({"t": time.time(), "seq": seq, "fields": {"broken": False}}))
            heard.wait(0.02)  # a sample stream at 50 Hz, or sooner when the twin reports
            heard.clear()

    other_ca = tmp_path / "other-keys"
    pki.init_keys(other_ca)
    with processes() as start:
        twin = start(["live", WELDING_CELL, "--out", str(tmp_path / "twin"), "--listen", endpoint, "--quiet",
                      "--set", "light_barrier.twin.mode=shadow", "--wait-physical", "0"], tmp_path / "twin.log")
        observer_session = session("observer")
        try:
            wait_alive(observer_session, "cellsim/welding_cell/alive/twin")
            observer_session.declare_subscriber("cellsim/welding_cell/twin/light_barrier/physical_link", on_link)
            observer_session.declare_subscriber("cellsim/welding_cell/status/twin", on_status)
            # the observer's samples do not reach the twin: two simulated seconds of them
            forged = observer_session.declare_publisher("cellsim/welding_cell/physical/light_barrier")
            publish_until(forged, lambda: sim_time[0] >= 3.0, 60)
            observer_phase_end = sim_time[0]
            # the two twin-mode commands that must not connect wait out their timeouts while the checks below do
            stranger = plain = None
            try:
                # the same command with the engineer's certificate of another CA cannot connect at all
                stranger = _twin_mode_started(endpoint, "robot", "shadow", "--keys", str(other_ca), "--timeout", "2")
                # nor can a session without TLS
                plain = _twin_mode_started(endpoint.replace("tls/", "tcp/"), "robot", "shadow", "--insecure", "--timeout", "2")
                # nor does the observer's mode request: no answer comes back
                request = json.dumps({"entity": "robot", "mode": "shadow", "by": "observer"})
                assert list(observer_session.get("cellsim/welding_cell/control/twin_mode", payload=request, timeout=2.0)) == []
                # nor can it pass for the bridge: its liveliness token is seen by nobody
                fake = observer_session.liveliness().declare_token("cellsim/welding_cell/alive/bridge")
                engineer = session("engineer")
                try:
                    wait_alive(engineer, "cellsim/welding_cell/alive/twin")  # the engineer does see the real ones
                    assert list(engineer.liveliness().get("cellsim/welding_cell/alive/bridge", timeout=2.0)) == []
                finally:
                    engineer.close()
                    fake.undeclare()
                # nor TLS without a client certificate
                anonymous = zenoh.Config()
                for key, value in (("mode", "client"), ("scouting/multicast/enabled", False), ("listen/endpoints", []),
                                   ("connect/endpoints", [endpoint]), ("connect/timeout_ms", {"client": 2000}),
                                   ("transport/link/tls/root_ca_certificate", str(cell_keys / "ca.pem"))):
                    anonymous.insert_json5(key, json.dumps(value))
                with pytest.raises(zenoh.ZError):
                    zenoh.open(anonymous).close()
            finally:
                # each collected (and stopped by its PID if it has not ended) whatever happened above
                try:
                    stranger = stranger and _twin_mode_ended(stranger)
                finally:
                    plain = plain and _twin_mode_ended(plain)
            assert stranger.returncode == 2 and "no running twin reachable" in stranger.stderr, stranger.stderr
            assert plain.returncode == 2 and "no running twin reachable" in plain.stderr, plain.stderr
            # the engineer may switch modes; the bridge may feed samples
            accepted = _twin_mode(endpoint, "robot", "shadow")
            assert accepted.returncode == 0 and accepted.stdout.startswith("accepted"), accepted.stdout + accepted.stderr
            bridge_session = session("bridge")
            try:
                device = bridge_session.declare_publisher("cellsim/welding_cell/physical/light_barrier")
                publish_until(device, lambda: any(v == "ok" for _, v in links), 60)
            finally:
                bridge_session.close()
        finally:
            observer_session.close()
        twin.stop()
    with BlackBox(tmp_path / "twin" / "blackbox.sqlite") as bb:
        link = bb.series("light_barrier.physical_link")
        trusted = [t for t, v in zip(link.times, link.values) if v in ("recovering", "ok")]
        assert trusted and trusted[0] > observer_phase_end  # nothing of the observer's was taken
        assert bb.series("robot.twin_mode").values == ["model", "shadow"]  # only the engineer's request
        assert [r["by"] for r in bb.metadata()["live"]["twin_mode_requests"]][0].startswith("cellsim twin-mode")


@pytest.mark.parametrize(
    "args, expected",
    [
        (["emulate", WELDING_CELL, "--fault", "robot=melt"], "--fault 'robot=melt'"),
        (["emulate", WELDING_CELL, "--fault", "robot=silence@5-2"], "T0 < T1"),
        (["emulate", WELDING_CELL, "--fault", "robto=silence"], "no entity named 'robto'"),
        (["emulate", WELDING_CELL, "--rate", "robot=0"], "HZ from 0.1 to 1000"),
        (["live", WELDING_CELL, "--wait-physical", "-1"], "--wait-physical -1"),
        (["live", WELDING_CELL, "--listen", "tls/127.0.0.1"], "not a Zenoh endpoint"),
        (["live", WELDING_CELL, "--set", "robot.twin.mode=shadw"], "'shadw' is not one of"),
    ],
)
def test_bad_live_arguments_are_one_line_exit_2_and_write_nothing(tmp_path, args, expected):
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "cellsim", *args, "--out", str(out)],
                          capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1 and expected in proc.stderr, proc.stderr
    assert not out.exists()


def test_a_fault_injected_at_run_time_fails_the_shadow_safe_and_sigterm_ends_the_twin_cleanly(tmp_path):
    import signal

    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"

    def inject(session, request: dict) -> dict:
        replies = list(session.get("cellsim/welding_cell/control/fault", payload=json.dumps(request), timeout=5))
        return json.loads(replies[0].ok.payload.to_bytes())

    with processes() as start:
        twin = start(["live", WELDING_CELL, "--out", str(tmp_path / "twin"), "--listen", endpoint, "--quiet",
                      "--set", "light_barrier.twin.mode=shadow"], tmp_path / "twin.log")
        with observer(port, role="engineer") as session:  # injects faults
            link = ChannelWatch(session, "cellsim/welding_cell/twin/light_barrier/physical_link")
            wait_alive(session, "cellsim/welding_cell/alive/twin")
            start(["emulate", WELDING_CELL, "--out", str(tmp_path / "emulator"), "--connect", endpoint, "--quiet"], tmp_path / "emu.log")
            wait_alive(session, "cellsim/welding_cell/alive/emulator")
            link.wait_for("ok", 60)
            assert inject(session, {"entity": "light_barrier", "kind": "melt", "seconds": 1}) == {
                "accepted": False, "reason": "'melt' is not a fault of light_barrier (silence, freeze, corrupt, delay, replay)"}
            assert inject(session, {"entity": "light_barrier", "kind": "corrupt", "seconds": 1.0})["accepted"]
            link.wait_for("corrupt", 5)
            link.wait_for("ok", 10)  # the fault ends after a second; trusted again after good samples in a row
            link.close()
        twin.stop(signal.SIGTERM)
        assert twin.popen.returncode == 130
    assert link.values[-3:] == ["corrupt", "recovering", "ok"]
    with BlackBox(tmp_path / "twin" / "blackbox.sqlite") as bb:
        assert bb.metadata()["status"] == "stopped"  # SIGTERM closed the black box as Ctrl-C does
        assert "corrupt" in bb.series("light_barrier.physical_link").values
