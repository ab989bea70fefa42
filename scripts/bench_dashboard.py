#!/usr/bin/env python3
"""Benchmark: the terminal dashboard's CPU beside a live twin with the robot's state at 500 Hz.

Starts ``cellsim live`` (every entity in shadow mode) and ``cellsim emulate
--rate robot=500`` on a free loopback port, and ``cellsim dashboard`` in a
terminal of its own (tmux, 120 x 40), which follows every twin channel and
every physical sample (the robot's at 500 Hz). After a warm-up it measures the
dashboard's CPU over ``--seconds`` of wall time, in % of one core.

Target (issue "A status dashboard in the terminal"): at most 10 % of one core.
The last line reads ``dashboard: X % of one core``.

    .venv/bin/python scripts/bench_dashboard.py [--seconds 30]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from live_processes import TmuxScreen, free_port, observer, processes, wait_alive  # noqa: E402

SCENARIO = str(ROOT / "scenarios" / "welding_cell.yaml")
SHADOW = [arg for e in ("robot", "welder", "light_barrier", "range_detector", "operator") for arg in ("--set", f"{e}.twin.mode=shadow")]


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / 100.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=30.0, help="seconds measured (default 30)")
    parser.add_argument("--profile", metavar="FILE", help="run the dashboard under cProfile, statistics to FILE")
    args = parser.parse_args()
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    with tempfile.TemporaryDirectory() as tmp, processes() as start:
        tmp = Path(tmp)
        from cellsim.live.pki import ENVIRONMENT, init_keys

        init_keys(tmp / "keys")  # the run's own keys, for every process (never the user's)
        os.environ[ENVIRONMENT] = str(tmp / "keys")
        start(["live", SCENARIO, "--out", str(tmp / "twin"), "--listen", endpoint, "--quiet", *SHADOW,
               "--duration", str(args.seconds + 60)], tmp / "twin.log")
        with observer(port) as session:
            wait_alive(session, "cellsim/welding_cell/alive/twin")
        start(["emulate", SCENARIO, "--out", str(tmp / "emulator"), "--connect", endpoint, "--quiet", "--rate", "robot=500",
               "--duration", str(args.seconds + 60)], tmp / "emulator.log")
        dashboard = ["dashboard", "--connect", endpoint]
        if args.profile:
            screen = TmuxScreen(["-o", args.profile, "-m", "cellsim", *dashboard], module="cProfile")
        else:
            screen = TmuxScreen(dashboard)
        try:
            screen.wait_for(lambda s: "twin running" in s and " OK " in s, 90, "the dashboard following the twin")
            threading.Event().wait(5.0)  # warm-up: the emulator's robot at full rate
            cpu0, t0 = cpu_seconds(screen.pid), time.monotonic()
            threading.Event().wait(args.seconds)
            cpu = (cpu_seconds(screen.pid) - cpu0) / (time.monotonic() - t0)
            shown = screen.text()
            if args.profile:  # quit as a user does, so that the profile is written
                screen.keys("q")
                deadline = time.monotonic() + 20
                while screen.running() and time.monotonic() < deadline:
                    threading.Event().wait(0.1)
        finally:
            screen.stop()
    print(shown.splitlines()[0])
    print(f"robot physical state at 500 Hz, every twin channel; measured over {args.seconds:g} s")
    print(f"dashboard: {100 * cpu:.1f} % of one core")


if __name__ == "__main__":
    main()
