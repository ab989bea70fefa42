"""Tests for cellsim.validation.coverage (situation coverage of recorded runs).

Hand-made traces check the exact covered and missing situations; a property test
compares :meth:`CoverageModel.observe` with a brute-force reference that classifies
the midpoint of every elementary interval between consecutive change points.
"""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellsim.logic.mtl import TraceEvaluator
from cellsim.logic.syntax import BoolDomain, EnumDomain, NumberDomain
from cellsim.logic.trace import Signal, Trace
from cellsim.config.validation import CoverageCriterion, NumberBins
from cellsim.validation.coverage import CoverageModel, situation_name

WACT = ("idle", "welding", "exchWrkp")
OLOC = ("none", "inCell", "atTable")
VOC = {
    "wact": EnumDomain(WACT),
    "oloc": EnumDomain(OLOC),
    "lgtBar": BoolDomain(),
    "speed": NumberDomain("m/s"),
}
EDGES = [0.5, 1.0, 2.0]
BINS = {"speed": NumberBins(EDGES)}
MACROS = {"busy": "wact in {welding, exchWrkp}"}


def model(**criteria: CoverageCriterion) -> CoverageModel:
    return CoverageModel.compile(criteria, VOC, MACROS, BINS)


def trace(end: float = 10.0, start: float = 0.0, **signals: tuple[list, list]) -> Trace:
    return Trace({k: Signal(np.asarray(t, float), v) for k, (t, v) in signals.items()}, start, end)


def covered(m: CoverageModel, tr: Trace) -> list[list[str]]:
    return m.observe(tr, set())["c"]


# --------------------------------------------------------------------------- single variables


def test_single_enum_variable():
    m = model(c=CoverageCriterion(["wact"]))
    tr = trace(wact=([0, 2, 5], ["idle", "welding", "idle"]))
    assert covered(m, tr) == [["idle"], ["welding"]]
    summary = m.merge([m.observe(tr, set())])
    assert summary.criteria["c"].missing == ["wact=exchWrkp"]
    assert (summary.criteria["c"].covered, summary.criteria["c"].total) == (2, 3)


def test_bool_variable():
    m = model(c=CoverageCriterion(["lgtBar"]))
    assert covered(m, trace(lgtBar=([0], [True]))) == [["true"]]
    assert covered(m, trace(lgtBar=([0, 3], [True, False]))) == [["false"], ["true"]]
    assert m.merge([m.observe(trace(lgtBar=([0], [True])), set())]).criteria["c"].missing == [
        "lgtBar=false"
    ]


def test_number_bins_names_and_edges():
    assert NumberBins(EDGES).labels == ("<0.5", "0.5..1", "1..2", ">=2")
    assert NumberBins([-1, 0.25]).labels == ("<-1", "-1..0.25", ">=0.25")
    m = model(c=CoverageCriterion(["speed"]))
    # Values exactly on an edge fall in the bin starting there.
    tr = trace(speed=([0, 1, 2], [0.5, 1.0, 2.0]))
    assert covered(m, tr) == [["0.5..1"], ["1..2"], [">=2"]]
    tr = trace(speed=([0, 1, 2], [0.4999, 1.9999, math.inf]))
    assert covered(m, tr) == [["<0.5"], ["1..2"], [">=2"]]
    tr = trace(speed=([0, 1], [-math.inf, math.nan]))  # NaN is undefined
    assert covered(m, tr) == [["<0.5"]]


# --------------------------------------------------------------------------- combinations


def test_combination_brief_overlap_counts():
    m = model(c=CoverageCriterion(["wact", "oloc"]))
    tr = trace(
        wact=([0, 2, 5], ["idle", "welding", "idle"]),
        oloc=([0, 4.999], ["none", "inCell"]),
    )
    assert covered(m, tr) == [
        ["idle", "none"],
        ["idle", "inCell"],
        ["welding", "none"],
        ["welding", "inCell"],  # only on [4.999, 5)
    ]


def test_zero_length_overlap_does_not_count():
    m = model(c=CoverageCriterion(["wact", "oloc"]))
    tr = trace(
        wact=([0, 2, 5], ["idle", "welding", "idle"]),
        oloc=([0, 5], ["none", "inCell"]),  # inCell exactly when welding stops
    )
    assert covered(m, tr) == [["idle", "none"], ["idle", "inCell"], ["welding", "none"]]
    # A value held for zero time (two samples at the same instant are impossible,
    # but a sample at the end of the trace is one) covers nothing either.
    tr = trace(end=5.0, wact=([0, 5], ["idle", "welding"]))
    assert covered(model(c=CoverageCriterion(["wact"])), tr) == [["idle"]]


