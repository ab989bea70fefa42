"""The ``cellsim`` command line.

Exit codes: 0 all well; 1 a safety finding (a mishap in a run, a safety
condition violated, inconclusive or with missing data); 2 a usage or input
error (one line on stderr naming the file, line and key); 130 interrupted.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
from datetime import datetime
from pathlib import Path

from cellsim.numbers import instant, measure, percent

EXIT_OK, EXIT_FINDING, EXIT_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130
EXIT_CODES = "Exit codes: 0 ok, 1 safety finding, 2 usage or input error, 130 interrupted."


class InputError(Exception):
    """Bad input found by the CLI itself (the message is the whole story)."""


def main(argv: list[str] | None = None) -> int:
    try:
        return _main(argv)
    except KeyboardInterrupt:  # also while starting up: importing Drake takes a while
        print("cellsim: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "handler", None):
        parser.print_help(sys.stderr)
        return EXIT_INPUT
    with _interrupt_deferred():  # pydrake's loader reports an interrupt with its own traceback
        from cellsim.config.typed_yaml import ConfigError
        from cellsim.live.session import SessionConfigError
        from cellsim.simulation import OutputExistsError

    try:
        return args.handler(args)
    except (ConfigError, OutputExistsError, InputError, SessionConfigError) as e:
        print(f"cellsim: error: {e}", file=sys.stderr)
        return EXIT_INPUT
    except OSError as e:  # an output path that cannot be written, a file that vanished
        where = f": {e.filename}" if e.filename else ""
        print(f"cellsim: error: {e.strerror or e}{where}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print("cellsim: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


@contextlib.contextmanager
def _interrupt_deferred():
    """Act on Ctrl-C only once the block is done (then as KeyboardInterrupt)."""
    interrupted = []
    previous = signal.signal(signal.SIGINT, lambda *_: interrupted.append(True))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if interrupted:
        raise KeyboardInterrupt


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cellsim",
        description="Scenario digital twins of collaborative robot cells: simulate them headless, "
        "record black boxes, and gather safety evidence.",
        epilog=EXIT_CODES,
    )
    from cellsim import __version__

    parser.add_argument("--version", action="version", version=f"cellsim {__version__}")
    sub = parser.add_subparsers(metavar="COMMAND")

    sim = sub.add_parser(
        "simulate",
        help="run a scenario headless and record its black box",
        description="Simulate a scenario (far faster than real time unless --meshcat) and write "
        "OUT/blackbox.sqlite (every message) and OUT/scenario.yaml (the resolved scenario). "
        "Exits 1 if a hazard reached its mishap phase or a safety condition does not hold on the run.",
    )
    sim.add_argument("scenario", type=Path, help="scenario YAML file")
    sim.add_argument("--duration", type=float, help="simulated seconds (default: the scenario's duration)")
    sim.add_argument("--seed", type=int, help="random seed (default: the scenario's seed)")
    sim.add_argument("--out", type=Path, help="output folder (default: runs/<scenario>-<date-time>)")
    sim.add_argument("--overwrite", action="store_true", help="replace a run already in --out")
    _add_set(sim)
    sim.add_argument(
        "--meshcat", action="store_true",
        help="show the cell in Meshcat (a browser, on localhost) at real-time speed; after the run, Enter closes it "
        "(without a terminal it closes when the run ends)",
    )
    sim.add_argument(
        "--meshcat-wait", type=float, default=None, metavar="SECONDS",
        help="with --meshcat: seconds to wait for a browser to open Meshcat before simulating anyway (default: 60 "
        "on a terminal, 0 without one, e.g. in a script; 0: do not wait)",
    )
    sim.add_argument("--quiet", action="store_true", help="print nothing but errors")
    sim.set_defaults(handler=cmd_simulate)

    chk = sub.add_parser(
        "check",
        help="check a run's black box against the safety conditions",
        description="Rebuild a run's trace from its black box and evaluate every safety condition "
        "and use-case classifier of the scenario's validation section. RUN is a run folder (as written "
        "by simulate) or a black-box file. Exits 0 if every condition holds, 1 if one is violated.",
    )
    chk.add_argument("run", type=Path, help="run folder or blackbox.sqlite")
    chk.add_argument(
        "--scenario", type=Path, help="check against this scenario's conditions (default: the run's scenario.yaml)"
    )
    chk.add_argument("--json", action="store_true", help="print the verdicts as JSON on standard output")
    chk.add_argument(
        "--export-trace", type=Path, metavar="FILE", help="also write the trace as JSON: {variable: [[t, value], ...]}"
    )
    chk.set_defaults(handler=cmd_check)

    camp = sub.add_parser(
        "campaign",
        help="simulate and check many sampled variants of a scenario",
        description="Draw --runs variants of the scenario from its samplers (campaign.samplers), simulate "
        "each in a worker process, check its safety conditions, use cases and coverage, and write "
        "OUT/results.json and OUT/report.html. Each run folder (OUT/runs/NNNN) holds copies of the files it "
        "used and re-runs alone. Re-running the same command on the same OUT resumes it (a larger --runs "
        "extends it) if its inputs are unchanged: the content of the scenario and of every file it uses, "
        "the overrides, seed, duration and cellsim's version. If one changed, the campaign refuses, naming "
        "it, unless --restart. "
        "Exits 1 if a condition does not hold on some run (violated, or missing data), 2 if a run could not be "
        "simulated (a sampled value out of range).",
    )
    camp.add_argument("scenario", type=Path, help="scenario YAML file")
    camp.add_argument("--runs", type=int, help="number of runs (default: the scenario's campaign.runs)")
    camp.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="worker processes (default: one per CPU)")
    camp.add_argument("--seed", type=int, default=0, help="campaign seed: run i is a pure function of it and i (default 0)")
    camp.add_argument("--out", type=Path, help="campaign folder (default: campaigns/<scenario>-seed<seed>)")
    camp.add_argument("--duration", type=float, help="simulated seconds per run (default: the scenario's duration)")
    camp.add_argument(
        "--restart",
        action="store_true",
        help="discard the runs already in OUT and start the campaign afresh; needed to reuse an OUT whose "
        "campaign had other inputs (an edited scenario, validation file, risk or robot model, other "
        "overrides, seed, duration or cellsim version), since runs of different inputs are never mixed",
    )
    _add_set(camp)
    camp.add_argument("--quiet", action="store_true", help="print nothing but errors")
    camp.set_defaults(handler=cmd_campaign)

    rep = sub.add_parser(
        "replay",
        help="play a recorded run in Meshcat (a browser), with a time slider",
        description="Rebuild the run's cell from its scenario.yaml and play its black box into a Meshcat recording: "
        "the robot's joints, the people, the light curtain, safety modes and scanner fields as recorded. Prints the "
        "Meshcat URL (localhost only), then serves until Enter on a terminal (exit 0), or Ctrl-C or SIGTERM (exit 130).",
    )
    rep.add_argument("run", type=Path, metavar="RUN", help="run folder (as written by simulate) or its blackbox.sqlite")
    rep.add_argument("--meshcat", action="store_true", help="play it in Meshcat (required: the browser player)")
    rep.add_argument(
        "--at", type=float, default=0.0, metavar="T",
        help="start the animation at T seconds of the run (default 0); the animation's time 0 is then T",
    )
    rep.add_argument("--speed", type=float, default=1.0, help="times real time (0.01 to 100, default 1)")
    rep.set_defaults(handler=cmd_replay)

    mods = sub.add_parser(
        "modules",
        help="list the module kinds a scenario can use, or describe one",
        description="Without KIND: every module kind (cellsim's and installed plug-ins'), its section and what it "
        "is. With KIND: its parameters (type, default, meaning), channels, physical-sample and command fields. "
        "Generated from the code's own declarations.",
    )
    mods.add_argument("kind", nargs="?", help="a kind to describe in full, e.g. robot")
    mods.add_argument("--json", action="store_true", help="print as JSON on standard output")
    mods.set_defaults(handler=cmd_modules)

    scenario = sub.add_parser("scenario", help="inspect scenario files", description="Inspect scenario files.")
    ssub = scenario.add_subparsers(metavar="ACTION")
    export = ssub.add_parser(
        "export",
        help="print the fully resolved scenario as YAML",
        description="Load a scenario, apply --set overrides, and write it back with every default "
        "filled in. Loading the export gives the same scenario.",
    )
    export.add_argument("scenario", type=Path, help="scenario YAML file")
    _add_set(export)
    export.add_argument("--out", type=Path, help="write to this file instead of standard output")
    export.set_defaults(handler=cmd_export)
    check = ssub.add_parser(
        "check",
        help="check a scenario without running it",
        description="Load and wire a scenario and compile its safety conditions; report the first problem.",
    )
    check.add_argument("scenario", type=Path, help="scenario YAML file")
    _add_set(check)
    check.set_defaults(handler=cmd_scenario_check)

    live = sub.add_parser(
        "live",
        help="run the twin in real time beside the real cell, on Zenoh",
        description="Run the scenario's twin paced to the wall clock. Entities in shadow or twin mode "
        "take their physical samples from Zenoh (cellsim/<cell>/physical/<entity>); commands of entities in "
        "twin mode are published (cellsim/<cell>/command/<entity>); every channel is published "
        "(cellsim/<cell>/twin/...). `cellsim twin-mode` switches an entity while it runs. The black box "
        "is recorded as in any run. Key space and formats: docs/live.md. By default it listens on "
        "tcp/127.0.0.1:7447, with multicast scouting off.",
    )
    live.add_argument("scenario", type=Path, help="scenario YAML file")
    _add_live_args(live, duration_default="until interrupted")
    live.add_argument(
        "--wait-physical", type=float, default=10.0, metavar="SECONDS",
        help="before starting the clock, wait this long at most for samples of every entity in shadow or twin mode (default 10)",
    )
    live.set_defaults(handler=cmd_live)

    emu = sub.add_parser(
        "emulate",
        help="play the physical cell in real time where no hardware is",
        description="Run the scenario's devices as their digital models, in real time, with the "
        "scenario's own safety controller, and publish each entity's state on its physical key in the "
        "format the twin reads. Keeps its own black box (the ground truth). By default it connects to "
        "tcp/127.0.0.1:7447.",
    )
    emu.add_argument("scenario", type=Path, help="scenario YAML file")
    _add_live_args(emu, duration_default="until interrupted")
    emu.add_argument(
        "--fault", action="append", default=[], metavar="ENTITY=KIND[@T0[-T1]]",
        help="inject a fault from simulated time T0 (default 0) to T1 (default: the end): silence, freeze, "
        "corrupt, delay or replay on Zenoh; drop, crc, replay, length, flood or delay for a device on CAN (repeatable)",
    )
    emu.add_argument(
        "--can", metavar="INTERFACE:CHANNEL",
        help="speak the real protocols: the cell's CAN devices send protected frames on this bus (e.g. "
        "remote:ws://127.0.0.1:54701/), its robot controllers stream their state, all for the bridge daemon",
    )
    emu.add_argument(
        "--bridge", type=Path, metavar="FILE",
        help="with --can: the bridge configuration naming the devices and their DBC "
        "(default: bridges/<scenario file name> beside the scenario's folder)",
    )
    emu.add_argument(
        "--commanded-by-twin", action="store_true",
        help="no safety controller of its own: the inputs it drove take the commands of the twin's entities in twin "
        "mode (with no command for stale_after, a safety-mode request reads stopped)",
    )
    emu.add_argument(
        "--rate", action="append", default=[], metavar="ENTITY=HZ",
        help="publish an entity's samples this often instead of once per update period, e.g. robot=500 (repeatable)",
    )
    emu.set_defaults(handler=cmd_emulate)

    bridge = sub.add_parser(
        "bridge",
        help="run the bridge daemon: a cell's CAN devices and robot controller to the twin and back",
        description="Map the CAN devices of a cell (a bridge configuration, e.g. bridges/welding_cell.yaml, and its "
        "DBC) and its robot controller's state stream to the twin's physical samples, checking every frame end to "
        "end, and send the twin's commands to the devices of entities in twin mode (safe ones when the twin is "
        "lost). Publishes each device's diagnostics on cellsim/<cell>/diagnostics/<entity>. Runs until interrupted "
        "(also as cellsim-bridge or python -m bridges).",
    )
    bridge.add_argument("bridge_config", type=Path, metavar="CONFIG", help="bridge configuration YAML file")
    bridge.add_argument("--can", metavar="INTERFACE:CHANNEL",
                        help="the CAN bus, e.g. socketcan:can0 (default: the configuration's)")
    _add_network_args(bridge)
    bridge.set_defaults(handler=cmd_bridge)

    dash = sub.add_parser(
        "dashboard",
        help="watch the cell in operation in the terminal (the running twin, or a recorded run)",
        description="A terminal dashboard of the running twin (found on the network, or --cell) or, with --replay, "
        "of a recorded run: safety modes, hazards, every entity's twin mode and link health with twin and physical "
        "values side by side, the robot, the safety conditions over the trace so far, the bridge daemon's "
        "diagnostics and an event log. Keys: m switches an entity's twin mode (with a confirmation), q quits.",
    )
    dash.add_argument("--cell", default=None, help="the running twin's cell (default: the first twin that answers)")
    dash.add_argument("--replay", type=Path, metavar="RUN", help="play a recorded run (a run folder or black box) instead")
    dash.add_argument("--speed", type=float, default=1.0, help="with --replay: times real time (default 1)")
    dash.add_argument("--start", type=float, default=0.0, help="with --replay: the simulated time to start from (s)")
    _add_network_args(dash)
    dash.set_defaults(handler=cmd_dashboard)

    mode = sub.add_parser(
        "twin-mode",
        help="switch an entity of the running twin to model, shadow or twin",
        description="Ask the running twin (cellsim live) to switch ENTITY to MODE. Prints the twin's "
        "answer; exits 0 if accepted, 2 if refused or if no twin answers.",
    )
    mode.add_argument("entity", help="an entity of the running twin, e.g. light_barrier")
    mode.add_argument("mode", help="model, shadow or twin")
    mode.add_argument("--cell", default=None, help="the cell's name (default: the only twin that answers)")
    _add_network_args(mode)
    mode.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the answer (default 5)")
    mode.set_defaults(handler=cmd_twin_mode)
    _end_with_exit_codes(parser)
    return parser


def _end_with_exit_codes(parser: argparse.ArgumentParser) -> None:
    """Every command's --help ends with the exit codes (a command's own description says when it exits 1)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                sub.epilog = sub.epilog or EXIT_CODES
                _end_with_exit_codes(sub)


