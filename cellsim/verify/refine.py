"""Counterexample-guided refinement: verify until the twin agrees, or the budget is spent.

Check the abstract model. For each violated property's witness, ask each module's abstraction where the witness
does what the module cannot (:meth:`cellsim.verify.model.ModuleAbstraction.refinement`: which variable, at which
period, why). A witness some module faults is not run on the twin: the first refinement offered is switched on, said,
and the model checked again (the refined model is as sound as the coarser one, so a violation the cell can show
survives it, with a witness of its own). The witnesses no module faults are replayed on the twin: one the twin
confirms is a violation for good (its property keeps that round's result); one it refutes leaves its property
undecided. A plug-in kind takes part by answering that question for its own module. The loop ends when no module
faults a witness, after ``budget`` refinements, or when the next refinement's model could be too large; the
witnesses of that last round are then all replayed, and a property whose witness the twin refutes ends undecided,
naming what was refined (:mod:`cellsim.verify.endings`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

DEFAULT_BUDGET = 3
"""Refinements ``cellsim verify`` tries by default (``--refine N``)."""
TRIES = 3
"""Refinements a round weighs against the state budget, in order (:func:`_refinements`), before it gives up: each
costs the refined abstract model's build, and maybe its decision diagrams'."""
COSTLY_GROWTH = 4
"""A refinement whose model could reach more than this many times the states of the largest model checked so far
runs the witnesses it would take up on the twin first (a replay costs seconds; such a round, minutes): the machine-
tending cell's pace, 382,299 states to millions, for a witness of TrueSSM the twin confirms."""
STATE_BUDGET = 5_000_000
"""A refinement whose model could reach more states than this (the largest model checked so far, times the growth
of its variables' ranges) is not tried: its property stays undecided, and says so, rather than exhaust the memory."""


@dataclass(frozen=True)
class Refinement:
    """One refinement: the ``key`` switched on (``<module>:<what>``), for the witness of ``prop``, and why."""

    step: int
    key: str
    prop: str
    why: str

    def __str__(self) -> str:
        return f"{self.key} (the witness of {self.prop}: {self.why})"