def test_when_restriction_with_macro():
    m = model(
        c=CoverageCriterion(["oloc"], when="lgtBar"),
        d=CoverageCriterion(["oloc"], when="busy and not lgtBar"),
    )
    tr = trace(
        oloc=([0, 2, 6], ["none", "inCell", "atTable"]),
        lgtBar=([0, 3, 7], [False, True, False]),
        wact=([0, 6.5], ["idle", "welding"]),
    )
    got = m.observe(tr, set())
    assert got["c"] == [["inCell"], ["atTable"]]  # lgtBar on [3, 7)
    assert got["d"] == [["atTable"]]  # welding and no light barrier: [7, 10)


def test_when_sharing_an_evaluator():
    m = model(c=CoverageCriterion(["oloc"], when="lgtBar"))
    tr = trace(oloc=([0], ["none"]), lgtBar=([0, 1], [False, True]))
    assert m.observe(tr, set(), TraceEvaluator(tr))["c"] == [["none"]]
    with pytest.raises(ValueError, match="another trace"):
        m.observe(tr, set(), TraceEvaluator(trace(oloc=([0], ["none"]))))


def test_use_case_filtering():
    m = model(c=CoverageCriterion(["wact"], use_case="exchange"), d=CoverageCriterion(["wact"]))
    tr = trace(wact=([0], ["exchWrkp"]))
    assert m.observe(tr, {"welding"}) == {"c": [], "d": [["exchWrkp"]]}
    assert m.observe(tr, {"welding", "exchange"}) == {"c": [["exchWrkp"]], "d": [["exchWrkp"]]}


def test_undefined_stretches_and_missing_variables():
    m = model(
        c=CoverageCriterion(["wact", "oloc"]),
        d=CoverageCriterion(["wact"], when="lgtBar"),
        e=CoverageCriterion(["wact"]),
    )
    tr = trace(
        start=0.0,
        wact=([-1, 3, 6], ["welding", "idle", "exchWrkp"]),  # sample before start: defined
        oloc=([2, 4, 5], ["none", None, "atTable"]),  # undefined on [0, 2) and [4, 5)
    )
    got = m.observe(tr, set())
    assert got["c"] == [
        ["idle", "none"],  # [3, 4)
        ["idle", "atTable"],  # [5, 6)
        ["welding", "none"],  # [2, 3)
        ["exchWrkp", "atTable"],  # [6, 10)
    ]
    assert got["d"] == []  # lgtBar is not recorded at all: nothing covered, no crash
    assert got["e"] == [["idle"], ["welding"], ["exchWrkp"]]
    # A variable whose only samples are at or after the end is never defined.
    assert m.observe(trace(end=5, wact=([6], ["idle"]), oloc=([0], ["none"])), set())["c"] == []


def test_value_outside_the_domain_is_an_error():
    m = model(c=CoverageCriterion(["wact"]))
    with pytest.raises(ValueError, match=r"'wact'.*'dancing' is not in its domain"):
        m.observe(trace(wact=([0], ["dancing"])), set())


def test_a_narrowed_domain_counts_only_its_values():
    """The designed domain: values left out cover nothing, and are not missing either."""
    m = CoverageModel.compile(
        {"c": CoverageCriterion(["wact", "lgtBar"])}, VOC, MACROS, BINS,
        domains={"wact": ["welding", "idle"], "lgtBar": ["true"]},
    )
    tr = trace(wact=([0, 2, 5], ["exchWrkp", "welding", "idle"]), lgtBar=([0, 6], [True, False]))
    assert covered(m, tr) == [["idle", "true"], ["welding", "true"]]  # domain order, not the listed order
    summary = m.merge([m.observe(trace(wact=([0], ["welding"]), lgtBar=([0], [True])), set())])
    assert summary.criteria["c"].total == 2 and summary.criteria["c"].missing == ["wact=idle, lgtBar=true"]
    with pytest.raises(ValueError, match=r"'dancing' is not in its domain"):
        m.observe(trace(wact=([0], ["dancing"]), lgtBar=([0], [True])), set())


