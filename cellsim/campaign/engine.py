"""The one run engine of campaigns and falsification searches: set-up, snapshot, lock, workers, one run.

Both make many runs of one scenario into one folder, and both go the same way:

1. :func:`set_up`: read the scenario and every file it uses once, compile its safety case once (a bad
   formula stops everything before anything is written), and take the content hash that identifies
   the runs (:mod:`cellsim.provenance`);
2. refuse, before the folder is touched, what cannot go on (:func:`check_scheduler`,
   :func:`check_snapshot`, and the caller's own check of the folder), then :func:`claimed` locks it;
3. :func:`snapshot_plan`: the runs are made from a snapshot of the bytes hashed;
4. :func:`run_all` on :func:`worker_pool` (this process, local processes, or a Dask cluster): each run
   is :func:`execute_run`, simulated and checked (:func:`cellsim.validation.check.simulate_and_check`)
   and written to its own folder, ``result.json`` last; the caller says when to stop starting runs.

What differs, which runs to make and what to make of them, is the campaign's (:mod:`.runner`: drawn at
random, resumed, bounded) or the search's (:mod:`.falsify`: chosen, never counted as a sample).
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import shutil
import time
from collections.abc import Callable, Iterable
from concurrent.futures import FIRST_COMPLETED, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path

from cellsim.atomic import LOCK, FolderBusy, folder_lock, write_text
from cellsim.campaign.local_pool import LocalPool
from cellsim.config.sampling import draw_configuration, run_seed
from cellsim.config.typed_yaml import override_value
from cellsim.provenance import INPUTS, PLAN, REPORT, SnapshotError, command_line, read_inputs, snapshot_scenario

RESULTS = "results.json"
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
    sets = list(plan.overrides) + [f"{path}={override_value(v)}" for path, v in configuration.items()]
    sets.append(f"seed={seed}")
    if plan.duration is not None:
        sets.append(f"duration={plan.duration}")
    return sets


@functools.lru_cache(maxsize=4)
def _base_scenario(plan: CampaignPlan):
    """The campaign's scenario before a run's configuration, once per worker process."""
    from cellsim.scenario import load_scenario

    return load_scenario(plan.scenario, plan.overrides)


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
    from cellsim.validation.check import simulate_and_check

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
        if folder.exists():
            shutil.rmtree(folder)  # an unfinished earlier attempt
        done = simulate_and_check(sf, folder, always_check=True, provenance=origin)
        summary, checked_run = done.summary, done.checked
        case, checked = checked_run.case, checked_run.result
        timing["simulate"] = time.perf_counter() - started - sum(checked_run.timing.values())
        timing.update(checked_run.timing)
        write_json(folder / TRACE, shown_variables(checked_run.trace.to_json(), sc.validation.variables), indent=None)
        result.update(
            status=summary.status,
            verdict=checked.verdict.value,
            verdicts=checked.verdicts_json(),
            violations=checked.violations,
            undecided=checked.undecided,
            use_cases=checked.use_cases,
            coverage=checked.coverage,
            figures=summary.figures_json(),
            findings=[f.to_json() for f in summary.findings],
            worst_severity=summary.worst_severity,
            wall_time=time.perf_counter() - started,
        )
        if search is not None:
            result["margins"] = margins_of(case, checked_run.trace.trace)
    except Exception as e:  # noqa: BLE001 - a failed run is a result, not the campaign's end
        result.update(status="failed", error=f"{type(e).__name__}: {e}", wall_time=time.perf_counter() - started)
    result["timing"] = timing
    folder.mkdir(parents=True, exist_ok=True)
    write_json(folder / RESULT, result)
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


def write_json(path: Path, data, indent: int | None = 1) -> None:
    write_text(path, json.dumps(data, indent=indent, separators=None if indent else (",", ":")))


def shown_variables(signals: dict, variables: dict) -> dict:
    """The variables a report draws: the validation section's short names, or every channel when it names none."""
    return {name: signals[name] for name in (variables or signals) if name in signals}


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


def set_aside(out: Path) -> Path | None:
    """Move what a campaign or search wrote in ``out`` (:func:`discard`'s files) into a hidden folder beside it, so
    that a search replacing it can give it back if it does not finish (:func:`put_back`); None if there was none."""
    names = [name for name in (PLAN, RESULTS, REPORT, RUNS, INPUTS) if (out / name).exists()]
    if not names:
        return None
    aside = out.parent / f".{out.name}.replaced"
    shutil.rmtree(aside, ignore_errors=True)
    aside.mkdir()
    for name in names:
        os.replace(out / name, aside / name)
    return aside


