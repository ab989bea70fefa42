"""The ``cellsim`` command line.

Exit codes: 0 all well; 1 a safety finding (a mishap in a run, a violated
safety condition); 2 a usage or input error (one line on stderr naming the
file, line and key); 130 interrupted.
"""

from __future__ import annotations

import argparse
import sys
from datetime import datetime
from pathlib import Path

EXIT_OK, EXIT_FINDING, EXIT_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130


class InputError(Exception):
    """Bad input found by the CLI itself (the message is the whole story)."""


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "handler", None):
        parser.print_help(sys.stderr)
        return EXIT_INPUT
    from cellsim.config.typed_yaml import ConfigError
    from cellsim.simulation import OutputExistsError

    try:
        return args.handler(args)
    except (ConfigError, OutputExistsError, InputError) as e:
        print(f"cellsim: error: {e}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print("cellsim: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cellsim",
        description="Scenario digital twins of collaborative robot cells: simulate them headless, "
        "record black boxes, and gather safety evidence.",
        epilog="Exit codes: 0 ok, 1 safety finding, 2 usage or input error.",
    )
    sub = parser.add_subparsers(metavar="COMMAND")

    sim = sub.add_parser(
        "simulate",
        help="run a scenario headless and record its black box",
        description="Simulate a scenario (far faster than real time unless --meshcat) and write "
        "OUT/blackbox.sqlite (every message) and OUT/scenario.yaml (the resolved scenario). "
        "Exits 1 if a hazard reached its mishap phase.",
    )
    sim.add_argument("scenario", type=Path, help="scenario YAML file")
    sim.add_argument("--duration", type=float, help="simulated seconds (default: the scenario's duration)")
    sim.add_argument("--seed", type=int, help="random seed (default: the scenario's seed)")
    sim.add_argument("--out", type=Path, help="output folder (default: runs/<scenario>-<date-time>)")
    sim.add_argument("--overwrite", action="store_true", help="replace a run already in --out")
    _add_set(sim)
    sim.add_argument(
        "--meshcat", action="store_true", help="show the cell in Meshcat (a browser) at real-time speed"
    )
    sim.add_argument("--quiet", action="store_true", help="print nothing but errors")
    sim.set_defaults(handler=cmd_simulate)

    scenario = sub.add_parser("scenario", help="inspect scenario files", description="Inspect scenario files.")
    ssub = scenario.add_subparsers(metavar="ACTION")
    export = ssub.add_parser(
        "export",
        help="print the fully resolved scenario as YAML",
        description="Load a scenario, apply --set overrides, and write it back with every default "
        "filled in. Loading the export gives the same scenario.",
    )
    export.add_argument("scenario", type=Path)
    _add_set(export)
    export.add_argument("--out", type=Path, help="write to this file instead of standard output")
    export.set_defaults(handler=cmd_export)
    check = ssub.add_parser(
        "check", help="check a scenario without running it", description="Load and wire a scenario; report the first problem."
    )
    check.add_argument("scenario", type=Path)
    _add_set(check)
    check.set_defaults(handler=cmd_scenario_check)
    return parser


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


def cmd_simulate(args) -> int:
    from rich.console import Console

    from cellsim.simulation import simulate

    if args.duration is not None and args.duration <= 0:
        raise InputError(f"--duration must be positive, got {args.duration}")
    sf = _load(args)
    out = args.out or Path("runs") / f"{sf.scenario.name}-{datetime.now():%Y%m%d-%H%M%S}"
    console = Console(stderr=True, quiet=args.quiet)
    meshcat = None
    if args.meshcat:
        from pydrake.geometry import Meshcat, MeshcatParams

        meshcat = Meshcat(MeshcatParams(host="localhost"))
        console.print(f"Meshcat: [link={meshcat.web_url()}]{meshcat.web_url()}[/link]")
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
            )
        if not args.quiet:
            print_summary(summary)
        if meshcat is not None and sys.stdin.isatty():
            input("Press Enter to close Meshcat. ")
    finally:
        if meshcat is not None:
            del meshcat
    return EXIT_FINDING if summary.mishap else EXIT_OK


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


def print_summary(summary) -> None:
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
        verdict = f"raised {counts.raised}, mitigated {counts.mitigated}"
        if counts.mishaps:
            verdict += f", [red]MISHAPS {counts.mishaps}[/red]"
        table.add_row(f"hazard {name}", verdict)
    table.add_row("final safety mode", summary.final_safety_mode or "-")
    table.add_row("simulated time", f"{summary.sim_time:.1f} s")
    table.add_row("wall time", f"{summary.wall_time:.2f} s")
    table.add_row("real-time factor", f"{summary.real_time_factor:.1f}x")
    table.add_row("black box", str(Path(summary.out_dir) / "blackbox.sqlite"))
    console.print(table)


def cmd_export(args) -> int:
    from cellsim.scenario import export_scenario

    sf = _load(args)
    if args.out is None:
        sys.stdout.write(export_scenario(sf))
    else:
        text = export_scenario(sf, destination_dir=args.out.resolve().parent)
        tmp = args.out.with_name(args.out.name + ".tmp")
        tmp.write_text(text)
        tmp.replace(args.out)
    return EXIT_OK


def cmd_scenario_check(args) -> int:
    from diagrams.cell import build_cell

    sf = _load(args)
    build_cell(sf, seed=sf.scenario.seed, duration=sf.scenario.duration, record=False)
    print(f"{args.scenario}: ok")
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
