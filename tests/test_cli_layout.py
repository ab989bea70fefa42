"""The command line's layout: one module per command under cellsim.cli, and a start that does not load Drake."""

from __future__ import annotations

import argparse
import subprocess
import sys
from importlib.metadata import version

import pytest

import cellsim.cli
from cellsim.cli import COMMANDS, build_parser


def _commands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    (action,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(action.choices)


def _handlers(parser: argparse.ArgumentParser) -> list:
    """The handlers of a command and of its own subcommands (``scenario export``, ``scenario check``)."""
    found = [parser.get_default("handler")] if parser.get_default("handler") else []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                found += _handlers(sub)
    return found


def test_every_command_s_handlers_live_in_its_own_module():
    commands = _commands(build_parser())
    assert len(commands) == len(COMMANDS)
    for name, parser in commands.items():
        module = f"cellsim.cli.{name.replace('-', '_')}"
        handlers = _handlers(parser)
        assert handlers, f"cellsim {name} has no handler"
        assert {h.__module__ for h in handlers} == {module}, f"cellsim {name}: its handlers belong in {module}"
        assert sys.modules[module] in COMMANDS, f"{module} is not in cellsim.cli.COMMANDS"


def test_each_command_module_declares_its_parser_and_runs_it():
    for module in COMMANDS:
        assert callable(module.add_parser), module.__name__
        assert module.__name__.startswith("cellsim.cli.") and module.__name__ != "cellsim.cli.common"
    assert len({m.__name__ for m in COMMANDS}) == len(COMMANDS)
    assert not [n for n, v in vars(cellsim.cli).items() if n.startswith("cmd_") and callable(v)]  # no handler left behind


@pytest.mark.parametrize("args", [["--version"], ["--help"]])
def test_the_command_line_starts_without_loading_drake(args):
    done = subprocess.run([sys.executable, "-X", "importtime", "-m", "cellsim", *args],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    imported = [line.rsplit("|", 1)[-1].strip() for line in done.stderr.splitlines() if line.startswith("import time:")]
    assert "cellsim.cli" in imported  # -X importtime did report
    assert not [m for m in imported if m.split(".")[0] in ("pydrake", "zenoh")], "cellsim " + " ".join(args)
    if args == ["--version"]:
        assert done.stdout.strip() == f"cellsim {version('cellsim')}"
