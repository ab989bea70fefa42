"""Tests for cellsim.logic.syntax: parsing, typing, macros, errors, printing."""

from __future__ import annotations

import math
import pickle

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellsim.logic.syntax import (
    Always,
    And,
    BoolDomain,
    BoolVar,
    Compare,
    Const,
    EnumDomain,
    Eventually,
    FormulaError,
    Implies,
    InSet,
    Not,
    NumberDomain,
    Or,
    Until,
    check,
    format_formula,
    is_temporal,
    parse,
    variables_of,
)

from logic_strategies import HAZARD, RLOC, SAFMOD, connectives, intervals

INF = math.inf
VOC = {
    "safmod": SAFMOD,
    "rloc": RLOC,
    "home": RLOC,  # a variable named like a value
    "ract": EnumDomain(("idle", "exchWrkp", "welding")),
    "wact": EnumDomain(("idle", "welding")),
    "rngDet": EnumDomain(("far", "near", "close")),
    "HS": HAZARD,
    "HC": HAZARD,
    "HRW": HAZARD,
    "lgtBar": BoolDomain(),
    "otab": BoolDomain(),
    "a": BoolDomain(),
    "b": BoolDomain(),
    "c": BoolDomain(),
    "robot.speed": NumberDomain("m/s"),
    "limit": NumberDomain("m/s"),
    "force": NumberDomain("N"),
}
A, B, C = BoolVar("a"), BoolVar("b"), BoolVar("c")


def p(text: str, macros=None, **kw):
    return parse(text, VOC, macros, **kw)


def error_of(text: str, macros=None, **kw) -> FormulaError:
    with pytest.raises(FormulaError) as info:
        parse(text, VOC, macros, **kw)
    return info.value


# --------------------------------------------------------------------------- atoms


def test_constants_and_boolean_variables():
    assert p("true") == Const(True)
    assert p("false") == Const(False)
    assert p("lgtBar") == BoolVar("lgtBar")
    assert p("(((lgtBar)))") == BoolVar("lgtBar")


def test_comparisons_with_literals():
    assert p("safmod == normal") == Compare("safmod", "==", "normal")
    assert p("safmod!=stopped") == Compare("safmod", "!=", "stopped")
    assert p("lgtBar == true") == Compare("lgtBar", "==", True)
    assert p("lgtBar != false") == Compare("lgtBar", "!=", False)
    for op in ("==", "!=", "<", "<=", ">", ">="):
        assert p(f"robot.speed {op} 0.25") == Compare("robot.speed", op, 0.25)
    assert p("robot.speed > -1.5e-3") == Compare("robot.speed", ">", -0.0015)
    assert p("force >= 140") == Compare("force", ">=", 140.0)


def test_comparisons_between_variables():
    assert p("robot.speed <= limit") == Compare("robot.speed", "<=", None, "limit")
    assert p("HS == HC") == Compare("HS", "==", None, "HC")
    assert p("lgtBar != otab") == Compare("lgtBar", "!=", None, "otab")
    # an enumeration value wins over a variable of the same name
    assert p("rloc == home") == Compare("rloc", "==", "home")
    assert p("rloc == sharedTbl") == Compare("rloc", "==", "sharedTbl")


def test_membership_with_braces_and_brackets():
    expected = InSet("safmod", frozenset({"normal", "hguid", "ssmon", "pflim"}))
    assert p("safmod in {normal, hguid, ssmon, pflim}") == expected
    assert p("safmod in [normal,hguid,ssmon,pflim]") == expected
    assert p("safmod in {normal, normal}") == InSet("safmod", frozenset({"normal"}))
    assert p("force in {1, -2.5}") == InSet("force", frozenset({1.0, -2.5}))
    assert p("lgtBar in {true}") == InSet("lgtBar", frozenset({True}))


