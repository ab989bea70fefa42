"""Falsification: search a scenario's configuration space for a run that violates a safety condition.

A campaign draws its runs at random and finds a rare violation by luck. ``cellsim
falsify`` chooses each run from those before it: it searches the space the
campaign's samplers define (:mod:`cellsim.campaign.space`) for a run whose
*criticality score* is lowest, and stops at the first run that violates a
targeted condition, or when its budget of runs is spent.

The score of a run (one rule, for every method; lower is closer to a violation):

* the least **robustness** (:mod:`cellsim.logic.robustness`) over the targeted
  conditions, each divided by its own scale (its largest moved threshold for the
  space margin, its longest bounded window for the time margin; the space margin
  where finite, else the time margin) and clipped to [-1, 1]; a margin infinite
  either way counts as +-1;
* plus the least **meeting distance** over the guides that lead to a targeted
  condition (``validation.guides``), as a fraction of the run's duration, clipped
  to [-1, 1]. A detection condition's robustness on discrete signals is flat (a
  hazard is detected at once or missed), so without a guide the search has
  nothing to climb; a guide names two situations whose meeting stresses the
  controller (a hazard while another is handled) and the search steers them
  together.

Methods, all through the same loop (ask a batch of points, run them, tell the
scores, in run order):

* ``cmaes``: CMA-ES (the ``cma`` package) on the score, started at the middle
  configuration of the space;
* ``qd``: quality diversity (pyribs, CMA-ME): an archive keeping the most critical
  run per cell of *use cases exercised* x *situation* (the guide that came
  closest, else the condition with the least margin), so the search spreads over
  kinds of runs instead of one basin;
* ``random``: points uniform in the space, i.e. configurations drawn from the
  campaign's own distribution: the baseline.

The search is a pure function of the scenario, seed, method and budget: run ``i``
is the ``i``-th point asked for, with simulation seed ``run_seed(seed, i)``, and
every batch is told in run order whatever order its runs finish in.

The runs are ordinary run folders (``OUT/runs/NNNN``), each with its place in the
search in its ``result.json`` (``search``: method, batch, point, score).
They are **not a random sample**: a search chooses where to look, so no
violation rate or bound is computed from them (results.json says so where a
campaign gives its ``bounds``).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from cellsim.atomic import LOCK
from cellsim.campaign import SEARCH_METHODS, engine, runner
from cellsim.campaign.engine import PLAN, CampaignError, CampaignPlan
from cellsim.campaign.space import SearchSpace
from cellsim.logic.syntax import Formula, numeric_comparisons, walk
from cellsim.provenance import INPUTS, provenance

NOT_A_SAMPLE = ("the runs of a falsification search are chosen by the search, not drawn at random: "
                "no violation rate or bound follows from them (a campaign's runs give one)")
FAILED_SCORE = 4.0
"""The score of a run that could not be simulated: worse than any run's (scores lie in [-2, 2])."""
SIGMA0 = 0.25
"""CMA-ES's and CMA-ME's first step size, in the unit cube's coordinates."""


@dataclass(frozen=True)
class FalsifyPlan:
    """What the user asks for."""

    scenario: str
    """Absolute path of the scenario file."""
    overrides: tuple[str, ...]
    seed: int
    budget: int
    """Most runs to spend."""
    method: str = "cmaes"
    duration: float | None = None
    conditions: tuple[str, ...] = ()
    """The conditions to falsify; empty: every condition."""


@dataclass
class SearchProgress:
    done: int
    budget: int
    best: float
    """The lowest score so far."""
    violating: int


@dataclass
class FalsifyOutcome:
    results: dict
    results_path: Path
    report_path: Path

    @property
    def first_violation(self) -> int | None:
        """The index of the first run that violated a targeted condition (None if none did)."""
        return self.results["search"]["first_violation"]


# --------------------------------------------------------------------------- the score


def scales(formula: Formula) -> tuple[float, float]:
    """The units a condition's space and time margins are divided by: its largest moved threshold
    (1 when all are 0) and its longest bounded window (s; 1 when it has none)."""
    thresholds = [abs(float(node.threshold)) for node in numeric_comparisons(formula)]
    windows = [node.hi for node in walk(formula) if node.temporal and math.isfinite(node.hi)]
    return (max(thresholds, default=0.0) or 1.0), (max(windows, default=0.0) or 1.0)


def _number(x) -> float:
    return float(x) if not isinstance(x, str) else (math.inf if x == "inf" else -math.inf)


def _clip(x: float) -> float:
    return max(-1.0, min(1.0, x))