def verify_with_twin(sf, out: Path, *, budget: int = DEFAULT_BUDGET, timed: bool = False, export: Path | None = None,
                     on_stage=None, only: tuple[str, ...] = ()):
    """:func:`cellsim.verify.run.verify`, refined as the module docstring says and each witness no refinement takes
    up replayed on the twin under ``out`` (a refinement's round under ``out/refined-<n>``); the result's
    ``refinements`` lists what was switched on, in order. ``only``: the properties asked for (every round's)."""
    from cellsim.verify.run import verify
    from cellsim.verify.witness import replay, walk_key

    say = on_stage or (lambda text: None)
    done: list[Refinement] = []
    built = None  # the next round's abstract model, built to judge its size
    confirmed: dict = {}  # property -> (its checked result, its replay) from the round whose witness the twin confirmed
    skipped: dict = {}  # property -> [(its checked result, that round's model, its folder, its replay if it ran first)]:
    # witnesses refined (run first, where the refinement was costly: the twin refuted them)
    waited: dict = {}  # property -> (that round's refinements, its folder): a witness deferred, never built
    once: dict = {}  # liveness conditions' stronger responses (no witness run, nothing to refine): checked in round 1
    grown_from = None  # the states of the largest model checked so far (a refined round's tables are sized on it)
    measured: dict = {}  # what the rounds' models read on the floor, pose by pose: each round measures only new poses
    growth: dict = {}  # each group's growth by its monitors, as the rounds so far built it (Verification.growth)
    ahead = None  # (its refinements, the properties confirmed when it was built, the round): built to size it

    def terms(refined: int) -> tuple:
        """(``enough``, ``checked_before``) of the round after ``refined`` refinements."""
        # a witness a module faults settles the round: the others wait for the refined model (while one may come)
        enough = None if refined >= budget else (
            lambda model, checked: checked.prop.name not in confirmed and _faults(model, checked.witness))
        # a violation the twin confirmed stands for good: its monitor leaves the refined model (a smaller one to
        # build), unless the model is exported, which keeps every monitor
        return enough, {**once, **({} if export is not None else {name: c for name, (c, _) in confirmed.items()})}

    while True:
        keys = frozenset(r.key for r in done)
        if ahead is not None and ahead[:2] == (keys, frozenset(confirmed)):
            result = ahead[2]  # built to size its refinement, and checked: nothing has changed since
        else:
            enough, before = terms(len(done))
            result = verify(sf, only=only, export=export, timed=timed, refinements=keys, on_stage=on_stage,
                            checked_before=before, model=built, enough=enough, grown_from=grown_from, measured=measured,
                            growth_seen=growth)
        ahead = None
        growth.update(result.growth)
        once = once or {r.prop.name: r for r in result.results if r.prop.within is not None}
        grown_from = max(grown_from or 0, (result.largest or result.stats).states)
        open_ = _witnessed(result, done, confirmed)
        refinable = _refinable(result.model, open_)
        found = None
        for tried, candidate in enumerate(_refinements(result.model, refinable, len(done) + 1) if len(done) < budget else ()):
            if tried == TRIES:
                break
            could, built, exact = _could_reach(sf, result, timed, [*(r.key for r in done), candidate.key], measured,
                                               only)
            if could <= STATE_BUDGET:
                found = candidate
                break
            too_large = (f"{candidate.key} not tried: the refined model could reach about {could:.2g} states "
                         f"(over {STATE_BUDGET:,})")
            result.not_refined = "; ".join(filter(None, (result.not_refined, too_large)))
            say(f"refinement {candidate.step}: {too_large}")
        if found is not None and could > COSTLY_GROWTH * grown_from and not exact:
            # the quick bound can be hundreds of times too high: the refined round is built to measure it, and checked
            # where it is not costly after all (the next round, then built once), else left for after the replays
            say(f"refinement {found.step}: building the model with {found.key} to size it")
            enough, before = terms(len(done) + 1)
            sized = verify(sf, only=only, export=export, timed=timed, refinements=keys | {found.key}, on_stage=on_stage,
                           checked_before=before, model=built, enough=enough, grown_from=grown_from, measured=measured,
                           growth_seen=growth, costly_above=COSTLY_GROWTH * grown_from)
            could = sized.stats.states
            if not sized.costly:
                ahead = (keys | {found.key}, frozenset(confirmed), sized)
        tried_first: dict = {}  # property -> the replay of its witness, run before a costly refinement
        if found is not None and could > COSTLY_GROWTH * grown_from:
            # a refinement that grows the model this much costs more than running the witnesses it would take up on
            # the twin: they run first, and the twin confirming every one leaves it nothing to do
            where = out if not done else out / f"refined-{len(done)}"
            trial = [r for r in refinable if _faults(result.model, r.witness)]
            tried_first = {r.prop.name: replay(result.model, r, where, on_stage=on_stage) for r in trial}
            if trial and all(run.confirmed for run in tried_first.values()):
                confirmed.update((r.prop.name, (r, tried_first[r.prop.name])) for r in trial)
                say(f"refinement {found.step}: {found.key} not needed: the twin confirms the witness of "
                    f"{', '.join(tried_first)} it would take up (its model could reach about {could:.2g} states)")
                found, built = None, None
        if found is not None:
            result.not_refined = ""
        if found is None and any(r.deferred for r in result.results):  # the last round after all: build them
            not_refined = result.not_refined
            result = verify(sf, only=only, export=export, timed=timed, refinements=keys, on_stage=on_stage,
                            checked_before={r.prop.name: r for r in result.results if not r.deferred},
                            grown_from=grown_from, measured=measured, growth_seen=growth)
            result.not_refined = not_refined
            open_ = _witnessed(result, done, confirmed)
            refinable = _refinable(result.model, open_)
        # the witnesses the refinement takes up are not run: the refined model checks their properties again
        faulted = set() if found is None else {r.prop.name for r in refinable if _faults(result.model, r.witness)}
        to_run = {r.prop.name for r in open_} - faulted
        where = out if not done else out / f"refined-{len(done)}"
        ran: list = []  # (walk, its replay) of this round: a condition whose witness walks the same reuses its runs
        for checked in result.results:
            if checked.prop.name in confirmed:
                result.replays[checked.prop.name] = confirmed[checked.prop.name][1]
            elif checked.prop.name in to_run:
                walked = walk_key(result.model, checked) if checked.witness else None
                same = next((run for path, run in ran if walked is not None and path == walked), None)
                result.replays[checked.prop.name] = replay(result.model, checked, where, on_stage=on_stage, same=same)
                ran.append((walked, result.replays[checked.prop.name]))
                if result.replays[checked.prop.name].confirmed:
                    confirmed[checked.prop.name] = (checked, result.replays[checked.prop.name])
        if found is None:
            def rebuild(keys, names):  # the deferred properties' witnesses, in the model of the round they waited in
                others = {r.prop.name: r for r in result.results if r.prop.name not in names}
                return verify(sf, only=only, timed=timed, refinements=keys, on_stage=on_stage, checked_before=others,
                              grown_from=grown_from, measured=measured, growth_seen=growth)

            _run_skipped(result, skipped, waited, confirmed, rebuild, on_stage)
            refuted = any(not result.replays[name].confirmed for name in to_run)
            kept = {r.prop.name for r in refinable}
            if refuted and not any(not result.replays[name].confirmed for name in to_run & kept):
                # only witnesses no refinement helps were refuted: say why, in their reasons
                why = {reason for r in open_ if r.prop.name in to_run - kept for part in result.model.parts
                       if (reason := getattr(part, "leaves_unrefined", lambda prop: None)(r.prop))}
                result.not_refined = "; ".join(filter(None, (result.not_refined, *sorted(why))))
                say(f"nothing refined: {'; '.join(sorted(why))}")
            elif refuted and len(done) >= budget:
                offered = next(iter(_refinements(result.model, refinable, len(done) + 1)), None)
                if offered is not None:  # what blocks the verdict is the budget: say what it would refine next
                    spent = f"the refinement budget (--refine {budget}) is spent: {offered.key} was next ({offered.why})"
                    result.not_refined = "; ".join(filter(None, (result.not_refined, spent)))
                    say(spent)
            elif refuted and not result.not_refined:  # what blocks the verdict, in each refuted property's reason too
                result.not_refined = ("nothing to refine (no module's abstraction finds where the refuted witnesses "
                                      "depart from the cell)")
                say("no module's abstraction finds where the refuted witnesses depart from the cell: "
                    "nothing to refine")
            return result
        for checked in open_:
            if checked.prop.name in faulted:
                skipped.setdefault(checked.prop.name, []).append(
                    (checked, result.model, where, tried_first.get(checked.prop.name)))
        for checked in result.results:
            if checked.deferred and checked.prop.name not in skipped:
                waited.setdefault(checked.prop.name, (keys, where))
        say(f"refinement {found.step}: {found}")
        done.append(found)


