"""``cellsim simulate``: run a scenario headless and record its black box."""

from __future__ import annotations

import sys
from datetime import datetime
from pathlib import Path

from cellsim.cli.check import _conditions_line
from cellsim.cli.common import EXIT_FINDING, EXIT_OK, InputError, _add_set, _load
from cellsim.numbers import measure


def add_parser(subparsers) -> None:
    sim = subparsers.add_parser(
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
    sim.add_argument("--overwrite", action="store_true",
                     help="replace a run already in --out, once the new one is written (interrupted, it leaves the "
                          "old one as it was)")
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
    sim.set_defaults(handler=run)


def run(args) -> int:
    from rich.console import Console

    from cellsim import api

    sf = _load(args)
    if args.duration is not None:
        api.check_duration(sf, args.duration, "--duration")
    if args.seed is not None:
        api.check_seed(args.seed, "--seed")
    out = args.out or Path("runs") / f"{sf.scenario.folder_name}-{datetime.now():%Y%m%d-%H%M%S}"
    console = Console(stderr=True, quiet=args.quiet)
    meshcat = meshcat_wait = None
    if args.meshcat:
        from cellsim.visual.serve import WAIT_DEFAULT

        wait = args.meshcat_wait
        if wait is None:
            wait = WAIT_DEFAULT if sys.stdin is not None and sys.stdin.isatty() else 0.0
        if not (0.0 <= wait <= 3600.0):
            raise InputError(f"--meshcat-wait {wait:g}: expected 0 to 3600 seconds")
        meshcat = api.open_meshcat()
        console.print(f"Meshcat: [link={meshcat.web_url()}]{meshcat.web_url()}[/link]")
        meshcat_wait = (wait, console.print)
    try:
        with _progress(console, args.quiet) as report:
            done = api.simulate(sf, out, seed=args.seed, duration=args.duration, overwrite=args.overwrite,
                                meshcat=meshcat, meshcat_wait=meshcat_wait, progress=report)
        checked = done.checked.result if done.checked is not None else None
        if not args.quiet:
            print_summary(done.summary, checked)
        if meshcat is not None and sys.stdin is not None and sys.stdin.isatty():
            from cellsim.visual.serve import serve_until_closed

            serve_until_closed(meshcat, console.print)
    finally:
        if meshcat is not None:
            del meshcat
    return EXIT_FINDING if done.finding else EXIT_OK


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


def findings_lines(summary, most: int | None = None) -> list[tuple[str, str]]:
    """(label, text) rows of the run's findings: its closest approach, every contact (the worst first) and blind spot
    (or at most ``most`` of each kind, and how many more), and the default conditions it waives with its reasons."""
    rows = []
    outrun = [f.what for f in summary.findings if f.outrun]  # (a measurement outrun between two looks: in red)
    for what in ("closest approach", "contact", "blind spot", "slow reaction", *dict.fromkeys(outrun)):
        found = [f for f in summary.findings if f.what == what]
        if what == "contact":
            found.sort(key=lambda f: -f.data.get("severity", 0.0))
        for f in found[:most]:  # (None: all)
            when = f"{f.start:.2f} s to the end" if f.end is None else f"{f.start:.2f}-{f.end:.2f} s"
            alarming = f.data.get("severity", 0.0) > 1.0 or what == "slow reaction" or f.outrun
            text = f"[red]{f.text}[/red]" if alarming else f.text
            rows.append((what, f"{text} ({when})" if what != "closest approach" else text))
        if most is not None and len(found) > most:
            rows.append((what, f"... and {len(found) - most} more (in the black box's channels: `cellsim export "
                                f"{summary.out_dir} --mcap FILE` plots them in Foxglove)"))
    rows += [("waived", f"{name}: {reason}") for name, reason in summary.waived.items()]
    return rows


def print_summary(summary, checked=None) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console()
    table = Table(title=f"Run {summary.out_dir}", show_header=False, title_justify="left")
    table.add_column(style="bold")
    table.add_column()
    table.add_row("status", summary.status)
    table.add_row("seed", str(summary.seed))
    labels = [figure.label for figure, _ in summary.figures]
    for figure, value in summary.figures:  # a label several modules give names each one's subject
        subject = f" ({figure.subject})" if labels.count(figure.label) > 1 else ""
        table.add_row(figure.label + subject, "-" if value is None else str(value))
    for channel, counts in summary.hazards.items():
        verdict = f"raised {counts.raised}, handled {counts.handled}"
        if counts.mishaps:
            verdict += f", [red]MISHAPS {counts.mishaps}[/red]"
        table.add_row(f"hazard {channel.rpartition('.')[2]}", verdict)
    if checked is not None:
        line = _conditions_line(checked)
        table.add_row("safety conditions", line if checked.all_hold else f"{line} (details: cellsim check {summary.out_dir})")
        table.add_row("use cases exercised", ", ".join(checked.use_cases) or "none")
    for line in findings_lines(summary):
        table.add_row(*line)
    table.add_row("simulated time", measure(summary.sim_time, "s"))
    table.add_row("wall time", measure(summary.wall_time, "s"))
    table.add_row("real-time factor", measure(summary.real_time_factor, "x"))
    table.add_row("black box", str(Path(summary.out_dir) / "blackbox.sqlite"))
    console.print(table)