@pytest.mark.parametrize(
    "domains, message",
    [
        ({"wact": ["welding", "dancing"]}, r"domain of 'wact': 'dancing'; choose among idle, welding, exchWrkp"),
        ({"wact": []}, r"domain of 'wact': no values"),
        ({"speed": ["fast"]}, r"'speed', which is numeric \(give it bins\)"),
        ({"wakt": ["idle"]}, r"'wakt', which is unknown \(did you mean 'wact'\?\)"),
    ],
)
def test_narrowed_domain_errors(domains, message):
    with pytest.raises(ValueError, match=message):
        CoverageModel.compile({"c": CoverageCriterion(["wact"])}, VOC, MACROS, BINS, domains=domains)


# --------------------------------------------------------------------------- merging


def test_merge_is_the_union_with_named_missing_situations():
    m = model(
        combo=CoverageCriterion(["wact", "lgtBar"], description="activity vs light barrier"),
        loc=CoverageCriterion(["oloc"]),
    )
    run1 = m.observe(
        trace(wact=([0, 5], ["idle", "welding"]), lgtBar=([0], [False]), oloc=([0], ["none"])),
        set(),
    )
    run2 = m.observe(
        trace(wact=([0], ["welding"]), lgtBar=([0, 1], [False, True]), oloc=([0], ["inCell"])),
        set(),
    )
    summary = m.merge([run1, run2])
    combo = summary.criteria["combo"]
    assert (combo.covered, combo.total) == (3, 6)
    assert combo.missing == [  # domain order: first variable slowest
        "wact=idle, lgtBar=true",
        "wact=exchWrkp, lgtBar=false",
        "wact=exchWrkp, lgtBar=true",
    ]
    assert summary.criteria["loc"].missing == ["oloc=atTable"]
    assert summary.overall == pytest.approx(5 / 9)
    data = summary.to_json()
    assert json.loads(json.dumps(data)) == data
    assert data["overall"] == {"covered": 5, "total": 9, "fraction": pytest.approx(5 / 9)}
    assert data["criteria"]["combo"] == {
        "variables": ["wact", "lgtBar"],
        "description": "activity vs light barrier",
        "covered": 3,
        "total": 6,
        "fraction": 0.5,
        "missing": combo.missing,
        # the heat map's data: how many runs saw each situation, first variable slowest
        "axes": [["idle", "welding", "exchWrkp"], ["false", "true"]],
        "runs": [1, 0, 2, 1, 0, 0],
    }
    assert m.merge([]).criteria["loc"].missing == [f"oloc={v}" for v in OLOC]


def test_merge_rejects_coverage_of_another_model():
    m = model(c=CoverageCriterion(["wact"]))
    with pytest.raises(ValueError, match="run 1 has no coverage for criterion 'c'"):
        m.merge([{"c": []}, {"x": []}])
    with pytest.raises(ValueError, match="'sleeping' is not a value of wact"):
        m.merge([{"c": [["sleeping"]]}])
    with pytest.raises(ValueError, match="not a situation"):
        m.merge([{"c": [["idle", "none"]]}])


def test_situation_name():
    assert situation_name(["wact", "oloc"], ["welding", "inCell"]) == "wact=welding, oloc=inCell"
    with pytest.raises(ValueError):
        situation_name(["wact"], [])


# --------------------------------------------------------------------------- errors


@pytest.mark.parametrize(
    ("criterion", "bins", "message"),
    [
        (CoverageCriterion(["wact", "olco"]), BINS, r"criterion 'c': unknown variable 'olco' \(did you mean 'oloc'\?\)"),
        (CoverageCriterion(["speed"]), {}, r"criterion 'c': numeric variable 'speed' needs bins"),
        (CoverageCriterion(["wact"], when="lgtbar"), BINS, r"criterion 'c': when: 1:1: unknown variable or macro 'lgtbar' \(did you mean 'lgtBar'\?\)"),
        (CoverageCriterion(["wact"], when="G lgtBar"), BINS, r"criterion 'c': when: .*temporal operator 'G' is not allowed"),
        (CoverageCriterion(["wact"]), {"wact": NumberBins([1])}, r"bins given for variable 'wact', which is not numeric"),
        (CoverageCriterion(["wact"]), {"sped": NumberBins([1])}, r"'sped', which is unknown \(did you mean 'speed'\?\)"),
    ],
)  # fmt: skip
def test_compile_errors(criterion, bins, message):
    with pytest.raises(ValueError, match=message):
        CoverageModel.compile({"c": criterion}, VOC, MACROS, bins)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: NumberBins([]), "at least one edge"),
        (lambda: NumberBins([1, 1]), "strictly increasing: 1 is followed by 1"),
        (lambda: NumberBins([0, math.inf]), "finite numbers"),
        (lambda: NumberBins(["a"]), "finite numbers"),
        (lambda: CoverageCriterion([]), "at least one variable"),
        (lambda: CoverageCriterion(["wact", "wact"]), "listed twice.*wact"),
    ],
)
def test_config_validation(make, message):
    with pytest.raises(ValueError, match=message):
        make()


