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