def _add_network_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                        help="Zenoh endpoint to listen on, e.g. tcp/127.0.0.1:7447 (repeatable)")
    parser.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                        help="Zenoh endpoint to connect to (repeatable)")
    parser.add_argument("--config", type=Path, metavar="FILE", help="a Zenoh JSON5 configuration for anything more")


def _add_live_args(parser: argparse.ArgumentParser, duration_default: str) -> None:
    parser.add_argument("--out", type=Path, help="output folder (default: runs/<scenario>-<process>-<date-time>)")
    parser.add_argument("--duration", type=float, help=f"seconds to run (default: {duration_default})")
    parser.add_argument("--seed", type=int, help="random seed (default: the scenario's seed)")
    _add_set(parser)
    _add_network_args(parser)
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")


def _add_set(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="PATH=VALUE",
        help="override a configuration point, e.g. operator.waypoints.cell.wait=4 (repeatable)",
    )


def _load(args):
    from cellsim.scenario import load_scenario

    return load_scenario(args.scenario, args.overrides)


def _open_session(args, listen_by_default: bool, wait: float = 30.0):
    import zenoh

    from cellsim.live.session import session_config

    config = session_config(
        listen=args.listen, connect=args.connect, config_file=args.config, listen_by_default=listen_by_default, wait=wait
    )
    try:
        return zenoh.open(config)
    except Exception as e:  # noqa: BLE001 - zenoh raises ZError with a long text
        raise InputError(f"cannot open a Zenoh session (is the twin running?): {' '.join(str(e).split())[:200]}") from None


