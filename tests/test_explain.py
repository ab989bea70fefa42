"""Each violated condition is explained in one sentence, read off the record at its first violation."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from cellsim.logic.mtl import TraceEvaluator
from cellsim.logic.syntax import BoolDomain, EnumDomain, parse
from cellsim.logic.trace import Signal, Trace
from cellsim.validation.explain import Explainer

from conftest import ROOT

PHASES = EnumDomain(("inact", "act", "mit"))
VOCABULARY = {"HZ": PHASES, "curtain": BoolDomain(), "mode": EnumDomain(("normal", "stopped"))}
MACROS = {"exposed": "curtain and mode == normal"}


def _violation(text: str, signals: dict, end: float = 10.0):
    """The explainer of a violated formula on a trace, the formula and its first violation."""
    trace = Trace({n: Signal(np.array([t for t, _ in s], float), [v for _, v in s]) for n, s in signals.items()}, 0.0, end)
    evaluator = TraceEvaluator(trace)
    macros = {name: parse(body, VOCABULARY) for name, body in MACROS.items()}
    formula = parse(text, VOCABULARY, MACROS)
    verdict = evaluator.evaluate(formula)
    assert not verdict.holds
    return Explainer(evaluator, macros), formula, verdict.violated_at


def _explain(text: str, signals: dict, end: float = 10.0) -> str:
    explainer, formula, at = _violation(text, signals, end)
    return explainer.explain(formula, at)


def test_a_missed_detection_names_the_macro_its_atoms_and_the_deadline():
    why = _explain("G((exposed and HZ == inact) -> (exposed U[0, 0.5s] HZ == act))",
                   {"curtain": [(0, False), (2.0, True)], "mode": [(0, "normal")], "HZ": [(0, "inact")]})
    assert why == ("exposed true from 2.00 s (curtain, mode = normal); HZ = inact; "
                   "HZ stayed inact; HZ == act required by 2.50 s")


def test_an_obligation_cut_short_by_its_condition_ending_says_when():
    why = _explain("G((exposed and HZ == inact) -> (exposed U[0, 0.5s] HZ == act))",
                   {"curtain": [(0, False), (2.0, True), (2.2, False)], "mode": [(0, "normal")],
                    "HZ": [(0, "inact"), (2.3, "act")]})
    assert why.endswith("exposed ended at 2.20 s, before HZ == act")


def test_an_unmet_eventuality_and_a_forbidden_state_say_what_the_record_shows():
    assert _explain("G(HZ == act -> F HZ == mit)", {"HZ": [(0, "inact"), (4.0, "act")]}) == (
        "HZ = act; HZ stayed act; HZ == mit never held from 4.00 s to the end of the run")
    assert _explain("G(not HZ == mit)", {"HZ": [(0, "inact"), (3.0, "mit")]}) == "HZ = mit"
    assert _explain("F G(not curtain)", {"curtain": [(0, False), (9.0, True)]}) == (
        "curtain went false -> true; G(not curtain) never held from 0.00 s to the end of the run")


def test_check_explains_the_misuse_runs_violation_in_the_table_and_the_json(tmp_path):
    from test_dashboard import VIOLATING

    run = tmp_path / "misuse"
    subprocess.run([sys.executable, "-m", "cellsim", "simulate", str(ROOT / "scenarios" / "two_operators.yaml"),
                    "--out", str(run), "--quiet", *VIOLATING], capture_output=True, timeout=300, cwd=ROOT)
    expected = ("HRW_e true from 12.68 s (permissive, working, rloc = sharedTbl, lgtBar); HRW = inact; "
                "HRW stayed inact; HRW == act required by 13.18 s")
    proc = subprocess.run([sys.executable, "-m", "cellsim", "check", str(run), "--json"], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)
    verdict = json.loads(proc.stdout)["verdicts"]["HRW:detected"]
    assert proc.returncode == 1 and verdict["explanation"] == expected
    # its evidence: the window, and every macro and atom, down to the phase that never came
    assert verdict["evidence"]["window"] == [12.68, 13.18]
    assert list(verdict["evidence"]["rows"]) == [
        "HRW_e", "permissive", "working",  # permissive is one atom: it is drawn once, by its name
        "ract in {exchWrkp, unknown, welding}", "wact == welding", "rloc in {sharedTbl, unknown}", "lgtBar",
        "HRW == inact", "HRW == act"]
    assert not any(lo <= 12.68 < hi for lo, hi in verdict["evidence"]["rows"]["HRW == act"])
    proc = subprocess.run([sys.executable, "-m", "cellsim", "check", str(run)], capture_output=True, text=True, timeout=120,
                          cwd=ROOT, env={**__import__("os").environ, "COLUMNS": "400"})
    assert f"HRW:detected violated at 12.68 s: {expected}" in proc.stdout


def _evidence(text: str, signals: dict, end: float = 10.0) -> dict:
    explainer, formula, at = _violation(text, signals, end)
    return explainer.evidence(formula, at)


def test_evidence_gives_the_required_window_and_where_each_macro_and_atom_held():
    evidence = _evidence("G((exposed and HZ == inact) -> (exposed U[0, 0.5s] HZ == act))",
                         {"curtain": [(0, False), (2.0, True), (6.0, False)], "mode": [(0, "normal")],
                          "HZ": [(0, "inact"), (7.0, "act")]})
    assert evidence["at"] == 2.0 and evidence["window"] == [2.0, 2.5]
    # the macro by its name, then its own atoms, then the condition's atoms, in the order written
    assert list(evidence["rows"]) == ["exposed", "curtain", "mode == normal", "HZ == inact", "HZ == act"]
    assert evidence["rows"]["exposed"] == [[2.0, 6.0]]
    assert evidence["rows"]["HZ == act"] == [[7.0, 10.0]]


def test_evidence_window_of_an_eventuality_runs_to_the_end_and_of_a_forbidden_state_is_an_instant():
    assert _evidence("G(HZ == act -> F HZ == mit)", {"HZ": [(0, "inact"), (4.0, "act")]})["window"] == [4.0, 10.0]
    assert _evidence("G(not HZ == mit)", {"HZ": [(0, "inact"), (3.0, "mit")]})["window"] == [3.0, 3.0]

