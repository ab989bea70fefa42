"""``cellsim check``: check a run's black box against the safety conditions."""

from __future__ import annotations

import sys
from pathlib import Path

from cellsim.cli.common import EXIT_FINDING, EXIT_INPUT, EXIT_OK, InputError
from cellsim.numbers import instant


def add_parser(subparsers) -> None:
    chk = subparsers.add_parser(
        "check",
        help="check a run's black box against the safety conditions",
        description="Rebuild a run's trace from its black box and evaluate every safety condition "
        "and use-case classifier of the scenario's validation section. RUN is a run folder (as written "
        "by simulate) or a black-box file. Given a campaign folder, it checks every run and gives, per "
        "condition and for any condition, the violation rate and its exact (Clopper-Pearson) 95 % upper "
        "bound, with the sampling distribution it holds under. Exits 0 if every condition holds (on every "
        "run), 1 if one is violated or undecided, 2 if the run (or any run of the campaign) cannot be checked: "
        "evidence never shrinks silently.",
    )
    chk.add_argument("run", type=Path, help="run folder, blackbox.sqlite, or campaign folder")
    chk.add_argument(
        "--scenario", type=Path, help="check against this scenario's conditions (default: the run's scenario.yaml)"
    )
    chk.add_argument("--json", action="store_true", help="print the verdicts as JSON on standard output")
    chk.add_argument(
        "--robustness", action="store_true",
        help="also give each condition's margins: how far its numeric thresholds (space, in their units) and "
        "its deadlines (time, s) could move against it before the verdict changes; negative when violated "
        "(docs/condition-language.md, Robustness)",
    )
    chk.add_argument(
        "--export-trace", type=Path, metavar="FILE", help="also write the trace as JSON: {variable: [[t, value], ...]}"
    )
    chk.set_defaults(handler=run)


def run(args) -> int:
    import json

    from cellsim import api

    if api.is_campaign(args.run):
        return check_campaign(args)
    try:
        sf = api.load_scenario(args.scenario) if args.scenario else None
        checked = api.check(args.run, sf)
    except api.CheckError as e:
        raise InputError(str(e)) from None
    result = checked.result
    margins = api.robustness(checked) if args.robustness else None
    if args.export_trace:
        api.export_trace(checked, args.export_trace)
    if args.json:
        json.dump(
            {
                "run": str(args.run),
                "holds": result.all_hold,
                "verdict": result.verdict.value,
                "complete": checked.trace.complete,
                "verdicts": result.verdicts_json(),
                "descriptions": {n: api.formula_and_description(c)[1]
                                 for n, c in {**checked.case.validation.conditions,
                                              **checked.case.validation.use_cases}.items()
                                 if api.formula_and_description(c)[1]},
                "violations": result.violations,
                "undecided": result.undecided,
                "use_cases": result.use_cases,
                "coverage": result.coverage,
                **({"robustness": {name: m.to_json() for name, m in margins.items()}} if margins else {}),
            },
            sys.stdout,
            indent=2,
        )
        sys.stdout.write("\n")
    else:
        print_verdicts(args.run, checked, margins)
    return EXIT_OK if result.all_hold else EXIT_FINDING


PROGRESS_FROM = 50
"""Checking a campaign of this many runs or more shows a progress bar (on standard error)."""


def _margin(x: float, unit: str = "") -> str:
    """A margin for people: its value, or 'any' / 'none' where no move of that kind changes the verdict."""
    import math

    return f"{x:.3g}{unit}" if math.isfinite(x) else ("any" if x > 0 else "none")


