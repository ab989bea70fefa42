"""What the commands of ``cellsim`` share: exit codes, the input error, common options and helpers.

Light to import: ``cellsim --help`` and ``--version`` load this and every command's module, and
none of them may pull in Drake, Zenoh or rich at import time (each imports those in the
function that needs them).
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
from datetime import datetime
from pathlib import Path

EXIT_OK, EXIT_FINDING, EXIT_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130
EXIT_CODES = "Exit codes: 0 ok, 1 safety finding, 2 usage or input error, 130 interrupted (Ctrl-C or SIGTERM)."


class InputError(Exception):
    """Bad input found by the CLI itself (the message is the whole story)."""


@contextlib.contextmanager
def _interrupt_deferred():
    """Act on Ctrl-C or SIGTERM only once the block is done (then as KeyboardInterrupt)."""
    interrupted = []
    previous = {sig: signal.signal(sig, lambda *_: interrupted.append(True)) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if interrupted:
        raise KeyboardInterrupt


@contextlib.contextmanager
def _terminate_as_interrupt():
    """SIGTERM (a batch scheduler stopping a job, ``kill``) ends a command as Ctrl-C does: a black box is
    closed with its status, a campaign keeps its finished runs, and the exit code is 130."""
    def on_term(*_):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, on_term)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _end_with_exit_codes(parser: argparse.ArgumentParser) -> None:
    """Every command's --help ends with the exit codes (a command's own description says when it exits 1)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                sub.epilog = sub.epilog or EXIT_CODES
                _end_with_exit_codes(sub)


def _add_set(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="PATH=VALUE",
        help="override a configuration point, e.g. operator.waypoints.cell.wait=4 (repeatable)",
    )


def _add_network_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                        help="Zenoh endpoint to listen on, e.g. tls/127.0.0.1:7447 (repeatable)")
    parser.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                        help="Zenoh endpoint to connect to (repeatable)")
    parser.add_argument("--config", type=Path, metavar="FILE", help="a Zenoh JSON5 configuration for anything more")
    parser.add_argument("--keys", type=Path, metavar="DIR",
                        help="the cell's keys: its CA and this process's certificate for mutual TLS, and the CAN "
                        "key of authenticated frames (default: $CELLSIM_KEYS, else ~/.config/cellsim/keys, created "
                        "on first use; see cellsim keys init)")
    parser.add_argument("--insecure", action="store_true",
                        help="plain TCP without TLS, authentication or access control, on loopback only "
                        "(a demo or a test; any local process can then publish samples and switch twin modes)")


def _network_security(args, role: str) -> dict:
    """The session's ``role``, ``keys`` and ``insecure`` (:func:`cellsim.live.session.session_config`);
    creates the default keys on first use, and says so on stderr."""
    from cellsim.live import pki

    if args.insecure:
        return {"role": role, "keys": None, "insecure": True}
    folder = args.keys if args.keys is not None else pki.default_keys_dir()
    if args.keys is None:
        try:
            if pki.ensure_keys(folder):
                print(f"cellsim: created the cell's keys in {folder}: a CA, a certificate per role and the CAN key "
                      "(docs/security.md)", file=sys.stderr)
        except pki.KeysError as e:
            raise InputError(str(e)) from None
    return {"role": role, "keys": folder, "insecure": False}


def warn_insecure(security: dict) -> None:
    """Say on stderr what ``--insecure`` gives up (once the session's configuration has passed its checks)."""
    if security["insecure"]:
        print("cellsim: warning: --insecure: no TLS, no authentication, no access control; any process on this "
              "machine can publish samples and switch twin modes", file=sys.stderr)


def _can_key(args, loaded) -> bytes | None:
    """The cell's CAN key from the keys folder (``--keys``, else the default, made on first use) when the
    bridge configuration ``loaded`` has authenticated messages; else None."""
    from cellsim.live import pki

    if not loaded.authenticated():
        return None
    folder = args.keys if args.keys is not None else pki.default_keys_dir()
    try:
        if args.keys is None and pki.ensure_keys(folder):
            print(f"cellsim: created the cell's keys in {folder}: a CA, a certificate per role and the CAN key "
                  "(docs/security.md)", file=sys.stderr)
        return pki.can_key(folder)
    except pki.KeysError as e:
        raise InputError(f"{', '.join(loaded.authenticated())} are authenticated: {e}") from None


