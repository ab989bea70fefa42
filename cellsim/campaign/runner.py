"""Test campaigns: many sampled variants of a scenario, simulated and checked in parallel.

A campaign is a pure function of its inputs: the scenario and every file it
uses (validation file, risk models, robot models), the ``--set`` overrides, the
campaign seed, the duration and cellsim's version, and of the number of runs.
Run ``i`` draws its configuration from the scenario's samplers
(``campaign.samplers``) and its simulation seed from ``(seed, i)`` (see
:mod:`cellsim.campaign.samplers`), so any run can be redone alone, in any
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

import contextlib
import dataclasses
import functools
import json
import os
import shlex
import shutil
import time
from concurrent.futures import FIRST_COMPLETED, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

from cellsim.campaign.local_pool import LocalPool
from cellsim.atomic import LOCK, FolderBusy, folder_lock, write_text
from cellsim.validation.config import description_of, formula_of
from cellsim.campaign.samplers import describe_sampling, draw_configuration, run_seed
from cellsim.config.typed_yaml import to_data
from cellsim.provenance import INPUTS, SnapshotError, changes, command_line, provenance, read_inputs, snapshot_scenario

PLAN = "campaign.json"
RESULTS = "results.json"
REPORT = "report.html"
RESULT = "result.json"
TRACE = "trace.json"
RUNS = "runs"


class CampaignError(Exception):
    """The campaign cannot go on: its folder holds another campaign, or a worker died."""


@dataclass(frozen=True)
class CampaignPlan:
    """What the user asks for; runs are numbered 0 .. runs-1.

    The campaign's identity is the content of the files this names (see
    :func:`cellsim.provenance.read_inputs`), not the path of the scenario.
    """

    scenario: str
    """Absolute path of the scenario file."""
    overrides: tuple[str, ...]
    seed: int
    runs: int
    duration: float | None = None
    until_bound: float | None = None
    """``--until-bound``: the violation rate the runs should bound (``runs`` is how many that takes with
    none violating). Runs stop being started once one violates a condition (or leaves one undecided);
    those already started finish and are kept, and the campaign resumes from there if asked again."""


def run_dir(out: Path, index: int) -> Path:
    return out / RUNS / f"{index:04d}"


def run_overrides(plan: CampaignPlan, configuration: dict[str, object], seed: int) -> list[str]:
    """The ``--set`` overrides that make run ``index`` out of the scenario."""
    sets = list(plan.overrides) + [f"{path}={_yaml_scalar(v)}" for path, v in configuration.items()]
    sets.append(f"seed={seed}")
    if plan.duration is not None:
        sets.append(f"duration={plan.duration}")
    return sets


def _yaml_scalar(value: object) -> str:
    return json.dumps(value) if isinstance(value, (bool, str)) else repr(value)


# --------------------------------------------------------------------------- one run (in a worker)

@functools.lru_cache(maxsize=4)
def _base_scenario(plan: CampaignPlan):
    """The campaign's scenario before a run's configuration, once per worker process."""
    from cellsim.scenario import load_scenario

    return load_scenario(plan.scenario, plan.overrides)


@functools.lru_cache(maxsize=4)
def _safety_case(plan: CampaignPlan):
    """The compiled safety case, once per worker process.

    A run's configuration changes values, never which channels exist, so every
    run of a campaign is checked against the case of the campaign's scenario.
    """
    from cellsim.validation.check import scenario_safety_case

    return scenario_safety_case(_base_scenario(plan))


def execute_run(plan: CampaignPlan, out: Path, index: int, origin: dict | None = None,
                configuration: dict[str, object] | None = None, search: dict | None = None) -> dict:
    """Simulate and check run ``index``; returns its result (also written to its folder).

    ``origin`` is the campaign's part of the run's provenance (its command line,
    folder and content hash), recorded in the black box; the result carries the
    content hash as ``inputs_hash``, so a resumed campaign keeps only its own runs.

    ``configuration`` is the run's, when a search chose it (else it is drawn from the
    samplers); ``search`` is then the run's place in the search, kept in its result,
    and the result also carries each condition's robustness and each guide's meeting
    distance (``margins``), which the search reads.

    Never raises for a problem of the run itself: a run that fails is reported
    with ``status: failed`` and the error, and the campaign goes on.
    """
    from cellsim.scenario import load_scenario
    from cellsim.simulation import simulate
    from cellsim.validation.check import check

    sc = _base_scenario(plan).scenario
    points = {name: point.paths for name, point in sc.configuration_points.items()}
    if configuration is None:
        configuration = draw_configuration(sc.campaign.samplers, points, plan.seed, index)
    seed = run_seed(plan.seed, index)
    folder = run_dir(out, index)
    result: dict = {"index": index, "seed": seed, "configuration": configuration, "out": str(folder.relative_to(out))}
    if search is not None:
        result["search"] = search
    origin = origin or {}
    if "campaign" in origin:
        result["inputs_hash"] = origin["campaign"].get("inputs_hash")
        origin = {**origin, "campaign": {**origin["campaign"], "run": index}}
    timing: dict[str, float] = {}
    try:
        started = time.perf_counter()
        sf = load_scenario(plan.scenario, run_overrides(plan, configuration, seed))
        case = _safety_case(plan)
        if folder.exists():
            shutil.rmtree(folder)  # an unfinished earlier attempt
        summary = simulate(sf, folder, provenance=origin)
        timing["simulate"] = time.perf_counter() - started
        checked_run = check(folder, case=case)
        timing.update(checked_run.timing)
        checked = checked_run.result
        _write_json(folder / TRACE, shown_variables(checked_run.trace.to_json(), sc.validation.variables), indent=None)
        result.update(
            status=summary.status,
            verdict=checked.verdict.value,
            verdicts=checked.verdicts_json(),
            violations=checked.violations,
            undecided=checked.undecided,
            use_cases=checked.use_cases,
            coverage=checked.coverage,
            cycles_completed=summary.cycles_completed,
            robots={name: figures.to_json() for name, figures in summary.robots.items()},
            wall_time=time.perf_counter() - started,
        )
        if search is not None:
            result["margins"] = margins_of(case, checked_run.trace.trace)
    except Exception as e:  # noqa: BLE001 - a failed run is a result, not the campaign's end
        result.update(status="failed", error=f"{type(e).__name__}: {e}", wall_time=time.perf_counter() - started)
    result["timing"] = timing
    folder.mkdir(parents=True, exist_ok=True)
    _write_json(folder / RESULT, result)
    return result


def margins_of(case, trace) -> dict:
    """Each condition's robustness and each guide's meeting distance (s) on a run's trace, as JSON."""
    from cellsim.logic.robustness import meeting, robustness

    def number(x: float) -> float | str:
        return x if x == x and abs(x) != float("inf") else ("inf" if x > 0 else "-inf")

    return {
        "robustness": {name: robustness(f, trace).to_json() for name, f in case.conditions.items()},
        "guides": {name: number(meeting(a, b, trace)) for name, (a, b) in case.guides.items()},
    }


