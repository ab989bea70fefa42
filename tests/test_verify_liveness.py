"""Liveness conditions G(a -> F b) in ``cellsim verify`` (issue 36): their response within a window holds for every
behaviour; a slower one is judged under fairness by a search Storm makes of the model, checked here on models small
enough to follow by hand, and each ending says which."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from cellsim.verify.endings import Ending, ending_of
from cellsim.verify.storm import always_answerable, build, build_symbolic, owed_at_the_end

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


# A person (p) and a request (x as above). The person may stand at 0 or 1, where its script leaves it ("end"); while
# it stands at 1 the response cannot come (the cell waits on it to leave), at 0 it can. Fairness alone says the
# response can always still come (the person can always leave 1).
OWED = """mdp
module m
  x : [0..2] init 0;
  p : [0..1] init 0;
  [] x=0 -> (x'=1);
  [] x=1 & p=0 -> (x'=2);
  [] x=1 -> (x'=1);
  [] x=2 -> (x'=0);
  [] true -> (p'=1-p);
endmodule
label "a" = x=0;
label "b" = x=2;
label "end_at_0" = p=0;
label "end_at_1" = p=1;
"""


@ENGINES
def test_a_response_a_run_may_end_owing_is_found_where_the_script_leaves_the_person(tmp_path, engine):
    """Where the script leaves the person at 1, a run can end with the request owed for good: the twin's strong F
    fails it, whatever fairness says. Left at 0, the response comes while it stands there."""
    program, model = _model(tmp_path, OWED, engine)
    assert always_answerable(program, model, "a", "b")
    assert owed_at_the_end(program, model, "a", "b", ["end_at_1"])
    assert not owed_at_the_end(program, model, "a", "b", ["end_at_0"])
    # a person whose script may not be over stands at one of its places, either, and stays: at 1 it is owed
    assert owed_at_the_end(program, model, "a", "b", ["end_at_0", "end_at_1"])
    assert owed_at_the_end(program, model, "a", "b", [])  # too many ways to ask: taken to be owed


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
    owed_at_end: bool = False


@pytest.mark.parametrize("checked, ending, says", [
    (Checked(True), Ending.HOLDS, "within 0.04 s, whatever the rest does"),
    (Checked(False, True), Ending.HOLDS, "under fairness"),
    (Checked(False, False), Ending.UNDECIDED, "a state from which it can never come"),
    (Checked(False, False, owed_at_end=True), Ending.UNDECIDED, "a run may end owing it"),
])
def test_each_liveness_ending_says_what_decided_it(checked, ending, says):
    final = ending_of(checked, None, replayed=True, symbolic=checked.fair is None)
    assert final.ending is ending and says in final.reason


# The welding cell with the person's last stop outside the south fence, where the range detector still reads them
# near: the hazard it raises stays mitigated until the run ends (a helper's audit found verify saying HOLDS, under
# fairness, for a condition this scenario's own run violates).
STANDOFF = """\
base: {base}
name: welding_cell_standoff
entities:
  operator:
    waypoints:
      cell: {{position: [0.6, -0.7], wait: 4.0}}
      exit: {{position: [1.0, -2.0], wait: 2.0}}
"""


def test_a_response_owed_where_the_script_leaves_the_person_is_undecided_and_the_twin_violates_it(tmp_path):
    import json
    import subprocess
    import sys

    from conftest import ROOT, WELDING_CELL

    scenario = tmp_path / "standoff.yaml"
    scenario.write_text(STANDOFF.format(base=WELDING_CELL))
    proc = subprocess.run([sys.executable, "-m", "cellsim", "verify", str(scenario), "--no-replay", "--json",
                           "--only", "*:handled"], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert proc.returncode == 3, proc.stderr
    endings = {e["name"]: e for e in json.loads(proc.stdout)["properties"]}
    assert endings["HS:handled"]["ending"] == "undecided" and "a run may end owing it" in endings["HS:handled"]["reason"]
    assert endings["HRW:handled"]["ending"] == "holds"  # (the robot's hazard is released where they stand)
    assert any("as if the run went on" in a for a in json.loads(proc.stdout)["assumptions"])
    run = tmp_path / "run"
    simulated = subprocess.run([sys.executable, "-m", "cellsim", "simulate", str(scenario), "--out", str(run)],
                               capture_output=True, timeout=600, cwd=ROOT)
    assert simulated.returncode in (0, 1) and (run / "blackbox.sqlite").exists()  # (1: a safety finding)
    checked = subprocess.run([sys.executable, "-m", "cellsim", "check", str(run), "--json"], capture_output=True,
                             text=True, timeout=600, cwd=ROOT)
    assert json.loads(checked.stdout)["verdicts"]["HS:handled"]["status"] == "violated"
    # its last stop held past the run's end: where it stands when the run ends is not known, so it may be any of its
    # places, and stay there (a review found the end left out then, and HOLDS again)
    scenario.write_text(STANDOFF.format(base=WELDING_CELL).replace("wait: 2.0", "wait: 60.0"))
    proc = subprocess.run([sys.executable, "-m", "cellsim", "verify", str(scenario), "--no-replay", "--json",
                           "--only", "*:handled"], capture_output=True, text=True, timeout=600, cwd=ROOT)
    endings = {e["name"]: e for e in json.loads(proc.stdout)["properties"]}
    assert endings["HS:handled"]["ending"] == "undecided" and "a run may end owing it" in endings["HS:handled"]["reason"]