def _add_live_args(parser: argparse.ArgumentParser, duration_default: str) -> None:
    parser.add_argument("--out", type=Path, help="output folder (default: runs/<scenario>-<process>-<date-time>)")
    parser.add_argument("--duration", type=float, help=f"seconds to run (default: {duration_default})")
    parser.add_argument("--seed", type=int, help="random seed (default: the scenario's seed)")
    _add_set(parser)
    _add_network_args(parser)
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")


def _load(args):
    from cellsim import api

    return api.load_scenario(args.scenario, args.overrides)


def _load_for_runs(args, limits: dict[str, int]):
    """A campaign's or search's scenario, after its counts (``--FLAG`` in [1, most]), seed and duration are checked."""
    from cellsim import api

    for flag, most in limits.items():
        value = getattr(args, flag)
        if value is not None and not 1 <= value <= most:
            raise InputError(f"--{flag} must be in [1, {most}], got {value}")
    api.check_seed(args.seed, "--seed")
    sf = _load(args)
    if args.duration is not None:
        api.check_duration(sf, args.duration, "--duration")
    return sf


def _open_session(args, role: str, listen_by_default: bool, wait: float = 30.0, security: dict | None = None):
    """A Zenoh session for this command running as ``role`` (:data:`cellsim.live.pki.ROLES`);
    ``security``: :func:`_network_security`'s answer when the caller asked for it already."""
    import zenoh

    from cellsim.live.session import session_config

    security = security or _network_security(args, role)
    config = session_config(
        **security, listen=args.listen, connect=args.connect, config_file=args.config,
        listen_by_default=listen_by_default, wait=wait
    )
    warn_insecure(security)
    try:
        return _interruptible(lambda: zenoh.open(config))
    except Exception as e:  # noqa: BLE001 - zenoh raises ZError with a long text
        raise InputError(f"cannot open a Zenoh session as {role} (is the twin running, and are this process's keys "
                         f"from the twin's CA?): {' '.join(str(e).split())[:200]}") from None


def _interruptible(call):
    """``call()`` on a thread of its own, this thread waiting for it: a native call that waits (Zenoh connecting for
    up to its timeout) holds off Python's signal handlers on the thread that makes it, so Ctrl-C and SIGTERM are
    taken here at once instead of when it returns."""
    import threading

    done, outcome = threading.Event(), {}

    def run() -> None:
        try:
            outcome["value"] = call()
        except BaseException as e:  # noqa: BLE001 - handed to the waiting thread
            outcome["error"] = e
        finally:
            done.set()

    threading.Thread(target=run, name="zenoh-open", daemon=True).start()
    while not done.wait(0.2):
        pass
    if "error" in outcome:
        raise outcome["error"]
    return outcome["value"]


def _live_run(args, process: str, listen_by_default: bool, run, check=None):
    """A live process (the twin, the emulator): load, check, open the session, ``run(sf, out, session, duration)``;
    ``process`` is also the session's role (``twin`` or ``emulator``)."""
    from cellsim import api
    from cellsim.config.units import MAX_DURATION

    sf = _load(args)
    if check is not None:
        check(sf)  # before any session is opened
    duration = MAX_DURATION if args.duration is None else args.duration
    api.check_duration(sf, duration, "--duration")
    if args.seed is not None:
        api.check_seed(args.seed, "--seed")
    out = args.out or Path("runs") / f"{sf.scenario.folder_name}-{process}-{datetime.now():%Y%m%d-%H%M%S}"
    session = _open_session(args, process, listen_by_default)
    try:
        with _terminate_as_interrupt():
            return run(sf, out, session, duration)
    finally:
        session.close()


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