@contextlib.contextmanager
def _terminate_as_interrupt():
    """SIGTERM ends a live process as Ctrl-C does: the black box is closed cleanly."""
    def on_term(*_):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, on_term)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _live_run(args, process: str, listen_by_default: bool, run, check=None):
    from cellsim.scenario import MAX_DURATION, check_run_length, check_seed

    sf = _load(args)
    if check is not None:
        check(sf)  # before any session is opened
    duration = MAX_DURATION if args.duration is None else args.duration
    check_run_length(sf, duration, "--duration")
    if args.seed is not None:
        check_seed(args.seed, "--seed")
    out = args.out or Path("runs") / f"{sf.scenario.name}-{process}-{datetime.now():%Y%m%d-%H%M%S}"
    session = _open_session(args, listen_by_default)
    try:
        with _terminate_as_interrupt():
            return run(sf, out, session, duration)
    finally:
        session.close()


def cmd_live(args) -> int:
    from cellsim.live.twin import run_live

    def check(sf):
        if not 0.0 <= args.wait_physical <= 3600.0:
            raise InputError(f"--wait-physical {args.wait_physical:g}: expected 0 to 3600 seconds")

    def run(sf, out, session, duration):
        if not args.quiet:
            print(f"cellsim live: {sf.scenario.name} twin running, recording to {out}", file=sys.stderr)
        summary, _ = run_live(sf, out, session=session, duration=duration, seed=args.seed, wait_physical=args.wait_physical)
        return EXIT_FINDING if summary.mishap else EXIT_OK

    return _live_run(args, "twin", True, run, check)


