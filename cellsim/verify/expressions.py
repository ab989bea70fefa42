"""The condition language (without temporal operators) as PRISM expressions.

A variable is encoded in the abstract model as one of

* an enumeration: an integer, the index of its value (``prism.Enum``);
* a boolean;
* a number, abstracted by its thresholds: the constants it is compared with in
  the model's guards (:class:`Thresholds`). Its code is a *region*: with
  thresholds c0 < c1 < ... the regions are (-inf, c0), {c0}, (c0, c1), {c1}, ...,
  (c_last, inf), so every comparison with a threshold is exactly a set of regions.

Translation is exact: a guard holds in a concrete state iff its translation holds
in the state's abstraction. A comparison the encoding cannot express exactly (a
number compared with a constant that is not one of its thresholds, two numbers
compared with each other) is refused with a ``VerifyError``.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass

from cellsim.logic.syntax import And, BoolVar, Compare, Const, Implies, InSet, Not, Or, Visitor, numeric_comparisons
from cellsim.verify.prism import Enum


class VerifyError(Exception):
    """A model that cannot be verified as it stands (the message is one line)."""


@dataclass(frozen=True)
class Thresholds:
    """A number abstracted by the constants it is compared with (sorted, distinct)."""

    values: tuple[float, ...]

    @property
    def regions(self) -> int:
        return 2 * len(self.values) + 1

    def region_of(self, x: float) -> int:
        """The region of a concrete value."""
        i = bisect.bisect_left(self.values, x)
        if i < len(self.values) and self.values[i] == x:
            return 2 * i + 1
        return 2 * i

    def point(self, value: float) -> int:
        if value not in self.values:
            raise VerifyError(f"{value:g} is not one of the thresholds {', '.join(f'{v:g}' for v in self.values)}")
        return 2 * self.values.index(value) + 1


Encoding = Enum | Thresholds | type(bool)
"""How a variable is encoded: its enumeration, its thresholds, or ``bool``."""


def to_prism(formula, encodings: dict[str, Encoding], names: dict[str, str] | None = None) -> str:
    """The PRISM expression of ``formula``; ``names`` maps a variable to its PRISM name (default: itself)."""
    return _Prism(encodings, names or {}).visit(formula)


_TEMPORAL = "a temporal operator has no place in a guard of the abstract model"


class _Prism(Visitor):
    """:func:`to_prism`, one operator at a time."""

    refused = {"Always": _TEMPORAL, "Eventually": _TEMPORAL, "Until": _TEMPORAL}

    def __init__(self, encodings: dict[str, Encoding], names: dict[str, str]) -> None:
        self.encodings, self.names = encodings, names

    def refuse(self, node, why: str) -> str:
        raise VerifyError(f"'{type(node).__name__}' (a temporal operator) has no place in a guard of the abstract model")

    def name(self, var: str) -> str:
        if var not in self.encodings:
            raise VerifyError(f"variable '{var}' has no abstraction in the model")
        return self.names.get(var, var)

    def visit_Const(self, node: Const) -> str:
        return "true" if node.value else "false"

    def visit_BoolVar(self, node: BoolVar) -> str:
        return self.name(node.name)

    def visit_Not(self, node: Not) -> str:
        return f"!({self.visit(node.arg)})"

    def visit_And(self, node: And) -> str:
        return "(" + " & ".join(self.visit(a) for a in node.args) + ")"

    def visit_Or(self, node: Or) -> str:
        return "(" + " | ".join(self.visit(a) for a in node.args) + ")"

    def visit_Implies(self, node: Implies) -> str:
        return f"(!({self.visit(node.lhs)}) | ({self.visit(node.rhs)}))"

    def visit_InSet(self, node: InSet) -> str:
        return "(" + " | ".join(self.visit(Compare(node.var, "==", value)) for value in sorted(node.values, key=str)) + ")"

    def visit_Compare(self, node: Compare) -> str:
        encoding = self.encodings.get(node.var)
        left = self.name(node.var)
        op = {"==": "=", "!=": "!="}.get(node.op, node.op)
        if node.other is not None:
            other = self.encodings.get(node.other)
            if isinstance(encoding, Thresholds) or isinstance(other, Thresholds):
                raise VerifyError(f"{node.var} {node.op} {node.other}: two numbers compared with each other cannot be "
                                  "abstracted by thresholds")
            return f"({left} {op} {self.name(node.other)})"
        if isinstance(encoding, Enum):
            return f"({left} {op} {encoding.code(node.value)})"
        if encoding is bool:
            value = "true" if node.value else "false"
            return f"({left} {op} {value})"
        if isinstance(encoding, Thresholds):
            point = encoding.point(float(node.value))
            return f"({left} {op} {point})"  # regions are ordered as the numbers are: < <= > >= = != all exact
        raise VerifyError(f"variable '{node.var}' has no abstraction in the model")


def thresholds_of(formulas, variable: str) -> Thresholds:
    """The constants ``variable`` is compared with in ``formulas`` (parsed condition-language formulas)."""
    found = {float(node.value) for formula in formulas for node in numeric_comparisons(formula) if node.var == variable}
    return Thresholds(tuple(sorted(found)))
