"""Counterexample-guided refinement: verify until the twin agrees, or the budget is spent.

Check the abstract model; replay each witness on the twin. Where the twin refutes one, ask each module's
abstraction where the witness does what the module cannot (:meth:`cellsim.verify.model.ModuleAbstraction.
refinement`: which variable, at which period, why); switch that refinement on, say so, and check again. A plug-in
kind takes part by answering that question for its own module. A witness the twin confirms in any round is a
violation for good (its property keeps that round's result). The loop ends when no witness is refuted, when no
module finds where a refuted witness departs from the cell, or after ``budget`` refinements; a property whose
witness is still refuted then ends undecided, naming what was refined (:mod:`cellsim.verify.endings`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

DEFAULT_BUDGET = 3
"""Refinements ``cellsim verify`` tries by default (``--refine N``)."""
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
                     on_stage=None):
    """:func:`cellsim.verify.run.verify`, each witness replayed on the twin under ``out`` (a refinement's replays
    under ``out/refined-<n>``), refined as the module docstring says; the result's ``refinements`` lists what was
    switched on, in order."""
    from cellsim.verify.run import verify
    from cellsim.verify.witness import replay

    say = on_stage or (lambda text: None)
    done: list[Refinement] = []
    built = None  # the next round's abstract model, built to judge its size
    confirmed: dict = {}  # property -> (its checked result, its replay) from the round whose witness the twin confirmed
    once: dict = {}  # liveness conditions' stronger responses (no witness run, nothing to refine): checked in round 1
    while True:
        result = verify(sf, export=export, timed=timed, refinements=frozenset(r.key for r in done), on_stage=on_stage,
                        checked_before=once, model=built)
        once = once or {r.prop.name: r for r in result.results if r.prop.within is not None}
        result.replayed, result.refinements = True, list(done)
        # a violation the twin confirmed stays confirmed: refining elsewhere cannot take it back
        result.results = [confirmed[r.prop.name][0] if r.prop.name in confirmed else r for r in result.results]
        where = out if not done else out / f"refined-{len(done)}"
        for checked in result.results:
            if checked.prop.name in confirmed:
                result.replays[checked.prop.name] = confirmed[checked.prop.name][1]
            elif checked.witness is not None and checked.prop.within is None:  # (a stronger response's: no verdict)
                result.replays[checked.prop.name] = replay(result.model, checked, where, on_stage=on_stage)
                if result.replays[checked.prop.name].confirmed:
                    confirmed[checked.prop.name] = (checked, result.replays[checked.prop.name])
        refuted = [r for r in result.results if r.prop.name in result.replays
                   and not result.replays[r.prop.name].confirmed]
        if not refuted or len(done) >= budget:
            return result
        found = _refinement(result.model, refuted, len(done) + 1)
        if found is None:
            say("no module's abstraction finds where the refuted witnesses depart from the cell: nothing to refine")
            return result
        could, built = _could_reach(sf, result, timed, [*(r.key for r in done), found.key])
        if could > STATE_BUDGET:
            result.not_refined = (f"{found.key} not tried: the refined model could reach about {could:.2g} states "
                                  f"(over {STATE_BUDGET:,})")
            say(f"refinement {found.step}: {result.not_refined}")
            return result
        say(f"refinement {found.step}: {found}")
        done.append(found)


def _could_reach(sf, result, timed: bool, keys: list[str]):
    """(States the model with refinements ``keys`` could reach: the largest model checked so far, times how much the
    refinement widens its variables' ranges (the product of their numbers of values); that model, to check next)."""
    from cellsim.verify.run import abstract_model

    refined = abstract_model(sf, timed=timed, refinements=frozenset(keys))
    largest = (result.refinable or result.largest or result.stats).states
    return largest * refined.bound() / max(result.model.bound(), 1.0), refined


def _refinement(model, refuted, step: int) -> Refinement | None:
    """The first refinement a module offers for the first refuted witness that shows one."""
    for checked in refuted:
        for part in model.parts:
            ask = getattr(part, "refinement", None)  # an observer (Observer) has nothing to refine
            offered = None if ask is None else ask(model.cell, checked.witness)
            if offered is not None:
                return Refinement(step, offered[0], checked.prop.name, offered[1])
    return None
