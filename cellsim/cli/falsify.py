"""``cellsim falsify``: search the scenario's configuration space for a run that violates a condition."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import cellsim
from cellsim.cli.common import EXIT_FINDING, EXIT_INPUT, EXIT_INTERRUPTED, EXIT_OK, InputError, RunsBar, _add_set, _load_for_runs, add_scheduler_argument


def add_parser(subparsers) -> None:
    cmd = subparsers.add_parser(
        "falsify",
        help="search for a run that violates a safety condition (quality diversity, CMA-ES, or random)",
        description="Search the configuration space the scenario's campaign samplers define (their ranges, "
        "choices and simplexes) for a run that violates a safety condition, choosing each run from the scores "
        "of those before it: the conditions' robustness (how far a run was from violating them) and the "
        "validation section's guides (two situations whose meeting stresses the controller). Stops at the first "
        "violation of a condition searched for (--condition) or after --budget runs. Every run is an ordinary run folder under OUT/runs (its place in "
        "the search in its result.json); OUT/results.json and OUT/report.html report the search. The runs are "
        "chosen, not drawn at random, so no violation rate or bound is given: for a bound, run a campaign. "
        "Exits 1 when a run violated any condition (every run is checked on all) or left one undecided, 0 "
        "when the budget ran out without one (which is no evidence of safety), 2 for bad input. See "
        "docs/falsify.md.",
    )
    cmd.add_argument("scenario", type=Path, help="scenario YAML file")
    cmd.add_argument("--budget", type=int, default=100, help="most runs to spend (default 100)")
    cmd.add_argument("--method", choices=cellsim.SEARCH_METHODS, default=cellsim.DEFAULT_SEARCH,
                     help="qd: quality diversity (CMA-ME), the most critical run per cell of use cases x situation "
                     "(default: the fastest in scripts/bench_falsify.py); cmaes: CMA-ES on the score; random: the "
                     "campaign's own distribution, the baseline")
    cmd.add_argument("--condition", action="append", default=[], metavar="NAME",
                     help="a condition to falsify (repeatable; default: every condition)")
    cmd.add_argument("--batch", type=int, help="runs per generation (default: the method's; random: --jobs)")
    cmd.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="worker processes (default: one per CPU)")
    add_scheduler_argument(cmd)
    cmd.add_argument("--seed", type=int, default=0, help="search seed: the search is a pure function of it (default 0)")
    cmd.add_argument("--out", type=Path, help="output folder (default: campaigns/<scenario>-falsify-<method>-seed<seed>)")
    cmd.add_argument("--duration", type=float, help="simulated seconds per run (default: the scenario's duration)")
    cmd.add_argument("--overwrite", action="store_true", help="replace an earlier search or campaign in OUT, once the new search "
                     "has written its results (interrupted, it leaves the earlier one as it was)")
    _add_set(cmd)
    cmd.add_argument("--quiet", action="store_true", help="print nothing but errors")
    cmd.set_defaults(handler=run)


def run(args) -> int:
    from rich.console import Console

    from cellsim import api

    sf = _load_for_runs(args, {k: api.COUNT_LIMITS[k] for k in ("budget", "jobs", "batch")})
    out = args.out or Path("campaigns") / f"{sf.scenario.folder_name}-falsify-{args.method}-seed{args.seed}"
    console = Console(stderr=True, quiet=args.quiet)
    try:
        with _search_progress(console, args.quiet, args.budget) as report:
            outcome = api.falsify(sf, out, budget=args.budget, method=args.method, conditions=args.condition,
                                  seed=args.seed, duration=args.duration, jobs=args.jobs, batch=args.batch,
                                  scheduler=args.scheduler, overwrite=args.overwrite, progress=report)
    except (api.CampaignError, ValueError) as e:
        raise InputError(str(e)) from None
    except KeyboardInterrupt:
        print(f"cellsim: interrupted; the runs so far are in {out}/runs" + (
            " (where it was replacing an earlier search or campaign, that one is back as it was instead)"
            if args.overwrite else ""), file=sys.stderr)
        return EXIT_INTERRUPTED
    if not args.quiet:
        print_search(outcome)
    runs = outcome.results["runs"]
    failed = [r for r in runs if r.get("status") == "failed"]
    if failed and len(failed) == len(runs):
        print(f"cellsim: error: every run failed, e.g. run {failed[0]['index']}: {failed[0].get('error', '?')}",
              file=sys.stderr)
        return EXIT_INPUT
    totals = outcome.results["totals"]
    # a violation is a finding whichever condition it is of: the search targets some, the runs are checked on all
    found = outcome.first_violation is not None or totals["violating_runs"] or totals["undecided_runs"]
    return EXIT_FINDING if found else EXIT_OK


def _search_progress(console, quiet: bool, total: int) -> RunsBar:
    """A progress bar of the budget spent, with the best score so far."""
    return RunsBar(console, quiet, total, "best score {task.fields[best]}  violating {task.fields[violating]}",
                   dict(best="-", violating=0), lambda p: dict(completed=p.done, best=f"{p.best:.3f}" if p.done else "-", violating=p.violating),
                   eta=False)


def _space_text(samplers: dict) -> str:
    """The configuration points a search moved, each with its range (as results.json records the samplers)."""
    parts = []
    for name, s in samplers.items():
        if s.get("kind") == "uniform":
            parts.append(f"{name} in [{s['low']:g}, {s['high']:g}]")
        elif s.get("kind") == "choice":
            parts.append(f"{name}: one of {', '.join(map(str, s['values']))}")
        else:
            parts.append(f"{name}: values of at least {s.get('minimum', 0):g} summing to {s.get('total'):g}")
    return "; ".join(parts) or "-"


def print_search(outcome) -> None:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    results, search = outcome.results, outcome.results["search"]
    runs = {r["index"]: r for r in results["runs"]}
    table = Table(title="Falsification", show_header=False, title_justify="left")
    table.add_column(style="bold")
    table.add_column()
    table.add_row("method", f"{search['method']}, batches of {search['batch']} runs, {search['dimension']} coordinates")
    table.add_row("searched over", _space_text(results["campaign"].get("samplers") or {}))
    table.add_row("conditions", ", ".join(search["conditions"]))
    table.add_row("guides", ", ".join(search["guides"]) or "none (the conditions' robustness alone)")
    first = search["first_violation"]
    if first is None:
        table.add_row("result", f"no violation of {', '.join(search['conditions'])} in {search['runs']} runs (the "
                      "budget): no evidence of safety, only of what this search did not find")
    else:
        run = runs[first]
        table.add_row("result", f"[red]violation found at run {first}[/red] ({search['runs_to_first_violation']} runs): "
                      f"{', '.join(run['violations'])}")
        table.add_row("its configuration", "\n".join(f"{k} = {v:.6g}" if isinstance(v, float) else f"{k} = {v}"
                                                     for k, v in run["configuration"].items()))
        table.add_row("re-run it", escape(run["rerun"]))
    targets = set(search["conditions"])
    others: dict[str, list] = {}
    for r in results["runs"]:  # every run is checked on every condition: what it showed beside the targets
        for name in r.get("violations", ()):
            if name not in targets:
                others.setdefault(name, []).append(r["index"])
    if others:
        table.add_row("other violations", "[red]" + "\n".join(f"{name}: runs {', '.join(map(str, found))}"
                                                             for name, found in others.items()) + "[/red]")
    for what, found in results["totals"].get("finding_runs", {}).items():  # (the report's harm section)
        table.add_row(f"runs {what}", f"[red]{', '.join(map(str, found))}[/red] (the report's harm section)")
    best = search["best"]
    table.add_row("lowest score", f"{best['score']:.3f} (run {best['index']})")
    for cell in search.get("archive", [])[:6]:
        table.add_row("archive cell", f"use cases {', '.join(cell['use_cases']) or 'none'} x {cell['situation']}: "
                      f"score {cell['score']:.3f}")
    table.add_row("results", str(outcome.results_path))
    table.add_row("report", str(outcome.report_path))
    console = Console()
    console.print(table)
    console.print(f"No bound: {search['not_a_sample']}.", highlight=False, markup=False)