def test_dotted_identifiers_and_keyword_like_prefixes():
    voc = {"Gx": BoolDomain(), "Fa.b": BoolDomain(), "inside": BoolDomain(), "s": BoolDomain()}
    assert parse("Gx and Fa.b and inside", voc) == And(
        (BoolVar("Gx"), BoolVar("Fa.b"), BoolVar("inside"))
    )
    # "s" is only a unit inside intervals
    assert parse("F[0, 1 s] s", voc) == Eventually(BoolVar("s"), 0.0, 1.0)


def test_enum_values_may_be_numbers_or_keywords():
    voc = {"gear": EnumDomain(("1", "2", "F", "in"))}
    assert parse("gear == 1", voc) == Compare("gear", "==", "1")
    assert parse("gear in {F, in}", voc) == InSet("gear", frozenset({"F", "in"}))


# --------------------------------------------------------------------------- operators


def test_boolean_operators_and_spellings():
    assert p("not a") == Not(A) == p("!a")
    assert p("a and b") == And((A, B)) == p("a && b")
    assert p("a or b") == Or((A, B)) == p("a || b")
    assert p("a -> b") == Implies(A, B) == p("a implies b")


def test_chains_are_flat_but_parentheses_are_kept():
    assert p("a and b and c") == And((A, B, C))
    assert p("(a and b) and c") == And((And((A, B)), C))
    assert p("a or b or c") == Or((A, B, C))


def test_precedence():
    assert p("a or b and c") == Or((A, And((B, C))))
    assert p("a and b or c") == Or((And((A, B)), C))
    assert p("a or b -> c") == Implies(Or((A, B)), C)
    assert p("not a and b") == And((Not(A), B))
    assert p("not a == true") == Not(Compare("a", "==", True))
    assert p("a and b U c") == And((A, Until(B, C)))
    assert p("a U b or c") == Or((Until(A, B), C))
    assert p("not a U b") == Until(Not(A), B)
    assert p("G a U b") == Until(Always(A), B)
    assert p("G a -> F b") == Implies(Always(A), Eventually(B))
    assert p("G(a -> F b)") == Always(Implies(A, Eventually(B)))
    assert p("F G a") == Eventually(Always(A))
    assert p("not not a") == Not(Not(A))


def test_right_associativity():
    assert p("a -> b -> c") == Implies(A, Implies(B, C))
    assert p("(a -> b) -> c") == Implies(Implies(A, B), C)
    assert p("a U b U c") == Until(A, Until(B, C))
    assert p("a U b W c") == Until(A, Until(B, C, weak=True))


def test_temporal_operators_and_spellings():
    assert p("G a") == Always(A, 0.0, INF) == p("always a")
    assert p("F a") == Eventually(A, 0.0, INF) == p("eventually a")
    assert p("a U b") == Until(A, B, 0.0, INF, weak=False)
    assert p("a W b") == Until(A, B, 0.0, INF, weak=True)


@pytest.mark.parametrize(
    "interval, lo, hi",
    [
        ("[0, 0.5 s]", 0.0, 0.5),
        ("[0,500ms]", 0.0, 0.5),
        ("[0.1s, 2]", 0.1, 2.0),
        ("[250 ms, inf]", 0.25, INF),
        ("[1, inf s]", 1.0, INF),
        ("[2, 2]", 2.0, 2.0),
        ("[0, 1e1]", 0.0, 10.0),
    ],
)
def test_intervals(interval, lo, hi):
    assert p(f"G{interval} a") == Always(A, lo, hi)
    assert p(f"F {interval} a") == Eventually(A, lo, hi)
    assert p(f"a U{interval} b") == Until(A, B, lo, hi)
    assert p(f"a W {interval} b") == Until(A, B, lo, hi, weak=True)