def put_back(aside: Path | None, out: Path) -> None:
    """Undo :func:`set_aside`: what the new work wrote is discarded, the old folder's files are back."""
    discard(out)
    if aside is not None:
        for item in aside.iterdir():
            os.replace(item, out / item.name)
        aside.rmdir()


def holds_others(out: Path) -> bool:
    """Whether ``out`` holds files no campaign wrote (its lock file aside)."""
    return out.is_dir() and not (out / PLAN).exists() and any(p.name != LOCK for p in out.iterdir())


@dataclass
class Workers:
    """Where runs go: ``submit(execute_run, plan, out, index, ...)`` returning a future of the result
    (None: run in this process), and the cluster when it is one."""

    submit: Callable | None
    cluster: object | None = None
    slots: int | Callable[[], int] | None = None
    """Runs to keep in flight at most (a cluster: asked again as workers come and go; None: submit them all)."""

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
            yield Workers(cluster.submit, cluster, slots=cluster.slots)
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


# --------------------------------------------------------------------------- set-up and the loop


@dataclass
class SetUp:
    """The runs' inputs, read once and checked: the scenario, its compiled safety case, the input files'
    bytes and the identity they give the runs."""

    scenario: object
    """The scenario as given (a :class:`cellsim.scenario.ScenarioFile`)."""
    case: object
    """Its safety case (:class:`cellsim.validation.conditions.SafetyCase`), compiled once: every run has the
    scenario's channels (a run's configuration changes values, never which channels exist)."""
    inputs: object
    """The input files' bytes (:func:`cellsim.provenance.read_inputs`)."""
    identity: dict
    """The content hash and what it is of: the runs of one identity may be mixed, never others."""


def set_up(scenario: str, overrides: tuple[str, ...], seed: int, duration: float | None) -> SetUp:
    """Read and check the runs' inputs (ConfigError naming file, line and key for a bad scenario or formula)."""
    from cellsim.scenario import load_scenario
    from cellsim.validation.check import scenario_safety_case

    _base_scenario.cache_clear()  # read afresh: the per-process cache serves this campaign's runs only
    given = load_scenario(scenario, overrides)
    _refuse_overridden_samples(given, overrides)
    case = scenario_safety_case(given)
    inputs = read_inputs(given)
    return SetUp(given, case, inputs, inputs.identity(overrides, seed, duration))


def _refuse_overridden_samples(sf, overrides: tuple[str, ...]) -> None:
    """A ``--set`` on a path the campaign samples (or inside one, or around one) would be replaced in every run by the
    drawn value, yet recorded as the campaign's: ConfigError naming both."""
    from cellsim.config.typed_yaml import ConfigError
    from cellsim.scenario import _shortcut

    sc = sf.scenario
    resolve = _shortcut(sc)
    sampled = {tuple(resolve(path.split("."))): (name, path) for name in sc.campaign.samplers
               for path in sc.configuration_points[name].paths}
    for assignment in overrides:
        given = assignment.split("=", 1)[0].strip()
        key = tuple(resolve(given.split(".")))
        for path, (name, written) in sampled.items():
            n = min(len(key), len(path))
            if key[:n] == path[:n]:
                raise ConfigError("--set", None, given, f"the campaign samples {written} (configuration point "
                                  f"'{name}'): each run would draw its own value over this one; drop the --set, or "
                                  f"the sampler (campaign.samplers.{name})")


def snapshot_plan(plan: CampaignPlan, out: Path, inputs) -> CampaignPlan:
    """Snapshot the inputs into ``out``/inputs (replacing an earlier snapshot) and return the plan the runs are
    made from: the snapshot's scenario, with its files pinned to their digests."""
    import dataclasses

    shutil.rmtree(out / INPUTS, ignore_errors=True)
    try:
        snapshot, pins = snapshot_scenario(inputs, out / INPUTS, plan.overrides)
    except SnapshotError as e:
        raise CampaignError(str(e)) from None
    return dataclasses.replace(plan, scenario=str(snapshot.resolve()), overrides=(*plan.overrides, *pins))


