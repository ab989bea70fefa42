"""Test campaigns: many sampled variants of a scenario, simulated and checked in parallel.

A campaign is a pure function of its inputs: the scenario and every file it
uses (validation file, risk models, robot models), the ``--set`` overrides, the
campaign seed, the duration and cellsim's version, and of the number of runs.
Run ``i`` draws its configuration from the scenario's samplers
(``campaign.samplers``) and its simulation seed from ``(seed, i)`` (see
:mod:`cellsim.config.sampling`), so any run can be redone alone, in any
order, in any process.

A campaign is identified by the *content* of its inputs (see
:mod:`cellsim.provenance`): a SHA-256 of the files' bytes with the overrides,
seed, duration and cellsim's version. The campaign reads its files once and
runs from a snapshot of them, so editing a file while it runs changes nothing.

The output folder holds::

    OUT/campaign.json        the identity: content hash, per-file digests, overrides,
                             seed, duration, cellsim version; and the number of runs
    OUT/inputs/              the snapshot of the input files every run is made from
    OUT/runs/0007/           one folder per run, as written by ``cellsim simulate``,
        blackbox.sqlite      ... its black box, with its provenance in its metadata
        scenario.yaml        ... the run's resolved scenario, seed included, validation
                             inline: ``cellsim simulate OUT/runs/0007/scenario.yaml`` redoes it
        inputs/              ... copies of the risk and robot models it used, which
                             scenario.yaml refers to: the folder re-runs alone, anywhere
        trace.json           ... its trace over the validation section's variables (the
                             ``check --export-trace`` format), for the report's timelines
        result.json          ... its verdicts, use cases and covered situations;
                             written last, so its presence means the run is done
    OUT/results.json         every run's result, the totals and the provenance
    OUT/report.html          the self-contained report

Running the same command again on the same ``OUT`` resumes: finished runs are
kept, unfinished ones are redone, and asking for more runs extends the
campaign, as long as the inputs' content is the same. If anything changed, the
campaign refuses with one line naming what changed; ``restart`` (``--restart``)
discards the folder's runs and starts afresh. Runs of different inputs are
never mixed.

Workers end with the campaign process, however it ends (SIGKILL included).
"""

from __future__ import annotations

import json
import os
import shlex
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

from cellsim.atomic import write_text
from cellsim.campaign.engine import (
    PLAN,
    REPORT,
    RESULT,
    RESULTS,
    RUNS,
    TRACE,
    CampaignError,
    CampaignPlan,
    check_scheduler,
    check_snapshot,
    claimed,
    discard,
    execute_run,
    holds_others,
    keep_before,
    origin_of,
    run_all,
    run_dir,
    set_up,
    shown_variables,
    snapshot_plan,
    worker_pool,
    write_json,
)
from cellsim.config.sampling import describe_sampling
from cellsim.config.typed_yaml import to_data
from cellsim.config.validation import description_of, formula_of
from cellsim.provenance import INPUTS, changes, provenance

__all__ = ["PLAN", "REPORT", "RESULT", "RESULTS", "RUNS", "TRACE", "CampaignError", "CampaignOutcome", "CampaignPlan",
           "Progress", "execute_run", "finish", "run_campaign", "run_dir"]


def _results_text(results: dict) -> str:
    """results.json: indented, but each run on one compact line. Indenting every run's verdicts
    makes it no easier to read and takes Python's slow encoder (0.8 s at 1000 runs)."""
    runs = ",\n  ".join(json.dumps(r, separators=(",", ":")) for r in results["runs"])
    head = {key: ([] if key == "runs" else value) for key, value in results.items()}
    # one space of indent marks the top-level key: "runs" inside "campaign" and "totals" sits deeper
    return json.dumps(head, indent=1).replace('\n "runs": []', '\n "runs": [\n  ' + runs + "\n ]", 1)


# --------------------------------------------------------------------------- the campaign


@dataclass
class Progress:
    """What the campaign reports after every finished run."""

    done: int
    total: int
    violating_runs: int
    failed: int
    coverage: float


@dataclass
class CampaignOutcome:
    results: dict
    results_path: Path
    report_path: Path
    resumed: int = 0
    timing: dict = field(default_factory=dict)

    @property
    def violating_runs(self) -> int:
        return self.results["totals"]["violating_runs"]