def cmd_emulate(args) -> int:
    from bridges.devices import CAN_FAULTS
    from cellsim.live.emulator import FAULTS as ZENOH_FAULTS
    from cellsim.live.emulator import Fault, run_emulator

    FAULTS = (*ZENOH_FAULTS, *(k for k in CAN_FAULTS if k not in ZENOH_FAULTS))  # noqa: N806 - any outlet's kinds
    loaded = None
    if args.can:
        from bridges.config import load_bridge

        bridge = args.bridge or args.scenario.resolve().parent.parent / "bridges" / args.scenario.name
        if not bridge.is_file():
            raise InputError(f"--can needs the cell's bridge configuration (its devices and DBC): no {bridge}; "
                             "name it with --bridge FILE")
        loaded = load_bridge(bridge)
        _can_bus_spec(args.can, "--can")
    elif args.bridge:
        raise InputError("--bridge is for --can: name the CAN bus the devices speak on")
    faults = []
    for text in args.fault:
        entity, _, rest = text.partition("=")
        kind, _, window = rest.partition("@")
        start, _, end = window.partition("-")
        try:
            at, until = float(start) if start else 0.0, float(end) if end else float("inf")
        except ValueError:
            at = until = -1.0
        if not entity or kind not in FAULTS or not 0.0 <= at < until or at != at:
            raise InputError(
                f"--fault {text!r}: expected ENTITY=KIND[@T0[-T1]] (seconds, T0 < T1) with KIND one of {', '.join(FAULTS)}"
            )
        faults.append(Fault(entity, kind, at, until))

    rates = {}
    for text in args.rate:
        entity, _, hz = text.partition("=")
        try:
            value = float(hz)
        except ValueError:
            value = -1.0
        if not entity or not 0.1 <= value <= 1000.0:
            raise InputError(f"--rate {text!r}: expected ENTITY=HZ with HZ from 0.1 to 1000")
        rates[entity] = value

    def check(sf):
        unknown = [f.entity for f in faults if f.entity not in sf.scenario.entities]
        unknown += [e for e in rates if e not in sf.scenario.entities]
        if unknown:
            raise InputError(f"--fault/--rate: no entity named {unknown[0]!r} (entities: {', '.join(sf.scenario.entities)})")
        if loaded is not None:
            if loaded.config.cell != sf.scenario.name:
                raise InputError(f"--bridge {loaded.source}: it is the bridge of cell '{loaded.config.cell}', "
                                 f"not of '{sf.scenario.name}'")
            for f in faults:
                kinds = CAN_FAULTS if f.entity in loaded.config.devices else ZENOH_FAULTS
                if f.kind not in kinds:
                    raise InputError(f"--fault {f.entity}={f.kind}: {f.entity} is "
                                     f"{'a CAN device' if kinds is CAN_FAULTS else 'on Zenoh'}; its faults: {', '.join(kinds)}")
        elif any(f.kind not in ZENOH_FAULTS for f in faults):
            bad = next(f for f in faults if f.kind not in ZENOH_FAULTS)
            raise InputError(f"--fault {bad.entity}={bad.kind}: a bus fault needs --can; on Zenoh: {', '.join(ZENOH_FAULTS)}")

    def run(sf, out, session, duration):
        devices = bus = None
        if loaded is not None:
            from bridges.devices import EmulatedDevices

            bus = _open_can_bus(args.can)
            devices = EmulatedDevices(loaded, bus, session)
        try:
            if not args.quiet:
                on = f" on {args.can}" if bus is not None else ""
                print(f"cellsim emulate: playing the physical {sf.scenario.name}{on}, recording to {out}", file=sys.stderr)
            summary, _ = run_emulator(sf, out, session=session, duration=duration, seed=args.seed, faults=faults,
                                      commanded_by_twin=args.commanded_by_twin, rates=rates, devices=devices)
        finally:
            if bus is not None:
                bus.shutdown()
        return EXIT_FINDING if summary.mishap else EXIT_OK

    return _live_run(args, "emulator", False, run, check)


