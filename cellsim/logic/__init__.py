"""The cellsim condition language: guards and metric-temporal safety conditions.

* :mod:`.syntax` - domains, AST, :func:`parse`, :func:`format_formula`;
* :mod:`.predicates` - :func:`compile_predicate` for propositional guards;
* :mod:`.trace` - :class:`Signal`, :class:`Trace` (piecewise-constant recorded runs);
* :mod:`.intervals` - :class:`IntervalSet` (unions of half-open intervals);
* :mod:`.mtl` - :func:`satisfaction`, :func:`evaluate`, :class:`Evaluation`.

The language reference is ``docs/condition-language.md``.
"""

from .intervals import IntervalSet
from .mtl import Evaluation, TraceEvaluator, evaluate, satisfaction
from .predicates import compile_predicate
from .syntax import (
    Always,
    And,
    BoolDomain,
    BoolVar,
    Compare,
    Const,
    EnumDomain,
    Eventually,
    Formula,
    FormulaError,
    Implies,
    InSet,
    Not,
    NumberDomain,
    Or,
    Until,
    Vocabulary,
    check,
    format_formula,
    is_temporal,
    parse,
    variables_of,
)
from .trace import Signal, Trace

__all__ = [
    "Always",
    "And",
    "BoolDomain",
    "BoolVar",
    "Compare",
    "Const",
    "EnumDomain",
    "Evaluation",
    "Eventually",
    "Formula",
    "FormulaError",
    "Implies",
    "InSet",
    "IntervalSet",
    "Not",
    "NumberDomain",
    "Or",
    "Signal",
    "Trace",
    "TraceEvaluator",
    "Until",
    "Vocabulary",
    "check",
    "compile_predicate",
    "evaluate",
    "format_formula",
    "is_temporal",
    "parse",
    "satisfaction",
    "variables_of",
]