def _run_skipped(result, skipped: dict, waited: dict, confirmed: dict, rebuild, on_stage) -> None:
    """A property the last round leaves violated but not confirmed (no witness: a model too large for one; or one the
    twin refutes) whose coarser witnesses were refined rather than run: run those now, in the order found, until the
    twin confirms one; one whose witness waited for a refinement and was never built (``waited``) has it built
    now (``rebuild(refinements, names)``: that round's model) and run. Refining them was a bet that the refined model
    decides the property; where it does not, the witness the old rule would have run still may."""
    from cellsim.verify.witness import replay

    def unsettled(checked) -> bool:
        name = checked.prop.name
        return (name not in confirmed and checked.holds is False and checked.prop.within is None
                and not (name in result.replays and result.replays[name].confirmed))

    def confirm(i, earlier, model, where, ran=None) -> bool:
        if ran is None:  # (one run before its refinement is not run again)
            ran = replay(model, earlier, where, on_stage=on_stage)
        if ran.confirmed:
            confirmed[earlier.prop.name] = (earlier, ran)
            result.results[i], result.replays[earlier.prop.name] = earlier, ran
        else:
            keys = sorted(model.cell.refinements)
            result.earlier.setdefault(earlier.prop.name, []).append(
                f"the witness of the model {'with ' + ', '.join(keys) if keys else 'before any refinement'} was run "
                f"too, and the twin refutes it in {len(ran.runs)} runs ({ran.scenarios[0]})")
        return ran.confirmed

    index = {r.prop.name: i for i, r in enumerate(result.results)}
    for name, runs in skipped.items():
        if name in index and unsettled(result.results[index[name]]):
            any(confirm(index[name], *run) for run in runs)
    by_round: dict = {}
    for name, (keys, where) in waited.items():
        if name in index and unsettled(result.results[index[name]]):
            by_round.setdefault((keys, where), []).append(name)
    for (keys, where), names in by_round.items():
        built = rebuild(keys, set(names))
        for earlier in built.results:
            if earlier.prop.name in names and earlier.witness is not None:
                confirm(index[earlier.prop.name], earlier, built.model, where)


