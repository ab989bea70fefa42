"""The refinement loop's rule (issue 36), on a scripted verifier: a witness some module's abstraction faults is
refined, not run on the twin; the others are run in the same round; a violation the twin confirmed stays; the last
round (budget spent, nothing to refine, or a refinement too large) runs every witness it has."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import cellsim.verify.refine as refine
import cellsim.verify.run as run
import cellsim.verify.witness as witness
from cellsim.verify.endings import Ending


@dataclass(frozen=True)
class Prop:
    name: str
    within: float | None = None


@dataclass
class Checked:
    prop: Prop
    holds: bool | None
    witness: list | None = None
    fair: bool | None = None
    deferred: bool = False


@dataclass
class Replay:
    confirmed: bool
    runs: list = field(default_factory=lambda: [Path("runs/w")])
    scenarios: list = field(default_factory=lambda: [Path("w.yaml")])


class Pace:
    """A module's abstraction that faults a witness marked ``fast``."""

    def refinement(self, cell, path):
        return ("operator:pace", "crosses a place too fast") if path and path[0].get("fast") else None


@dataclass
class Model:
    parts: list = field(default_factory=lambda: [object(), Pace()])
    cell: object = None
    round: int = 0

    def bound(self) -> float:
        return 10.0


@dataclass
class Stats:
    states: int = 100
    symbolic: bool = False


class Slow:
    """A second module's abstraction that also faults a witness marked ``fast``, at a later step."""

    def refinement(self, cell, path):
        return ("robot:timed", "moves too fast", 5) if path and path[0].get("fast") else None


def scripted(monkeypatch, rounds: dict, confirms: set[tuple[int, str]], could=10.0, parts=None, exact=True,
             states=None):
    """``rounds``: the refinements switched on (frozenset) -> {property: its witness ("fast", "slow") or None (holds)};
    ``confirms``: (round, property) pairs whose replay the twin confirms (the round the witness is of); a witness
    ``"none"``: violated without one; ``could``: the states a refinement could reach (a number, or a function of the
    refinements' keys); ``parts``: the modules' abstractions (default: one that refines the pace); ``exact``: whether
    ``could`` is the states the refined cell reaches (else a quick bound, measured by building the round);
    ``states``: the states of a round's whole cell (a function of its refinements; default 100). Returns the log of
    replays and of the verifier's calls (round, the properties whose witnesses it built; ("sized", round): a round
    stopped once built, too large to check before the replays)."""
    replays: list[tuple[int, str]] = []
    current = {"round": 0}

    def fake_verify(sf, *, refinements, enough=None, checked_before=None, costly_above=None, **kwargs):
        """As :func:`cellsim.verify.run.verify`: witnesses built in order until ``enough`` says one settles it."""
        current["round"] = len(refinements)
        model = Model(cell=SimpleNamespace(refinements=frozenset(refinements)), round=len(refinements))
        if parts is not None:
            model.parts = parts
        stats = Stats(states(frozenset(refinements)) if states else 100)
        if costly_above is not None and stats.states > costly_above:
            replays.append(("sized", len(refinements)))
            return run.Verification(model, stats, [], {}, costly=True)
        results, settled, built = [], False, []
        for name, w in rounds[frozenset(refinements)].items():
            if checked_before and name in checked_before:
                results.append(checked_before[name])
            elif w is None:
                results.append(Checked(Prop(name), True))
            elif w == "none":  # violated, and no witness (decision diagrams only)
                results.append(Checked(Prop(name), False))
            elif settled:
                results.append(Checked(Prop(name), False, deferred=True))
            else:
                results.append(Checked(Prop(name), False, [{w: True}]))
                built.append(name)
                settled = enough is not None and enough(model, results[-1])
        replays.append(("verify", len(refinements), tuple(built)))
        return run.Verification(model, stats, results, {})

    def fake_replay(model, checked, where, on_stage=None, same=None):
        """Logs (the round running, the property) and, for a witness of an earlier round (a skipped one run at the
        end), which round's model it came from as a third item."""
        entry = (current["round"], checked.prop.name) + (() if model.round == current["round"] else (model.round,))
        replays.append(entry)
        return Replay(entry[:2] in confirms if len(entry) == 2 else (model.round, checked.prop.name) in confirms)

    monkeypatch.setattr(run, "verify", fake_verify)
    monkeypatch.setattr(witness, "replay", fake_replay)
    monkeypatch.setattr(refine, "_could_reach",
                        lambda sf, result, timed, keys, measured=None, only=(): (
                            could(keys) if callable(could) else could, None, exact))
    return replays


PACE = frozenset({"operator:pace"})


