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

``--security ur_plc`` runs the cell beside a UR controller and a PLC
(``bridges/welding_cell_ur_plc.yaml``, TLS, the scanner's frames authenticated):
the bench plays the controller's RTDE server (``cellsim.ur.controller``) at 500 Hz
(5 kHz at ten times nominal) and the PLC's OPC UA server (``cellsim.bridges.plc_server``,
Sign & Encrypt, a 1 ms scan) whose welder changes its activity every 0.1 s (every
10 ms at ten times nominal). It prints the RTDE package -> sample latency inside the
daemon and the packages lost, the PLC's notification -> sample inside the daemon,
and the PLC's value written -> the twin's sample received, end to end on the bench's clock (it includes OPC UA's sampling and
publishing, at most one publishing interval, 20 ms, by design), with the
publishing cycles the daemon heard. Targets (issue "Beside a real cell"): RTDE p99
at most 1 ms added and nothing lost at ten times nominal; OPC UA p99 at most the
publishing interval.

    .venv/bin/python scripts/bench_bridge.py [--seconds 60] [--security tls plain secoc ur_plc]
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
            cpu = play_for(players, stop, seconds, daemon.pid)
            # the daemon's status once it has taken in every frame sent (or two status periods on)
            devices = list(loaded.config.devices)
            status = settled(statuses, lambda s: all(s["received"].get(e, 0) >= sent[e] for e in [*devices, "robot"]))
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


def play_for(players: list[threading.Thread], stop: threading.Event, seconds: float, pid: int) -> float:
    """Run ``players`` for ``seconds``, then stop and join them; the daemon's (``pid``) CPU over that time, as a
    fraction of one core."""
    for player in players:
        player.start()
    cpu0, t0 = cpu_seconds(pid), time.monotonic()
    stop.wait(seconds)
    cpu = (cpu_seconds(pid) - cpu0) / (time.monotonic() - t0)
    stop.set()
    for player in players:
        player.join()
    return cpu


def settled(statuses: list[dict], done) -> dict:
    """The daemon's newest status once ``done(status)`` holds (every frame sent taken in), or after two status
    periods (2.5 s) whatever it says."""
    deadline, pause = time.monotonic() + 2.5, threading.Event()
    while time.monotonic() < deadline and not (statuses and done(statuses[-1])):
        pause.wait(0.1)
    return statuses[-1]


def play_controller(server, program, load: float, stop: threading.Event, sent: dict) -> None:
    """The UR controller's RTDE packages at 500 Hz times ``load`` (catching up when late: none is skipped)."""
    fields = {**{f"q{i}": 0.1 * i for i in range(6)}, "safety_mode": "normal", "activity": "welding",
              "reached_pose": "moving"}
    period, due, t, n = 0.002 / load, time.monotonic(), 0.0, 0
    pause = threading.Event()
    while not stop.is_set():
        now = time.monotonic()
        while due <= now:
            t += period
            n += server.publish(program.state(fields, [0.0] * 6, t, 1.0))
            due += period
        pause.wait(max(0.0, due - time.monotonic()))
    sent["robot"] = n


def play_plc(plc, load: float, stop: threading.Event, written: dict) -> None:
    """The PLC's welder changing its activity every 0.1 s / ``load``: the time each value was written."""
    pause, k = threading.Event(), 0
    while not stop.is_set():
        k += 1
        activity = ("idle", "welding", "off")[k % 3]
        written[k] = (activity, time.perf_counter())
        plc.publish("welder", {"safety_mode": "normal", "activity": activity}, None)
        plc.publish("light_barrier", {"broken": False}, None)
        pause.wait(0.1 / load)