RESTART_HINT = "pass --restart to discard its runs and start afresh, or choose another --out"


def prepare(plan: CampaignPlan, out: Path, identity: dict, restart: bool = False) -> list[dict]:
    """Create, resume or (``restart``) start afresh the campaign folder; returns the
    results of runs already done.

    A folder is resumed only if it holds a campaign of the same ``identity``
    (content of the inputs, see :mod:`cellsim.provenance`); otherwise CampaignError,
    one line naming what changed. ``restart`` discards a campaign folder's runs
    (never a folder that is not a campaign's).
    """
    plan_path = out / PLAN
    check_resumable(out, identity, restart)
    from cellsim.validation.bound import counts_against

    sizing = []  # how the number of runs was decided, call by call (a bound's honesty depends on it)
    if plan_path.exists() and restart:
        discard(out)
    elif plan_path.exists():
        try:
            sizing = list(json.loads(plan_path.read_text()).get("sizing") or [])
        except (OSError, ValueError, AttributeError):
            sizing = []
        beyond = _finished_from(out, plan.runs, identity)
        if beyond:  # a sample is never made smaller after the fact: a run left out may be one that violated
            asked = (f"the {plan.runs} runs --until-bound {plan.until_bound:g} takes" if plan.until_bound is not None
                     else f"--runs {plan.runs}")
            instead = " instead of --until-bound" if plan.until_bound is not None else ""
            raise CampaignError(f"{out} holds {len(beyond)} finished run(s) of these inputs beyond {asked} "
                                f"(up to run {max(beyond) + 1}): pass --runs {max(beyond) + 1} or more{instead} to "
                                f"keep them, or {RESTART_HINT}")
    out.mkdir(parents=True, exist_ok=True)
    done = []
    for index in range(plan.runs):
        path = run_dir(out, index) / RESULT
        if path.is_file():
            try:
                result = json.loads(path.read_text())
            except json.JSONDecodeError:
                path.unlink()  # a result cut short: redo the run
                continue
            if result.get("inputs_hash") == identity["hash"]:
                done.append(result)  # any other is redone: never count a run of other inputs
    sizing.append({"runs": plan.runs, "until_bound": plan.until_bound, "finished_before": len(done),
                   "against_before": sum(1 for r in done if counts_against(r))})
    write_json(plan_path, {"identity": identity, "runs": plan.runs, "scenario": plan.scenario, "sizing": sizing})
    return done


def sampled_bounds(runs: list[dict], conditions: list[str], distribution: str, sizing: list[dict]) -> dict:
    """The ``bounds`` block of a campaign's results (:func:`cellsim.validation.bound.campaign_bounds`) for runs drawn
    from ``distribution`` (in words), their number decided as ``sizing`` (``campaign.json``) says: the one rule for
    the campaign and for a check of its folder. The distribution is kept apart (``distribution``), so a check counting
    other runs says how their number was decided afresh."""
    from cellsim.validation.bound import campaign_bounds, counts_against

    completed = [r for r in runs if r.get("status") not in ("failed", "unfinished")]
    how = chosen_as_they_came(sizing, any(counts_against(r) for r in completed))
    return {**campaign_bounds(runs, conditions, "; ".join(filter(None, [distribution, how]))),
            "distribution": distribution}


def chosen_as_they_came(sizing: list[dict], any_against: bool) -> str | None:
    """How the number of runs depended on the runs' outcomes, in words, or None where it did not: ``--until-bound``
    that stopped at a run counted against the bound (``any_against``: one did; with none, its runs went to the number
    fixed in advance, and 0 of them is an exact bound), and a campaign extended after runs counted against it. The
    exact bound takes the number of runs as fixed."""
    stopped = any_against and any(entry.get("until_bound") is not None for entry in sizing)
    # a plan changed (more runs, or --until-bound given or dropped) once runs against it were seen; resuming an
    # interrupted campaign as it was planned is no new decision
    def plan(entry):
        return entry.get("runs"), entry.get("until_bound")

    extended = any(entry.get("against_before") and plan(entry) != plan(sizing[k - 1])
                   for k, entry in enumerate(sizing) if k)
    if not (stopped or extended):
        return None
    how = []
    if stopped:
        how.append("--until-bound stops at the first run counted against the bound")
    if extended:
        how.append("the campaign was extended after runs counted against it")
    return (f"the number of runs was decided as their outcomes came ({'; '.join(how)}): the exact bound takes it as "
            "fixed in advance, so it is approximate here")


