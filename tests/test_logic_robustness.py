"""The condition language's quantitative reading (cellsim/logic/robustness.py): hand-computed margins,
and over random formulas and traces, that its sign agrees with the verdict and that it is the distance
at which the verdict changes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from logic_strategies import connectives
from test_logic_mtl import formulas, grid_intervals, grid_traces

from cellsim.logic.mtl import evaluate
from cellsim.logic.robustness import robustness, shifted
from cellsim.logic.syntax import BoolDomain, BoolVar, Compare, EnumDomain, NumberDomain, parse
from cellsim.logic.trace import TICKS_PER_SECOND, Signal, Trace


def _trace(end=10.0, **signals) -> Trace:
    return Trace({name: Signal(np.array([t for t, _ in pairs], dtype=float), [v for _, v in pairs])
                  for name, pairs in signals.items()}, 0.0, end)


def test_a_speed_limit_held_by_5_cm_per_second_and_broken_by_10():
    limit = parse("G(speed <= 0.5)", {"speed": NumberDomain()})
    below = _trace(speed=[(0, 0.2), (2, 0.45), (4, 0.3)])
    assert robustness(limit, below).space == pytest.approx(0.05)
    above = _trace(speed=[(0, 0.2), (2, 0.6), (4, 0.3)])
    assert robustness(limit, above).space == pytest.approx(-0.1)
    assert robustness(limit, below).time == math.inf  # no deadline to move


@pytest.mark.parametrize("formula, values, expected", [
    # the audit's: where the verdict changes just past the largest distance (or the only value sits on the
    # threshold), the search saw no change and said +-inf, the farthest score a search can get
    ("G(speed <= 0.5)", [0.45], 0.05),  # (docs/condition-language.md 5.8's own example)
    ("G(speed <= 0.5)", [0.5], 0.0),
    ("F(speed >= 0.1)", [0.0, 0.5], 0.4),
    ("G(speed < 0.25)", [0.0, 0.6], -0.35),
    ("G(speed <= 0.25)", [0.0, 0.6], -0.35),
])
def test_the_margin_is_found_where_the_verdict_changes_just_past_the_largest_distance(formula, values, expected):
    f = parse(formula, {"speed": NumberDomain()})
    trace = _trace(end=5.0, speed=[(float(k), v) for k, v in enumerate(values)])
    assert robustness(f, trace).space == pytest.approx(expected, abs=1e-9)


def test_a_detection_with_0_3_s_to_spare_and_one_0_2_s_late():
    detected = parse("G(e -> (e U[0, 0.5s] h == act))", {"e": BoolDomain(), "h": EnumDomain(("inact", "act"))})
    on_time = _trace(e=[(0, False), (1.0, True), (1.6, False)], h=[(0, "inact"), (1.2, "act"), (1.7, "inact")])
    margin = robustness(detected, on_time)
    assert margin.time == pytest.approx(0.3, abs=1e-9) and margin.space == math.inf
    late = _trace(e=[(0, False), (1.0, True), (2.0, False)], h=[(0, "inact"), (1.7, "act")])
    assert not evaluate(detected, late).holds
    margin = robustness(detected, late)
    assert margin.time == pytest.approx(-0.2, abs=1e-9) and margin.space == -math.inf


def test_a_negated_threshold_moves_the_other_way():
    # "never slower than 0.1 while moving" written with a negation: its margin is still the distance
    slow = parse("G(not (speed < 0.1))", {"speed": NumberDomain()})
    assert robustness(slow, _trace(speed=[(0, 0.25), (3, 0.15)])).space == pytest.approx(0.05)


def _holds(f, trace, space=0.0, time=0.0) -> bool:
    return evaluate(shifted(f, space, time), trace).holds


# formulas over the numeric variable mostly, so that the space margin is finite often
NUMERIC = st.recursive(
    st.one_of(st.builds(Compare, st.just("x"), st.sampled_from(["<", "<=", ">", ">="]),
                        st.sampled_from([0.0, 0.5, 1.0, 1.5, 2.0])),
              st.sampled_from(["p", "q"]).map(BoolVar)),
    lambda children: connectives(children, intervals=grid_intervals()), max_leaves=5,
)
ANY = st.one_of(formulas, NUMERIC)
MOVES = st.sampled_from([-2.5, -1.5, -1.0, -0.5, 0.0, 0.5, 1.0, 1.5, 2.5])


@settings(max_examples=400, deadline=None)
@given(ANY, grid_traces(), MOVES, MOVES)
def test_moving_thresholds_and_deadlines_against_a_condition_never_makes_it_hold_more(f, trace_cells, a, b):
    """The shift is monotone (the searches rely on it): what holds when made harder held when easier."""
    trace, _, _ = trace_cells
    low, high = sorted((a, b))
    if _holds(f, trace, space=high):
        assert _holds(f, trace, space=low)
    if _holds(f, trace, time=high):
        assert _holds(f, trace, time=low)


@settings(max_examples=400, deadline=None)
@given(ANY, grid_traces())
def test_the_sign_agrees_with_the_verdict_and_the_margin_is_where_it_changes(f, trace_cells):
    trace, _, _ = trace_cells
    verdict = evaluate(f, trace).holds
    margin = robustness(f, trace)
    for value in (margin.space, margin.time):
        if value > 0:
            assert verdict
        if value < 0:
            assert not verdict
    tick = 1 / TICKS_PER_SECOND
    if math.isfinite(margin.space) and margin.space != 0:
        r = abs(margin.space)  # the grid's values are a whole unit apart: 1e-6 either side is clear
        sign = 1 if verdict else -1
        assert _holds(f, trace, space=sign * (r - 1e-6)) == verdict
        assert _holds(f, trace, space=sign * (r + 1e-6)) != verdict
    if math.isfinite(margin.time):
        r = abs(margin.time)
        if verdict:  # still holds with deadlines r shorter, not one tick more
            assert _holds(f, trace, time=r) and not _holds(f, trace, time=r + tick)
        else:  # holds with deadlines r longer, not one tick less
            assert _holds(f, trace, time=-r) and not _holds(f, trace, time=-(r - tick))


def test_check_gives_each_conditions_margins_on_a_run(tmp_path):
    """On the misuse run that misses HRW: a negative time margin where the verdict is violated, margins of
    the verdict's sign everywhere, as JSON and in the table."""
    import json
    import subprocess
    import sys

    from conftest import ROOT
    from test_dashboard import VIOLATING

    run = tmp_path / "misuse"
    subprocess.run([sys.executable, "-m", "cellsim", "simulate", str(ROOT / "scenarios" / "two_operators.yaml"),
                    "--out", str(run), "--quiet", *VIOLATING], capture_output=True, timeout=300, cwd=ROOT, check=False)
    done = subprocess.run([sys.executable, "-m", "cellsim", "check", str(run), "--robustness", "--json"],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 1, done.stderr
    result = json.loads(done.stdout)
    margins = result["robustness"]
    assert set(margins) == set(result["verdicts"])
    missed = margins["HRW:detected"]
    assert isinstance(missed["time"], float) and missed["time"] < 0 and missed["space"] == "-inf"
    for name, verdict in result["verdicts"].items():
        for value in margins[name].values():
            number = float(value)
            assert (number >= 0) if verdict["holds"] else (number <= 0), (name, verdict, margins[name])
    table = subprocess.run([sys.executable, "-m", "cellsim", "check", str(run), "--robustness"], capture_output=True,
                           text=True, timeout=120, cwd=ROOT, env={**__import__("os").environ, "COLUMNS": "250"})
    assert f"{missed['time']:.3g} s" in table.stdout and "margin: space" in table.stdout
