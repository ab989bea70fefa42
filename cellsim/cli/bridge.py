"""``cellsim bridge`` (also ``cellsim-bridge``, ``python -m cellsim.bridges``): the bridge daemon."""

from __future__ import annotations

import sys
from pathlib import Path

from cellsim.cli.common import (
    EXIT_OK,
    InputError,
    _add_network_args,
    _can_key,
    _can_bus_spec,
    _open_can_bus,
    _open_session,
    _plc_certificates,
    _rtde_robot,
    _terminate_as_interrupt,
)


def add_parser(subparsers) -> None:
    bridge = subparsers.add_parser(
        "bridge",
        help="run the bridge daemon: a cell's CAN devices and robot controller to the twin and back",
        description="Map the CAN devices of a cell (a bridge configuration, e.g. bridges/welding_cell.yaml, and its "
        "DBC) and its robot controller's state stream to the twin's physical samples, checking every frame end to "
        "end, and send the twin's commands to the devices of entities in twin mode (safe ones when the twin is "
        "lost). Publishes each device's diagnostics on cellsim/<cell>/diagnostics/<entity>. Runs until interrupted "
        "(also as cellsim-bridge or python -m cellsim.bridges).",
    )
    bridge.add_argument("bridge_config", type=Path, metavar="CONFIG", help="bridge configuration YAML file")
    bridge.add_argument("--can", metavar="INTERFACE:CHANNEL",
                        help="the CAN bus, e.g. socketcan:can0 (default: the configuration's)")
    bridge.add_argument("--rtde", metavar="[HOST:]PORT", type=_rtde_address,
                        help="where the robot's UR controller serves RTDE (default: the configuration's rtde.host and "
                        "rtde.port); for a configuration with one robot over RTDE")
    bridge.add_argument("--opcua", metavar="opc.tcp://HOST:PORT",
                        help="where the PLC serves OPC UA (default: the configuration's plc.endpoint)")
    _add_network_args(bridge)
    bridge.set_defaults(handler=run)


def _rtde_address(text: str) -> tuple[str | None, int]:
    import argparse

    from cellsim.bridges.config import bad_host

    host, sep, port = text.rpartition(":")
    if not port.isdigit() or not 1 <= int(port) <= 65535 or (sep and not host):
        raise argparse.ArgumentTypeError(f"expected [HOST:]PORT, e.g. 127.0.0.1:30004, got {text!r}")
    why = bad_host(host) if host else None
    if why is not None:
        raise argparse.ArgumentTypeError(why)
    return (host or None), int(port)


def run(args) -> int:
    import logging
    import threading

    from cellsim.bridges.config import load_bridge
    from cellsim.bridges.daemon import Bridge, run_bridge

    loaded = load_bridge(args.bridge_config)
    can_key = _can_key(args, loaded)
    if args.rtde is not None:
        settings = loaded.config.robots[_rtde_robot(loaded)].rtde
        settings.host = args.rtde[0] or settings.host
        settings.port = args.rtde[1]
    if args.opcua is not None:
        if loaded.config.plc is None:
            raise InputError(f"--opcua: {args.bridge_config} names no PLC")
        from cellsim.bridges.config import bad_endpoint

        why = bad_endpoint(args.opcua)
        if why is not None:
            raise InputError(f"--opcua: {why}")
        loaded.config.plc.endpoint = args.opcua
    plc_certificates = _plc_certificates(args, loaded, "bridge")
    default = (loaded.config.can.interface, loaded.config.can.channel)
    interface, channel = _can_bus_spec(args.can, "--can") if args.can else default
    zenoh_settings = loaded.config.zenoh  # the command line's network options win over the configuration's
    if not args.connect and not args.listen:
        args.connect = list(zenoh_settings.connect)
    if args.config is None and zenoh_settings.config:
        args.config = loaded.source.parent / zenoh_settings.config
    bus = _open_can_bus(args.can, default)
    for line in loaded.e2e_only():  # an explicit choice of the configuration, said at every start
        print(f"cellsim bridge: warning: not authenticated, E2E only (forgeable by anyone on the bus): {line}",
              file=sys.stderr)
    if loaded.config.plc is not None and loaded.config.plc.security == "none":
        print(f"cellsim bridge: warning: the PLC is read WITHOUT security (anyone on its network can read and forge "
              f"its values): {loaded.config.plc.insecure_because}", file=sys.stderr)
    try:
        session = _open_session(args, "bridge", listen_by_default=False)
        try:
            bridge = Bridge(loaded, session, bus=bus, can_key=can_key, plc_certificates=plc_certificates)
            stop = threading.Event()
            logging.basicConfig(level=logging.INFO, format="cellsim bridge: %(message)s", stream=sys.stderr)
            controllers = "".join(f", {name} over RTDE at {robot.rtde.host}:{robot.rtde.port}"
                                  for name, robot in loaded.config.robots.items() if robot.rtde is not None)
            if loaded.config.plc is not None:
                controllers += f", a PLC at {loaded.config.plc.endpoint} ({', '.join(loaded.config.plc.entities)})"
            print(f"cellsim bridge: {loaded.cell} on {interface}:{channel}{controllers}", file=sys.stderr)
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