# --------------------------------------------------------------------------- speed


def test_observe_is_a_sweep_not_sampling():
    rng = np.random.default_rng(0)
    names = ["wact", "oloc", "lgtBar", "speed"]
    domains = [list(WACT), list(OLOC), [False, True], [0.2, 0.7, 1.5, 3.0]]
    tr = Trace(
        {
            n: Signal(np.sort(rng.choice(np.arange(0, 30, 0.02), 200, replace=False)),
                      list(rng.choice(np.array(d, dtype=object), 200)))
            for n, d in zip(names, domains)
        },
        0.0,
        30.0,
    )  # fmt: skip
    m = model(
        a=CoverageCriterion(["wact"]),
        b=CoverageCriterion(["wact", "oloc"], when="lgtBar"),
        c=CoverageCriterion(["wact", "oloc", "speed"]),
        d=CoverageCriterion(["lgtBar", "speed"], when="busy"),
    )
    best = math.inf
    for _ in range(5):
        t0 = time.perf_counter()
        m.observe(tr, set())
        best = min(best, time.perf_counter() - t0)
    assert best / 4 < 2e-3  # typically ~0.1 ms per criterion


# --------------------------------------------------------------------------- reference


def _bin(v: float) -> str:
    """Reference binning of EDGES, written out by hand."""
    if v < 0.5:
        return "<0.5"
    if v < 1.0:
        return "0.5..1"
    if v < 2.0:
        return "1..2"
    return ">=2"


def _name(var: str, v: object) -> str | None:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return None
    if var == "speed":
        return _bin(v)
    if var == "lgtBar":
        return "true" if v else "false"
    return v


# when-formulas and their pointwise meaning (atoms on undefined variables are false)
WHENS = {
    "": lambda val: True,
    "lgtBar": lambda val: val["lgtBar"] is True,
    "not lgtBar": lambda val: val["lgtBar"] is not True,
    "busy or speed >= 1": lambda val: val["wact"] in ("welding", "exchWrkp")
    or (val["speed"] is not None and val["speed"] >= 1),
}
VALUES = {
    "wact": [*WACT, None],
    "oloc": [*OLOC, None],
    "lgtBar": [False, True, None],
    "speed": [0.0, 0.5, 0.7, 1.0, 1.5, 2.0, 3.0, math.nan, None],
}


@st.composite
def signals(draw, var: str) -> Signal:
    times = draw(st.lists(st.integers(-2, 22), min_size=1, max_size=8, unique=True))
    values = draw(st.lists(st.sampled_from(VALUES[var]), min_size=len(times), max_size=len(times)))
    return Signal(np.sort(np.asarray(times, float)) * 0.25, values)


@settings(max_examples=100, deadline=None)
@given(
    sigs=st.fixed_dictionaries({v: signals(v) for v in VALUES}),
    variables=st.sampled_from(
        [["wact"], ["speed"], ["wact", "oloc"], ["lgtBar", "speed"], ["oloc", "wact", "speed"]]
    ),
    when=st.sampled_from(list(WHENS)),
)
def test_observe_matches_midpoint_reference(sigs, variables, when):
    tr = Trace(sigs, 0.0, 5.0)
    m = model(c=CoverageCriterion(variables, when=when))
    points = sorted(
        {tr.start, tr.end}
        | {float(t) for s in sigs.values() for t in s.times if tr.start < t < tr.end}
    )
    expected = set()
    for lo, hi in zip(points, points[1:]):
        mid = (lo + hi) / 2
        val = {v: tr.value_at(v, mid) for v in VALUES}
        names = [_name(v, val[v]) for v in variables]
        if None not in names and WHENS[when](val):
            expected.add(tuple(names))
    got = covered(m, tr)
    assert {tuple(s) for s in got} == expected
    universe = m.merge([]).criteria["c"].missing  # every situation, in domain order
    positions = [universe.index(situation_name(variables, s)) for s in got]
    assert positions == sorted(set(positions))
