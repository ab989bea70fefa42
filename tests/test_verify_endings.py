"""The one rule that gives each verified property its final verdict, and the exit code that follows (issue 36):
a witness the twin refutes, or that nobody ran, is undecided, never a violation."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import pytest

from cellsim.verify.endings import EXIT_UNDECIDED, Ending, ending_of, exit_code


@dataclass
class Prop:
    name: str = "HS:detected"


@dataclass
class Checked:
    holds: bool | None
    witness: list | None = None
    prop: Prop = field(default_factory=Prop)


@dataclass
class Replay:
    confirmed: bool
    runs: list = field(default_factory=lambda: [Path("runs/w/shift-0"), Path("runs/w/shift-0.5")])


@pytest.mark.parametrize("checked, replay, replayed, symbolic, ending, says", [
    (Checked(True), None, True, False, Ending.HOLDS, "proved"),
    (Checked(False, [{}]), Replay(True), True, False, Ending.VIOLATED, "confirms the witness: runs/w/shift-0.5"),
    (Checked(False, [{}]), Replay(False), True, False, Ending.UNDECIDED, "refutes the witness in 2 runs"),
    (Checked(False, [{}]), None, False, False, Ending.UNDECIDED, "not replayed on the twin (--no-replay)"),
    (Checked(False, None), None, True, True, Ending.UNDECIDED, "decision diagrams"),
    (Checked(None), None, True, False, None, "a value"),
])
def test_each_ending_and_its_reason(checked, replay, replayed, symbolic, ending, says):
    final = ending_of(checked, replay, replayed=replayed, symbolic=symbolic)
    assert final.ending is ending and says in final.reason and final.name == "HS:detected"


def test_refinements_tried_are_named_in_an_undecided_reason():
    final = ending_of(Checked(False, [{}]), Replay(False), replayed=True, symbolic=False,
                      refinements=["timed: moves, dwells and cycles take their durations"])
    assert final.ending is Ending.UNDECIDED and final.reason.endswith("refinement: timed: moves, dwells and cycles take "
                                                                        "their durations")


def test_the_exit_code_follows_the_endings():
    def final(ending):
        return ending_of(Checked(*{Ending.HOLDS: (True,), Ending.VIOLATED: (False, [{}]),
                                   Ending.UNDECIDED: (False, [{}])}[ending]),
                         Replay(ending is Ending.VIOLATED), replayed=True, symbolic=False)

    assert exit_code([final(Ending.HOLDS), ending_of(Checked(None), None, replayed=True, symbolic=False)]) == 0
    assert exit_code([final(Ending.HOLDS), final(Ending.UNDECIDED)]) == EXIT_UNDECIDED == 3
    assert exit_code([final(Ending.UNDECIDED), final(Ending.VIOLATED), final(Ending.HOLDS)]) == 1
    assert exit_code([]) == 0


def test_a_refuted_witness_the_twin_walks_slower_says_by_how_much_and_where():
    """The two-operator cell's HC:detected stays undecided with nothing to refine: its witness has the operator cross
    places that meet near one point in a few 20 ms steps, which the pace bound (place by place) allows and no walk
    does. The twin stretches the witness's clock to walk it, so it meets the robot at other moments; the ending says
    so, with the leg that adds the most. Places here: three stops 1 m apart, walked at 1 m/s."""
    from types import SimpleNamespace

    from cellsim.verify.model import Pose
    from cellsim.verify.witness import Replay as Replayed
    from cellsim.verify.witness import lag

    stops = [Pose(0.0, 0.0, 0.0), Pose(1.0, 0.0, 0.0), Pose(1.0, 1.0, 0.0)]
    role = SimpleNamespace(module="visitor", start=stops[0], step=0.1, end=None,
                           travel=lambda a, b: abs(a.x - b.x) + abs(a.y - b.y))
    person = SimpleNamespace(variable="visitor_place", start=0, role=role, end=None,
                             at=lambda place: SimpleNamespace(poses=[stops[place]]))
    model = SimpleNamespace(cell=SimpleNamespace(period=0.02, places=SimpleNamespace(people=[person])))
    witness = [{"visitor_place": p} for p in (0, 0, 1, 2, 2)]
    checked = SimpleNamespace(witness=witness, prop=SimpleNamespace(final=False))
    words = lag(model, checked)
    assert words.startswith("the twin takes 2.04 s to walk the witness's 0.08 s: visitor walks from (0.00, 0.00) to "
                            "(1.00, 0.00) in 1 s, one 0.02 s step in the witness (at 0.04 s)"), words
    final = ending_of(Checked(False, witness), Replayed(False, runs=[Path("runs/w")], lag=words), replayed=True,
                      symbolic=False)
    assert final.ending is Ending.UNDECIDED and words in final.reason
    # stops a step's walk apart (1 cm): the twin keeps the witness's time, and nothing is said
    near = [Pose(0.0, 0.0, 0.0), Pose(0.01, 0.0, 0.0), Pose(0.01, 0.01, 0.0)]
    person.at = lambda place: SimpleNamespace(poses=[near[place]])
    assert lag(model, checked) == ""