def _can_bus_spec(text: str, option: str) -> tuple[str, str]:
    """(interface, channel) of an INTERFACE:CHANNEL argument."""
    interface, sep, channel = text.partition(":")
    if not sep or not interface or not channel:
        raise InputError(f"{option} {text!r}: expected INTERFACE:CHANNEL, e.g. socketcan:can0")
    return interface, channel


def _open_can_bus(text: str | None, default: tuple[str, str] | None = None, option: str = "--can"):
    """A python-can bus for INTERFACE:CHANNEL (or the default pair), or one clear error."""
    import can

    interface, channel = _can_bus_spec(text, option) if text else default
    try:
        return can.Bus(interface=interface, channel=channel)
    except Exception as e:  # noqa: BLE001 - python-can raises many kinds for a bus it cannot open
        raise InputError(f"cannot open CAN bus {interface}:{channel}: {' '.join(str(e).split())[:200]}") from None


def cmd_bridge(args) -> int:
    import logging
    import threading

    from bridges.config import load_bridge
    from bridges.daemon import Bridge, run_bridge

    loaded = load_bridge(args.bridge_config)
    default = (loaded.config.can.interface, loaded.config.can.channel)
    interface, channel = _can_bus_spec(args.can, "--can") if args.can else default
    zenoh_settings = loaded.config.zenoh  # the command line's network options win over the configuration's
    if not args.connect and not args.listen:
        args.connect = list(zenoh_settings.connect)
    if args.config is None and zenoh_settings.config:
        args.config = loaded.source.parent / zenoh_settings.config
    bus = _open_can_bus(args.can, default)
    try:
        session = _open_session(args, listen_by_default=False)
        try:
            bridge = Bridge(loaded, session, bus=bus)
            stop = threading.Event()
            logging.basicConfig(level=logging.INFO, format="cellsim bridge: %(message)s", stream=sys.stderr)
            print(f"cellsim bridge: {loaded.config.cell} on {interface}:{channel}", file=sys.stderr)
            with _terminate_as_interrupt():
                try:
                    run_bridge(bridge, bus, stop)
                finally:
                    bridge.close()
        finally:
            session.close()
    finally:
        bus.shutdown()
    return EXIT_OK


def cmd_dashboard(args) -> int:
    import math

    from cellsim.dashboard.app import Dashboard
    from cellsim.dashboard.feeds import LiveFeed, ReplayFeed

    if not (math.isfinite(args.speed) and 0.01 <= args.speed <= 1000.0):
        raise InputError(f"--speed {args.speed:g}: expected from 0.01 to 1000 times real time")
    if not (math.isfinite(args.start) and args.start >= 0.0):
        raise InputError(f"--start {args.start:g}: expected a time from 0 s")
    if args.replay is not None:
        from cellsim.services.blackbox import BlackBoxError
        from cellsim.validation.check import CheckError

        try:
            feed = ReplayFeed(args.replay, args.speed, args.start)
        except (CheckError, BlackBoxError) as e:
            raise InputError(str(e)) from None
        Dashboard(feed).run()
        return EXIT_OK
    from cellsim.live.session import session_config

    config = dict(listen=args.listen, connect=args.connect, config_file=args.config, listen_by_default=False, wait=2.0)
    session_config(**config)  # a bad endpoint or configuration file: one line, exit 2, before the screen opens

    def open_session():
        import zenoh

        return zenoh.open(session_config(**config))

    feed = LiveFeed(open_session, args.cell)  # waits for a twin to be reachable, saying so
    try:
        Dashboard(feed).run()
    finally:
        feed.close()
    return EXIT_OK


def cmd_twin_mode(args) -> int:
    import json

    from cellsim.live import keys

    try:
        session = _open_session(args, listen_by_default=False, wait=args.timeout)
    except InputError:
        print(f"cellsim: error: no running twin reachable within {args.timeout:g} s", file=sys.stderr)
        return EXIT_INPUT
    try:
        selector = keys.twin_mode_control(args.cell) if args.cell else f"{keys.ROOT}/*/control/twin_mode"
        request = json.dumps({"entity": args.entity, "mode": args.mode, "by": f"cellsim twin-mode ({session.zid()})"})
        answers = []
        for reply in session.get(selector, payload=request, timeout=args.timeout):
            if reply.ok is not None:
                answers.append(json.loads(reply.ok.payload.to_bytes()))
    finally:
        session.close()
    if not answers:
        print(f"cellsim: error: no running twin answered on {selector} within {args.timeout:g} s", file=sys.stderr)
        return EXIT_INPUT
    answer = answers[0]
    print(("accepted: " if answer.get("accepted") else "refused: ") + str(answer.get("reason", "")))
    return EXIT_OK if answer.get("accepted") else EXIT_INPUT