def origin_of(out: Path, scenario: str, identity: dict, **more) -> dict:
    """The runs' part of their provenance: the command, and the campaign's folder, scenario and content hash
    (``more``: a search names its method)."""
    return {"command": command_line(), "cwd": os.getcwd(),
            "campaign": {"folder": str(out.resolve()), "scenario": scenario, "inputs_hash": identity["hash"], **more}}


Task = tuple[int, "dict | None", "dict | None"]
"""A run to make: (index, configuration or None to draw it, its place in a search or None)."""


def keep_before(out: Path, results: dict[int, dict], limit: int | None, made: Iterable[int] | None = None) -> list[int]:
    """Leave out of ``results`` (index -> result) every run from index ``limit`` on among those just ``made`` (default:
    all), and remove its folder: a campaign or search that stops at a run (``run_all``'s ``cutoff``) is the runs
    before it, as one worker running them in order would make it, whatever runs other workers had in flight. (A run
    an earlier command made stays: one extended past the stop with ``--runs``.) Returns the indices left out."""
    if limit is None:
        return []
    dropped = sorted(i for i in (results if made is None else made) if i >= limit and i in results)
    for index in dropped:
        del results[index]
        shutil.rmtree(run_dir(out, index), ignore_errors=True)
    return dropped


@contextlib.contextmanager
def interrupts_remembered():
    """The block's Ctrl-C and SIGTERM, remembered (the list yielded) as well as acted on as before.

    A run made in this process is interrupted by the KeyboardInterrupt its signal handler raises, but Python
    drops an exception raised while a finaliser runs (a run's objects are freed in the middle of the next
    one): the caller checks the list between runs, so an interruption is never lost. Only the main thread
    can handle signals; elsewhere (and for a signal that is ignored or left to its default) nothing changes."""
    import signal
    import threading

    heard: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield heard
        return
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}

    def remembering(handler):
        def on_signal(sig, frame):
            heard.append(sig)
            handler(sig, frame)
        return on_signal

    for sig, handler in previous.items():
        if callable(handler):
            signal.signal(sig, remembering(handler))
    try:
        yield heard
    finally:
        for sig, handler in previous.items():
            if callable(handler):
                signal.signal(sig, handler)


def run_all(workers: "Workers", plan: CampaignPlan, out: Path, tasks: Iterable[Task], origin: dict,
            on_result: Callable[[dict], None], cutoff: Callable[[], int | None] = lambda: None,
            lost: str = "the finished runs are kept in {out}: run the same command again to resume") -> None:
    """Make ``tasks`` on ``workers``, in index order, handing each result to ``on_result`` as it comes back.

    ``cutoff()``, asked after every result: an index from which runs are no longer started (None: go on);
    runs already started finish and are handed on (the caller leaves out those past the cutoff: ``keep_before``,
    so that what is kept does not depend on how many ran at once). A dead worker is a CampaignError saying what became of
    the runs (``lost``, with ``{out}`` the folder).
    """
    tasks = list(tasks)
    with interrupts_remembered() as heard:
        def take(result: dict) -> None:
            on_result(result)
            if heard:  # an interrupt whose KeyboardInterrupt was lost (in a run made here): stop all the same
                raise KeyboardInterrupt

        if workers.submit is None:
            for index, configuration, place in tasks:
                limit = cutoff()
                if limit is not None and index >= limit:
                    break
                take(execute_run(plan, out, index, origin, configuration, place))
            return
        waiting = list(reversed(tasks))
        slots = workers.slots if callable(workers.slots) else (lambda: workers.slots or len(tasks))
        index_of: dict = {}
        try:
            while waiting or index_of:
                limit = cutoff()
                if limit is not None:
                    waiting = [t for t in waiting if t[0] < limit]
                    for future, index in index_of.items():
                        if index >= limit:
                            future.cancel()  # not started yet: dropped; a running one finishes
                while waiting and len(index_of) < max(1, slots()):
                    index, configuration, place = waiting.pop()
                    index_of[workers.submit(execute_run, plan, out, index, origin, configuration, place)] = index
                if not index_of:
                    break
                finished, _ = wait(index_of, return_when=FIRST_COMPLETED)
                for future in finished:
                    del index_of[future]
                    if not future.cancelled():
                        take(future.result())
        except BrokenProcessPool as e:
            raise CampaignError(f"a worker process died ({e}); {lost.format(out=out)}") from None
