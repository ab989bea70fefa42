#!/usr/bin/env python3
"""Benchmark: the bridge daemon at nominal and at ten times nominal CAN load.

For each load the bench starts a python-can-remote server on loopback and a
``cellsim bridge`` process, and plays everything
around the daemon itself:

* the CAN devices: the light curtain, the scanner and the welder status, each
  at its cycle time (nominal) or ten times as often (10x), every frame protected
  (counter, CRC) as the DBC says;
* the robot controller: its state at 500 Hz over Zenoh;
* the twin: a Zenoh router with the twin's liveliness token, the welder and the
  robot in twin mode, their commands changing every 0.1 s (each change goes out
  at once).

Each load runs in turns: with mutual TLS and the twin's access control (the default of
every cellsim session, keys made for the run) and CAN frames end-to-end protected only
(``tls``: the shipped configuration with every message's ``e2e_only`` plain counterpart), the
same over plain TCP (``--insecure``, ``plain``), and the shipped configuration as it is
(``secoc``: TLS, and every device's frames carrying a freshness value and a truncated CMAC
that the daemon checks, every command frame signed by it), so the costs of TLS and of SecOC
are read beside the plain figures of the same run.

It prints per load and security: the latency the daemon adds from a CAN frame received to its
Zenoh sample published, and from a changed command received to its frames sent
(p50, p99, max; measured inside the daemon, from python-can's or Zenoh's
callback to the send, as its status on cellsim/<cell>/diagnostics/bridge
reports them), the frames lost (sent by the bench, not received by the daemon)
and the daemon's CPU in % of one core.

Targets (issue "The bridge daemon"): p99 at most 1 ms added; no frame lost at
ten times nominal; the daemon at most 25 % of one core at nominal. The last line
reads ``bridge: p50 X ms, p99 Y ms, lost N of M`` per security: the worse of the
two loads' frame latencies, and the frames lost over both.

    .venv/bin/python scripts/bench_bridge.py [--seconds 60] [--security tls plain secoc]
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from live_processes import can_server, free_port, processes, wait_alive  # noqa: E402

SHIPPED = ROOT / "bridges" / "welding_cell.yaml"
"""The welding cell's bridge: every message authenticated."""
VALUES = {"LightCurtainState": {"Broken": 0}, "ScannerState": {"Range": "far", "Distance": 3.5},
          "WelderStatus": {"SafetyMode": "normal", "Activity": "idle"}}
"""What each device says, by message (an authenticated message: by the name it extends)."""
ROBOT_HZ = 500.0
PROFILE = None
"""With --profile FILE: the daemon runs under cProfile, its statistics in FILE (of the last load run)."""


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / 100.0  # utime + stime, in clock ticks of 10 ms


def play_devices(bus, loaded, load: float, stop: threading.Event, sent: dict, can_key: bytes | None) -> None:
    """Each CAN device's frames at ``load`` times its rate, on one paced thread; an authenticated message's
    frames signed as they are sent (their freshness follows the clock), the others made once."""
    import can

    from cellsim.bridges.e2e import protect
    from cellsim.bridges.secoc import Authenticator, is_authenticated, message_key

    cfg, database = loaded.config, loaded.database
    devices = []
    for entity, mapping in cfg.devices.items():
        message = database.get_message_by_name(mapping.message)
        values = VALUES[message.name.removesuffix("Authenticated")]
        if is_authenticated(message):
            signer = Authenticator(message, message_key(can_key, message.frame_id), cfg.freshness_tick)

            def frame(c, message=message, values=values, signer=signer):
                return can.Message(arbitration_id=message.frame_id, data=protect(message, values, c, signer),
                                   is_extended_id=False)
        else:
            made = [can.Message(arbitration_id=message.frame_id, data=protect(message, values, c), is_extended_id=False)
                    for c in range(16)]

            def frame(c, made=made):
                return made[c % 16]
        devices.append([entity, mapping.cycle_time / load, frame, time.monotonic(), 0])
        sent[entity] = 0
    pause = threading.Event()
    while not stop.is_set():
        now = time.monotonic()
        for device in devices:
            entity, period, frame, due, counter = device
            while due <= now:
                bus.send(frame(counter))
                counter += 1
                sent[entity] += 1
                due += period
            device[3], device[4] = due, counter
        pause.wait(max(0.0, min(d[3] for d in devices) - time.monotonic()))


