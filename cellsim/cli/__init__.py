"""The ``cellsim`` command line.

Exit codes: 0 all well; 1 a safety finding (a mishap in a run, a safety
condition violated, inconclusive or with missing data); 2 a usage or input
error (one line on stderr naming the file, line and key); 3 (``verify`` only) nothing violated but a
property undecided; 130 interrupted (Ctrl-C, or SIGTERM,
which every command takes as Ctrl-C: a black box is closed, a campaign keeps its finished runs).

One module per command (``cellsim.cli.simulate``, ...), each with ``add_parser(subparsers)``
(its arguments, help and description; ``handler=run``) and ``run(args) -> int``;
``COMMANDS`` lists them in the order ``cellsim --help`` shows them. What they share is in
``cellsim.cli.common``.
"""

from __future__ import annotations

import argparse
import sys

from cellsim.cli import (
    bridge,
    campaign,
    check,
    dashboard,
    emulate,
    export,
    falsify,
    keys,
    live,
    modules,
    replay,
    scenario,
    simulate,
    twin_mode,
    verify,
)
from cellsim.cli.common import (
    EXIT_CODES,
    EXIT_FINDING,
    EXIT_INPUT,
    EXIT_INTERRUPTED,
    EXIT_OK,
    InputError,
    _add_live_args,
    _add_network_args,
    _add_set,
    _end_with_exit_codes,
    _interrupt_deferred,
    _load,
    _open_session,
    _terminate_as_interrupt,
)

__all__ = [
    "COMMANDS", "EXIT_CODES", "EXIT_FINDING", "EXIT_INPUT", "EXIT_INTERRUPTED", "EXIT_OK", "InputError",
    "bridge_main", "build_parser", "main",
    "_add_live_args", "_add_network_args", "_add_set", "_end_with_exit_codes", "_interrupt_deferred", "_load",
    "_open_session", "_terminate_as_interrupt",
]

COMMANDS = (simulate, check, verify, campaign, falsify, replay, export, modules, scenario, live, emulate, bridge, dashboard, twin_mode, keys)
"""The commands, in the order of ``cellsim --help``: each a module with ``add_parser`` and ``run``."""


def main(argv: list[str] | None = None) -> int:
    given = sys.stdout
    sys.stdout = _ReaderMayLeave(given)
    try:
        with _terminate_as_interrupt():  # from the start: SIGTERM while the command is being set up is Ctrl-C too
            return _main(argv)
    except KeyboardInterrupt:  # also while starting up: importing Drake takes a while
        print("cellsim: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        sys.stdout.flush()  # (through the wrapper: a reader gone by now is no error at exit either)
        sys.stdout = given


class _ReaderMayLeave:
    """Standard output whose reader may stop reading early (``cellsim check RUN | head -1``): once the pipe is
    closed, what is written goes nowhere, and the command still ends with its own exit code (a verdict, not an
    error). The stream's file descriptor is pointed at the null device, so nothing fails at exit either."""

    def __init__(self, stream):
        self._stream = stream
        self._left = False

    def write(self, text: str) -> int:
        if not self._left:
            try:
                return self._stream.write(text)
            except BrokenPipeError:
                self._leave()
        return len(text)

    def flush(self) -> None:
        if not self._left:
            try:
                self._stream.flush()
            except BrokenPipeError:
                self._leave()

    def _leave(self) -> None:
        import os

        self._left = True
        try:
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, self._stream.fileno())
            os.close(null)
        except (OSError, ValueError, AttributeError):
            pass  # (a stream with no descriptor: nothing is left to flush at exit)

    def __getattr__(self, name):
        return getattr(self._stream, name)


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:  # said by the command's own parser, with its own usage (not the top-level one)
        _parser_of(parser, args).error(f"unrecognized arguments: {' '.join(extra)}")
    if not getattr(args, "handler", None):
        parser.print_help(sys.stderr)
        return EXIT_INPUT
    with _interrupt_deferred():  # pydrake's loader reports an interrupt with its own traceback
        from cellsim.api import ConfigError, OutputExistsError, OverwritesInput
        from cellsim.live.session import SessionConfigError

    try:
        with _terminate_as_interrupt():
            return args.handler(args)
    except (ConfigError, OutputExistsError, InputError, SessionConfigError, OverwritesInput) as e:
        print(f"cellsim: error: {e}", file=sys.stderr)
        return EXIT_INPUT
    except OSError as e:  # an output path that cannot be written, a file that vanished
        where = f": {e.filename}" if e.filename else ""
        print(f"cellsim: error: {e.strerror or e}{where}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print("cellsim: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


def _parser_of(parser: argparse.ArgumentParser, args) -> argparse.ArgumentParser:
    """The parser of the (sub)command ``args`` ran: ``cellsim scenario check`` -> its own."""
    for name in ("_command", "_action|action"):
        actions = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]  # noqa: SLF001
        chosen = next((getattr(args, n) for n in name.split("|") if getattr(args, n, None) is not None), None)
        if not actions or chosen is None or chosen not in actions[0].choices:
            break
        parser = actions[0].choices[chosen]
    return parser


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cellsim",
        description="Scenario digital twins of collaborative robot cells: simulate them headless, "
        "record black boxes, and gather safety evidence.",
        epilog=EXIT_CODES + " `cellsim verify` also exits 3: nothing violated, but a property undecided.",
    )
    from cellsim.version import __version__

    parser.add_argument("--version", action="version", version=f"cellsim {__version__}")
    sub = parser.add_subparsers(metavar="COMMAND", dest="_command")
    for command in COMMANDS:
        command.add_parser(sub)
    _end_with_exit_codes(parser)
    return parser


def bridge_main(argv: list[str] | None = None) -> int:
    """``cellsim-bridge`` and ``python -m cellsim.bridges``: the bridge daemon on its own (as ``cellsim bridge``)."""
    return main(["bridge", *(sys.argv[1:] if argv is None else argv)])
