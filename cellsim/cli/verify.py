"""``cellsim verify``: model-check the safety controller against an abstract cell, and replay witnesses on the twin."""

from __future__ import annotations

import sys
from pathlib import Path

from cellsim.cli.common import InputError, _add_set, _load


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "verify",
        help="model-check the safety controller against an abstract cell (Storm)",
        description="Build an abstract model of the cell (an MDP: every module kind's abstraction, the risk model "
        "exactly as the controller executes it, the floor cut into places by what the sensors read) and check it with "
        "Storm: each hazard's mishap unreachable, each validation condition of a checkable shape, and the validation "
        "file's own PCTL (verify:). A property violated in the model has its witness written as a scenario under --out, "
        "simulated and checked: the twin confirms it (the property is VIOLATED) or refutes it (UNDECIDED: the "
        "abstraction is too coarse there). Exits 0 when every property holds, 1 when one is violated (a witness the "
        "twin confirms), 3 when none is but one is undecided (refuted, not replayed, or no witness), 2 on bad input. "
        "docs/verify.md says what a result means.",
        epilog="Exit codes: 0 every property holds, 1 one is violated (its witness confirmed on the twin), 3 none "
        "is violated but one is undecided, 2 usage or input error, 130 interrupted (Ctrl-C or SIGTERM).",
    )
    p.add_argument("scenario", type=Path, help="scenario YAML")
    p.add_argument("--out", type=Path, help="folder for witnesses and their runs (default: runs/<scenario>-verify)")
    p.add_argument("--export", type=Path, metavar="FILE",
                   help="also write the model in the PRISM language (and its properties beside it, FILE with .props)")
    p.add_argument("--timed", action="store_true",
                   help="bound the cell's durations (moves, dwells, cycles) below: closer witnesses, far more states")
    p.add_argument("--no-replay", dest="replay", action="store_false", help="do not replay witnesses on the twin")
    p.add_argument("--refine", type=int, default=None, metavar="N",
                   help="where a module's abstraction finds a witness doing what the module cannot (a person crossing "
                        "a place faster than it walks...), refine the abstraction there and check again instead of "
                        "running that witness on the twin, at most N times (default 3, at most 20; 0: never). It "
                        "needs the replays: --no-replay refines nothing, and refuses a --refine above 0")
    p.add_argument("--only", action="append", default=[], metavar="NAME",
                   help="check only the properties named like NAME (shell-style: 'HS:*', 'NoHarm'; repeatable); the "
                        "others are not modelled at all, so the model is built for these alone (a NAME that names no "
                        "property is an error listing them). The exit code then speaks for these only")
    p.add_argument("--json", action="store_true", help="print the results as JSON on standard output")
    _add_set(p)
    p.set_defaults(handler=run)


