"""The live twin on Zenoh against the emulated physical cell: processes on loopback, stopped by PID."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from cellsim.services.blackbox import BlackBox

from live_processes import ROOT, free_port, observer, processes, wait_alive

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


def _offset(twin: BlackBox, emulator: BlackBox) -> float:
    """Emulator time + offset = twin time of the same wall-clock instant."""
    return emulator.metadata()["live"]["wall_at_zero"] - twin.metadata()["live"]["wall_at_zero"]


@pytest.fixture(scope="module")
def shadow_run(tmp_path_factory):
    """The twin with every entity in shadow mode beside the standalone emulator, 12 s."""
    tmp = tmp_path_factory.mktemp("shadow")
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    with processes() as start, observer(port) as session:
        twin = start(["live", WELDING_CELL, "--out", str(tmp / "twin"), "--listen", endpoint, "--quiet", *ALL_SHADOW],
                     tmp / "twin.log")
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
        assert twin.metadata()["status"] == "interrupted"
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
    with BlackBox(shadow_run / "twin" / "blackbox.sqlite") as twin, BlackBox(shadow_run / "emulator" / "blackbox.sqlite") as emu:
        offset = _offset(twin, emu)
        q_emu, q_twin = emu.series("robot.joint_positions"), twin.series("robot.joint_positions")
        errors = []
        for t, q in zip(q_emu.times, q_emu.values):
            if 1.0 < t < 11.0:
                seen = q_twin.value_at(t + offset + 0.06)  # a sample's way: one period to publish, one to take
                errors.append(np.max(np.abs(np.array(seen) - np.array(q))))
        assert errors and max(errors) < 0.15, max(errors)


def test_the_live_twins_run_is_checked_as_any_run(shadow_run):
    proc = subprocess.run([sys.executable, "-m", "cellsim", "check", str(shadow_run / "twin"), "--json"],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    verdicts = json.loads(proc.stdout)
    assert proc.returncode in (0, 1) and verdicts  # readable evidence, whatever it says
    with BlackBox(shadow_run / "twin" / "blackbox.sqlite") as twin:
        live = twin.metadata()["live"]
        assert live["process"] == "twin" and live["pacing_lag_s"]["p99"] < 0.05
        links = twin.series("robot.physical_link").values
        assert links[0] == "stale" and "ok" in links  # no emulator yet, then its samples