def _finished_from(out: Path, first: int, identity: dict) -> list[int]:
    """The indices, from ``first`` on, of the runs of ``out`` finished with these inputs (``identity``)."""
    found = []
    for path in sorted((out / RUNS).glob("*/" + RESULT)) if (out / RUNS).is_dir() else ():
        name = path.parent.name
        if not name.isdigit() or int(name) < first:
            continue
        try:
            result = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError):
            continue  # a result cut short counts as not finished (it would be redone)
        if isinstance(result, dict) and result.get("inputs_hash") == identity["hash"]:
            found.append(int(name))
    return found


def check_resumable(out: Path, identity: dict, restart: bool = False) -> None:
    """CampaignError unless ``out`` may take this campaign: absent, empty, a campaign of the same ``identity``
    (resumed), or any campaign's with ``restart``; reads only (called before anything is written, and again
    under the folder's lock)."""
    plan_path = out / PLAN
    if plan_path.exists():
        if restart:
            return
        try:
            previous = json.loads(plan_path.read_text())
            old = previous.get("identity")
        except (json.JSONDecodeError, AttributeError) as e:
            raise CampaignError(f"{plan_path}: unreadable ({e}); {RESTART_HINT}") from None
        if previous.get("search") is not None:
            raise CampaignError(f"{out} holds a falsification search, whose runs were chosen, not drawn at random: "
                                f"they are never counted as a campaign's; {RESTART_HINT}")
        if not isinstance(old, dict) or "hash" not in old:
            raise CampaignError(
                f"{out} holds a campaign of an earlier cellsim, which did not record the content of its inputs, "
                f"so it cannot be resumed safely; {RESTART_HINT}"
            )
        differences = changes(old, identity)
        if differences:
            raise CampaignError(f"{out} holds a different campaign ({'; '.join(differences)}); {RESTART_HINT}")
    elif holds_others(out):
        raise CampaignError(f"{out} exists and is not a campaign folder; choose another --out")


def run_campaign(
    plan: CampaignPlan,
    out: str | os.PathLike,
    jobs: int = 1,
    on_progress: Callable[[Progress], None] | None = None,
    restart: bool = False,
    scheduler: str | None = None,
) -> CampaignOutcome:
    """Run (or resume) the campaign into ``out``; writes results.json and report.html.

    ``scheduler``: the address of a Dask scheduler to run on instead of ``jobs``
    local processes (:mod:`cellsim.campaign.cluster`); the runs are the same.

    Raises ConfigError for a bad scenario and CampaignError for a bad folder (one
    holding a campaign of other inputs, unless ``restart``), both before any run
    starts. KeyboardInterrupt stops the workers; finished runs stay, and running
    the same campaign again resumes it.
    """
    out = Path(out)
    wall_start = time.perf_counter()
    runs = set_up(plan.scenario, plan.overrides, plan.seed, plan.duration)
    # every refusal before the folder is touched, lock file included
    check_resumable(out, runs.identity, restart)
    check_scheduler(scheduler)
    check_snapshot(runs.inputs, plan.overrides)
    with claimed(out, f"{out} is being written by another cellsim campaign; choose another --out"):
        return _run_locked(plan, out, jobs, on_progress, restart, runs, wall_start, scheduler)


