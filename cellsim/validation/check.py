"""The one evidence path: a run's black box and a scenario's validation in, verdicts out.

``check(run)`` is what the CLI (``check``, ``simulate``), campaigns and falsification
call: black box -> trace -> the compiled conditions -> a :class:`CheckedRun` with a
``Verdict`` per condition and for the run. It works on any black box that has the
channels the conditions name: a simulated run (whose folder holds the resolved
``scenario.yaml``), or a recording made beside the real cell checked against a
scenario given explicitly. A live trace that is no black box (the dashboard's) is
checked by the same compiled :class:`SafetyCase`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from cellsim.config.typed_yaml import ConfigError
from cellsim.scenario import ScenarioFile, load_scenario
from cellsim.blackbox import BlackBox
from cellsim.provenance import BLACKBOX, PLAN, REPORT, RESOLVED_SCENARIO
from cellsim.validation.conditions import CheckResult, SafetyCase
from cellsim.validation.defaults import judged_validation
from cellsim.validation.verdict import Verdict
from cellsim.channels import channel_domains
from cellsim.validation.traces import (
    RunTrace,
    TraceError,
    blackbox_domains,
    trace_of_run,
    with_aliases,
)



class CheckError(Exception):
    """The run cannot be checked: the path is not a run, or there are no conditions."""


class NoConditions(CheckError):
    """The run's scenario has no safety conditions to judge it by (its mishaps alone say whether it harmed)."""


@dataclass
class CheckedRun:
    trace: RunTrace
    result: CheckResult
    case: SafetyCase
    timing: dict = field(default_factory=dict)
    """Seconds spent building the trace (``trace``) and evaluating it (``check``)."""
    inputs: list = field(default_factory=list)
    """The files the check read (the run folder's, the scenario's): what no output of it may replace."""

    @property
    def verdict(self) -> Verdict:
        """The run's verdict: the worst of its conditions'."""
        return self.result.verdict


def safety_case(sf: ScenarioFile, vocabulary_domains: dict, channels, recorded_in: Path | None = None) -> SafetyCase:
    """The scenario's validation compiled against the given channel domains (those of the black box
    ``recorded_in``, when a run's: a channel it lacks is said to be the run's)."""
    aliases = sf.scenario.validation.variables
    try:
        vocabulary = with_aliases(vocabulary_domains, aliases, channels)
    except TraceError as e:
        run = f"; the run {recorded_in} has none: was it made from another scenario?" if e.missing and recorded_in else ""
        raise ConfigError(*sf.locate(f"validation.variables.{e.variable}"), f"{e}{run}") from None
    return SafetyCase.compile(judged_validation(sf, channels), vocabulary, sf.locate)


def scenario_safety_case(sf: ScenarioFile) -> SafetyCase:
    """The scenario's validation compiled against the channels its diagram publishes.

    Builds the diagram (without recording): this is how a campaign or
    ``scenario check`` finds a bad formula before any run.
    """
    from cellsim.diagrams.cell import build_cell

    return cell_safety_case(sf, build_cell(sf, seed=sf.scenario.seed, duration=sf.scenario.duration, record=False))


def cell_safety_case(sf: ScenarioFile, cell) -> SafetyCase:
    """The scenario's validation compiled against the channels of a built cell."""
    specs = [spec for spec, _ in cell.channels.values()]
    return safety_case(sf, channel_domains(specs), cell.channels)


def locate_run(path: str | os.PathLike) -> tuple[Path, Path | None]:
    """(black box, resolved scenario or None) of a run folder or a black-box file."""
    path = Path(path)
    if path.is_dir():
        blackbox, scenario = path / BLACKBOX, path / RESOLVED_SCENARIO
        if not blackbox.is_file():
            runs = sorted(p.parent for p in path.glob(f"runs/*/{BLACKBOX}"))
            if runs:  # a campaign folder (whole, or without its plan): point at its runs
                shown = ", ".join(str(r) for r in runs[:3]) + (", ..." if len(runs) > 3 else "")
                what = ("a campaign folder, not a run" if (path / PLAN).is_file() else
                        f"holds runs but no {PLAN}: not a run, and not a campaign cellsim can check whole")
                report = path / REPORT
                raise CheckError(f"{path}: {what}: check one of its {len(runs)} runs ({shown})"
                                 + (f"; its report is {report}" if report.is_file() else ""))
            raise CheckError(f"{path}: not a run folder (no {BLACKBOX})")
        return blackbox, scenario if scenario.is_file() else None
    if path.is_file():
        if path.name != BLACKBOX:  # (a damaged black box is said to be corrupt when it is read)
            with open(path, "rb") as f:
                if f.read(16) != b"SQLite format 3\x00":
                    raise CheckError(f"{path}: not a run folder, nor a black box (a run's {BLACKBOX})")
        scenario = path.parent / RESOLVED_SCENARIO
        return path, scenario if scenario.is_file() else None
    raise CheckError(f"{path}: no such run folder or black box")