def test_a_faulted_witness_is_refined_unrun_and_the_others_are_run_in_the_same_round(monkeypatch, tmp_path):
    replays = scripted(monkeypatch, {
        frozenset(): {"A": "fast", "B": "slow", "C": "slow", "D": None},
        PACE: {"A": "slow", "B": "slow", "C": "slow", "D": None},
    }, confirms={(1, "B"), (1, "A")})
    said = []
    result = refine.verify_with_twin(None, tmp_path, budget=3, on_stage=said.append)
    # round 0: A's witness is refined, not run, and B's and C's wait for the refined model; round 1 builds them
    # all, no module faults one, and all three are run
    assert replays[:5] == [("verify", 0, ("A",)), ("verify", 1, ("A", "B", "C")), (1, "A"), (1, "B"), (1, "C")]
    # C's refuted: its round-0 witness, which waited for the refinement, is built and run at the end (refuted too)
    assert replays[5:] == [("verify", 0, ("C",)), (0, "C")]
    assert [(r.step, r.key, r.prop) for r in result.refinements] == [(1, "operator:pace", "A")]
    assert "refinement 1: operator:pace (the witness of A: crosses a place too fast)" in said
    endings = {f.name: f.ending for f in result.endings()}
    assert endings == {"A": Ending.VIOLATED, "B": Ending.VIOLATED, "C": Ending.UNDECIDED, "D": Ending.HOLDS}
    assert result.exit_code == 1
    # C's ending names both refutations: its own round's witness, and the coarser one run at the end
    reason = next(f.reason for f in result.endings() if f.name == "C")
    assert reason.startswith("the twin refutes the witness in 1 runs")
    assert "the witness of the model before any refinement was run too, and the twin refutes it in 1 runs" in reason
    assert any("nothing to refine" in s for s in said)  # C's refuted witness: no module faults it
    assert "nothing to refine (no module's abstraction finds where" in reason  # and its ending says so


def test_with_the_budget_spent_a_faulted_witness_is_run_on_the_twin(monkeypatch, tmp_path):
    replays = scripted(monkeypatch, {frozenset(): {"A": "fast"}, PACE: {"A": "fast"}}, confirms=set())
    result = refine.verify_with_twin(None, tmp_path, budget=1)
    # the last round's witness, refuted; then the one refined in round 0 (never run), refuted too
    assert [r for r in replays if r[0] != "verify"] == [(1, "A"), (1, "A", 0)] and len(result.refinements) == 1
    (final,) = result.endings()
    assert final.ending is Ending.UNDECIDED and "refinement: operator:pace" in final.reason
    assert refine.verify_with_twin(None, tmp_path, budget=0).refinements == [] and replays[-2:] == [
        ("verify", 0, ("A",)), (0, "A")]


def test_a_refinement_too_large_to_try_leaves_every_witness_run(monkeypatch, tmp_path):
    replays = scripted(monkeypatch, {frozenset(): {"A": "fast", "B": "slow"}}, confirms=set(),
                       could=refine.STATE_BUDGET * 2.0)
    said = []
    result = refine.verify_with_twin(None, tmp_path, budget=3, on_stage=said.append)
    # B's witness, left for a refined model that will not come, is built after all; then both are run
    assert replays == [("verify", 0, ("A",)), ("verify", 0, ("B",)), (0, "A"), (0, "B")]
    assert result.refinements == [] and not any(r.deferred for r in result.results)
    assert result.not_refined.startswith("operator:pace not tried")
    assert not any("nothing to refine" in s for s in said)
    assert {f.ending for f in result.endings()} == {Ending.UNDECIDED}


def test_a_stronger_response_witness_is_neither_run_nor_refined(monkeypatch, tmp_path):
    """A liveness condition's stronger response (``within``) has no verdict of its own: its witness is not run,
    and a module's fault in it refines nothing."""
    replays = []

    def fake_verify(sf, *, refinements, **kwargs):
        return run.Verification(Model(), Stats(), [Checked(Prop("HS:handled", 2.0), False, [{"fast": True}], True)],
                                {})

    monkeypatch.setattr(run, "verify", fake_verify)
    monkeypatch.setattr(witness, "replay", lambda *a, **k: replays.append(a))
    result = refine.verify_with_twin(None, tmp_path, budget=3)
    assert replays == [] and result.refinements == []


def test_a_witness_run_before_the_refinement_that_the_twin_confirmed_stays_violated(monkeypatch, tmp_path):
    replays = scripted(monkeypatch, {
        frozenset(): {"A": "slow", "B": "fast", "C": "slow"},
        PACE: {"A": "slow", "B": "slow", "C": None},
    }, confirms={(0, "A")})
    result = refine.verify_with_twin(None, tmp_path, budget=3)
    # A's witness, built before B's settled the round, is run there and confirmed; C's waited and then holds. A
    # confirmed violation stands for good: the refined round leaves it out (a smaller model to build)
    assert replays == [("verify", 0, ("A", "B")), (0, "A"), ("verify", 1, ("B",)), (1, "B"), (1, "B", 0)]
    endings = {f.name: f.ending for f in result.endings()}
    assert endings == {"A": Ending.VIOLATED, "B": Ending.UNDECIDED, "C": Ending.HOLDS}