def play_robot(session, cell: str, stop: threading.Event, sent: dict) -> None:
    from cellsim.live import keys

    publisher = session.declare_publisher(keys.controller_state(cell, "robot"))
    pause, seq, due = threading.Event(), 0, time.monotonic()
    while not stop.is_set():
        seq += 1
        publisher.put(json.dumps({"t": time.time(), "seq": seq, "position": [0.1, -1.2, 1.0, 0.0, 1.5, 0.0],
                                  "velocity": [0.0] * 6, "safety_mode": "normal", "activity": "exchWrkp",
                                  "reached_pose": "moving"}, separators=(",", ":")))
        due += 1.0 / ROBOT_HZ
        pause.wait(max(0.0, due - time.monotonic()))
    sent["robot"] = seq


def play_twin(session, cell: str, stop: threading.Event) -> None:
    """The twin's side: the welder and the robot in twin mode, commands changing every 0.1 s."""
    from cellsim.live import keys

    modes = {e: session.declare_publisher(keys.channel(cell, e, "twin_mode")) for e in ("welder", "robot")}
    commands = {e: session.declare_publisher(keys.command(cell, e)) for e in ("welder", "robot")}
    pause, seq = threading.Event(), 0
    while not stop.is_set():
        seq += 1
        mode = ("normal", "ssmon")[seq % 2]
        for entity, publisher in modes.items():
            publisher.put(json.dumps({"t": time.time(), "sim_time": 0.0, "value": "twin"}))
        commands["welder"].put(json.dumps({"t": time.time(), "seq": seq, "fields": {
            "safety_mode_request": mode, "activity_request": None, "command": float(seq % 2)}}))
        commands["robot"].put(json.dumps({"t": time.time(), "seq": seq, "fields": {
            "safety_mode_request": mode, "activity": None, "target_pose": None}}))
        pause.wait(0.1)


def e2e_only(folder: Path) -> Path:
    """The shipped configuration with each message's plain (E2E-only) counterpart, each by explicit choice."""
    import re

    text = SHIPPED.read_text().replace("scenario: ../scenarios/", f"scenario: {ROOT / 'scenarios'}/")
    text = text.replace("dbc: welding_cell.dbc", f"dbc: {ROOT / 'bridges' / 'welding_cell.dbc'}")
    text = re.sub(r"^( *)(- )?message: (\w+)Authenticated$",
                  lambda m: f"{m[1]}{m[2] or ''}message: {m[3]}\n{m[1]}{'  ' if m[2] else ''}e2e_only: the benchmark's baseline",
                  text, flags=re.M)
    path = folder / "e2e_only.yaml"
    path.write_text(text)
    return path