def check_campaign(args) -> int:
    """Every run of a campaign folder checked, and the bound they give per condition."""
    import json

    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    from cellsim import api

    for flag, given in (("--export-trace", args.export_trace), ("--robustness", args.robustness)):
        if given:
            raise InputError(f"{args.run} is a campaign folder: {flag} takes one run (check one of "
                             f"{api.runs_folder(args.run)})")
    bar = None

    def report(done: int, total: int) -> None:  # a progress bar on standard error, for a large campaign
        nonlocal bar
        if total < PROGRESS_FROM:
            return
        if bar is None:
            bar = Progress(TextColumn("checking runs"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                           console=Console(stderr=True), transient=True)
            bar.start()
            bar.add_task("check", total=total)
        bar.update(bar.task_ids[0], completed=done)

    try:
        sf = api.load_scenario(args.scenario) if args.scenario else None
        found = api.check_campaign(args.run, sf, progress=report)
    except api.CheckError as e:
        raise InputError(str(e)) from None
    finally:
        if bar is not None:
            bar.stop()
    if found.bounds is None:  # a search chose these runs, or what they were drawn from is unknown: no bound
        return _report_search_runs(args, found.runs, found.conditions, found.not_a_sample, found.waived or {})
    if args.json:
        json.dump({"campaign": str(args.run), "bounds": found.bounds, "runs": found.runs, "waived": found.waived or {}},
                  sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print_bounds(args.run, found.bounds, found.runs)
        _say_waived(found.waived or {})
    if _uncheckable(args.run, found.runs):
        return EXIT_INPUT
    return EXIT_FINDING if found.bounds["overall"]["failures"] else EXIT_OK


def _uncheckable(folder: Path, runs: list[dict]) -> bool:
    """Say so, in one line on stderr, if some runs could not be checked: the figures printed leave them out,
    so the check does not pass (exit 2, as for one such run checked alone)."""
    failed = [r for r in runs if r["status"] == "failed"]
    if failed:
        print(f"cellsim: error: {len(failed)} of {len(runs)} runs of {folder} could not be checked and are left out "
              f"of the figures above ({failed[0]['run']}: {failed[0]['error']})", file=sys.stderr)
    return bool(failed)


def _say_waived(waived: dict) -> None:
    """Each default condition the runs' scenario waives, and its reason: no figure above judged it."""
    from rich.console import Console
    from rich.markup import escape

    for name, reason in waived.items():
        Console().print(f"waived: {escape(name)} ({escape(reason)})", highlight=False)


def _report_search_runs(args, runs: list[dict], conditions: list[str], reason: str, waived: dict) -> int:
    """Runs re-checked that bound nothing (a falsification search's, or a campaign's whose sampling distribution is
    not recorded): which violate what, and no bound (``reason``)."""
    import json

    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    checked = [r for r in runs if r["status"] == "completed"]
    violating = {c: [r["run"] for r in checked if c in r["violations"]] for c in conditions}
    undecided = {c: [r["run"] for r in checked if c in r["undecided"]] for c in conditions}
    if args.json:
        json.dump({"campaign": str(args.run), "bounds": {"excluded": reason}, "runs": runs, "waived": waived}, sys.stdout,
                  indent=2)
        sys.stdout.write("\n")
    else:
        table = Table(title=f"Safety conditions over the runs in {args.run}", title_justify="left")
        table.add_column("condition")
        table.add_column("violating runs", justify="right")
        if any(undecided.values()):  # (runs that ended early: neither violating nor holding)
            table.add_column("undecided runs", justify="right")

        def cell(found: list[str], style: str) -> str:
            return f"[{style}]{len(found)}[/{style}] of {len(checked)}: {', '.join(found[:8])}" if found else f"0 of {len(checked)}"

        for name, found in violating.items():
            table.add_row(escape(name), cell(found, "red"), *([cell(undecided[name], "yellow")] if any(undecided.values()) else []))
        console = Console()
        console.print(table)
        console.print(f"No violation rate or bound: {escape(reason)}.", highlight=False)
        _say_unfinished(console, runs)
        _say_waived(waived)
    if _uncheckable(args.run, runs):
        return EXIT_INPUT
    return EXIT_FINDING if any(r["violations"] or r["undecided"] for r in checked) else EXIT_OK


def print_bounds(folder: Path, bounds: dict, runs: list[dict]) -> None:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from cellsim.numbers import percent, probability

    table = Table(title=f"Safety conditions over the runs of {folder}", title_justify="left")
    for column in ("condition", "violating runs", "rate", f"upper bound ({percent(bounds['confidence'])})"):
        table.add_column(column, justify="left" if column == "condition" else "right")

    def row(name, figures, style=""):
        failures, n = figures["failures"], figures["runs"]
        mark = f"[red]{failures}[/red]" if failures else "0"
        table.add_row(f"{style}{escape(name)}", f"{mark} of {n}", probability(figures["rate"]), probability(figures["upper_bound"]))

    for name, figures in bounds["conditions"].items():
        row(name, figures)
    row("any condition", bounds["overall"], "[bold]")
    console = Console()
    console.print(table)
    console.print(f"The upper bound is the {bounds['method']}, {bounds['counted']}.", highlight=False)
    console.print(f"It holds for runs drawn as this campaign's: {escape(bounds['sampling'])}.", highlight=False)
    failed = [r["run"] for r in runs if r["status"] == "failed"]
    if failed:
        console.print(f"[yellow]{len(failed)} run(s) left out, not checkable: {', '.join(failed[:8])}[/yellow]")
    _say_unfinished(console, runs)


UNFINISHED = ("stopped before they ended (no result.json): left out of the figures; the campaign finishes them when "
              "run again")


def _say_unfinished(console, runs: list[dict]) -> None:
    """One line naming the runs a campaign was stopped in (Ctrl-C) before they ended, which no figure counts."""
    unfinished = [r["run"] for r in runs if r["status"] == "unfinished"]
    if unfinished:
        console.print(f"[yellow]{len(unfinished)} run(s) {UNFINISHED}: {', '.join(unfinished[:8])}[/yellow]",
                      highlight=False)


def print_verdicts(run: Path, checked, margins: dict | None = None) -> None:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from cellsim.api import Verdict, formula_and_description

    result, conditions = checked.result, checked.case.validation.conditions
    table = Table(title=f"Safety conditions on {run}", title_justify="left")
    table.add_column("condition", style="bold")
    table.add_column("verdict")
    table.add_column("first violation")
    if margins:
        table.add_column("margin: space", justify="right")
        table.add_column("time", justify="right")
    table.add_column("formula", style="dim")
    for name, verdict in result.verdicts.items():
        mark = {Verdict.HOLDS: "[green]holds[/green]", Verdict.VIOLATED: "[red]VIOLATED[/red]"}.get(
            verdict.status, f"[yellow]{verdict.describe()}[/yellow]"
        )
        when = "" if verdict.violated_at is None or verdict.holds else f"t = {instant(verdict.violated_at)}"
        formula, description = formula_and_description(conditions[name])
        cells = [_margin(margins[name].space), _margin(margins[name].time, " s")] if margins else []
        table.add_row(name, mark, when, *cells,
                      escape(formula) + (f"\n[italic]{escape(description)}[/italic]" if description else ""))
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
        _, description = formula_and_description(use_cases[name])
        if description:
            console.print(f"  {escape(name)}: [italic]{escape(description)}[/italic]", highlight=False)
    for name, reason in checked.case.validation.waive.items():
        console.print(f"waived: {escape(name)} ({escape(reason)})", highlight=False)
    console.print(_conditions_line(result))


def _conditions_line(result) -> str:
    """'all 14 conditions hold', or what keeps them from holding (also in simulate's summary)."""
    total = len(result.verdicts)
    if result.all_hold:
        return f"all {total} conditions hold"
    parts = []
    if result.violations:
        parts.append(f"[red]{len(result.violations)} of {total} conditions violated: {', '.join(result.violations)}[/red]")
    if result.undecided:
        parts.append(f"[yellow]{len(result.undecided)} undecided (inconclusive or missing data): {', '.join(result.undecided)}[/yellow]")
    return "; ".join(parts)