def _write_json(path: Path, data, indent: int | None = 1) -> None:
    write_text(path, json.dumps(data, indent=indent, separators=None if indent else (",", ":")))


def _results_text(results: dict) -> str:
    """results.json: indented, but each run on one compact line. Indenting every run's verdicts
    makes it no easier to read and takes Python's slow encoder (0.8 s at 1000 runs)."""
    runs = ",\n  ".join(json.dumps(r, separators=(",", ":")) for r in results["runs"])
    head = {key: ([] if key == "runs" else value) for key, value in results.items()}
    # one space of indent marks the top-level key: "runs" inside "campaign" and "totals" sits deeper
    return json.dumps(head, indent=1).replace('\n "runs": []', '\n "runs": [\n  ' + runs + "\n ]", 1)


def shown_variables(signals: dict, variables: dict) -> dict:
    """The variables a report draws: the validation section's short names, or every channel when it names none."""
    return {name: signals[name] for name in (variables or signals) if name in signals}


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
    if plan_path.exists() and restart:
        discard(out)
    out.mkdir(parents=True, exist_ok=True)
    _write_json(plan_path, {"identity": identity, "runs": plan.runs, "scenario": plan.scenario})
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
    return done


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
    elif _holds_others(out):
        raise CampaignError(f"{out} exists and is not a campaign folder; choose another --out")


def check_snapshot(inputs, overrides) -> None:
    """CampaignError, before anything is written, if the inputs cannot be snapshotted (made in a scratch folder)."""
    import tempfile

    with tempfile.TemporaryDirectory(prefix="cellsim-snapshot-") as scratch:
        try:
            snapshot_scenario(inputs, Path(scratch) / INPUTS, overrides)
        except SnapshotError as e:
            raise CampaignError(str(e).replace(str(Path(scratch) / INPUTS), "the campaign's inputs/")) from None


