"""Tests for cellsim.logic.mtl (and trace, intervals) against a brute-force reference.

The reference works on grid cells: with every breakpoint of the trace and every
interval bound a multiple of ``D``, all satisfaction sets are unions of cells
``[start + k*D, start + (k+1)*D)``, so the continuous semantics reduces to a
discrete-time semantics on cell indices ``k = 0 .. N-1`` (truth at ``start + k*D``,
window ``k+a/D .. k+b/D``).  The end-of-trace rules become conditions on ``N``:

* ``F[a,b]`` with ``b`` finite: true if ``k + b/D >= N`` (window cut by the end);
* ``G[a,b]``: only cells ``< N`` are checked;
* ``p U[a,b] q``: a witness ``j`` in ``[k+a/D, min(k+b/D, N-1)]`` with ``q(j)`` and
  ``p`` on cells ``k .. j-1``, and also on cell ``k+a/D`` when ``a > 0`` (see the
  docs: ``p`` must hold throughout ``[t, t+a]``); if ``b`` is finite and
  ``k + b/D >= N``, also true when ``p`` holds on cells ``k .. N-1``;
* ``p W[a,b] q``: the above or ``p`` on cells ``k .. min(k + b/D, N-1)``.

The implementation is compared at every cell (at its left end and its middle) and
its boundaries must lie on the grid.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellsim.logic.intervals import IntervalSet
from cellsim.logic.mtl import Evaluation, TraceEvaluator, evaluate, satisfaction
from cellsim.logic.syntax import (
    Always,
    And,
    BoolDomain,
    BoolVar,
    Compare,
    Const,
    EnumDomain,
    Eventually,
    Implies,
    InSet,
    Not,
    NumberDomain,
    Or,
    Until,
    parse,
)
from cellsim.logic.trace import Signal, Trace

from logic_strategies import HAZARD, OPS, connectives, intervals

INF = math.inf
D = 0.25
MODES = ("a", "b", "c")
VOC = {
    "p": BoolDomain(),
    "q": BoolDomain(),
    "r": BoolDomain(),
    "m": EnumDomain(MODES),
    "m2": EnumDomain(MODES),
    "x": NumberDomain(),
}

# --------------------------------------------------------------------------- reference


def _cells(lo: float, hi: float) -> tuple[int, float]:
    a = round(lo / D)
    b = INF if math.isinf(hi) else round(hi / D)
    assert a * D == lo and (math.isinf(b) or b * D == hi), "bounds must be on the grid"
    return a, b


def ref(f, cells: dict[str, list], n: int) -> list[bool]:
    """Truth of ``f`` on each of the ``n`` cells (``cells[var][k]`` is None if undefined)."""
    if isinstance(f, Const):
        return [f.value] * n
    if isinstance(f, BoolVar):
        return [v is not None and bool(v) for v in cells[f.name]]
    if isinstance(f, Compare):
        op = OPS[f.op]
        if f.other is None:
            return [v is not None and op(v, f.value) for v in cells[f.var]]
        return [
            v is not None and w is not None and op(v, w)
            for v, w in zip(cells[f.var], cells[f.other])
        ]
    if isinstance(f, InSet):
        return [v is not None and v in f.values for v in cells[f.var]]
    if isinstance(f, Not):
        return [not x for x in ref(f.arg, cells, n)]
    if isinstance(f, And):
        parts = [ref(a, cells, n) for a in f.args]
        return [all(p[k] for p in parts) for k in range(n)]
    if isinstance(f, Or):
        parts = [ref(a, cells, n) for a in f.args]
        return [any(p[k] for p in parts) for k in range(n)]
    if isinstance(f, Implies):
        lhs, rhs = ref(f.lhs, cells, n), ref(f.rhs, cells, n)
        return [(not x) or y for x, y in zip(lhs, rhs)]
    a, b = _cells(f.lo, f.hi)
    last = lambda k: min(k + b, n - 1)  # noqa: E731 - last observed cell of the window
    if isinstance(f, Eventually):
        x = ref(f.arg, cells, n)
        return [
            (b != INF and k + b >= n) or any(x[j] for j in range(k + a, last(k) + 1))
            for k in range(n)
        ]
    if isinstance(f, Always):
        x = ref(f.arg, cells, n)
        return [all(x[j] for j in range(k + a, last(k) + 1)) for k in range(n)]
    assert isinstance(f, Until)
    x, y = ref(f.lhs, cells, n), ref(f.rhs, cells, n)
    out = []
    for k in range(n):
        holds = False
        for j in range(k + a, last(k) + 1):
            need_until = max(j, k + a + 1) if a > 0 else j
            if y[j] and all(x[i] for i in range(k, need_until)):
                holds = True
                break
        if not holds and f.weak:
            holds = all(x[i] for i in range(k, last(k) + 1))
        if not holds and not f.weak and b != INF and k + b >= n:
            holds = all(x[i] for i in range(k, n))
        out.append(holds)
    return out


# --------------------------------------------------------------------------- strategies

VALUES = {
    "p": st.booleans(),
    "q": st.booleans(),
    "r": st.booleans(),
    "m": st.sampled_from(MODES),
    "m2": st.sampled_from(MODES),
    "x": st.sampled_from([0.0, 1.0, 2.0]),
}


@st.composite
def grid_traces(draw):
    """A trace on the grid, with its per-cell valuation for the reference."""
    n = draw(st.integers(1, 16))
    start = draw(st.sampled_from([0.0, 2.5, -1.0]))
    signals, cells = {}, {}
    for var, values in VALUES.items():
        # sample indices, possibly before the start (clipped), late (undefined
        # prefix) or at/after the end (ignored)
        idx = sorted(draw(st.sets(st.integers(-2, n + 1), min_size=1, max_size=n + 2)))
        if draw(st.integers(0, 4)) > 0 and idx[0] > 0:
            idx = [0] + idx  # mostly defined from the start
        vals = [
            None if draw(st.integers(0, 30)) == 0 else draw(values) for _ in idx
        ]
        signals[var] = Signal(np.array([start + i * D for i in idx]), vals)
        row = []
        for k in range(n):
            before = [v for i, v in zip(idx, vals) if i <= k]
            row.append(before[-1] if before else None)
        cells[var] = row
    return Trace(signals, start, start + n * D), cells, n


def grid_intervals():
    return intervals(
        st.sampled_from([0, 0, 1, 2, 4]).map(lambda k: k * D),
        st.integers(0, 10).map(lambda k: k * D),
    )


atoms = st.one_of(
    st.sampled_from(["p", "q", "r"]).map(BoolVar),
    st.builds(Compare, st.sampled_from(["p", "q"]), st.just("=="), st.booleans()),
    st.builds(Compare, st.just("m"), st.sampled_from(["==", "!="]), st.sampled_from(MODES)),
    st.builds(Compare, st.just("m"), st.sampled_from(["==", "!="]), st.none(), st.just("m2")),
    st.builds(
        InSet, st.just("m2"), st.sets(st.sampled_from(MODES), min_size=1).map(frozenset)
    ),
    st.builds(
        Compare, st.just("x"), st.sampled_from(list(OPS)), st.sampled_from([0.0, 1.0, 2.0])
    ),
    st.builds(Const, st.booleans()),
)


formulas = st.recursive(
    atoms, lambda children: connectives(children, intervals=grid_intervals()), max_leaves=7
)


def assert_matches_reference(f, trace, cells, n):
    expected = ref(f, cells, n)
    sat = satisfaction(f, trace)
    assert (sat.start, sat.end) == (trace.start, trace.end)
    for bound in sat.flat:  # all boundaries on the grid
        k = (bound - trace.start) / D
        assert k == round(k), (bound, sat)
    for k in range(n):
        t = trace.start + k * D
        assert (t in sat) == expected[k], (k, sat, expected)
        assert (t + D / 2 in sat) == expected[k], (k, sat, expected)
    # verdicts
    verdict = evaluate(f, trace)
    assert verdict.holds == expected[0]
    if isinstance(f, Always):
        inner = ref(f.arg, cells, n)
        a, b = _cells(f.lo, f.hi)
        bad = [j for j in range(a, min(b, n - 1) + 1) if not inner[j]]
        assert verdict.violated_at == (trace.start + bad[0] * D if bad else None)
    else:
        assert verdict.violated_at == (None if expected[0] else trace.start)


@settings(max_examples=600, deadline=None)
@given(formulas, grid_traces())
def test_satisfaction_matches_reference(f, trace_cells):
    trace, cells, n = trace_cells
    assert_matches_reference(f, trace, cells, n)


@settings(max_examples=150, deadline=None)
@given(formulas, grid_traces())
def test_top_level_always_verdicts(f, trace_cells):
    trace, cells, n = trace_cells
    for lo, hi in [(0.0, INF), (0.5, 1.0), (0.0, 0.0)]:
        assert_matches_reference(Always(f, lo, hi), trace, cells, n)


@settings(max_examples=60, deadline=None)
@given(st.lists(formulas, min_size=2, max_size=5), grid_traces())
def test_shared_evaluator_gives_the_same_results(fs, trace_cells):
    trace, _, _ = trace_cells
    shared = TraceEvaluator(trace)
    for f in fs:
        assert shared.satisfaction(f) == satisfaction(f, trace)
        assert shared.evaluate(f) == evaluate(f, trace)


@settings(max_examples=100, deadline=None)
@given(formulas, formulas, grid_intervals(), grid_traces())
def test_documented_identities(f, g, interval, trace_cells):
    trace = trace_cells[0]
    lo, hi = interval
    sat = lambda x: satisfaction(x, trace)  # noqa: E731
    assert sat(Eventually(f, lo, hi)) == sat(Until(Const(True), f, lo, hi))
    assert sat(Always(f, lo)) == sat(Not(Eventually(Not(f), lo)))
    assert sat(Until(f, g, lo, hi, weak=True)) == sat(Or((Until(f, g, lo, hi), Always(f, 0, hi))))


# --------------------------------------------------------------------------- hand-written cases

CELL_VOC = {"HS": HAZARD, "HC": HAZARD, "e": BoolDomain(), "otab": BoolDomain(),
            "oloc": EnumDomain(("none", "table", "door"))}  # fmt: skip


def sig(*pairs) -> Signal:
    return Signal(np.array([t for t, _ in pairs], dtype=float), [v for _, v in pairs])


def cell(text: str):
    return parse(text, CELL_VOC, {"HS_e": "e"})


DETECTED = "G((HS_e and HS == inact) -> (HS_e U[0, 0.5s] HS == act))"


@pytest.mark.parametrize(
    "t_act, verdict",
    [
        (1.25, Evaluation(True, None)),
        (1.5, Evaluation(True, None)),  # exactly at the deadline: in time
        (1.5 + 1e-9, Evaluation(False, 1.0)),  # just after: violated when HS_e began
        (2.0, Evaluation(False, 1.0)),
    ],
)
def test_until_deadline_at_half_a_second(t_act, verdict):
    trace = Trace(
        {"e": sig((0, False), (1.0, True), (5.0, False)),
         "HS": sig((0, "inact"), (t_act, "act"), (3.0, "mit"), (5.0, "inact"))},  # fmt: skip
        0.0,
        10.0,
    )
    assert evaluate(cell(DETECTED), trace) == verdict


def test_until_witness_when_the_situation_ends_at_detection():
    # HS_e stops at the very instant HS becomes act: detected (phi on [t, t') only)
    trace = Trace(
        {"e": sig((0, False), (1.0, True), (1.3, False)),
         "HS": sig((0, "inact"), (1.3, "act"))},  # fmt: skip
        0.0,
        10.0,
    )
    assert evaluate(cell(DETECTED), trace) == Evaluation(True, None)
    assert evaluate(cell("not HS == act U HS == act"), trace).holds


def test_until_with_positive_lower_bound_needs_phi_up_to_t_plus_a():
    # p on [0, 2), q on [2, 3): p U[1, 2] q holds on [0, 1) - not at t = 1, where
    # p would only hold on [1, 2) and the sole witness t' = 2 = t + a.
    voc = {"p": BoolDomain(), "q": BoolDomain()}
    q = sig((0, False), (2, True), (3, False))
    trace = Trace({"p": sig((0, True), (2, False)), "q": q}, 0, 10)
    assert satisfaction(parse("p U[1, 2] q", voc), trace) == IntervalSet(0, 10, [(0, 1)])
    assert satisfaction(parse("p U[0, 2] q", voc), trace) == IntervalSet(0, 10, [(0, 3)])
    # overlapping p [0, 2.5) and q [2, 3): t = 1.5 is excluded for the same reason
    trace = Trace({"p": sig((0, True), (2.5, False)), "q": q}, 0, 10)
    assert satisfaction(parse("p U[1, 2] q", voc), trace) == IntervalSet(0, 10, [(0, 1.5)])


def test_unbounded_eventualities_are_strong_at_the_end():
    trace = Trace(
        {"HC": sig((0, "inact"), (2, "act"), (3, "mit"), (4, "inact"), (9, "act")),
         "otab": sig((0, True)), "oloc": sig((0, "table"), (7, "none"))},  # fmt: skip
        0.0,
        10.0,
    )
    # the hazard activated at 9 s is never mitigated before the run ends
    assert evaluate(cell("G(HC == act -> F HC == mit)"), trace) == Evaluation(False, 9.0)
    assert evaluate(cell("G(HC == act -> F[0, 2] HC == mit)"), trace) == Evaluation(True, None)
    assert evaluate(cell("F(not otab)"), trace) == Evaluation(False, 0.0)
    assert evaluate(cell("F(oloc == none)"), trace) == Evaluation(True, None)
    assert evaluate(cell("G(not HC == mis)"), trace) == Evaluation(True, None)
    assert evaluate(cell("HC == inact U HC == mis"), trace) == Evaluation(False, 0.0)
    assert evaluate(cell("HC == inact W HC == mis"), trace) == Evaluation(False, 0.0)


def test_bounded_operators_are_not_violated_by_the_end_of_the_trace():
    voc = {"p": BoolDomain(), "q": BoolDomain()}
    trace = Trace({"p": sig((0, True), (9.5, False)), "q": sig((0, False))}, 0.0, 10.0)
    f = lambda text: satisfaction(parse(text, voc), trace)  # noqa: E731
    assert f("F[0, 2] q") == IntervalSet(0, 10, [(8, 10)])  # window reaches 10
    assert f("F[1, 1] q") == IntervalSet(0, 10, [(9, 10)])
    assert f("F[0, 0] q").is_empty()
    assert f("F q").is_empty()
    assert f("G[0, 2] p") == IntervalSet(0, 10, [(0, 7.5)])
    assert f("G[0, 2] not p") == IntervalSet(0, 10, [(9.5, 10)])
    # p fails at 9.5 inside the observed part: until is decided false before 9.5
    assert f("p U[0, 2] q") == IntervalSet(0, 10, [])
    trace2 = Trace({"p": sig((0, True)), "q": sig((0, False))}, 0.0, 10.0)
    assert satisfaction(parse("p U[0, 2] q", voc), trace2) == IntervalSet(0, 10, [(8, 10)])
    assert satisfaction(parse("p U q", voc), trace2).is_empty()
    assert satisfaction(parse("p W q", voc), trace2).is_full()


def test_signal_starting_late_is_undefined_before():
    trace = Trace(
        {"HS": sig((2.0, "inact"), (4.0, "mis")), "e": sig((0, True))}, 0.0, 10.0
    )
    assert satisfaction(cell("HS == inact"), trace) == IntervalSet(0, 10, [(2, 4)])
    assert satisfaction(cell("HS != inact"), trace) == IntervalSet(0, 10, [(4, 10)])
    assert satisfaction(cell("not HS == inact"), trace) == IntervalSet(0, 10, [(0, 2), (4, 10)])
    assert evaluate(cell("G(HS == inact or HS != inact)"), trace) == Evaluation(False, 0.0)
    assert evaluate(cell("G(not HS == mis)"), trace) == Evaluation(False, 4.0)
    assert trace.value_at("HS", 1.0) is None
    assert trace.value_at("HS", 2.0) == "inact"


def test_samples_outside_the_domain():
    trace = Trace({"e": sig((-5, False), (1, True), (3, False), (12, True))}, 0.5, 10.0)
    assert satisfaction(cell("e"), trace) == IntervalSet(0.5, 10, [(1, 3)])
    assert satisfaction(cell("F e"), trace) == IntervalSet(0.5, 10, [(0.5, 3)])


def test_none_values_are_undefined():
    voc = {"x": NumberDomain(), "y": NumberDomain()}
    trace = Trace({"x": sig((0, 1.0), (1, None), (2, 3.0)), "y": sig((0, 2.0))}, 0, 4)
    assert satisfaction(parse("x < 5", voc), trace) == IntervalSet(0, 4, [(0, 1), (2, 4)])
    assert satisfaction(parse("x != y", voc), trace) == IntervalSet(0, 4, [(0, 1), (2, 4)])
    assert satisfaction(parse("x > y", voc), trace) == IntervalSet(0, 4, [(2, 4)])


def test_missing_signal():
    trace = Trace({"e": sig((0, True))}, 0, 1)
    with pytest.raises(KeyError, match="trace has no signal for variable 'HS'"):
        evaluate(cell("G(not HS == mis)"), trace)


def test_violated_at_for_windowed_always():
    voc = {"p": BoolDomain()}
    trace = Trace({"p": sig((0, True), (0.5, False), (0.7, True), (3, False))}, 0, 10)
    assert evaluate(parse("G p", voc), trace) == Evaluation(False, 0.5)
    assert evaluate(parse("G[1, 2] p", voc), trace) == Evaluation(True, None)
    assert evaluate(parse("G[1, 3] p", voc), trace) == Evaluation(False, 3.0)
    assert evaluate(parse("G[0.6, 5] p", voc), trace) == Evaluation(False, 0.6)
    assert evaluate(parse("not G p", voc), trace) == Evaluation(True, None)
    assert evaluate(parse("F(not p)", voc), trace) == Evaluation(True, None)


# --------------------------------------------------------------------------- data classes


def test_signal_validation_and_helpers():
    with pytest.raises(ValueError, match="strictly increasing"):
        Signal(np.array([0.0, 0.0]), [1, 2])
    with pytest.raises(ValueError, match="2 times but 1 values"):
        Signal(np.array([0.0, 1.0]), [1])
    with pytest.raises(ValueError, match="bad trace domain"):
        Trace({}, 1.0, 1.0)
    s = Signal.from_samples([0.0, 0.02, 0.04, 0.06, 0.08], ["a", "a", "b", "b", "a"])
    assert s.times.tolist() == [0.0, 0.04, 0.08] and s.values == ["a", "b", "a"]
    assert s.value_at(-1) is None and s.value_at(0.05) == "b" and s.value_at(100) == "a"


def test_interval_set_algebra():
    a = IntervalSet(0, 10, [(1, 2), (2, 3), (5, 6), (-4, 0.5), (9, 12)])
    assert a.intervals == [(0, 0.5), (1, 3), (5, 6), (9, 10)]
    b = IntervalSet(0, 10, [(2, 5.5)])
    assert a | b == IntervalSet(0, 10, [(0, 0.5), (1, 6), (9, 10)])
    assert a & b == IntervalSet(0, 10, [(2, 3), (5, 5.5)])
    assert ~a == IntervalSet(0, 10, [(0.5, 1), (3, 5), (6, 9)])
    assert a - b == IntervalSet(0, 10, [(0, 0.5), (1, 2), (5.5, 6), (9, 10)])
    assert 1 in a and 3 not in a and 0 in a and 10 not in a and -1 not in a
    assert a.first() == 0 and IntervalSet.empty(0, 10).first() is None
    assert IntervalSet.full(0, 10).is_full() and len(a) == 4
    assert a.measure() == pytest.approx(4.5)
    assert b.eventually(1, 2) == IntervalSet(0, 10, [(0, 4.5)])
    assert b.always(0, 1) == IntervalSet(0, 10, [(2, 4.5)])
    assert b.always(0, 1) == ~((~b).eventually(0, 1))
    assert hash(a) == hash(IntervalSet(0, 10, a.intervals))
    with pytest.raises(ValueError, match="domains differ"):
        a | IntervalSet(0, 11)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.tuples(st.integers(-2, 22), st.integers(0, 6))),
    st.lists(st.tuples(st.integers(-2, 22), st.integers(0, 6))),
)
def test_interval_set_boolean_ops_match_cell_sets(xs, ys):
    def make(pairs):
        return IntervalSet(0, 20, [(s * D, (s + w) * D) for s, w in pairs])

    def cells_of(pairs):
        return {k for s, w in pairs for k in range(s, s + w) if 0 <= k < 80}

    a, b = make(xs), make(ys)
    ca, cb = cells_of(xs), cells_of(ys)
    everything = set(range(80))
    for got, want in [(a | b, ca | cb), (a & b, ca & cb), (~a, everything - ca), (a - b, ca - cb)]:
        assert {k for k in range(80) if k * D in got} == want
        assert all(a_ < b_ for a_, b_ in got) and all(
            x[1] < y[0] for x, y in zip(got.intervals, got.intervals[1:])
        )  # canonical: non-empty, sorted, non-adjacent


# --------------------------------------------------------------------------- exact bounds


@pytest.mark.parametrize(
    "t_hazard, t_act, holds",
    [
        # 8.3 - 0.5 > 7.8 in binary floating point: on the tick grid the deadline is exact
        (7.8, 8.3, True),
        (0.1, 0.6, True),
        (2.7, 3.2, True),
        (7.8, 8.300000001, False),  # one tick (1 ns) late
    ],
)
def test_deadline_exactly_half_a_second_after_the_hazard(t_hazard, t_act, holds):
    trace = Trace(
        {"e": sig((0, False), (t_hazard, True), (20.0, False)),
         "HS": sig((0, "inact"), (t_act, "act"))},  # fmt: skip
        0.0,
        30.0,
    )
    verdict = evaluate(cell(DETECTED), trace)
    assert verdict == (Evaluation(True, None) if holds else Evaluation(False, t_hazard))


@pytest.mark.parametrize("stint, exercised", [(1.0, False), (1.000000001, True), (0.7, False), (1.3, True)])
def test_a_stint_of_exactly_one_second_is_not_more_than_a_second(stint, exercised):
    # the welding cell's MU: "for more than a second" (G[0, 1s] and recorded 1 s on)
    mu = cell("F(G[0, 1s] e and not G[1s, 1s] not e)")
    trace = Trace({"e": sig((0, False), (12.1, True), (12.1 + stint, False))}, 0.0, 30.0)
    # G[0,1s] e at t needs e on [t, t+1]; e holds on [12.1, 12.1 + stint): a stint of
    # exactly 1 s misses the closed window's right end
    assert evaluate(mu, trace).holds is exercised


# --------------------------------------------------------------------------- conclusive verdicts


def _readings(f, trace):
    from cellsim.logic.mtl import DEFAULT, OPTIMISTIC, PESSIMISTIC

    ev = TraceEvaluator(trace)
    return {m: ev._sat(f, m) for m in (DEFAULT, OPTIMISTIC, PESSIMISTIC)}, ev


def _within(inner, outer, start, end):
    a = IntervalSet.from_flat(start, end, list(inner))
    b = IntervalSet.from_flat(start, end, list(outer))
    return (a - b).is_empty()


@settings(max_examples=300, deadline=None)
@given(formulas, grid_traces())
def test_pessimistic_within_default_within_optimistic(f, trace_cells):
    from cellsim.logic.mtl import DEFAULT, OPTIMISTIC, PESSIMISTIC

    trace = trace_cells[0]
    sets, ev = _readings(f, trace)
    assert _within(sets[PESSIMISTIC], sets[DEFAULT], ev.start, ev.end)
    assert _within(sets[DEFAULT], sets[OPTIMISTIC], ev.start, ev.end)


@settings(max_examples=300, deadline=None)
@given(formulas, grid_traces(), st.integers(1, 15))
def test_a_conclusive_verdict_survives_any_continuation(f, trace_cells, cut_cells):
    """Cut the trace short: where the cut trace's verdict is conclusive, the whole
    trace (one of its continuations) gives the same verdict, however it goes on."""
    from cellsim.logic.mtl import OPTIMISTIC, PESSIMISTIC

    trace, _, n = trace_cells
    if cut_cells >= n:
        return
    cut = Trace(trace.signals, trace.start, trace.start + cut_cells * D)
    short = TraceEvaluator(cut)
    if not short.conclusive(f):
        return
    verdict = short._holds_at_start(f, PESSIMISTIC)
    whole = TraceEvaluator(trace)
    # the whole trace's own readings bracket its truth on every further continuation
    assert whole._holds_at_start(f, PESSIMISTIC) == verdict
    assert whole._holds_at_start(f, OPTIMISTIC) == verdict


def test_a_safety_condition_that_held_so_far_is_inconclusive_and_a_seen_violation_is_not():
    trace = Trace({"HS": sig((0, "inact"), (3.0, "mis"))}, 0.0, 10.0)
    ev = TraceEvaluator(trace)
    assert not ev.evaluate(cell("G(not HS == mis)")).holds
    assert ev.conclusive(cell("G(not HS == mis)"))  # the mishap was recorded
    quiet = TraceEvaluator(Trace({"HS": sig((0, "inact"))}, 0.0, 10.0))
    assert quiet.evaluate(cell("G(not HS == mis)")).holds
    assert not quiet.conclusive(cell("G(not HS == mis)"))  # held so far: could still fail
    # a hazard still open at the cut: violated by the strong F, but the run might have mitigated it
    open_ = TraceEvaluator(Trace({"HS": sig((0, "inact"), (9.0, "act"))}, 0.0, 10.0))
    f = cell("G(HS == act -> F HS == mit)")
    assert not open_.evaluate(f).holds
    assert not open_.conclusive(f)