def _witnessed(result, done: list, confirmed: dict) -> list:
    """Mark ``result`` as a round of refinement (after ``done``), put back the results whose witnesses the twin
    confirmed (refining elsewhere cannot take them back), and return the violated properties with a witness to refine
    or run (a stronger response's has no verdict of its own: neither)."""
    result.replayed, result.refinements = True, list(done)
    result.results = [confirmed[r.prop.name][0] if r.prop.name in confirmed else r for r in result.results]
    return [r for r in result.results if r.prop.name not in confirmed and r.witness is not None
            and r.prop.within is None]


def _refinable(model, witnessed: list) -> list:
    """The witnessed properties a refinement may be asked for: not those a module says no refinement helps
    (``ModuleAbstraction.leaves_unrefined``); their witnesses are run on the twin as they are."""
    return [r for r in witnessed
            if not any(getattr(part, "leaves_unrefined", lambda prop: None)(r.prop) for part in model.parts)]


def _could_reach(sf, result, timed: bool, keys: list[str], measured: dict | None = None, only: tuple[str, ...] = ()):
    """(States the model with refinements ``keys`` could reach: the largest model checked so far, times how much the
    refinement widens its variables' ranges (the product of their numbers of values), a quick upper bound; where that
    is over the budget, the states the refined cell really reaches (:func:`_reached`); that model, to check next;
    whether the states are those it reaches, not the bound)."""
    from cellsim.verify.run import abstract_model

    refined = abstract_model(sf, timed=timed, refinements=frozenset(keys), measured=measured, only=only)
    largest = (result.refinable or result.largest or result.stats).states
    could = largest * refined.bound() / max(result.model.bound(), 1.0)
    if could <= STATE_BUDGET:
        return could, refined, False
    return _reached(refined, largest), refined, True


def _reached(refined, grown_from: int) -> float:
    """The states the refined cell (no monitor) reaches, built as decision diagrams in a process of its own: seconds,
    where the quick bound can be a hundredfold too high (the assembly bench's pace: 337,208 states against an
    estimated 130 million); infinite when Storm stops (its tables full)."""
    import math
    import tempfile

    from cellsim.verify.isolated import ProcessStopped, in_own_process
    from cellsim.verify.run import dd_memory
    from cellsim.verify.storm import DD_MEMORY, build_symbolic

    with tempfile.TemporaryDirectory(prefix="cellsim-refined-") as scratch:  # (ours: a stopped Storm leaves none)
        path = Path(scratch) / "refined.prism"
        path.write_text(refined.cell.program(refined.header, [], {}).text())
        small = dd_memory(refined.bound(), grown_from)
        for memory in dict.fromkeys([small, DD_MEMORY]):  # tables that prove too small: built again with the large
            try:
                return float(in_own_process(lambda say: build_symbolic(path, memory)[2].states))
            except ProcessStopped:
                continue
        return math.inf


def _refinements(model, witnessed, step: int) -> list[Refinement]:
    """The refinements the modules offer for the ``witnessed`` properties' witnesses, in the order to try them: the
    first witness's first (:func:`_offers`), then its others, then the next witness's (each refinement once)."""
    found: dict[str, Refinement] = {}
    for checked in witnessed:
        for key, why in _offers(model, checked.witness):
            found.setdefault(key, Refinement(step, key, checked.prop.name, why))
    return list(found.values())


def _faults(model, witness) -> bool:
    """Whether some module's abstraction finds the witness doing what the module cannot."""
    return bool(_offers(model, witness))


def _offers(model, witness) -> list[tuple[str, str]]:
    """The modules' refinements for ``witness`` as (key, why), that of the module it departs from first first (the
    earliest step a module's abstraction names; between equals, the module first in the scenario)."""
    offers = []
    for order, part in enumerate(model.parts):
        ask = getattr(part, "refinement", None)  # an observer (Observer) has nothing to refine
        offered = None if ask is None else ask(model.cell, witness)
        if offered is not None:
            step = offered[2] if len(offered) > 2 else len(witness)
            offers.append((step, order, offered[0], offered[1]))
    return [offer[2:] for offer in sorted(offers)]