def cmd_simulate(args) -> int:
    from rich.console import Console

    from cellsim.simulation import simulate

    from cellsim.scenario import check_run_length, check_seed

    sf = _load(args)
    if args.duration is not None:
        check_run_length(sf, args.duration, "--duration")
    if args.seed is not None:
        check_seed(args.seed, "--seed")
    out = args.out or Path("runs") / f"{sf.scenario.name}-{datetime.now():%Y%m%d-%H%M%S}"
    console = Console(stderr=True, quiet=args.quiet)
    meshcat = on_start = None
    if args.meshcat:
        from cellsim.visual.serve import WAIT_DEFAULT, open_meshcat, wait_for_browser

        wait = args.meshcat_wait
        if wait is None:
            wait = WAIT_DEFAULT if sys.stdin is not None and sys.stdin.isatty() else 0.0
        if not (0.0 <= wait <= 3600.0):
            raise InputError(f"--meshcat-wait {wait:g}: expected 0 to 3600 seconds")
        meshcat = open_meshcat()
        console.print(f"Meshcat: [link={meshcat.web_url()}]{meshcat.web_url()}[/link]")
        on_start = lambda: wait_for_browser(meshcat, wait, console.print)  # noqa: E731
    try:
        with _progress(console, args.quiet) as report:
            summary = simulate(
                sf,
                out,
                seed=args.seed,
                duration=args.duration,
                overwrite=args.overwrite,
                meshcat=meshcat,
                realtime_rate=1.0 if meshcat else 0.0,
                on_progress=report,
                on_start=on_start,
            )
        checked = _check_of(summary)
        if not args.quiet:
            print_summary(summary, checked)
        if meshcat is not None and sys.stdin is not None and sys.stdin.isatty():
            from cellsim.visual.serve import serve_until_closed

            serve_until_closed(meshcat, console.print)
    finally:
        if meshcat is not None:
            del meshcat
    return EXIT_FINDING if summary.mishap or (checked is not None and not checked.all_hold) else EXIT_OK


def cmd_replay(args) -> int:
    from cellsim.visual.serve import cmd_replay as replay

    with _terminate_as_interrupt():  # from the start: a SIGTERM right after the URL is printed ends it as Ctrl-C does
        return replay(args, InputError)


class _progress:
    """A transient progress bar of simulated time on an interactive terminal."""

    def __init__(self, console, quiet: bool):
        self.console, self.enabled = console, not quiet and console.is_terminal
        self.bar = None

    def __enter__(self):
        if not self.enabled:
            return None
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        self.bar = Progress(
            TextColumn("simulating"), BarColumn(), TextColumn("{task.completed:.0f}/{task.total:.0f} s"),
            TimeElapsedColumn(), console=self.console, transient=True,
        )
        self.bar.start()
        self.task = None
        return self.report

    def report(self, t: float, total: float) -> None:
        if self.task is None:
            self.task = self.bar.add_task("sim", total=total)
        self.bar.update(self.task, completed=t)

    def __exit__(self, *exc):
        if self.bar is not None:
            self.bar.stop()


def _check_of(summary):
    """The run's check result, or None when the scenario has no safety conditions."""
    from cellsim.services.blackbox import BlackBox
    from cellsim.simulation import BLACKBOX
    from cellsim.validation.traces import trace_of_run

    case = summary.safety_case
    if case is None:
        return None
    with BlackBox(Path(summary.out_dir) / BLACKBOX) as bb:
        run = trace_of_run(bb, case.validation.variables)
    return case.check(run.trace, complete=run.complete)


def print_summary(summary, checked=None) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console()
    table = Table(title=f"Run {summary.out_dir}", show_header=False, title_justify="left")
    table.add_column(style="bold")
    table.add_column()
    table.add_row("status", summary.status)
    table.add_row("seed", str(summary.seed))
    table.add_row("work cycles completed", str(summary.cycles_completed))
    for name, counts in summary.hazards.items():
        verdict = f"raised {counts.raised}, handled {counts.handled}"
        if counts.mishaps:
            verdict += f", [red]MISHAPS {counts.mishaps}[/red]"
        table.add_row(f"hazard {name}", verdict)
    table.add_row("final safety mode", summary.final_safety_mode or "-")
    if checked is not None:
        line = _conditions_line(checked)
        table.add_row("safety conditions", line if checked.all_hold else f"{line} (details: cellsim check {summary.out_dir})")
        table.add_row("use cases exercised", ", ".join(checked.use_cases) or "none")
    table.add_row("simulated time", measure(summary.sim_time, "s"))
    table.add_row("wall time", measure(summary.wall_time, "s"))
    table.add_row("real-time factor", measure(summary.real_time_factor, "x"))
    table.add_row("black box", str(Path(summary.out_dir) / "blackbox.sqlite"))
    console.print(table)


def cmd_check(args) -> int:
    import json

    from cellsim.scenario import load_scenario
    from cellsim.services.blackbox import BlackBoxError
    from cellsim.validation.check import CheckError, check_run
    from cellsim.validation.config import description_of
    from cellsim.validation.traces import TraceError, write_trace_json

    try:
        sf = load_scenario(args.scenario) if args.scenario else None
        checked = check_run(args.run, sf)
    except (CheckError, BlackBoxError, TraceError) as e:
        raise InputError(str(e)) from None
    result = checked.result
    if args.export_trace:
        write_trace_json(checked.trace, args.export_trace)
    if args.json:
        json.dump(
            {
                "run": str(args.run),
                "holds": result.all_hold,
                "complete": checked.trace.complete,
                "verdicts": result.verdicts_json(),
                "descriptions": {n: description_of(c) for n, c in {**checked.case.validation.conditions,
                                                                      **checked.case.validation.use_cases}.items()
                                 if description_of(c)},
                "violations": result.violations,
                "undecided": result.undecided,
                "use_cases": result.use_cases,
                "coverage": result.coverage,
            },
            sys.stdout,
            indent=2,
        )
        sys.stdout.write("\n")
    else:
        print_verdicts(args.run, checked)
    return EXIT_OK if result.all_hold else EXIT_FINDING


