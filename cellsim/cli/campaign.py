"""``cellsim campaign``: simulate and check many sampled variants of a scenario."""

from __future__ import annotations

import os
import sys
from pathlib import Path

from cellsim.cli.common import EXIT_FINDING, EXIT_INPUT, EXIT_INTERRUPTED, EXIT_OK, InputError, RunsBar, _add_set, _load_for_runs, add_scheduler_argument
from cellsim.numbers import measure, percent


def add_parser(subparsers) -> None:
    camp = subparsers.add_parser(
        "campaign",
        help="simulate and check many sampled variants of a scenario",
        description="Draw --runs variants of the scenario from its samplers (campaign.samplers), simulate "
        "each in a worker process, check its safety conditions, use cases and coverage, and write "
        "OUT/results.json and OUT/report.html. Each run folder (OUT/runs/NNNN) holds copies of the files it "
        "used and re-runs alone. Re-running the same command on the same OUT resumes it (a larger --runs "
        "extends it) if its inputs are unchanged: the content of the scenario and of every file it uses, "
        "the overrides, seed, duration and cellsim's version. If one changed, the campaign refuses, naming "
        "it, unless --restart. "
        "Exits 1 if a condition does not hold on some run (violated, or missing data), else 2 if a run could "
        "not be simulated (a sampled value out of range).",
    )
    camp.add_argument("scenario", type=Path, help="scenario YAML file")
    camp.add_argument("--runs", type=int, help="number of runs (default: the scenario's campaign.runs)")
    camp.add_argument(
        "--until-bound", type=float, metavar="P",
        help="run until the exact 95%% upper bound on the probability that a run violates a condition is "
        "below P (with no violation: about 3/P runs, printed before starting), or until the first "
        "violation; instead of --runs",
    )
    camp.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="worker processes (default: one per CPU)")
    add_scheduler_argument(camp)
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
    camp.set_defaults(handler=run)


def run(args) -> int:
    from rich.console import Console

    from cellsim import api

    sf = _load_for_runs(args, {k: api.COUNT_LIMITS[k] for k in ("runs", "jobs")})
    runs = args.runs or sf.scenario.campaign.runs
    console = Console(stderr=True, quiet=args.quiet)
    if args.until_bound is not None:
        runs = _runs_for_bound(args, console)
    out = args.out or Path("campaigns") / f"{sf.scenario.folder_name}-seed{args.seed}"
    try:
        with _campaign_progress(console, args.quiet, runs) as report:
            outcome = api.run_campaign(sf, out, runs=runs, seed=args.seed, duration=args.duration, jobs=args.jobs,
                                   scheduler=args.scheduler, restart=args.restart, until_bound=args.until_bound,
                                   progress=report)
    except api.CampaignError as e:
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
    if outcome.violating_runs or outcome.results["totals"]["undecided_runs"]:
        return EXIT_FINDING  # a safety finding outranks the runs that could not be simulated (said above)
    return EXIT_INPUT if failed else EXIT_OK


def _runs_for_bound(args, console) -> int:
    """The runs ``--until-bound P`` takes with none violating, said before they start."""
    from cellsim.api import CONFIDENCE, runs_needed

    target = args.until_bound
    if args.runs is not None:
        raise InputError("--until-bound sets the number of runs: give it or --runs, not both")
    if not 0.0 < target < 1.0:
        raise InputError(f"--until-bound must be a probability in (0, 1), got {target:g}")
    runs = runs_needed(target)
    if runs > 100_000:
        raise InputError(f"--until-bound {target:g} needs {runs:,} runs without a violation; a campaign has at most "
                         "100,000 (split it, or aim at a larger probability)")
    console.print(f"bounding the violation rate below {target:g} at {percent(CONFIDENCE)} confidence takes {runs:,} "
                  "runs without a violation; the campaign stops at the first violation", highlight=False)
    return runs


def _campaign_progress(console, quiet: bool, total: int) -> RunsBar:
    """A progress bar of runs done, with violations and coverage so far."""
    return RunsBar(console, quiet, total,
                   "violating {task.fields[violating]}  failed {task.fields[failed]}  coverage {task.fields[coverage]}",
                   dict(violating=0, failed=0, coverage=percent(0.0)),
                   lambda p: dict(completed=p.done, violating=p.violating_runs, failed=p.failed, coverage=percent(p.coverage)))


