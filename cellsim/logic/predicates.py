"""Compilation of propositional formulas (risk-model guards) to fast Python callables.

A guard is evaluated every control step (50 Hz) on the current valuation of the
variables, for tens of guards, so the AST is compiled once into a tree of nested
closures: a call does no dispatch on node types, only the comparisons themselves.

    >>> from cellsim.logic.syntax import EnumDomain, BoolDomain, parse
    >>> voc = {"safmod": EnumDomain(("normal", "stopped")), "lgtBar": BoolDomain()}
    >>> guard = compile_predicate(parse("safmod == normal and not lgtBar", voc), voc)
    >>> guard({"safmod": "normal", "lgtBar": False})
    True

Valuations map variable names to values: enumeration values as ``str``, booleans as
``bool``, numbers as ``float``.  A variable missing from the valuation raises
``KeyError(name)`` when it is read; ``and``/``or``/``->`` short-circuit left to right,
so a variable that is not needed for the verdict may not be read.  The returned
function carries ``.variables`` (all variables it may read, to validate a valuation
once up-front) and ``.formula``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from .syntax import (
    And,
    BoolVar,
    Compare,
    Const,
    Formula,
    FormulaError,
    Implies,
    InSet,
    Not,
    Or,
    Visitor,
    Vocabulary,
    check,
    is_temporal,
    variables_of,
)

__all__ = ["compile_predicate", "Predicate"]

Valuation = Mapping[str, object]
Predicate = Callable[[Valuation], bool]


def compile_predicate(formula: Formula, vocabulary: Vocabulary) -> Predicate:
    """Compile a propositional formula into ``valuation -> bool``.

    Raises :class:`FormulaError` if the formula is temporal or does not type-check
    against ``vocabulary``.
    """
    if is_temporal(formula):
        raise FormulaError("temporal operators cannot be evaluated on a single valuation")
    check(formula, vocabulary, allow_temporal=False)
    fn = _COMPILER.visit(formula)  # always a fresh function object: safe to annotate
    fn.variables = variables_of(formula)  # type: ignore[attr-defined]
    fn.formula = formula  # type: ignore[attr-defined]
    return fn


# Closure factories.  Each call creates a *fresh* function object, so the attributes
# set by compile_predicate never leak between predicates.


def _compare_const(name: str, op: str, c: object) -> Predicate:
    if op == "==":
        return lambda v: v[name] == c
    if op == "!=":
        if isinstance(c, float):  # a number with no value (NaN) is unequal to nothing
            return lambda v: v[name] != c and v[name] == v[name]
        return lambda v: v[name] != c
    if op == "<":
        return lambda v: v[name] < c
    if op == "<=":
        return lambda v: v[name] <= c
    if op == ">":
        return lambda v: v[name] > c
    if op == ">=":
        return lambda v: v[name] >= c
    raise AssertionError(op)


def _compare_vars(name: str, op: str, other: str) -> Predicate:
    if op == "==":
        return lambda v: v[name] == v[other]
    if op == "!=":  # a number with no value (NaN) is unequal to nothing, itself included
        return lambda v: v[name] != v[other] and v[name] == v[name] and v[other] == v[other]
    if op == "<":
        return lambda v: v[name] < v[other]
    if op == "<=":
        return lambda v: v[name] <= v[other]
    if op == ">":
        return lambda v: v[name] > v[other]
    if op == ">=":
        return lambda v: v[name] >= v[other]
    raise AssertionError(op)


# ``and``/``or`` of the usual 2 to 4 operands, unrolled so that a call runs no loop;
# both short-circuit left to right.
_AND_OF = {
    2: lambda a, b: lambda v: a(v) and b(v),
    3: lambda a, b, c: lambda v: a(v) and b(v) and c(v),
    4: lambda a, b, c, d: lambda v: a(v) and b(v) and c(v) and d(v),
}
_OR_OF = {
    2: lambda a, b: lambda v: a(v) or b(v),
    3: lambda a, b, c: lambda v: a(v) or b(v) or c(v),
    4: lambda a, b, c, d: lambda v: a(v) or b(v) or c(v) or d(v),
}


def _junction(fs: tuple[Predicate, ...], disjunction: bool) -> Predicate:
    """The conjunction (or, with ``disjunction``, the disjunction) of ``fs``."""
    unrolled = (_OR_OF if disjunction else _AND_OF).get(len(fs))
    if unrolled is not None:
        return unrolled(*fs)
    if disjunction:

        def disj(v: Valuation) -> bool:
            for f in fs:
                if f(v):
                    return True
            return False

        return disj

    def conj(v: Valuation) -> bool:
        for f in fs:
            if not f(v):
                return False
        return True

    return conj


class _Compiler(Visitor):
    """A propositional formula as a closure, one operator at a time (``visit(node)``)."""

    refused = dict.fromkeys(("Always", "Eventually", "Until"),
                            "a guard is evaluated on one valuation: it has no future to look at")

    def refuse(self, node: Formula, why: str) -> Predicate:
        raise FormulaError(f"not a propositional formula: {node!r}")

    def visit_Compare(self, node: Compare) -> Predicate:
        if node.other is not None:
            return _compare_vars(node.var, node.op, node.other)
        return _compare_const(node.var, node.op, node.value)

    def visit_InSet(self, node: InSet) -> Predicate:
        name, values = node.var, frozenset(node.values)
        if len(values) == 1:
            (c,) = values
            return lambda v: v[name] == c
        return lambda v: v[name] in values

    def visit_BoolVar(self, node: BoolVar) -> Predicate:
        name = node.name
        return lambda v: True if v[name] else False

    def visit_Const(self, node: Const) -> Predicate:
        if node.value:
            return lambda v: True
        return lambda v: False

    def visit_Not(self, node: Not) -> Predicate:
        arg = node.arg
        # Peephole: negated leaves become a single comparison.
        if isinstance(arg, InSet) and len(arg.values) > 1:
            name, values = arg.var, frozenset(arg.values)
            return lambda v: v[name] not in values
        if isinstance(arg, BoolVar):
            name = arg.name
            return lambda v: False if v[name] else True
        f = self.visit(arg)
        return lambda v: not f(v)

    def visit_And(self, node: And) -> Predicate:
        return _junction(tuple(self.visit(a) for a in node.args), False)

    def visit_Or(self, node: Or) -> Predicate:
        return _junction(tuple(self.visit(a) for a in node.args), True)

    def visit_Implies(self, node: Implies) -> Predicate:
        a, b = self.visit(node.lhs), self.visit(node.rhs)
        return lambda v: (not a(v)) or b(v)


_COMPILER = _Compiler()