def print_verdicts(run: Path, checked) -> None:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from cellsim.validation.config import description_of, formula_of

    result, conditions = checked.result, checked.case.validation.conditions
    table = Table(title=f"Safety conditions on {run}", title_justify="left")
    table.add_column("condition", style="bold")
    table.add_column("verdict")
    table.add_column("first violation")
    table.add_column("formula", style="dim")
    for name, verdict in result.verdicts.items():
        mark = {"holds": "[green]holds[/green]", "violated": "[red]VIOLATED[/red]"}.get(
            verdict.status, f"[yellow]{verdict.describe()}[/yellow]"
        )
        when = "" if verdict.violated_at is None or verdict.holds else f"t = {instant(verdict.violated_at)}"
        description = description_of(conditions[name])
        table.add_row(name, mark, when,
                      escape(formula_of(conditions[name])) + (f"\n[italic]{escape(description)}[/italic]" if description else ""))
    console = Console()
    if not checked.trace.complete:
        console.print(
            f"[yellow]the run did not complete: its record ends at t = {instant(checked.trace.trace.end)}; "
            "verdicts that a longer run could change are inconclusive[/yellow]"
        )
    console.print(table)
    for name, verdict in result.verdicts.items():  # pytest-style: each violation and why
        if verdict.explanation:
            console.print(f"[red]{escape(name)}[/red] violated at {instant(verdict.violated_at)}: {escape(verdict.explanation)}",
                          highlight=False)
    use_cases = checked.case.validation.use_cases
    console.print(f"use cases exercised: {', '.join(result.use_cases) or 'none'}")
    for name in result.use_cases:
        if description_of(use_cases[name]):
            console.print(f"  {escape(name)}: [italic]{escape(description_of(use_cases[name]))}[/italic]", highlight=False)
    console.print(_conditions_line(result))


def _conditions_line(result) -> str:
    """'all 14 conditions hold', or what keeps them from holding."""
    total = len(result.verdicts)
    if result.all_hold:
        return f"all {total} conditions hold"
    parts = []
    if result.violations:
        parts.append(f"[red]{len(result.violations)} of {total} conditions violated: {', '.join(result.violations)}[/red]")
    if result.undecided:
        parts.append(f"[yellow]{len(result.undecided)} undecided (inconclusive or missing data): {', '.join(result.undecided)}[/yellow]")
    return "; ".join(parts)


def cmd_campaign(args) -> int:
    from rich.console import Console

    from cellsim.campaign.runner import CampaignError, CampaignPlan, run_campaign

    for flag, most in (("runs", 100_000), ("jobs", 256)):
        value = getattr(args, flag)
        if value is not None and not 1 <= value <= most:
            raise InputError(f"--{flag} must be in [1, {most}], got {value}")
    from cellsim.scenario import check_run_length, check_seed

    check_seed(args.seed, "--seed")
    sf = _load(args)
    if args.duration is not None:
        check_run_length(sf, args.duration, "--duration")
    runs = args.runs or sf.scenario.campaign.runs
    out = args.out or Path("campaigns") / f"{sf.scenario.name}-seed{args.seed}"
    plan = CampaignPlan(str(args.scenario.resolve()), tuple(args.overrides), args.seed, runs, args.duration)
    console = Console(stderr=True, quiet=args.quiet)
    try:
        with _campaign_progress(console, args.quiet, runs) as report:
            outcome = run_campaign(plan, out, jobs=args.jobs, on_progress=report, restart=args.restart)
    except CampaignError as e:
        raise InputError(str(e)) from None
    except KeyboardInterrupt:
        print(f"cellsim: interrupted; finished runs are kept in {out}: run the same command again to resume", file=sys.stderr)
        return EXIT_INTERRUPTED
    if not args.quiet:
        print_campaign(outcome)
    failed = [r for r in outcome.results["runs"] if r.get("status") == "failed"]
    if failed:
        print(
            f"cellsim: error: {len(failed)} of {len(outcome.results['runs'])} runs failed, e.g. run {failed[0]['index']}: "
            f"{failed[0].get('error', '?')} (all in {outcome.results_path})",
            file=sys.stderr,
        )
        return EXIT_INPUT
    return EXIT_FINDING if outcome.violating_runs or outcome.results["totals"]["undecided_runs"] else EXIT_OK


class _campaign_progress:
    """A progress bar of runs done, with violations and coverage so far."""

    def __init__(self, console, quiet: bool, total: int):
        self.console, self.quiet, self.total = console, quiet, total
        self.bar = None

    def __enter__(self):
        if self.quiet:
            return None
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

        self.bar = Progress(
            TextColumn("runs"), BarColumn(), MofNCompleteColumn(),
            TextColumn("violating {task.fields[violating]}  failed {task.fields[failed]}  coverage {task.fields[coverage]}"),
            TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(), console=self.console,
        )
        self.bar.start()
        self.task = self.bar.add_task("campaign", total=self.total, violating=0, failed=0, coverage=percent(0.0))
        return self.report

    def report(self, p) -> None:
        self.bar.update(self.task, completed=p.done, violating=p.violating_runs, failed=p.failed, coverage=percent(p.coverage))

    def __exit__(self, *exc):
        if self.bar is not None:
            self.bar.stop()


