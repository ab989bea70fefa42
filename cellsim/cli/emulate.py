"""``cellsim emulate``: play the physical cell in real time where no hardware is.

The grammar of ``--fault`` and ``--rate`` and the rules for which fault applies where are
``cellsim.live.faults``'s, beside the emulator; here they become input errors (exit 2).
"""

from __future__ import annotations

import sys
from pathlib import Path

from cellsim.cli.common import (
    EXIT_FINDING,
    EXIT_OK,
    InputError,
    _add_live_args,
    _can_bus_spec,
    _can_key,
    _live_run,
    _open_can_bus,
    _plc_certificates,
    _port,
    _rtde_robot,
    _with_port,
)


def add_parser(subparsers) -> None:
    emu = subparsers.add_parser(
        "emulate",
        help="play the physical cell in real time where no hardware is",
        description="Run the scenario's devices as their digital models, in real time, with the "
        "scenario's own safety controller, and publish each entity's state on its physical key in the "
        "format the twin reads. Keeps its own black box (the ground truth). By default it connects to "
        "tls/127.0.0.1:7447 with the emulator's certificate (docs/security.md).",
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
        "--rtde", type=_port, metavar="PORT",
        help="speak the real protocols, the robot as a UR controller: its RTDE server on this port of the "
        "configuration's host (127.0.0.1 by default; a real controller's is 30004), for the bridge daemon or any "
        "RTDE client (docs/ur.md); the CAN devices on --can or the configuration's bus",
    )
    emu.add_argument(
        "--opcua", type=_port, metavar="PORT",
        help="speak the real protocols, the configuration's PLC as an OPC UA server on this port of its endpoint's "
        "host (docs/opcua.md)",
    )
    emu.add_argument(
        "--bridge", type=Path, metavar="FILE",
        help="with --can, --rtde or --opcua: the bridge configuration naming the devices, their DBC and the robot's "
        "controller (default: bridges/<scenario file name> beside the scenario's folder)",
    )
    emu.add_argument(
        "--commanded-by-twin", action="store_true",
        help="no safety controller of its own: the inputs it drove take the commands of the twin's entities in twin "
        "mode (with no command for stale_after, a safety-mode request reads stopped)",
    )
    emu.add_argument(
        "--rate", action="append", default=[], metavar="ENTITY=HZ",
        help="run an entity's device this often: its samples are published at this rate instead of once per update "
        "period, and a rate faster than its update period runs the emulated device at it too (robot=500: a UR "
        "controller's 500 Hz cycle, which takes a command within 4 ms) (repeatable)",
    )
    emu.set_defaults(handler=run)


def _devices_at_their_rates(sf, rates: dict[str, float]) -> None:
    """An entity given a rate faster than its update period is emulated at that rate (its ``period``, rounded to the
    plant step): a real device publishing that often also works that often, so a robot emulated at a UR controller's
    500 Hz takes the twin's command within two of its 2 ms cycles (its command source drains as it updates), not at
    the twin's model's 20 ms update. The twin's own model of the entity keeps the scenario's period. Each such change
    is added to the scenario's overrides, so the run's provenance and metadata say so."""
    import dataclasses

    step = sf.scenario.time_step
    for name, hz in rates.items():
        cfg = sf.scenario.entities[name]
        period = max(step, round(1.0 / hz / step) * step)
        if period < (getattr(cfg, "period", None) or 0.0):
            sf.scenario.entities[name] = dataclasses.replace(cfg, period=period)
            sf.overrides.append(f"{name}.period={period:g}")


def run(args) -> int:
    from cellsim.cell_io import Emulated, FaultSchedule
    from cellsim.simulation import simulate
    from cellsim.live.faults import FaultError, check_entities, check_faults, parse_fault, parse_rate

    loaded = bridge = can_key = None
    if args.can or args.rtde or args.opcua:
        option = "--can" if args.can else "--rtde" if args.rtde else "--opcua"
        bridge = args.bridge or args.scenario.resolve().parent.parent / "bridges" / args.scenario.name
        if not bridge.is_file():
            raise InputError(f"{option} needs the cell's bridge configuration (its devices, DBC and controllers): "
                             f"no {bridge}; name it with --bridge FILE")
        if args.can:
            _can_bus_spec(args.can, "--can")
    elif args.bridge:
        raise InputError("--bridge is for --can, --rtde or --opcua: name the CAN bus, RTDE or OPC UA port the devices "
                         "speak on")
    try:
        faults = [parse_fault(text) for text in args.fault]
        rates = dict(parse_rate(text) for text in args.rate)
    except FaultError as e:
        raise InputError(str(e)) from None

    def check(sf):
        nonlocal loaded, can_key
        entities = sf.scenario.entities
        if bridge is not None:  # loaded with this scenario: its devices must be this cell's entities
            from cellsim.bridges.config import load_bridge
            from cellsim.bridges.devices import protocols_of

            loaded = load_bridge(bridge, sf)
            can_key = _can_key(args, loaded)
            if args.rtde:
                _rtde_robot(loaded)
            if args.opcua and loaded.config.plc is None:
                raise InputError(f"--opcua: {bridge} names no PLC")
        try:
            check_entities(faults, rates, entities)
            _devices_at_their_rates(sf, rates)
            check_faults(faults, entities, set(loaded.config.devices) if loaded is not None else None,
                         protocols_of(loaded.config) if loaded is not None else None)
        except FaultError as e:
            raise InputError(str(e)) from None

    def emulator(sf, out, session, duration):
        devices = bus = None
        if loaded is not None:
            from cellsim.bridges.devices import EmulatedDevices

            cfg = loaded.config
            if cfg.devices or cfg.commands:
                bus = _open_can_bus(args.can, (cfg.can.interface, cfg.can.channel))
            plc = loaded.config.plc
            endpoint = _with_port(plc.endpoint, args.opcua) if plc is not None and args.opcua else None
            try:
                certificates = _plc_certificates(args, loaded, "plc")
                devices = EmulatedDevices(loaded, bus, session, can_key, rtde_port=args.rtde, opcua_endpoint=endpoint,
                                          plc_certificates=certificates)
            except OSError as e:
                if bus is not None:
                    bus.shutdown()
                raise InputError(f"cannot serve the devices' protocols: {e}") from None
        try:
            if not args.quiet:
                on = f" on {args.can}" if args.can else ""
                for name, controller in (devices.controllers.items() if devices is not None else ()):
                    host, port = controller.server.address
                    on += f", {name} as a UR controller on RTDE {host}:{port}"
                if devices is not None and devices.plc is not None:
                    on += f", its PLC on {devices.plc.endpoint}"
                print(f"cellsim emulate: playing the physical {sf.scenario.name}{on}, recording to {out}", file=sys.stderr)
            io = Emulated(session, args.commanded_by_twin, rates, devices, FaultSchedule(list(faults)))
            summary = simulate(sf, out, io=io, seed=args.seed, duration=duration)
        finally:
            if bus is not None:
                bus.shutdown()
        return EXIT_FINDING if summary.mishap else EXIT_OK

    return _live_run(args, "emulator", False, emulator, check)