def test_welding_cell_conditions():
    macros = {
        "HS_e": "safmod in {normal, hguid, ssmon, pflim} and "
        "(ract in {exchWrkp, welding} or wact == welding) and rngDet in {near, close}"
    }
    f = p("G((HS_e and HS == inact) -> (HS_e U[0, 0.5s] HS == act))", macros)
    hs_e = p(macros["HS_e"])
    assert f == Always(
        Implies(
            And((hs_e, Compare("HS", "==", "inact"))),
            Until(hs_e, Compare("HS", "==", "act"), 0.0, 0.5),
        )
    )
    assert p("G(HC == act -> F HC == mit)") == Always(
        Implies(Compare("HC", "==", "act"), Eventually(Compare("HC", "==", "mit")))
    )
    assert p("G(not HC == mis)") == Always(Not(Compare("HC", "==", "mis")))
    assert p("F(not otab)") == Eventually(Not(BoolVar("otab")))
    guard = (
        "safmod in {normal, hguid, ssmon, pflim} and lgtBar and rloc == sharedTbl and HRW == inact"
    )
    assert p(guard, allow_temporal=False).args[2] == Compare("rloc", "==", "sharedTbl")


def test_multiline_text():
    assert p("G(\n  a ->\n  F b\n)") == Always(Implies(A, Eventually(B)))


# --------------------------------------------------------------------------- macros


def test_macros_nested_and_shared():
    macros = {"ab": "a and b", "abc": "ab or c", "neg": "not abc"}
    assert p("neg", macros) == Not(Or((And((A, B)), C)))
    f = p("abc -> ab", macros)
    assert f == Implies(Or((And((A, B)), C)), And((A, B)))


def test_macro_cycles_are_errors():
    e = error_of("a and x", {"x": "y", "y": "a or x"})
    assert e.message == "macro cycle: x -> y -> x"
    assert (e.line, e.column) == (1, 7)
    e = error_of("self", {"self": "not self"})
    assert "macro cycle: self -> self" in e.message


def test_macro_must_not_shadow_a_variable():
    e = error_of("a", {"a": "b"})
    assert "shadows" in e.message
    e = error_of("a", {"not": "b"})
    assert "invalid macro name" in e.message


def test_macro_errors_point_at_the_use_and_inside_the_macro():
    e = error_of("a and\n  m", {"m": "b or rngdet == near"}, source="risk.yaml", line_offset=10)
    assert (e.source, e.line, e.column) == ("risk.yaml", 12, 3)
    assert e.message == (
        "in macro 'm' (at 1:6 of its text): "
        "unknown variable or macro 'rngdet' (did you mean 'rngDet'?)"
    )


def test_macros_cannot_be_compared():
    e = error_of("m == a", {"m": "a"})
    assert "macro 'm' is a formula and cannot be compared" in e.message
    assert e.column == 3


def test_temporal_macro_in_guard_is_rejected():
    e = error_of("a and m", {"m": "F b"}, allow_temporal=False)
    assert "temporal operator 'F' is not allowed here" in e.message
    assert e.column == 7


# --------------------------------------------------------------------------- errors