def print_campaign(outcome) -> None:
    from rich.console import Console
    from rich.table import Table

    totals, timing = outcome.results["totals"], outcome.timing
    console = Console()
    table = Table(title="Campaign", show_header=False, title_justify="left")
    table.add_column(style="bold")
    table.add_column()
    table.add_row("runs", f"{totals['runs']} ({outcome.resumed} resumed, {totals['failed']} failed)")
    runs_of = {c: [r["index"] for r in outcome.results["runs"] if c in r.get("violations", ())] for c in totals["violations"]}
    bad = {c: runs for c, runs in runs_of.items() if runs}
    undecided = {c: [r["index"] for r in outcome.results["runs"] if c in r.get("undecided", ())] for c in totals["violations"]}
    undecided = {c: runs for c, runs in undecided.items() if runs}
    table.add_row(
        "violating runs",
        f"[red]{totals['violating_runs']}[/red]\n" + "\n".join(f"{c}: {_run_list(runs)}" for c, runs in bad.items())
        if bad else ("none" if undecided or totals["failed"] else "none: every condition holds in every run"),
    )
    if undecided:
        table.add_row(
            "undecided (inconclusive or missing data)",
            "[yellow]" + "\n".join(f"{c}: {_run_list(runs)}" for c, runs in undecided.items()) + "[/yellow]",
        )
    table.add_row("use cases", ", ".join(f"{u} {n}" for u, n in totals["use_cases"].items()) or "-")
    table.add_row("coverage", f"{percent(totals['coverage']['overall']['fraction'])} of situations")
    table.add_row("time per stage", ", ".join(f"{k} {measure(v, 's')}" for k, v in timing.items()))
    inputs = (outcome.results.get("provenance") or {}).get("inputs") or {}
    if inputs:
        table.add_row("inputs", f"content hash {inputs['hash'][:16]} ({len(inputs['files'])} files, snapshot in {outcome.results_path.parent / 'inputs'})")
    table.add_row("results", str(outcome.results_path))
    table.add_row("report", str(outcome.report_path))
    console.print(table)


def _run_list(indices: list[int], shown: int = 8) -> str:
    listed = ", ".join(str(i) for i in indices[:shown])
    more = f" and {len(indices) - shown} more" if len(indices) > shown else ""
    return f"{len(indices)} run{'s' if len(indices) > 1 else ''} ({listed}{more})"


def cmd_export(args) -> int:
    from cellsim.scenario import export_scenario

    sf = _load(args)
    if args.out is None:
        sys.stdout.write(export_scenario(sf))
    else:
        from cellsim.atomic import write_text

        write_text(args.out, export_scenario(sf, destination_dir=args.out.resolve().parent))
    return EXIT_OK


def cmd_scenario_check(args) -> int:
    from cellsim.validation.check import scenario_safety_case

    sf = _load(args)
    case = scenario_safety_case(sf)  # builds and wires the diagram, then compiles the formulas
    print(
        f"{args.scenario}: ok ({len(case.conditions)} safety conditions, {len(case.use_cases)} use cases, "
        f"{len(sf.scenario.validation.coverage)} coverage criteria)"
    )
    return EXIT_OK


def cmd_modules(args) -> int:
    import json

    from rich.console import Console
    from rich.markup import escape as e
    from rich.table import Table

    from cellsim import kinds_doc, registry

    console = Console()
    if args.kind is None:
        kinds, errors = kinds_doc.catalogue()
        if args.json:
            json.dump({"kinds": kinds, "errors": errors}, sys.stdout, indent=2)
            sys.stdout.write("\n")
        else:
            table = Table(title="Module kinds (cellsim modules KIND for one in full)", title_justify="left")
            for column in ("kind", "section", "what it is"):
                table.add_column(column, style="bold" if column == "kind" else None)
            for k in kinds:
                table.add_row(e(k["kind"]), k["section"], e(k["summary"]))
            console.print(table)
            for error in errors:
                console.print(f"[yellow]not available: {e(error)}[/yellow]")
        return EXIT_OK
    try:
        info = kinds_doc.describe(args.kind)
    except registry.KindError as error:
        from cellsim.config.typed_yaml import suggest

        known = registry.kind_names()
        raise InputError(f"{error}" + (suggest(args.kind, known) or f" (known: {', '.join(known)})")) from None
    if args.json:
        json.dump(info, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return EXIT_OK
    console.print(f"[bold]{e(info['kind'])}[/bold] ({info['section']}): {e(info['summary'])}")
    params = Table(title="parameters", title_justify="left")
    for column in ("name", "type", "default", "valid range", "meaning"):
        params.add_column(column, style="bold" if column == "name" else None)
    for p in info["parameters"]:
        params.add_row(e(p["name"]), e(p["type"]), e(p["default"]), e(p["range"]), e(p["doc"]))
    console.print(params)
    if info["channels"]:
        channels = Table(title=f"channels ({info['kind']} module NAME publishes NAME.signal)", title_justify="left")
        for column in ("signal", "type", "meaning"):
            channels.add_column(column, style="bold" if column == "signal" else None)
        for c in info["channels"]:
            channels.add_row(e(c["signal"]), e(c["type"]), e(c["meaning"]))
        console.print(channels)
    if info["physical_sample_fields"]:
        console.print("physical sample fields (shadow and twin mode): " + e(", ".join(info["physical_sample_fields"])))
    if info["command_fields"]:
        console.print("command fields (sent to the physical twin in twin mode): " + e(", ".join(info["command_fields"])))
    if info["files"]:
        console.print("file parameters (relative to the scenario): " + e(", ".join(info["files"])))
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())


def bridge_main(argv: list[str] | None = None) -> int:
    """``cellsim-bridge`` and ``python -m bridges``: the bridge daemon on its own (as ``cellsim bridge``)."""
    return main(["bridge", *(sys.argv[1:] if argv is None else argv)])
