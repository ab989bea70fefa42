"""Tests for cellsim.logic.predicates: compiled guards vs a direct recursive evaluator."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellsim.logic.predicates import compile_predicate
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
    parse,
)

from logic_strategies import HAZARD, OPS, RLOC, SAFMOD, connectives

VOC = {
    "safmod": SAFMOD,
    "rloc": RLOC,
    "HS": HAZARD,
    "HRW": HAZARD,
    "lgtBar": BoolDomain(),
    "otab": BoolDomain(),
    "speed": NumberDomain("m/s"),
    "limit": NumberDomain("m/s"),
}


def reference(f, v) -> bool:
    """Direct recursive evaluation of a propositional AST."""
    if isinstance(f, Const):
        return f.value
    if isinstance(f, BoolVar):
        return bool(v[f.name])
    if isinstance(f, Compare):
        rhs = v[f.other] if f.other is not None else f.value
        return OPS[f.op](v[f.var], rhs)
    if isinstance(f, InSet):
        return v[f.var] in f.values
    if isinstance(f, Not):
        return not reference(f.arg, v)
    if isinstance(f, And):
        return all([reference(a, v) for a in f.args])
    if isinstance(f, Or):
        return any([reference(a, v) for a in f.args])
    if isinstance(f, Implies):
        return (not reference(f.lhs, v)) or reference(f.rhs, v)
    raise AssertionError(f)


# --------------------------------------------------------------------------- strategies

NUMS = [-1.0, 0.0, 0.5, 1.0, 2.0]


def _values(var):
    domain = VOC[var]
    if isinstance(domain, EnumDomain):
        return st.sampled_from(domain.values)
    if isinstance(domain, BoolDomain):
        return st.booleans()
    return st.sampled_from(NUMS)


@st.composite
def atoms(draw):
    var = draw(st.sampled_from(sorted(VOC)))
    domain = VOC[var]
    kind = draw(st.sampled_from(["cmp", "var", "set", "bare"]))
    if isinstance(domain, BoolDomain) and kind == "bare":
        return BoolVar(var)
    ops = ["==", "!=", "<", "<=", ">", ">="] if isinstance(domain, NumberDomain) else ["==", "!="]
    op = draw(st.sampled_from(ops))
    if kind == "var":
        others = [w for w in VOC if VOC[w] == domain]
        return Compare(var, op, None, draw(st.sampled_from(others)))
    if kind == "set":
        return InSet(var, frozenset(draw(st.lists(_values(var), min_size=1, max_size=3))))
    return Compare(var, op, draw(_values(var)))


leaves = st.one_of(atoms(), st.builds(Const, st.booleans()))
formulas = st.recursive(
    leaves, lambda children: connectives(children, max_args=6), max_leaves=16
)
valuations = st.fixed_dictionaries({var: _values(var) for var in VOC})


@settings(max_examples=300, deadline=None)
@given(formulas, st.lists(valuations, min_size=1, max_size=5))
def test_compiled_predicate_agrees_with_reference(f, vals):
    pred = compile_predicate(f, VOC)
    for v in vals:
        result = pred(v)
        assert type(result) is bool
        assert result == reference(f, v)


# --------------------------------------------------------------------------- examples


def test_guard_from_the_risk_model():
    text = (
        "safmod in {normal, hguid, ssmon, pflim} and lgtBar and rloc == sharedTbl and HRW == inact"
    )
    guard = compile_predicate(parse(text, VOC, allow_temporal=False), VOC)
    v = {"safmod": "hguid", "lgtBar": True, "rloc": "sharedTbl", "HRW": "inact"}
    assert guard(v) is True
    assert guard({**v, "safmod": "stopped"}) is False
    assert guard({**v, "lgtBar": False}) is False
    assert guard.variables == {"safmod", "lgtBar", "rloc", "HRW"}
    assert guard.formula == parse(text, VOC)


def test_numeric_and_variable_comparisons():
    guard = compile_predicate(parse("speed <= limit and speed > -0.5", VOC), VOC)
    assert guard({"speed": 0.2, "limit": 0.25})
    assert not guard({"speed": 0.3, "limit": 0.25})
    assert not guard({"speed": -1.0, "limit": 0.25})


def test_missing_variable_raises_key_error_naming_it():
    guard = compile_predicate(parse("lgtBar and HS == act", VOC), VOC)
    with pytest.raises(KeyError) as info:
        guard({"lgtBar": True})
    assert info.value.args == ("HS",)


@pytest.mark.parametrize(
    "formula",
    [
        Always(BoolVar("lgtBar")),
        Eventually(BoolVar("lgtBar"), 0.0, 1.0),
        And((BoolVar("otab"), Until(BoolVar("otab"), BoolVar("lgtBar")))),
        Not(Until(BoolVar("otab"), BoolVar("lgtBar"), weak=True)),
    ],
)
def test_temporal_formulas_are_rejected(formula):
    with pytest.raises(FormulaError, match="temporal"):
        compile_predicate(formula, VOC)


def test_ill_typed_asts_are_rejected():
    with pytest.raises(FormulaError, match="not a value of safmod"):
        compile_predicate(Compare("safmod", "==", "pflm"), VOC)
    with pytest.raises(FormulaError, match="unknown variable"):
        compile_predicate(BoolVar("lgtbar"), VOC)


def test_each_compiled_predicate_is_a_distinct_function():
    f1 = compile_predicate(Const(True), VOC)
    f2 = compile_predicate(Const(True), VOC)
    assert f1 is not f2 and f1({}) is True
    assert compile_predicate(Const(False), VOC)({}) is False


def test_speed():
    """A typical guard must cost a few microseconds at most (called 50 Hz x tens)."""
    import timeit

    text = (
        "safmod in {normal, hguid, ssmon, pflim} and lgtBar and rloc == sharedTbl and HRW == inact"
    )
    guard = compile_predicate(parse(text, VOC), VOC)
    v = {"safmod": "hguid", "lgtBar": True, "rloc": "sharedTbl", "HRW": "inact"}
    per_call = min(timeit.repeat(lambda: guard(v), number=2000, repeat=5)) / 2000
    assert per_call < 20e-6


@pytest.mark.parametrize(
    "text", ["speed < 1.0", "speed <= 1.0", "speed > 1.0", "speed >= 1.0", "speed == 1.0", "speed != 1.0",
             "speed != limit", "limit != speed", "speed == limit", "speed < limit"],
)
def test_a_number_with_no_value_makes_every_comparison_false(text):
    """NaN is how the safety controller reads a number channel with no value."""
    guard = compile_predicate(parse(text, VOC, allow_temporal=False), VOC)
    assert guard({"speed": float("nan"), "limit": 1.0}) is False


@pytest.mark.parametrize("op, below, equal, above", [
    ("<", True, False, False), ("<=", True, True, False), (">", False, False, True), (">=", False, True, True),
    ("==", False, True, False), ("!=", True, False, True),
])
def test_each_comparison_at_its_boundary_against_a_constant_and_a_variable(op, below, equal, above):
    """Every operator on both sides of its boundary and on it, number against constant and against variable."""
    const = compile_predicate(parse(f"speed {op} 0.25", VOC), VOC)
    var = compile_predicate(parse(f"speed {op} limit", VOC), VOC)
    for speed, expected in ((0.2, below), (0.25, equal), (0.3, above)):
        assert const({"speed": speed}) is expected, (op, speed)
        assert var({"speed": speed, "limit": 0.25}) is expected, (op, speed)


def test_a_temporal_formula_is_refused_for_what_it_is():
    with pytest.raises(FormulaError) as e:
        compile_predicate(Always(BoolVar("lgtBar")), VOC)
    assert str(e.value) == "temporal operators cannot be evaluated on a single valuation"


def test_a_negated_set_membership_holds_outside_the_set_only():
    guard = compile_predicate(parse("not (safmod in {normal, stopped})", VOC), VOC)
    assert guard({"safmod": "pflim"}) is True and guard({"safmod": "normal"}) is False
    single = compile_predicate(parse("not (safmod in {normal})", VOC), VOC)
    assert single({"safmod": "pflim"}) is True and single({"safmod": "normal"}) is False


@pytest.mark.parametrize("width", [2, 4, 5, 7])
def test_a_wide_or_and_and_give_their_value_beyond_the_unrolled_widths(width):
    """Two to four operands are unrolled; wider ones loop: both ways the same value, every operand counted."""
    ors = compile_predicate(Or(tuple(BoolVar(f"b{i}") for i in range(width))), {f"b{i}": BoolDomain() for i in range(width)})
    ands = compile_predicate(And(tuple(BoolVar(f"b{i}") for i in range(width))), {f"b{i}": BoolDomain() for i in range(width)})
    for true_at in [None, *range(width)]:
        valuation = {f"b{i}": i == true_at for i in range(width)}
        assert ors(valuation) is (true_at is not None)
        assert ands({k: not v for k, v in valuation.items()}) is (true_at is None)


def test_the_compiler_itself_refuses_a_temporal_operator_naming_it():
    """compile_predicate checks a guard first; the compiler's own refusal is the second line, said the same way."""
    from cellsim.logic.predicates import _Compiler
    from cellsim.logic.syntax import Always, FormulaError

    with pytest.raises(FormulaError, match=r"not a propositional formula: Always\("):
        _Compiler().visit(Always(BoolVar("lgtBar")))