@pytest.mark.parametrize(
    "text, line, column, message",
    [
        ("rngdet == near", 1, 1, "unknown variable or macro 'rngdet' (did you mean 'rngDet'?)"),
        ("a and xyzzy", 1, 7, "unknown variable or macro 'xyzzy'"),
        (
            "safmod == pflm",
            1,
            11,
            "'pflm' is not a value of safmod (normal, hguid, ssmon, pflim, srmst, stopped)",
        ),
        (
            "safmod in {normal,\n  pflm}",
            2,
            3,
            "'pflm' is not a value of safmod (normal, hguid, ssmon, pflim, srmst, stopped)",
        ),
        ("lgtBar == near", 1, 11, "lgtBar is boolean: expected true or false, found 'near'"),
        (
            "safmod < 3",
            1,
            8,
            "'<' is not defined for enumeration variable safmod (use ==, != or in)",
        ),
        ("lgtBar >= true", 1, 8, "'>=' is not defined for boolean variable lgtBar (use == or !=)"),
        ("robot.speed < fast", 1, 15, "robot.speed is numeric: expected a number, found 'fast'"),
        (
            "robot.speed < force",
            1,
            15,
            "cannot compare robot.speed (numeric, in m/s) with force (numeric, in N): the domains differ",
        ),
        (
            "safmod == lgtBar",
            1,
            11,
            "cannot compare safmod (enumeration) with lgtBar (boolean): the domains differ",
        ),
        ("safmod", 1, 1, "safmod is an enumeration"),
        ("robot.speed", 1, 1, "robot.speed is numeric, not a boolean"),
        ("a and (b or c", 1, 14, "expected ')' to close the '(' at 1:7, found end of input"),
        ("(a and b))", 1, 10, "unbalanced ')': no matching '('"),
        (")", 1, 1, "expected a formula, found ')'"),
        ("a b", 1, 3, "unexpected 'b' after a complete formula"),
        ("a and", 1, 6, "expected a formula, found end of input"),
        ("", 1, 1, "expected a formula, found end of input"),
        ("a and or b", 1, 7, "expected a formula, found keyword 'or'"),
        ("a # b", 1, 3, "unexpected character '#'"),
        ("safmod in {}", 1, 11, "empty set"),
        ("safmod in normal", 1, 11, "expected '{' after 'in'"),
        ("safmod in {normal hguid}", 1, 19, "expected ',' or '}' in the set, found 'hguid'"),
        ("F[2, 1] a", 1, 2, "empty interval: the lower bound 2 s exceeds the upper bound 1 s"),
        ("F[-1, 1] a", 1, 3, "interval bounds must be non-negative"),
        ("F[inf, inf] a", 1, 3, "the lower bound of an interval must be finite"),
        ("F[0, 3 min] a", 1, 8, "unknown time unit 'min' (use s or ms)"),
        ("F[0 1] a", 1, 5, "expected ',' between the interval bounds, found '1'"),
        ("F[0, 1 a", 1, 8, "expected ']' to close the interval, found 'a'"),
        ("F[0, x] a", 1, 6, "expected a number as interval bound, found 'x'"),
    ],
)
def test_error_locations_and_messages(text, line, column, message):
    e = error_of(text)
    assert (e.line, e.column) == (line, column), str(e)
    assert message in e.message, str(e)


def test_temporal_operators_rejected_in_guards():
    for text, op, col in [("G a", "G", 1), ("a and F b", "F", 7), ("a U b", "U", 3),
                          ("a W b", "W", 3), ("always a", "always", 1)]:  # fmt: skip
        e = error_of(text, allow_temporal=False)
        assert e.message == f"temporal operator {op!r} is not allowed here"
        assert e.column == col


def test_error_string_format_and_line_offset():
    e = error_of("a and\n\n   bogus", source="risk.yaml", line_offset=39)
    assert (e.line, e.column) == (42, 4)
    assert str(e) == "risk.yaml:42:4: unknown variable or macro 'bogus'"
    assert str(FormulaError("m")) == "m"
    assert str(FormulaError("m", line=3, column=2)) == "3:2: m"
    assert str(FormulaError("m", source="f.yaml")) == "f.yaml: m"
    copy = pickle.loads(pickle.dumps(e))
    assert (copy.message, copy.source, copy.line, copy.column) == (
        e.message,
        e.source,
        e.line,
        e.column,
    )


# --------------------------------------------------------------------------- helpers


def test_variables_of_and_is_temporal():
    f = p("G(safmod == normal -> (a U robot.speed < limit))")
    assert variables_of(f) == {"safmod", "a", "robot.speed", "limit"}
    assert is_temporal(f)
    assert not is_temporal(p("not (a or HS == act)"))
    assert variables_of(Const(True)) == frozenset()


def test_check_programmatic_asts():
    check(Always(Compare("HS", "==", "act")), VOC)
    with pytest.raises(FormulaError, match="not a value of HS"):
        check(Compare("HS", "==", "acted"), VOC)
    with pytest.raises(FormulaError, match="unknown variable 'zz'"):
        check(BoolVar("zz"), VOC)
    with pytest.raises(FormulaError, match="not allowed"):
        check(Eventually(A), VOC, allow_temporal=False)