def test_a_refined_round_without_a_witness_runs_the_witness_it_refined_and_the_twin_may_confirm_it(monkeypatch, tmp_path):
    """The refined model gives no witness (decision diagrams only, too large for a sparse form): the coarser witness
    that was refined rather than run is run after all, and the twin confirms it: violated, not undecided."""
    replays = scripted(monkeypatch, {
        frozenset(): {"A": "fast", "B": None},
        PACE: {"A": "none", "B": None},  # (violated, no witness)
    }, confirms={(0, "A")})
    result = refine.verify_with_twin(None, tmp_path, budget=3)
    assert [r for r in replays if r[0] != "verify"] == [(1, "A", 0)]
    endings = {f.name: f.ending for f in result.endings()}
    assert endings == {"A": Ending.VIOLATED, "B": Ending.HOLDS}
    assert result.exit_code == 1


def test_a_witness_that_waited_for_a_refinement_that_gave_none_is_built_and_run_at_the_end(monkeypatch, tmp_path):
    """Round 0 refines for A's witness, so B's waits (deferred, never built); the refined round gives neither a
    witness: both coarser witnesses are then run, B's built first in round 0's model, and the twin confirms both."""
    replays = scripted(monkeypatch, {
        frozenset(): {"A": "fast", "B": "slow"},
        PACE: {"A": "none", "B": "none"},
    }, confirms={(0, "A"), (0, "B")})
    result = refine.verify_with_twin(None, tmp_path, budget=3)
    assert replays == [("verify", 0, ("A",)), ("verify", 1, ()), (1, "A", 0), ("verify", 0, ("B",)), (0, "B")]
    assert {f.name: f.ending for f in result.endings()} == {"A": Ending.VIOLATED, "B": Ending.VIOLATED}


def test_a_refinement_too_large_gives_way_to_the_next_one_offered(monkeypatch, tmp_path):
    """Two modules fault A's witness: the pace (it departs there first) would make too large a model, the robot's
    timing would not: the loop refines the robot's timing, and says why not the pace."""
    timed = frozenset({"robot:timed"})
    replays = scripted(monkeypatch, {frozenset(): {"A": "fast"}, timed: {"A": None}}, confirms=set(),
                       could=lambda keys: refine.STATE_BUDGET * (2.0 if "operator:pace" in keys else 0.1),
                       parts=[Pace(), Slow()])
    said = []
    result = refine.verify_with_twin(None, tmp_path, budget=3, on_stage=said.append)
    assert [(r.step, r.key) for r in result.refinements] == [(1, "robot:timed")]
    assert said[0].startswith("refinement 1: operator:pace not tried: the refined model could reach about")
    # the timing's model could reach thousands of times the states: A's witness is run first, the twin refutes it,
    # and the timing is refined; A holds once the robot's moves are timed
    assert [r for r in replays if r[0] != "verify"] == [(0, "A")]
    assert {f.name: f.ending for f in result.endings()} == {"A": Ending.HOLDS}


def test_a_refinement_that_would_grow_the_model_far_runs_the_witness_first_and_the_twin_may_spare_it(monkeypatch,
                                                                                                   tmp_path):
    """The machine-tending cell's pace, once its counter stopped at its guards, fit the state budget: refining
    took its verify from 60 s to 150 s for a TrueSSM witness the twin confirms anyway. A refinement whose model could
    reach more than COSTLY_GROWTH times the largest checked runs the witnesses it would take up first; the twin
    confirming them all, nothing is refined (a refuted one is refined, as before)."""
    costly = refine.COSTLY_GROWTH * Stats().states * 10.0
    replays = scripted(monkeypatch, {frozenset(): {"A": "fast", "B": "slow"}, PACE: {"A": "slow", "B": "slow"}},
                       confirms={(0, "A"), (0, "B")}, could=costly)
    said = []
    result = refine.verify_with_twin(None, tmp_path, budget=3, on_stage=said.append)
    assert result.refinements == [] and replays == [("verify", 0, ("A",)), (0, "A"), ("verify", 0, ("B",)), (0, "B")]
    assert any("operator:pace not needed: the twin confirms the witness of A" in s for s in said)
    assert {f.name: f.ending for f in result.endings()} == {"A": Ending.VIOLATED, "B": Ending.VIOLATED}
    # refuted, the witness is refined after all
    replays = scripted(monkeypatch, {frozenset(): {"A": "fast"}, PACE: {"A": "slow"}}, confirms={(1, "A")},
                       could=costly)
    result = refine.verify_with_twin(None, tmp_path, budget=3)
    assert [(r.key, r.prop) for r in result.refinements] == [("operator:pace", "A")]
    assert replays[:2] == [("verify", 0, ("A",)), (0, "A")] and (1, "A") in replays