def _run_locked(plan, out: Path, jobs, on_progress, restart, runs, wall_start, scheduler=None) -> CampaignOutcome:
    """The campaign, with ``out`` locked against every other cellsim process."""
    from cellsim.validation.bound import counts_against

    results = {r["index"]: r for r in prepare(plan, out, runs.identity, restart)}
    worker_plan = snapshot_plan(plan, out, runs.inputs)  # every run is made from the bytes hashed
    case = runs.case
    resumed = len(results)

    def report_progress():
        if on_progress is not None:
            done = list(results.values())
            coverage = case.coverage.merge([r["coverage"] for r in done if "coverage" in r]).overall
            on_progress(Progress(len(done), plan.runs, sum(1 for r in done if r.get("violations")),
                                 sum(1 for r in done if r.get("status") == "failed"), coverage))

    made: list[int] = []  # the runs this command makes

    def take(result: dict) -> None:
        results[result["index"]] = result
        made.append(result["index"])
        report_progress()

    # --until-bound: the campaign ends at the first run that counts against the bound: no later run is started, and
    # one in flight when it came is left out (the runs are those one worker would have made, in order)
    bounded = plan.until_bound is not None

    def cutoff() -> int | None:
        against = [i for i, r in results.items() if counts_against(r)] if bounded else []
        return min(against) + 1 if against else None

    report_progress()
    todo = [(i, None, None) for i in range(plan.runs) if i not in results and (cutoff() is None or i < cutoff())]
    cluster = None
    if todo:
        with worker_pool(jobs, scheduler, out / INPUTS) as workers:
            run_all(workers, worker_plan, out, todo, origin_of(out, plan.scenario, runs.identity), take, cutoff)
            cluster = workers.record()
    keep_before(out, results, cutoff(), made)
    done = [results[i] for i in range(plan.runs) if i in results]
    return finish(plan, out, runs.scenario, case, done, resumed, wall_start, provenance(runs.identity), cluster=cluster)


def finish(plan, out: Path, sf, case, runs: list[dict], resumed: int, wall_start: float, record: dict | None = None,
           search: dict | None = None, cluster: dict | None = None) -> CampaignOutcome:
    """Totals, results.json and report.html from the runs' results; ``record`` is the
    campaign's provenance (:func:`cellsim.provenance.provenance`); ``search``, the
    falsification search's record when a search chose the runs (then no bound is given)."""
    from cellsim.campaign.report import finding_runs, write_report
    from cellsim.scenario import unit_of

    sc = sf.scenario
    try:
        sizing = [] if search else (json.loads((out / PLAN).read_text()).get("sizing") or [])
    except (OSError, ValueError, AttributeError):
        sizing = []
    t0 = time.perf_counter()
    coverage = case.coverage.merge([r["coverage"] for r in runs if "coverage" in r])
    t_coverage = time.perf_counter() - t0
    completed = [r for r in runs if r.get("status") != "failed"]
    judged = case.validation  # the scenario's conditions and the default ones its cell is judged by
    conditions = list(judged.conditions)
    stage = lambda name: sum(r.get("timing", {}).get(name, 0.0) for r in runs)  # noqa: E731
    results = {
        "campaign": {
            "scenario": plan.scenario,
            "scenario_name": sc.name,
            "overrides": list(plan.overrides),
            "runs": plan.runs,
            "seed": plan.seed,
            "duration": plan.duration if plan.duration is not None else sc.duration,
            "created": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "conditions": {n: formula_of(c) for n, c in judged.conditions.items()},
            "waived": dict(judged.waive),
            "use_cases": {n: formula_of(u) for n, u in sc.validation.use_cases.items()},
            "descriptions": {n: description_of(e) for n, e in {**judged.conditions, **sc.validation.use_cases}.items()
                             if description_of(e)},
            "samplers": {name: to_data(s) for name, s in sc.campaign.samplers.items()},
            "until_bound": plan.until_bound,
            "sizing": sizing,
        },
        "provenance": record,
        "runs": [{**r, "rerun": _rerun_command(out, r)} for r in runs],
        "totals": {
            "runs": len(runs),
            "completed": len(completed),
            "failed": len(runs) - len(completed),
            "violating_runs": sum(1 for r in runs if r.get("violations")),
            "violations": {c: sum(c in r.get("violations", ()) for r in runs) for c in conditions},
            "undecided_runs": sum(1 for r in runs if r.get("undecided")),
            "undecided": {c: sum(c in r.get("undecided", ()) for r in runs) for c in conditions},
            "use_cases": {u: sum(u in r.get("use_cases", ()) for r in runs) for u in sc.validation.use_cases},
            "coverage": coverage.to_json(),
            "finding_runs": finding_runs(runs),
        },
        "bounds": {"excluded": search["not_a_sample"]} if search else sampled_bounds(runs, conditions, describe_sampling(
            sc.campaign.samplers, {name: point.paths for name, point in sc.configuration_points.items()},
            plan.duration if plan.duration is not None else sc.duration, tuple(plan.overrides)), sizing),
        "timing": {
            "simulate": stage("simulate"),
            "trace": stage("trace"),
            "check": stage("check"),
            "coverage": t_coverage,
        },
    }
    if search:
        results["search"] = search
    if cluster:
        results["cluster"] = cluster
    t0 = time.perf_counter()
    timelines = {r["index"]: trace for r in runs if (trace := _run_trace(out, r, sc)) is not None}
    phases, units = _channel_facts(out, runs, sc.validation.variables)
    results["campaign"]["units"] = units
    results["campaign"]["configuration_units"] = {
        key: unit_of(sc, key) for key in dict.fromkeys(k for r in runs for k in r.get("configuration", {}))
    }
    results["timing"]["report"] = time.perf_counter() - t0
    results["timing"]["wall"] = time.perf_counter() - wall_start
    try:
        write_report(out / REPORT, results, timelines, phases=phases)
    finally:  # the results are kept even if the report cannot be drawn
        results["timing"]["report"] = time.perf_counter() - t0
        results["timing"]["wall"] = time.perf_counter() - wall_start
        write_text(out / RESULTS, _results_text(results))
    return CampaignOutcome(results, out / RESULTS, out / REPORT, resumed, results["timing"])