def test_ast_validation():
    with pytest.raises(ValueError):
        And((A,))
    with pytest.raises(ValueError):
        Always(A, 2.0, 1.0)
    with pytest.raises(ValueError):
        Compare("a", "=~", True)
    with pytest.raises(ValueError):
        Compare("a", "==", None, None)
    assert And([A, B]) == And((A, B))  # lists are frozen into tuples
    assert hash(p("G(a -> F b)")) == hash(p("G (a -> F b)"))


def test_format_examples():
    cases = {
        "G((a and b) -> (a U[0, 0.5s] b))": "G(a and b -> a U[0, 0.5] b)",
        "(a -> b) -> c": "(a -> b) -> c",
        "(a and b) and c": "(a and b) and c",
        "(a or b) and c": "(a or b) and c",
        "(a U b) U c": "(a U b) U c",
        "not (a and b)": "not (a and b)",
        "safmod in {stopped, normal}": "safmod in {normal, stopped}",
        "F[0, 1500ms] robot.speed < 1e-3": "F[0, 1.5] robot.speed < 0.001",
        "G(not HC == mis)": "G(not HC == mis)",
        "a W[1, inf] b": "a W[1, inf] b",
    }
    for text, canonical in cases.items():
        assert format_formula(p(text)) == canonical
        assert p(canonical) == p(text)


# --------------------------------------------------------------------------- round trip

ENUM_VARS = ["safmod", "rloc", "HS", "HC"]
BOOL_VARS = ["lgtBar", "otab", "a", "b"]
NUM_VARS = ["robot.speed", "limit", "force"]

numbers = st.one_of(
    st.integers(-1000, 1000).map(float),
    st.floats(allow_nan=False, allow_infinity=False, width=64),
)
bounds = st.one_of(
    st.sampled_from([0.0, 0.02, 0.1, 0.5, 1.0, 2.5, 30.0]),
    st.floats(0, 1e6, allow_nan=False),
)


@st.composite
def enum_atoms(draw):
    var = draw(st.sampled_from(ENUM_VARS))
    values = VOC[var].values
    kind = draw(st.sampled_from(["value", "var", "set"]))
    if kind == "set":
        return InSet(var, frozenset(draw(st.lists(st.sampled_from(values), min_size=1))))
    op = draw(st.sampled_from(["==", "!="]))
    if kind == "var":
        same = [v for v in ENUM_VARS if set(VOC[v].values) == set(values)]
        return Compare(var, op, None, draw(st.sampled_from(same)))
    return Compare(var, op, draw(st.sampled_from(values)))


@st.composite
def num_atoms(draw):
    var = draw(st.sampled_from(NUM_VARS))
    op = draw(st.sampled_from(["==", "!=", "<", "<=", ">", ">="]))
    if var in ("robot.speed", "limit") and draw(st.booleans()):
        return Compare(var, op, None, "limit" if var == "robot.speed" else "robot.speed")
    if draw(st.booleans()):
        return InSet(var, frozenset(draw(st.lists(numbers, min_size=1, max_size=3))))
    return Compare(var, op, draw(numbers))


bool_atoms = st.one_of(
    st.sampled_from(BOOL_VARS).map(BoolVar),
    st.builds(
        Compare,
        st.sampled_from(BOOL_VARS),
        st.sampled_from(["==", "!="]),
        st.booleans(),
    ),
    st.builds(Const, st.booleans()),
)
atoms = st.one_of(bool_atoms, enum_atoms(), num_atoms())


time_intervals = intervals(bounds, bounds)
formulas = st.recursive(
    atoms, lambda children: connectives(children, intervals=time_intervals), max_leaves=12
)


@settings(max_examples=300, deadline=None)
@given(formulas)
def test_format_round_trip(f):
    text = format_formula(f)
    assert parse(text, VOC) == f, text
    assert format_formula(parse(text, VOC)) == text


@settings(max_examples=100, deadline=None)
@given(formulas)
def test_generated_formulas_type_check(f):
    check(f, VOC)