def run_ur_plc(load: float, seconds: float, tmp: Path, key_dir: Path) -> dict:
    """The welding cell beside a UR controller and a PLC (see the module docstring), for ``seconds``."""
    import re

    import can
    import zenoh

    import cellsim.bridges.plc_server as plc_server
    from cellsim.bridges.config import load_bridge
    from cellsim.bridges.plc_server import EmulatedPlc
    from cellsim.live import keys, pki
    from cellsim.live.session import session_config
    from cellsim.ur.controller import RtdeServer

    rtde_port, opcua_port, port = free_port(), free_port(), free_port()
    text = (ROOT / "bridges" / "welding_cell_ur_plc.yaml").read_text().replace("base: welding_cell.yaml", f"base: {SHIPPED}")
    text = text.replace("port: 30004", f"port: {rtde_port}").replace("127.0.0.1:4840", f"127.0.0.1:{opcua_port}")
    config = tmp / "ur_plc.yaml"
    config.write_text(re.sub(r"^( *)watchdog: 0.05$", r"\1watchdog: 0.05", text, flags=re.M))
    loaded = load_bridge(config)
    cell, plc_settings = loaded.cell, loaded.config.plc
    plc_server.SCAN = 0.001  # the PLC's scan is not the daemon's cost: 1 ms, so a written value goes out at once
    statuses: list[dict] = []
    seen: list[tuple[str, float]] = []
    with processes() as start:
        channel = can_server(start, tmp / f"can-ur-{load:g}.log")
        hub = zenoh.open(session_config(role="twin", keys=key_dir, listen=[f"tls/127.0.0.1:{port}"], listen_by_default=True))
        bus = can.Bus(interface="remote", channel=channel)
        server = RtdeServer("127.0.0.1", rtde_port)
        plc = EmulatedPlc(plc_settings, loaded.samples, loaded.commands, loaded.safe,
                          certificates=(*pki.opcua_files(key_dir, "plc"), pki.opcua_files(key_dir, "bridge")[0]))
        try:
            token = hub.liveliness().declare_token(keys.alive(cell, "twin"))
            hub.declare_subscriber(keys.diagnostics(cell, "bridge"), lambda s: statuses.append(json.loads(s.payload.to_bytes())))

            def on_welder(sample) -> None:
                message = json.loads(sample.payload.to_bytes())
                if "fields" in message:
                    seen.append((message["fields"]["activity"], time.perf_counter()))

            hub.declare_subscriber(keys.physical(cell, "welder"), on_welder)
            daemon = start(["bridge", str(config), "--can", f"remote:{channel}", "--connect", f"tls/127.0.0.1:{port}",
                            "--keys", str(key_dir)], tmp / f"bridge-ur-{load:g}.log")
            wait_alive(hub, keys.alive(cell, "bridge"))
            deadline, pause = time.monotonic() + 30, threading.Event()
            while not (server.clients and statuses and statuses[-1].get("plc_connected")):
                assert time.monotonic() < deadline, "the daemon did not reach the controller and the PLC"
                pause.wait(0.05)
            stop = threading.Event()
            sent: dict[str, int] = {}
            written: dict[int, tuple[str, float]] = {}
            players = [threading.Thread(target=play_controller, args=(server, loaded.programs["robot"], load, stop, sent)),
                       threading.Thread(target=play_plc, args=(plc, load, stop, written)),
                       threading.Thread(target=play_twin, args=(hub, cell, stop))]
            received0 = statuses[-1]["received"].get("robot", 0)
            cpu = play_for(players, stop, seconds, daemon.pid)
            status = settled(statuses, lambda s: s["received"].get("robot", 0) - received0 >= sent["robot"])
            token.undeclare()
            daemon.stop()
        finally:
            server.close()
            plc.close()
            bus.shutdown()
            hub.close()
    # each value written -> the first sample carrying it before that value is written again (a value overwritten
    # within one publishing interval is never sent: OPC UA's queue of one keeps the latest, by design)
    latencies, changes = [], 0
    order = sorted(written.values(), key=lambda w: w[1])
    for i, (value, at) in enumerate(order):
        again = next((t for v, t in order[i + 1:] if v == value), float("inf"))
        got = next((t for v, t in seen if v == value and at <= t < again), None)
        if got is not None:
            latencies.append(got - at)
            changes += 1
    import numpy as np

    ms = np.asarray(latencies) * 1e3
    return {"load": load, "cpu": cpu, "robot_states": sent["robot"],
            "robot_received": status["received"]["robot"] - received0, "robot_ms": status["robot_latency_ms"],
            "plc_added_ms": status["plc_latency_ms"],
            "plc_written": len(written), "plc_seen": changes,
            "plc_ms": {"n": int(ms.size), "p50": float(np.percentile(ms, 50)), "p99": float(np.percentile(ms, 99)),
                       "max": float(ms.max())} if ms.size else {"n": 0},
            "plc_interval_ms": plc_settings.publishing_interval * 1e3}