def _run_trace(out: Path, run: dict, sc) -> dict | None:
    """A finished run's trace for the report: its trace.json, else (runs of older campaigns) its black box."""
    from cellsim.blackbox import BlackBox, BlackBoxError
    from cellsim.simulation import BLACKBOX
    from cellsim.validation.traces import TraceError, trace_of_run

    if run.get("status") == "failed":
        return None
    folder = out / run["out"]
    try:
        return json.loads((folder / TRACE).read_text())
    except (OSError, ValueError):
        pass
    try:
        with BlackBox(folder / BLACKBOX) as bb:
            return shown_variables(trace_of_run(bb, sc.validation.variables).to_json(), sc.validation.variables)
    except (BlackBoxError, TraceError):
        return None  # the run's black box is gone or damaged: the report says it has no trace


def _channel_facts(out: Path, runs: list[dict], aliases: dict[str, str]) -> tuple[dict, dict]:
    """Hazard phases (see :func:`hazard_phases`) and each variable's unit, from the first readable black box."""
    from cellsim.blackbox import BlackBox, BlackBoxError
    from cellsim.simulation import BLACKBOX

    for r in runs:
        if r.get("status") == "failed":
            continue
        try:
            with BlackBox(out / r["out"] / BLACKBOX) as bb:
                channels = bb.channels()
                units = {name: info.unit for name, info in channels.items() if info.unit}
                units.update({alias: channels[ch].unit for alias, ch in aliases.items() if ch in channels and channels[ch].unit})
                return hazard_phases(bb, aliases), units
        except BlackBoxError:
            continue
    return {}, {}


def hazard_phases(bb, aliases: dict[str, str]) -> dict[str, dict]:
    """Each hazard's trace variable (its alias, else its channel) -> ``{values, initial, mishap}``,
    from a run's black box (an open ``BlackBox``): its record of the risk model's phases."""
    by_channel = {channel: alias for alias, channel in aliases.items()}
    channels = bb.channels()
    found = {}
    for channel, spec in (bb.metadata().get("hazards") or {}).items():
        if channel in channels:
            found[by_channel.get(channel, channel)] = {**spec, "values": list(channels[channel].domain)}
    return found


def _rerun_command(out: Path, run: dict) -> str:
    """Re-runs one run alone, into a folder beside the campaign's (``campaigns/c1-run0007``), never inside it."""
    folder = out / run["out"]
    rerun = out.parent / f"{out.name}-run{run['index']:04d}"
    return f"cellsim simulate {shlex.quote(str(folder / 'scenario.yaml'))} --out {shlex.quote(str(rerun))}"