class Scorer:
    """The criticality score of a run's result (see the module), for the targeted conditions."""

    def __init__(self, case, targets: tuple[str, ...], duration: float):
        self.targets = targets or tuple(case.conditions)
        self.scales = {name: scales(case.conditions[name]) for name in self.targets}
        self.guides = [name for name, g in case.validation.guides.items()
                       if not g.conditions or set(g.conditions) & set(self.targets)]
        self.duration = duration

    def margins(self, result: dict) -> dict[str, float]:
        """Each targeted condition's normalised margin in [-1, 1]."""
        robust = result["margins"]["robustness"]
        out = {}
        for name in self.targets:
            space, time_ = _number(robust[name]["space"]), _number(robust[name]["time"])
            space_scale, time_scale = self.scales[name]
            out[name] = _clip(space / space_scale if math.isfinite(space) else time_ / time_scale)
        return out

    def distances(self, result: dict) -> dict[str, float]:
        """Each guide's meeting distance as a fraction of the run, in [-1, 1]."""
        return {name: _clip(_number(result["margins"]["guides"][name]) / self.duration) for name in self.guides}

    def score(self, result: dict) -> float:
        if result.get("status") == "failed" or "margins" not in result:
            return FAILED_SCORE
        distances = self.distances(result)
        return min(self.margins(result).values()) + (min(distances.values()) if distances else 0.0)

    def situation(self, result: dict) -> int:
        """The QD archive's second measure: the closest guide's index, else the least-margin condition's."""
        if result.get("status") == "failed" or "margins" not in result:
            return 0
        values = self.distances(result) if self.guides else self.margins(result)
        names = self.guides if self.guides else list(self.targets)
        return names.index(min(values, key=values.get))

    def violates(self, result: dict) -> bool:
        return any(name in self.targets for name in result.get("violations", ()))


# --------------------------------------------------------------------------- the methods


class RandomSearch:
    """Points uniform in the cube: the campaign's distribution (the baseline)."""

    def __init__(self, space: SearchSpace, seed: int, batch: int):
        self.rng, self.dimension, self.batch = np.random.default_rng([seed, 0xFA15]), space.dimension, batch

    def ask(self) -> list[np.ndarray]:
        return [self.rng.random(self.dimension) for _ in range(self.batch)]

    def tell(self, points, results, scores) -> None:
        pass


class CmaesSearch:
    """CMA-ES on the score, in the unit cube, from the space's middle configuration.

    The cma library needs two dimensions at least: a space of one configuration point searches a second,
    idle coordinate beside it (the runs never see it)."""

    def __init__(self, space: SearchSpace, seed: int, batch: int | None):
        import cma

        options = {"bounds": [0.0, 1.0], "seed": seed + 1, "verbose": -9, "tolfun": 0, "tolflatfitness": 10**9,
                   "tolx": 0, "tolstagnation": 10**9}
        if batch:
            options["popsize"] = batch
        self.dimension = space.dimension
        start = space.centre().tolist() + [0.5] * max(0, 2 - self.dimension)
        self.es = cma.CMAEvolutionStrategy(start, SIGMA0, options)
        self.batch = self.es.popsize
        self._asked: list = []

    def ask(self) -> list[np.ndarray]:
        self._asked = [np.asarray(x) for x in self.es.ask()]
        return [x[: self.dimension] for x in self._asked]

    def tell(self, points, results, scores) -> None:
        if len(points) == self.es.popsize:  # a batch cut short by the budget is not told
            self.es.tell(self._asked, scores)