@contextlib.contextmanager
def claimed(out: Path, busy: str):
    """Create (if need be) and lock ``out`` for the block; a refusal before any run was written leaves a folder
    it created as it found it: absent."""
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    try:
        try:
            with folder_lock(out):
                yield
        except FolderBusy:
            raise CampaignError(busy) from None
    except (CampaignError, ValueError):
        if created and not any((out / RUNS).glob("*/" + RESULT)):
            shutil.rmtree(out, ignore_errors=True)
        raise


def discard(out: Path) -> None:
    """Remove what a campaign wrote in ``out``, the plan last (files of others stay)."""
    for name in (RUNS, INPUTS):
        shutil.rmtree(out / name, ignore_errors=True)
    for name in (RESULTS, REPORT):
        (out / name).unlink(missing_ok=True)
    for name in (RESULTS, REPORT, PLAN):  # a write cut short left its temporary file (cellsim.atomic)
        for tmp in out.glob(f".{name}.*.tmp"):
            tmp.unlink(missing_ok=True)
    (out / PLAN).unlink(missing_ok=True)


def _holds_others(out: Path) -> bool:
    """Whether ``out`` holds files no campaign wrote (its lock file aside)."""
    return out.is_dir() and not (out / PLAN).exists() and any(p.name != LOCK for p in out.iterdir())


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
    from cellsim.scenario import load_scenario
    from cellsim.validation.check import scenario_safety_case

    out = Path(out)
    wall_start = time.perf_counter()
    # Read afresh: bad input, bad formulas included, stops the campaign before it
    # starts. The per-process caches serve the runs of this campaign only.
    _base_scenario.cache_clear()
    _safety_case.cache_clear()
    given = load_scenario(plan.scenario, plan.overrides)
    scenario_safety_case(given)
    inputs = read_inputs(given)
    identity = inputs.identity(plan.overrides, plan.seed, plan.duration)
    # every refusal before the folder is touched, lock file included
    check_resumable(out, identity, restart)
    check_scheduler(scheduler)
    check_snapshot(inputs, plan.overrides)
    with claimed(out, f"{out} is being written by another cellsim campaign; choose another --out"):
        return _run_locked(plan, out, jobs, on_progress, restart, inputs, identity, wall_start, scheduler)


def _run_locked(plan, out: Path, jobs, on_progress, restart, inputs, identity, wall_start, scheduler=None) -> CampaignOutcome:
    """The campaign, with ``out`` locked against every other cellsim process."""
    from cellsim.scenario import load_scenario
    from cellsim.validation.check import scenario_safety_case

    results = {r["index"]: r for r in prepare(plan, out, identity, restart)}
    # Every run, and the checks here, are made from the snapshot of the bytes hashed.
    shutil.rmtree(out / INPUTS, ignore_errors=True)
    try:
        snapshot, pins = snapshot_scenario(inputs, out / INPUTS, plan.overrides)
    except SnapshotError as e:
        raise CampaignError(str(e)) from None
    worker_plan = dataclasses.replace(plan, scenario=str(snapshot.resolve()), overrides=(*plan.overrides, *pins))
    sf = load_scenario(worker_plan.scenario, worker_plan.overrides)
    case = scenario_safety_case(sf)
    origin = {
        "command": command_line(),
        "cwd": os.getcwd(),
        "campaign": {"folder": str(out.resolve()), "scenario": plan.scenario, "inputs_hash": identity["hash"]},
    }
    resumed = len(results)
    todo = [i for i in range(plan.runs) if i not in results]

    def report_progress():
        if on_progress is not None:
            runs = list(results.values())
            coverage = case.coverage.merge([r["coverage"] for r in runs if "coverage" in r]).overall
            on_progress(
                Progress(
                    len(runs),
                    plan.runs,
                    sum(1 for r in runs if r.get("violations")),
                    sum(1 for r in runs if r.get("status") == "failed"),
                    coverage,
                )
            )

    report_progress()
    from cellsim.validation.bound import counts_against

    stop = (lambda: any(counts_against(r) for r in results.values())) if plan.until_bound is not None else (lambda: False)
    cluster = None
    if todo and not stop():
        with worker_pool(jobs, scheduler, out / INPUTS) as workers:
            if workers.submit is None:
                for index in todo:
                    results[index] = execute_run(worker_plan, out, index, origin)
                    report_progress()
                    if stop():
                        break
            else:
                _run_parallel(worker_plan, out, todo, workers, results, report_progress, origin, stop)
            cluster = workers.record()
    runs = [results[i] for i in range(plan.runs) if i in results]
    return finish(plan, out, sf, case, runs, resumed, wall_start, provenance(identity), cluster=cluster)