def print_campaign(outcome) -> None:
    from rich.console import Console
    from rich.markup import escape
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
    for what, runs in totals.get("finding_runs", {}).items():  # what the verdicts do not say (cellsim.campaign.report)
        table.add_row(f"runs {what}", f"[red]{_run_list(runs)}[/red] (the report's harm section)")
    waived = outcome.results["campaign"].get("waived") or {}
    if waived:  # default conditions no run was judged by: said with the scenario's reasons
        table.add_row("waived", "\n".join(f"{escape(name)}: {escape(reason)}" for name, reason in waived.items()))
    bounds = outcome.results.get("bounds")
    target = outcome.results["campaign"].get("until_bound")
    if bounds and target is not None:
        table.add_row("--until-bound", _until_bound_text(bounds, target, outcome.results["campaign"].get("runs")))
    if bounds:
        table.add_row(f"violation rate, {percent(bounds['confidence'])} upper bound", _bound_text(bounds))
    table.add_row("use cases", ", ".join(f"{u} {n}" for u, n in totals["use_cases"].items()) or "-")
    overall = totals["coverage"]["overall"]
    table.add_row("coverage", f"{percent(overall['fraction'])} of situations" if overall["total"]
                  else "no coverage criteria")
    table.add_row("time per stage", ", ".join(f"{k} {measure(v, 's')}" for k, v in timing.items()))
    inputs = (outcome.results.get("provenance") or {}).get("inputs") or {}
    if inputs:
        table.add_row("inputs", f"content hash {inputs['hash'][:16]} ({len(inputs['files'])} files, snapshot in {outcome.results_path.parent / 'inputs'})")
    table.add_row("results", str(outcome.results_path))
    table.add_row("report", str(outcome.report_path))
    console.print(table)
    if bounds:
        console.print(f"The bound is the {bounds['method']}, {bounds['counted']}. It holds for runs drawn as this "
                      f"campaign's: {bounds['sampling']}. Every condition's: cellsim check {outcome.results_path.parent}",
                      highlight=False, markup=False)


def _until_bound_text(bounds: dict, target: float, planned: int | None) -> str:
    """Whether ``--until-bound`` reached its target, stopped at a violation, has runs still to do, or cannot reach it
    with the runs it takes (some failed: they are counted nowhere)."""
    overall = bounds["overall"]
    upper, failures, runs = overall["upper_bound"], overall["failures"], overall["runs"]
    if failures:
        return f"[red]not reached: {failures} violating run(s) in {runs}; the violation is the finding, not the bound[/red]"
    if upper < target:
        return f"[green]reached: {upper:.3g} < {target:g}[/green]"
    failed = bounds.get("excluded_failed_runs", 0)
    shown = f"{upper:.6g}"  # (enough digits to tell it from the target it missed)
    if failed and planned is not None and runs + failed >= planned:
        # every run it takes is done and the failed ones are not redone: the same command would add nothing
        return (f"[red]not reached: {shown} after {runs} runs; {failed} failed and count nowhere. --runs "
                f"{planned + failed} instead of --until-bound adds as many (these are kept)[/red]")
    return f"not reached yet: {shown} after {runs} runs (run the same command to go on)"


def _bound_text(bounds: dict) -> str:
    """Any condition's rate and bound, and each violated condition's (``cellsim check OUT`` lists all)."""
    from cellsim.numbers import probability

    def figures(f):
        return f"{f['failures']} of {f['runs']} runs, rate {probability(f['rate'])}, at most {probability(f['upper_bound'])}"

    lines = [f"any condition: {figures(bounds['overall'])}"]
    lines += [f"{name}: {figures(f)}" for name, f in bounds["conditions"].items() if f["failures"]]
    return "\n".join(lines)


def _run_list(indices: list[int], shown: int = 8) -> str:
    listed = ", ".join(str(i) for i in indices[:shown])
    more = f" and {len(indices) - shown} more" if len(indices) > shown else ""
    return f"{len(indices)} run{'s' if len(indices) > 1 else ''} ({listed}{more})"