def _port(text: str) -> int:
    """A TCP port argument (1-65535)."""
    import argparse

    if not text.isdigit() or not 1 <= int(text) <= 65535:
        raise argparse.ArgumentTypeError(f"a port is a number from 1 to 65535, got {text!r}")
    return int(text)


def _rtde_robot(loaded, option: str = "--rtde") -> str:
    """The one robot of a bridge configuration with an RTDE controller (what ``--rtde PORT`` applies to)."""
    robots = [name for name, robot in loaded.config.robots.items() if robot.rtde is not None]
    if len(robots) != 1:
        raise InputError(f"{option}: {loaded.source} names {len(robots)} robots over RTDE "
                         f"({', '.join(robots) or 'none'}); {option} PORT needs exactly one")
    return robots[0]


def _with_port(endpoint: str, port: int) -> str:
    """An opc.tcp:// endpoint with its port replaced."""
    head, _, _ = endpoint.rpartition(":")
    return f"{head}:{port}" if head.count(":") >= 1 and not head.endswith("/") else f"{endpoint}:{port}"


def _plc_certificates(args, loaded, side: str) -> tuple | None:
    """The OPC UA certificate files ``side`` (``bridge`` or ``plc``) needs for the configuration's PLC: its own
    certificate and key, and the other side's certificate it trusts; None without a PLC or security."""
    from cellsim.live.pki import opcua_files
    from cellsim.live import pki

    plc = loaded.config.plc
    if plc is None or plc.security == "none":
        return None
    folder = args.keys if args.keys is not None else pki.default_keys_dir()
    try:
        if args.keys is None and pki.ensure_keys(folder):
            print(f"cellsim: created the cell's keys in {folder} (docs/security.md)", file=sys.stderr)
        other = "plc" if side == "bridge" else "bridge"
        certificate, key = opcua_files(folder, side)
        peer = pki.opcua_peer_certificate(folder, other)
    except OSError as e:
        raise InputError(f"the PLC's OPC UA certificates in {folder}: {e}") from None
    return certificate, key, peer


def add_scheduler_argument(parser) -> None:
    """``--scheduler``: run on a Dask cluster instead of local worker processes."""
    parser.add_argument(
        "--scheduler", type=_scheduler_address, metavar="tcp://HOST:PORT",
        help="run on the Dask distributed cluster of this scheduler (started with `dask scheduler` and "
        "`dask worker`, or dask-jobqueue) instead of --jobs local processes; workers need not share this "
        "file system: each gets the inputs once and sends back its runs' files (docs/cluster.md)",
    )


def _scheduler_address(text: str) -> str:
    import argparse
    import re

    if not re.fullmatch(r"(tcp|tls|ucx|ws|wss)://[^\s/:]+:\d{1,5}", text):
        raise argparse.ArgumentTypeError(f"a scheduler address is tcp://HOST:PORT, got {text!r}")
    return text


class RunsBar:
    """A progress bar of runs done out of ``total``, with the figures ``read(progress)`` gives
    (``completed`` and the ``fields`` the ``figures`` template names); nothing when ``quiet``."""

    def __init__(self, console, quiet: bool, total: int, figures: str, initial: dict, read, eta: bool = True):
        self.console, self.quiet, self.total = console, quiet, total
        self.figures, self.initial, self.read, self.eta = figures, initial, read, eta
        self.bar = None

    def __enter__(self):
        return None if self.quiet else self.report

    def _start(self) -> None:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

        eta = (TextColumn("eta"), TimeRemainingColumn()) if self.eta else ()
        self.bar = Progress(TextColumn("runs"), BarColumn(), MofNCompleteColumn(), TextColumn(self.figures),
                            TimeElapsedColumn(), *eta, console=self.console)
        self.bar.start()
        self.task = self.bar.add_task("runs", total=self.total, **self.initial)

    def report(self, progress) -> None:
        """Show ``progress``; the bar appears with the first report, once the work has passed its checks (a
        refused start shows no bar before its error)."""
        if self.bar is None:
            self._start()
        self.bar.update(self.task, **self.read(progress))

    def __exit__(self, *exc):
        if self.bar is not None:
            self.bar.stop()