def main() -> None:
    import tempfile

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="seconds at each load (default 60)")
    parser.add_argument("--loads", type=float, nargs="+", default=[1.0, 10.0], help="loads to run (default 1 10)")
    parser.add_argument("--profile", metavar="FILE", help="run the daemon under cProfile, statistics to FILE")
    parser.add_argument("--security", nargs="+", choices=("tls", "plain", "secoc", "ur_plc"),
                        default=["tls", "plain", "secoc", "ur_plc"],
                        help="mutual TLS with E2E-only frames, the same on plain TCP, TLS with every frame authenticated "
                        "(the shipped configuration), the cell beside a UR controller over RTDE and a PLC over OPC UA "
                        "(bridges/welding_cell_ur_plc.yaml), taking turns (default: all)")
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
                if security == "ur_plc":
                    r = run_ur_plc(load, args.seconds, Path(tmp), keys)
                    results[security].append(r)
                    rm, pm = r["robot_ms"], r["plc_ms"]
                    print(f"{load:g}x nominal, ur_plc: RTDE packages {r['robot_received']} of {r['robot_states']} "
                          f"({r['robot_states'] / args.seconds:.0f}/s), lost {max(0, r['robot_states'] - r['robot_received'])}")
                    print(f"  RTDE package -> sample: p50 {rm['p50']:.3f} ms, p99 {rm['p99']:.3f} ms, max {rm['max']:.3f} ms "
                          f"(n {rm['n']})")
                    am = r["plc_added_ms"]
                    print(f"  PLC notification -> sample (inside the daemon): p50 {am['p50']:.3f} ms, p99 {am['p99']:.3f} ms, "
                          f"max {am['max']:.3f} ms (n {am['n']})")
                    print(f"  PLC value written -> twin's sample: p50 {pm['p50']:.3f} ms, p99 {pm['p99']:.3f} ms, "
                          f"max {pm['max']:.3f} ms (n {pm['n']}; {r['plc_seen']} of {r['plc_written']} values seen; "
                          f"publishing interval {r['plc_interval_ms']:g} ms)")
                    print(f"  daemon CPU: {100 * r['cpu']:.1f} % of one core")
                    continue
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
        if security == "ur_plc":
            rtde99 = max(r["robot_ms"]["p99"] for r in runs)
            lost = sum(max(0, r["robot_states"] - r["robot_received"]) for r in runs)
            plc99 = max(r["plc_ms"]["p99"] for r in runs)
            added99 = max(r["plc_added_ms"]["p99"] for r in runs)
            print(f"bridge (ur_plc): RTDE p99 {rtde99:.3f} ms, lost {lost} of {sum(r['robot_states'] for r in runs)}; "
                  f"OPC UA p99 {added99:.3f} ms added, {plc99:.3f} ms written -> twin (publishing interval "
                  f"{runs[0]['plc_interval_ms']:g} ms)")
            continue
        p50 = max(r["frame_ms"]["p50"] for r in runs)
        p99 = max(r["frame_ms"]["p99"] for r in runs)
        lost, total = sum(r["lost"] for r in runs), sum(r["frames"] for r in runs)
        print(f"bridge ({security}): p50 {p50:.3f} ms, p99 {p99:.3f} ms, lost {lost} of {total}")


if __name__ == "__main__":
    main()
