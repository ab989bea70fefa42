"""Liveness conditions G(a -> F b) in ``cellsim verify`` (issue 36): their response within a window holds for every
behaviour; a slower one is judged under fairness by a search Storm makes of the model, checked here on models small
enough to follow by hand, and each ending says which."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from cellsim.verify.endings import Ending, ending_of
from cellsim.verify.storm import always_answerable, build, build_symbolic

# x = 0 is the request (a); x = 2 the response (b). From 1 the environment may wait (a self-loop) as long as it
# likes, or move on to 2: the response is not bounded, but it can always still come.
WAITS = """mdp
module m
  x : [0..3] init 0;
  [] x=0 -> (x'=1);
  [] x=1 -> (x'=1);
  [] x=1 -> (x'=2);
  [] x=2 -> (x'=0);
  [] x=3 -> (x'=3);
endmodule
label "a" = x=0;
label "b" = x=2;
"""
# the same, but from 1 the environment may also go to 3, from which the response never comes
TRAPPED = WAITS.replace("  [] x=1 -> (x'=2);\n", "  [] x=1 -> (x'=2);\n  [] x=1 -> (x'=3);\n")


ENGINES = pytest.mark.parametrize("engine", ["state by state", "decision diagrams"])


def _model(tmp_path, text: str, engine: str):
    """The model built as ``verify`` builds a group for a witness (state by state) or the whole cell (decision
    diagrams, where the question is asked of the initial state alone)."""
    path = tmp_path / "m.prism"
    path.write_text(text)
    program, model, _ = (build if engine == "state by state" else build_symbolic)(path)
    assert model.is_symbolic_model == (engine == "decision diagrams")
    return program, model


@ENGINES
def test_a_response_that_can_always_still_come_holds_under_fairness(tmp_path, engine):
    assert always_answerable(*_model(tmp_path, WAITS, engine), "a", "b")


@ENGINES
def test_a_state_from_which_the_response_never_comes_is_found(tmp_path, engine):
    assert not always_answerable(*_model(tmp_path, TRAPPED, engine), "a", "b")


@ENGINES
def test_a_trap_outside_the_requests_reach_does_not_count(tmp_path, engine):
    """Here x = 3 is reached only from the response (2): every request made is answered, and from 3 none is made
    again; the search goes from each request up to its response, not beyond."""
    text = WAITS.replace("  [] x=2 -> (x'=0);\n", "  [] x=2 -> (x'=0);\n  [] x=2 -> (x'=3);\n")
    assert always_answerable(*_model(tmp_path, text, engine), "a", "b")


@dataclass
class Prop:
    name: str = "HRW:handled"
    within: float = 0.04


@dataclass
class Checked:
    holds: bool
    fair: bool | None = None
    witness: list | None = None
    prop: Prop = field(default_factory=Prop)


@pytest.mark.parametrize("checked, ending, says", [
    (Checked(True), Ending.HOLDS, "within 0.04 s, whatever the rest does"),
    (Checked(False, True), Ending.HOLDS, "under fairness"),
    (Checked(False, False), Ending.UNDECIDED, "a state from which it can never come"),
])
def test_each_liveness_ending_says_what_decided_it(checked, ending, says):
    final = ending_of(checked, None, replayed=True, symbolic=checked.fair is None)
    assert final.ending is ending and says in final.reason