def run_files(run: str | os.PathLike) -> list[Path]:
    """The files of the run ``run`` (a run folder or its black box): its black box (and SQLite's files beside it),
    its scenario and the copies of its inputs: what no output may replace. (Other files beside them, an export made
    earlier say, are the user's to replace.)"""
    from cellsim.provenance import INPUTS

    blackbox, scenario = locate_run(run)
    own = [blackbox, *(blackbox.with_name(blackbox.name + suffix) for suffix in ("-wal", "-shm", "-journal"))]
    if scenario is not None:
        own.append(scenario)
        own += [p for p in (scenario.parent / INPUTS).rglob("*") if p.is_file()]
    return [p for p in own if p.is_file()]


def locate_rebuildable_run(run: str | os.PathLike, purpose: str) -> tuple[Path, ScenarioFile]:
    """(black box, its scenario loaded) of a run whose cell is to be rebuilt; a CheckError without a
    scenario.yaml beside the black box, saying ``purpose`` (why the cell is rebuilt)."""
    from cellsim.scenario import load_scenario

    blackbox, scenario = locate_run(run)
    if scenario is None:
        raise CheckError(f"{run}: no scenario.yaml beside the black box; {purpose}")
    return blackbox, load_scenario(scenario)


@dataclass
class CheckedSimulation:
    """A run simulated and checked: its summary, and its check (None: the scenario has no conditions)."""

    summary: object
    """The run's :class:`cellsim.simulation.RunSummary`."""
    checked: CheckedRun | None

    @property
    def finding(self) -> bool:
        """A safety finding: a hazard reached its mishap phase, or a condition does not hold."""
        return self.summary.mishap or (self.checked is not None and not self.checked.result.all_hold)


def simulate_and_check(sf: ScenarioFile, out: str | os.PathLike, *, always_check: bool = False,
                       **simulate_args) -> CheckedSimulation:
    """Simulate ``sf`` into ``out`` (:func:`cellsim.simulation.simulate` with ``simulate_args``) and check the run
    against its safety conditions: what the CLI's ``simulate``, each run of a campaign or a search, and
    ``verify``'s witness replays do. The conditions are compiled against the built cell before the run folder
    is touched, so a bad formula leaves nothing written. A scenario without conditions is checked only
    ``always_check`` (a campaign's runs: their use cases and coverage)."""
    from cellsim.simulation import simulate

    cases: list[SafetyCase] = []

    def compile_conditions(cell) -> None:
        case = cell_safety_case(cell.sf, cell)  # the scenario's conditions and the default ones
        if always_check or case.conditions:
            cases.append(case)

    summary = simulate(sf, out, before_run=compile_conditions, **simulate_args)
    return CheckedSimulation(summary, check(out, case=cases[0]) if cases else None)


def check(run: str | os.PathLike, sf: ScenarioFile | None = None, *, case: SafetyCase | None = None) -> CheckedRun:
    """Check the run at ``run`` (a run folder or a black box) against ``sf``'s validation (default: the
    run's own scenario), or against ``case`` already compiled (a campaign's, a simulation's)."""
    import time

    blackbox, scenario = locate_run(run)
    if case is None and sf is None:
        if scenario is None:
            raise CheckError(f"{run}: no {RESOLVED_SCENARIO} beside the black box; name a scenario with --scenario")
        sf = load_scenario(scenario)
    started = time.perf_counter()
    with BlackBox(blackbox) as bb:
        if case is None:
            bb.check_channels()  # a record the black box cannot place is its fault, not the scenario's
            case = safety_case(sf, blackbox_domains(bb), bb.channels(), recorded_in=blackbox)
            if not case.conditions:
                raise NoConditions(f"{sf.source}: the scenario has no safety conditions (validation.conditions, or the "
                                 f"default ones of a cell with a robot and a person) to check")
        trace = trace_of_run(bb, case.validation.variables)
    traced = time.perf_counter()
    result = case.check(trace.trace, complete=trace.complete)
    inputs = [*run_files(run), *(sf.inputs() if sf is not None else ())]
    return CheckedRun(trace, result, case, {"trace": traced - started, "check": time.perf_counter() - traced}, inputs)