def run(args) -> int:
    import json

    from cellsim import api

    if args.refine is not None and not 0 <= args.refine <= 20:
        raise InputError(f"--refine {args.refine}: expected 0 to 20 refinements")
    if args.refine and not args.replay:
        raise InputError("--refine ends with the last round's witnesses run on the twin: it needs the replays "
                         "--no-replay turns off")
    sf = _load(args)
    say = (lambda text: None) if args.json else (lambda text: print(f"  {text}", file=sys.stderr))
    out = args.out or Path("runs") / f"{sf.scenario.folder_name}-verify"
    if out.exists() and not out.is_dir():  # said now, not after Storm has run
        raise InputError(f"--out {out} is a file: name a folder for the witnesses and their runs")
    for folder in Path(out).parents:  # (a file on the way, too)
        if folder.exists():
            if not folder.is_dir():
                raise InputError(f"--out {out}: {folder} is a file, not a folder to write into")
            break

    try:
        result = api.verify_cell(sf, export=args.export, timed=args.timed, replay_in=out if args.replay else None,
                                 refine=args.refine, progress=say, only=args.only)
    except api.VerifyError as e:
        raise InputError(f"{args.scenario}: {e}") from None
    replays = result.replays
    if args.json:
        json.dump(_json(result, replays), sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        _print(result, replays, args.export)
    return result.exit_code


def _json(result, replays) -> dict:
    stats = result.stats
    endings = {f.name: f for f in result.endings()}
    return {
        "holds": result.holds,
        "exit_code": result.exit_code,
        "refinements": [{"step": r.step, "refinement": r.key, "property": r.prop, "why": r.why}
                        for r in result.refinements],
        "states": stats.states, "transitions": stats.transitions, "choices": stats.choices,
        "largest_states": (result.largest or stats).states,
        "engine": ", then ".join(["symbolic", *(["explicit"] if stats.by_state else []),
                                  *(["sparse"] if stats.made_sparse else []), *(["held"] if stats.symbolic else [])]),
        "seconds": {k: round(v, 4) for k, v in result.times.items()},
        "period": result.model.cell.period,
        "assumptions": result.model.cell.assumptions,
        "properties": [
            {
                "name": r.prop.name, "description": r.prop.description, "value": r.value, "holds": r.holds,
                "ending": None if endings[r.prop.name].ending is None else endings[r.prop.name].ending.value,
                "reason": endings[r.prop.name].reason,
                "witness_periods": len(r.witness) if r.witness else None,
                "twin": None if r.prop.name not in replays else {
                    "confirmed": replays[r.prop.name].confirmed,
                    "shift": replays[r.prop.name].shift,
                    "scenarios": [str(p) for p in replays[r.prop.name].scenarios],
                    "runs": [str(p) for p in replays[r.prop.name].runs],
                    "violated": replays[r.prop.name].violated,
                },
            }
            for r in result.results
        ],
        "not_checked": [{"name": s.name, "reason": s.reason} for s in result.model.skipped],
        "not_asked": list(result.model.unasked),
    }


def _print(result, replays, export) -> None:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from cellsim.api import EXPLICIT_LIMIT

    console = Console(highlight=False)
    stats, model = result.stats, result.model
    endings = {f.name: f for f in result.endings()}
    table = Table(title=f"cellsim verify: {escape(model.cell.sf.scenario.name)}", title_justify="left")
    for column in ("property", "value", "in the model", "twin", "verdict"):
        table.add_column(column)
    for r in result.results:
        if r.holds is None:
            verdict = "(value)"
        else:
            verdict = "[green]holds[/]" if r.holds else "[red]violated[/]"
            if r.prop.within is not None:
                verdict = f"[green]within {r.prop.within:g} s[/]" if r.holds else f"[yellow]not within {r.prop.within:g} s[/]"
        value = f"{r.value:.6g}" if isinstance(r.value, float) else str(r.value)
        ending = endings[r.prop.name].ending
        twin = ""
        if r.holds is False and r.witness is None and ending is not None and ending.value != "holds":
            twin = "no witness (decision diagrams)" if stats.symbolic and r.prop.bad else ""  # (a response that holds under
            # fairness wants none: its window's violation is no violation of the condition)
        if r.prop.name in replays:
            rp = replays[r.prop.name]
            twin = (f"[red]confirmed[/] ({escape(rp.scenarios[-1].name)})" if rp.confirmed
                    else "[yellow]refuted[/]: the abstraction is too coarse here")
        final = {None: "", "holds": "[green]HOLDS[/]", "violated": "[red]VIOLATED[/]",
                 "undecided": "[yellow]UNDECIDED[/]"}[None if ending is None else ending.value]
        table.add_row(escape(r.prop.name), value, verdict, twin, final)
    console.print(table)
    for r in result.refinements:
        console.print(f"  refinement {r.step}: {escape(str(r))}")
    for r in result.results:  # a response slower than its window that holds all the same: why
        f = endings[r.prop.name]
        if r.holds is False and f.ending is not None and f.ending.value == "holds":
            console.print(f"  holds: {escape(f.name)}: {escape(f.reason)}")
    for f in endings.values():
        if f.ending is not None and f.ending.value == "undecided":
            console.print(f"  undecided: {escape(f.name)}: {escape(f.reason)}")
    for s in model.skipped:
        console.print(f"  not checked: {escape(s.name)}: {escape(s.reason)}")
    if model.unasked:
        console.print(f"  not asked for (--only): {escape(', '.join(model.unasked))}")
    times = result.times
    how = [*(["built state by state"] if stats.by_state else []), *(["made sparse"] if stats.made_sparse else []),
           *(["sought with people held, its own model too large to make sparse"] if stats.symbolic else [])]
    shape = ("checked as decision diagrams (without monitors: each obligation as a nested formula)"
             + (f", a violated property's witness from its own model {' or '.join(how)}" if how else ""))
    last = " (the last round's)" if result.refinements else ""
    console.print(f"  the cell{last}: {stats.states:,} states, {stats.transitions:,} transitions; {shape}; "
                  f"period {model.cell.period:g} s; floor {times.get('floor', 0):.2f} s, Storm build "
                  f"{times.get('storm_build', 0):.2f} s, check {times.get('storm_check', 0):.2f} s{last}")
    console.print("  assumptions:")
    for a in model.cell.assumptions:
        console.print(f"    - {escape(a)}")
    for name, rp in replays.items():
        where = rp.runs[-1] if rp.runs else None
        if rp.confirmed:
            console.print(f"  {escape(name)}: the twin confirms the witness: {escape(str(rp.scenarios[-1]))} "
                          f"(started {rp.shift:g} s later); its run {escape(str(where))} violates "
                          f"{escape(', '.join(rp.violated) or 'the property')}")
        else:
            console.print(f"  {escape(name)}: the twin refutes the witness in {len(rp.runs)} runs "
                          f"({escape(str(rp.scenarios[0]))} and later starts): the abstract model allows a behaviour "
                          "the twin does not show; a finding about the model, not the cell")
    if stats.symbolic and any(r.holds is False and r.witness is None and r.prop.within is None and r.prop.bad
                              for r in result.results):
        console.print(f"  no witness: a property's own model has too many transitions to make sparse (over "
                      f"{EXPLICIT_LIMIT:,}), a witness cannot be read from decision diagrams, and no model with people "
                      "held at their start has the violation; the violations are the abstract model's, not yet tried "
                      "on the twin")
    if export is not None:
        console.print(f"  wrote {escape(str(export))} and {escape(str(export.with_suffix('.props')))}")