class QualityDiversity:
    """CMA-ME (pyribs): the most critical run per cell of use cases x situation."""

    EMITTERS = 2

    def __init__(self, space: SearchSpace, seed: int, batch: int | None, scorer: Scorer, use_cases: list[str]):
        from ribs.archives import GridArchive
        from ribs.emitters import EvolutionStrategyEmitter
        from ribs.schedulers import Scheduler

        self.scorer, self.use_cases = scorer, use_cases
        situations = max(1, len(scorer.guides) or len(scorer.targets))
        combos = 2 ** len(use_cases)
        archive = GridArchive(solution_dim=space.dimension, dims=[combos, situations],
                              ranges=[(0, combos), (0, situations)], seed=seed)
        per_emitter = max(1, (batch or 8) // self.EMITTERS)
        emitters = [EvolutionStrategyEmitter(archive, x0=space.centre(), sigma0=SIGMA0, ranker="2imp",
                                             bounds=[(0.0, 1.0)] * space.dimension, batch_size=per_emitter,
                                             seed=seed * 1000 + i + 1)
                    for i in range(self.EMITTERS)]
        self.scheduler = Scheduler(archive, emitters)
        self.archive = archive
        self.batch = per_emitter * self.EMITTERS
        self._asked = 0

    def ask(self) -> list[np.ndarray]:
        points = self.scheduler.ask()
        self._asked = len(points)
        return [np.asarray(p) for p in points]

    def measures(self, result: dict) -> tuple[float, float]:
        ran = set(result.get("use_cases", ()))
        combo = sum(1 << i for i, name in enumerate(self.use_cases) if name in ran)
        return combo + 0.5, self.scorer.situation(result) + 0.5

    def tell(self, points, results, scores) -> None:
        if not points:
            return
        objectives, measures = -np.asarray(scores), np.asarray([self.measures(r) for r in results])
        if len(points) == self._asked:
            self.scheduler.tell(objectives, measures)
        else:  # a batch cut short (the budget, or a violation): into the archive, the emitters untold
            self.archive.add(np.asarray(points), objectives, measures)

    def cells(self) -> list[dict]:
        """The archive: per occupied cell, its use cases, situation and most critical score."""
        data = self.archive.data()
        out = []
        for measures, objective in zip(data["measures"], data["objective"]):
            combo, situation = int(measures[0]), int(measures[1])
            names = self.scorer.guides or list(self.scorer.targets)
            out.append({"use_cases": [u for i, u in enumerate(self.use_cases) if combo >> i & 1],
                        "situation": names[situation] if situation < len(names) else None,
                        "score": -float(objective)})
        return sorted(out, key=lambda c: c["score"])


def _searcher(method: str, space: SearchSpace, seed: int, batch: int | None, scorer: Scorer, use_cases: list[str]):
    if method == "random":
        return RandomSearch(space, seed, batch or 1)
    if method == "cmaes":
        return CmaesSearch(space, seed, batch)
    if method == "qd":
        return QualityDiversity(space, seed, batch, scorer, use_cases)
    raise ValueError(f"unknown method {method!r}; one of {', '.join(SEARCH_METHODS)}")


# --------------------------------------------------------------------------- the search


def run_falsify(
    plan: FalsifyPlan,
    out: str | os.PathLike,
    jobs: int = 1,
    on_progress: Callable[[SearchProgress], None] | None = None,
    overwrite: bool = False,
    batch: int | None = None,
    scheduler: str | None = None,
) -> FalsifyOutcome:
    """Search, writing every run under ``out``, then results.json and report.html.

    Raises ConfigError for a bad scenario, ValueError for an unknown condition or
    method or a scenario with nothing to search, and CampaignError for a folder in
    use or holding other files (unless ``overwrite``), all before any run starts.
    """
    out = Path(out)
    wall_start = time.perf_counter()
    if plan.method not in SEARCH_METHODS:
        raise ValueError(f"unknown method {plan.method!r}; one of {', '.join(SEARCH_METHODS)}")
    runs = engine.set_up(plan.scenario, plan.overrides, plan.seed, plan.duration)
    unknown = [c for c in plan.conditions if c not in runs.case.conditions]
    if unknown:
        raise ValueError(f"no condition named {', '.join(unknown)}; conditions: {', '.join(runs.case.conditions)}")
    sc = runs.scenario.scenario
    space = SearchSpace(sc.campaign.samplers, {name: point.paths for name, point in sc.configuration_points.items()})
    if space.dimension == 0:
        raise ValueError(f"{plan.scenario}: nothing to search: its campaign.samplers draw no configuration point "
                         "(add samplers for the values to search over)")
    # every refusal before the folder is touched (an earlier search or campaign it replaces included)
    if out.exists() and any(p.name != LOCK for p in out.iterdir()):
        if not overwrite:
            raise CampaignError(f"{out} is not empty; choose another --out, or pass --overwrite to replace it")
        if not (out / PLAN).is_file():
            raise CampaignError(f"{out} holds files no cellsim search or campaign wrote; choose another --out")
    engine.check_scheduler(scheduler)
    engine.check_snapshot(runs.inputs, plan.overrides)
    with engine.claimed(out, f"{out} is being written by another cellsim process; choose another --out"):
        # what it replaces is set aside, not deleted, until the search has written its results: one interrupted
        # or failing gives it back whole
        aside = engine.set_aside(out)
        try:
            outcome = _search(plan, out, jobs, on_progress, batch, runs, space, wall_start, scheduler)
        except BaseException:
            if aside is not None:  # (a new search keeps its runs so far, as a campaign does)
                engine.put_back(aside, out)
            raise
        if aside is not None:
            shutil.rmtree(aside, ignore_errors=True)
        return outcome


def _search(plan: FalsifyPlan, out: Path, jobs, on_progress, batch, runs, space, wall_start,
            scheduler=None) -> FalsifyOutcome:
    campaign_plan = CampaignPlan(plan.scenario, plan.overrides, plan.seed, plan.budget, plan.duration)
    worker_plan = engine.snapshot_plan(campaign_plan, out, runs.inputs)
    sf, case = runs.scenario, runs.case
    duration = plan.duration if plan.duration is not None else sf.scenario.duration
    scorer = Scorer(case, plan.conditions, duration)
    use_cases = list(case.use_cases)
    searcher = _searcher(plan.method, space, plan.seed, batch or (max(jobs, 1) if plan.method == "random" else None),
                         scorer, use_cases)
    search_record = {"method": plan.method, "budget": plan.budget, "batch": searcher.batch,
                     "conditions": list(scorer.targets), "guides": scorer.guides, "dimension": space.dimension}
    engine.write_json(out / PLAN, {"identity": runs.identity, "runs": plan.budget, "scenario": plan.scenario,
                                   "search": search_record})
    origin = engine.origin_of(out, plan.scenario, runs.identity, search=plan.method)
    results: dict[int, dict] = {}
    first: int | None = None
    generation = 0
    with engine.worker_pool(jobs, scheduler, out / INPUTS) as workers:
        if on_progress is not None:  # under way: its checks passed, its workers ready
            on_progress(SearchProgress(0, plan.budget, math.inf, 0))
        while len(results) < plan.budget and first is None:
            points = searcher.ask()[: plan.budget - len(results)]
            start = len(results)
            tasks = []
            for k, point in enumerate(points):
                place = {"method": plan.method, "batch": generation, "point": [round(float(x), 12) for x in point]}
                tasks.append((start + k, space.decode(point), place))
            batch_results = _evaluate(workers, worker_plan, out, tasks, origin, scorer)
            for index, result in sorted(batch_results.items()):
                result["search"]["score"] = scorer.score(result)
                results[index] = result
                if first is None and scorer.violates(result):
                    first = index
                engine.write_json(engine.run_dir(out, index) / engine.RESULT, result)
            told = [k for k in range(len(points)) if start + k in batch_results]
            searcher.tell([points[k] for k in told], [batch_results[start + k] for k in told],
                          [batch_results[start + k]["search"]["score"] for k in told])
            generation += 1
            if on_progress is not None:
                on_progress(SearchProgress(len(results), plan.budget, min(r["search"]["score"] for r in results.values()),
                                           sum(1 for r in results.values() if scorer.violates(r))))
        cluster = workers.record()
    done = [results[i] for i in sorted(results)]
    best = min(done, key=lambda r: r["search"]["score"])
    search_record.update(
        runs=len(done), first_violation=first, runs_to_first_violation=None if first is None else first + 1,
        best={"index": best["index"], "score": best["search"]["score"]},
        not_a_sample=NOT_A_SAMPLE,
    )
    if isinstance(searcher, QualityDiversity):
        search_record["archive"] = searcher.cells()
    outcome = runner.finish(campaign_plan, out, sf, case, done, 0, wall_start, provenance(runs.identity),
                            search=search_record, cluster=cluster)
    return FalsifyOutcome(outcome.results, outcome.results_path, outcome.report_path)


def _evaluate(workers, plan: CampaignPlan, out: Path, tasks, origin, scorer: Scorer) -> dict[int, dict]:
    """Run one batch; runs after the first that violates a targeted condition are not started (those before
    it finish), and one running when it came is left out (``engine.keep_before``): the search's runs do not depend on
    how many ran at once."""
    done: dict[int, dict] = {}

    def take(result: dict) -> None:
        done[result["index"]] = result

    def cutoff() -> int | None:
        violating = [i for i, r in done.items() if scorer.violates(r)]
        return min(violating) + 1 if violating else None

    engine.run_all(workers, plan, out, tasks, origin, take, cutoff, lost="the runs so far are in {out}")
    engine.keep_before(out, done, cutoff())
    return done


def read_search(out: Path) -> dict | None:
    """The ``search`` record of a folder ``cellsim falsify`` wrote (None for a campaign's)."""
    try:
        return json.loads((out / PLAN).read_text()).get("search")
    except (OSError, ValueError, AttributeError):
        return None