def test_a_witness_run_before_a_costly_refinement_is_not_run_again_at_the_end(monkeypatch, tmp_path):
    """A witness the twin refuted before a costly refinement was taken up stays refuted: when the refined round's
    own witness is refuted too, the end does not run the coarser one a second time (seconds of the twin's, and a
    second folder for one replay), and its ending still names both refutations."""
    costly = refine.COSTLY_GROWTH * Stats().states * 10.0
    replays = scripted(monkeypatch, {frozenset(): {"A": "fast"}, PACE: {"A": "slow"}}, confirms=set(), could=costly)
    result = refine.verify_with_twin(None, tmp_path, budget=3)
    assert [r for r in replays if r[0] != "verify"] == [(0, "A"), (1, "A")]
    (final,) = result.endings()
    assert final.ending is Ending.UNDECIDED
    assert "the witness of the model before any refinement was run too, and the twin refutes it" in final.reason



def test_a_refinement_sized_by_building_its_round_is_checked_in_that_build_unless_it_is_costly(monkeypatch, tmp_path):
    """A quick bound far over the largest model checked is measured by building the refined round itself (the welding
    cell's pace: about 4 million states bounded, 19,458 reached): small after all, that round is checked there and
    taken as the next round, not built a second time; costly, it stops once built, the witnesses it would take up
    run on the twin first, and it is built again only if the twin refutes one."""
    rounds = {frozenset(): {"A": "fast"}, PACE: {"A": None}}
    replays = scripted(monkeypatch, rounds, confirms=set(), could=10.0 ** 6, exact=False)
    result = refine.verify_with_twin(None, tmp_path, budget=3)
    assert [r.key for r in result.refinements] == ["operator:pace"]
    assert replays == [("verify", 0, ("A",)), ("verify", 1, ())]  # the refined round built once
    assert {f.name: f.ending for f in result.endings()} == {"A": Ending.HOLDS}
    # costly: stopped once built, the witness runs first; the twin confirming it, nothing is refined
    replays = scripted(monkeypatch, rounds, confirms={(0, "A")}, could=10.0 ** 6, exact=False,
                       states=lambda keys: 10_000 if keys else 100)
    result = refine.verify_with_twin(None, tmp_path, budget=3)
    # (the witness of round 0, run once round 1 was sized)
    assert result.refinements == [] and replays == [("verify", 0, ("A",)), ("sized", 1), (1, "A", 0)]
    # refuted: refined after all, the round built again
    replays = scripted(monkeypatch, rounds, confirms=set(), could=10.0 ** 6, exact=False,
                       states=lambda keys: 10_000 if keys else 100)
    result = refine.verify_with_twin(None, tmp_path, budget=3)
    assert [r.key for r in result.refinements] == ["operator:pace"]
    assert replays == [("verify", 0, ("A",)), ("sized", 1), (1, "A", 0), ("verify", 1, ())]


class Unrefined:
    """A module's abstraction saying no refinement helps the witnesses of property ``H`` (as the harm service's)."""

    def leaves_unrefined(self, prop):
        return "no refinement tightens H" if prop.name == "H" else None


def test_a_witness_no_refinement_helps_is_run_as_it_is_and_its_ending_says_why(monkeypatch, tmp_path):
    """A witness the pace faults, of a property a module says no refinement helps (the harm conditions': their bound's
    looseness no refinement tightens): the loop refines nothing for it and runs it on the twin; refuted, its
    ending names the module's reason. The same witness of another property is refined."""
    replays = scripted(monkeypatch, {frozenset(): {"H": "fast"}, PACE: {"H": "fast"}}, confirms=set(),
                       parts=[Pace(), Unrefined()])
    said = []
    result = refine.verify_with_twin(None, tmp_path, budget=3, on_stage=said.append)
    assert result.refinements == [] and replays == [("verify", 0, ("H",)), (0, "H")]
    (final,) = result.endings()
    assert final.ending is Ending.UNDECIDED and "no refinement tightens H" in final.reason
    assert "nothing refined: no refinement tightens H" in said
    replays = scripted(monkeypatch, {frozenset(): {"A": "fast"}, PACE: {"A": None}}, confirms=set(),
                       parts=[Pace(), Unrefined()])
    assert [r.key for r in refine.verify_with_twin(None, tmp_path, budget=3).refinements] == ["operator:pace"]