def _run_parallel(plan, out, todo, workers, results, report_progress, origin=None, stop=lambda: False) -> None:
    """Runs ``todo`` on ``workers`` (:func:`worker_pool`), recording each result as it comes back."""
    waiting = list(reversed(todo))
    slots = workers.slots or len(todo)
    pending = set()
    try:
        while waiting or pending:
            while waiting and len(pending) < slots:
                pending.add(workers.submit(execute_run, plan, out, waiting.pop(), origin))
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for future in finished:
                if future.cancelled():
                    continue
                result = future.result()
                results[result["index"]] = result
            report_progress()
            if stop():  # runs not started are dropped; those running finish and are kept
                waiting.clear()
                for future in pending:
                    future.cancel()
    except BrokenProcessPool as e:
        raise CampaignError(
            f"a worker process died ({e}); the finished runs are kept in {out}: run the same command again to resume"
        ) from None


@dataclass
class Workers:
    """Where runs go: ``submit(execute_run, plan, out, index, ...)`` returning a future of the result
    (None: run in this process), and the cluster when it is one."""

    submit: Callable | None
    cluster: object | None = None
    slots: int | None = None
    """Runs to keep in flight at most (None: submit them all, the cluster queues them)."""

    def record(self) -> dict | None:
        """What results.json says of the cluster: its scheduler, workers and retried runs."""
        if self.cluster is None:
            return None
        return {"scheduler": self.cluster.address, "workers": self.cluster.workers(), "retries": self.cluster.retries()}


def check_scheduler(scheduler: str | None) -> None:
    """A --scheduler nothing answers at is refused before any folder is written."""
    if scheduler is not None:
        from cellsim.campaign.cluster import ClusterError, check_reachable

        try:
            check_reachable(scheduler)
        except ClusterError as e:
            raise CampaignError(str(e)) from None


@contextlib.contextmanager
def worker_pool(jobs: int, scheduler: str | None = None, inputs_dir: Path | None = None):
    """The campaign's workers: a Dask cluster at ``scheduler``, else ``jobs`` local processes
    (:class:`~cellsim.campaign.local_pool.LocalPool`; one job: none, runs in this process)."""
    if scheduler is not None:
        from cellsim.campaign.cluster import ClusterError, ClusterPool

        try:
            cluster = ClusterPool(scheduler, inputs_dir, RESULT)
        except ClusterError as e:
            raise CampaignError(str(e)) from None
        try:
            yield Workers(cluster.submit, cluster)
        except ClusterError as e:  # a worker of another version, a run lost on too many workers
            raise CampaignError(f"{e}; the finished runs are kept: run the same command again to resume") from None
        finally:
            cluster.close()
        return
    if jobs <= 1:
        yield Workers(None)
        return
    pool = LocalPool(jobs)
    try:
        yield Workers(pool.submit, slots=pool.slots)
    except BaseException:
        pool.shutdown(cancel=True)
        raise
    pool.shutdown()


def finish(plan, out: Path, sf, case, runs: list[dict], resumed: int, wall_start: float, record: dict | None = None,
           search: dict | None = None, cluster: dict | None = None) -> CampaignOutcome:
    """Totals, results.json and report.html from the runs' results; ``record`` is the
    campaign's provenance (:func:`cellsim.provenance.provenance`); ``search``, the
    falsification search's record when a search chose the runs (then no bound is given)."""
    from cellsim.campaign.report import write_report
    from cellsim.scenario import unit_of
    from cellsim.validation.bound import campaign_bounds

    sc = sf.scenario
    t0 = time.perf_counter()
    coverage = case.coverage.merge([r["coverage"] for r in runs if "coverage" in r])
    t_coverage = time.perf_counter() - t0
    completed = [r for r in runs if r.get("status") != "failed"]
    conditions = list(sc.validation.conditions)
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
            "conditions": {n: formula_of(c) for n, c in sc.validation.conditions.items()},
            "use_cases": {n: formula_of(u) for n, u in sc.validation.use_cases.items()},
            "descriptions": {n: description_of(e) for n, e in {**sc.validation.conditions, **sc.validation.use_cases}.items()
                             if description_of(e)},
            "samplers": {name: to_data(s) for name, s in sc.campaign.samplers.items()},
            "until_bound": plan.until_bound,
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
        },
        "bounds": {"excluded": search["not_a_sample"]} if search else campaign_bounds(runs, conditions, describe_sampling(
            sc.campaign.samplers, {name: point.paths for name, point in sc.configuration_points.items()})),
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