def run_load(load: float, seconds: float, tmp: Path, key_dir: Path | None, config: Path = SHIPPED) -> dict:
    """One load for ``seconds``; ``key_dir``: mutual TLS with those keys (and their CAN key for an
    authenticated ``config``), None: plain TCP (--insecure)."""
    import can
    import zenoh

    from cellsim.bridges.config import load_bridge
    from cellsim.live import keys, pki
    from cellsim.live.session import session_config

    loaded = load_bridge(config)
    can_key = pki.can_key(key_dir) if key_dir is not None and loaded.authenticated() else None
    cell = loaded.cell
    port = free_port()
    endpoint = f"{'tls' if key_dir else 'tcp'}/127.0.0.1:{port}"
    security = ["--keys", str(key_dir)] if key_dir else ["--insecure"]
    statuses: list[dict] = []
    with processes() as start:
        channel = can_server(start, tmp / f"can-{load:g}.log")
        hub = zenoh.open(session_config(role="twin", keys=key_dir, insecure=key_dir is None, listen=[endpoint],
                                        listen_by_default=True))
        bus = can.Bus(interface="remote", channel=channel)
        try:
            token = hub.liveliness().declare_token(keys.alive(cell, "twin"))
            hub.declare_subscriber(keys.diagnostics(cell, "bridge"), lambda s: statuses.append(json.loads(s.payload.to_bytes())))
            args = ["bridge", str(config), "--can", f"remote:{channel}", "--connect", endpoint, *security]
            if PROFILE:  # the daemon under cProfile, its statistics written when it is stopped
                daemon = start(["-o", PROFILE, "-m", "cellsim", *args], tmp / f"bridge-{load:g}.log", module="cProfile")
            else:
                daemon = start(args, tmp / f"bridge-{load:g}.log")
            wait_alive(hub, keys.alive(cell, "bridge"))
            stop = threading.Event()
            sent: dict[str, int] = {}
            players = [threading.Thread(target=play_devices, args=(bus, loaded, load, stop, sent, can_key)),
                       threading.Thread(target=play_robot, args=(hub, cell, stop, sent)),
                       threading.Thread(target=play_twin, args=(hub, cell, stop))]
            for player in players:
                player.start()
            cpu0, t0 = cpu_seconds(daemon.pid), time.monotonic()
            stop.wait(seconds)
            cpu = (cpu_seconds(daemon.pid) - cpu0) / (time.monotonic() - t0)
            stop.set()
            for player in players:
                player.join()
            # the daemon's status once it has taken in every frame sent (or two status periods on)
            devices = list(loaded.config.devices)
            deadline, pause = time.monotonic() + 2.5, threading.Event()
            while time.monotonic() < deadline:
                if statuses and all(statuses[-1]["received"].get(e, 0) >= sent[e] for e in [*devices, "robot"]):
                    break
                pause.wait(0.1)
            status = statuses[-1]
            token.undeclare()
            daemon.stop()
        finally:
            bus.shutdown()
            hub.close()
    can_sent = sum(sent[e] for e in loaded.config.devices)
    can_received = sum(status["received"][e] for e in loaded.config.devices)
    return {"load": load, "cpu": cpu, "frames": can_sent, "lost": max(0, can_sent - can_received),
            "robot_states": sent["robot"], "robot_received": status["received"]["robot"],
            "frame_ms": status["frame_latency_ms"], "command_ms": status["command_latency_ms"]}


def main() -> None:
    import tempfile

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="seconds at each load (default 60)")
    parser.add_argument("--loads", type=float, nargs="+", default=[1.0, 10.0], help="loads to run (default 1 10)")
    parser.add_argument("--profile", metavar="FILE", help="run the daemon under cProfile, statistics to FILE")
    parser.add_argument("--security", nargs="+", choices=("tls", "plain", "secoc"), default=["tls", "plain", "secoc"],
                        help="mutual TLS with E2E-only frames, the same on plain TCP, TLS with every frame authenticated "
                        "(the shipped configuration), taking turns (default: all)")
    args = parser.parse_args()
    global PROFILE
    PROFILE = args.profile
    from cellsim.live.pki import init_keys

    results: dict[str, list] = {s: [] for s in args.security}
    with tempfile.TemporaryDirectory() as tmp:
        keys = Path(tmp) / "keys"
        init_keys(keys)
        for load in args.loads:
            for security in args.security:
                print(f"load {load:g}x nominal, {security}, for {args.seconds:g} s ...", file=sys.stderr, flush=True)
                r = run_load(load, args.seconds, Path(tmp), None if security == "plain" else keys,
                             SHIPPED if security == "secoc" else e2e_only(Path(tmp)))
                results[security].append(r)
                f, c = r["frame_ms"], r["command_ms"]
                print(f"{load:g}x nominal, {security}: {r['frames']} CAN frames ({r['frames'] / args.seconds:.0f}/s), "
                      f"lost {r['lost']}; robot states {r['robot_received']} of {r['robot_states']}")
                print(f"  frame -> sample: p50 {f['p50']:.3f} ms, p99 {f['p99']:.3f} ms, max {f['max']:.3f} ms (n {f['n']})")
                if c.get("n"):
                    print(f"  command -> frames: p50 {c['p50']:.3f} ms, p99 {c['p99']:.3f} ms, max {c['max']:.3f} ms "
                          f"(n {c['n']})")
                print(f"  daemon CPU: {100 * r['cpu']:.1f} % of one core")
    for security, runs in results.items():
        p50 = max(r["frame_ms"]["p50"] for r in runs)
        p99 = max(r["frame_ms"]["p99"] for r in runs)
        lost, total = sum(r["lost"] for r in runs), sum(r["frames"] for r in runs)
        print(f"bridge ({security}): p50 {p50:.3f} ms, p99 {p99:.3f} ms, lost {lost} of {total}")


if __name__ == "__main__":
    main()
