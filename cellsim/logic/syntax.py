"""Syntax of the cellsim condition language: domains, AST, parser and printer.

One language serves two purposes:

* **guards** of a risk model (propositional formulas such as
  ``safmod in {normal, hguid} and lgtBar and rloc == sharedTbl``), compiled by
  :func:`cellsim.logic.predicates.compile_predicate` and evaluated on the current
  valuation of the variables;
* **safety conditions** in metric temporal logic (``G(HC == act -> F HC == mit)``),
  checked on a recorded run by :mod:`cellsim.logic.mtl`.

The grammar, the typing rules and the semantics are documented in
``docs/condition-language.md``.  In short (precedence from low to high)::

    formula  := implies
    implies  := or_expr [ ("->" | "implies") implies ]            # right associative
    or_expr  := and_expr { ("or" | "||") and_expr }
    and_expr := until { ("and" | "&&") until }
    until    := unary [ ("U" | "W") [interval] until ]             # right associative
    unary    := ("not" | "!") unary
              | ("G" | "always" | "F" | "eventually") [interval] unary
              | atom
    atom     := "true" | "false" | "(" formula ")" | macro | boolvar
              | var ("==" | "!=" | "<" | "<=" | ">" | ">=") value
              | var "in" ( "{" value {"," value} "}" | "[" value {"," value} "]" )
    interval := "[" number [unit] "," (number [unit] | "inf") "]"   unit := "s" | "ms"

Every AST node is a frozen (hashable) dataclass; :func:`format_formula` prints the
canonical text, which :func:`parse` reads back to an equal AST.

The tree is walked one way: every node gives its sub-formulas (``children()``,
:class:`Node`), :func:`walk` yields every node, and a pass that does something
different per operator (printing, type checking, evaluation, margins, PRISM,
explanations) is a :class:`Visitor`, which must handle or refuse each class of
:data:`NODE_CLASSES`.
"""

from __future__ import annotations

import difflib
import math
import re
from bisect import bisect_right
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, TypeAlias, Union

__all__ = [
    "FormulaError",
    "EnumDomain",
    "BoolDomain",
    "NumberDomain",
    "Domain",
    "Vocabulary",
    "Const",
    "BoolVar",
    "Compare",
    "InSet",
    "Not",
    "And",
    "Or",
    "Implies",
    "Always",
    "Eventually",
    "Until",
    "Formula",
    "Node",
    "NODE_CLASSES",
    "walk",
    "numeric_comparisons",
    "Visitor",
    "KEYWORDS",
    "COMPARISON_OPERATORS",
    "parse",
    "check",
    "variables_of",
    "is_temporal",
    "format_formula",
]


# --------------------------------------------------------------------------- errors


class FormulaError(Exception):
    """A formula is malformed or ill-typed.

    ``str(error)`` is ``"{source}:{line}:{column}: {message}"``, leaving out the
    parts that are ``None``.  Lines and columns are 1-based; lines include the
    ``line_offset`` given to :func:`parse`.
    """

    def __init__(
        self,
        message: str,
        source: str | None = None,
        line: int | None = None,
        column: int | None = None,
    ) -> None:
        super().__init__(message)
        self.message = message
        self.source = source
        self.line = line
        self.column = column

    def __str__(self) -> str:
        where = [str(p) for p in (self.source, self.line, self.column) if p is not None]
        return ":".join(where) + ": " + self.message if where else self.message

    def __reduce__(self):  # keep the location when pickled (e.g. across processes)
        return (type(self), (self.message, self.source, self.line, self.column))


class _MacroCycleError(FormulaError):
    """A cycle between macros; re-located, not re-worded, at each enclosing use."""


# --------------------------------------------------------------------------- domains


@dataclass(frozen=True)
class EnumDomain:
    """A finite set of symbolic values (compared with ``==``, ``!=``, ``in``)."""

    values: tuple[str, ...]

    def __post_init__(self) -> None:
        values = tuple(self.values)
        if not values:
            raise ValueError("an enumeration domain needs at least one value")
        if not all(isinstance(v, str) and v for v in values):
            raise ValueError(f"enumeration values must be non-empty strings: {values!r}")
        if len(set(values)) != len(values):
            raise ValueError(f"duplicate enumeration values: {values!r}")
        object.__setattr__(self, "values", values)


@dataclass(frozen=True)
class BoolDomain:
    """Booleans: usable directly as a formula, or compared with ``true``/``false``."""


@dataclass(frozen=True)
class NumberDomain:
    """Real numbers (all six comparisons).  ``unit`` is informative; literals are in it."""

    unit: str | None = None


Domain: TypeAlias = Union[EnumDomain, BoolDomain, NumberDomain]
Vocabulary: TypeAlias = Mapping[str, Domain]

KEYWORDS = frozenset(
    {
        "G", "F", "U", "W", "not", "and", "or", "in", "implies",
        "always", "eventually", "true", "false", "inf",
    }
)  # fmt: skip
COMPARISON_OPERATORS = ("==", "!=", "<", "<=", ">", ">=")
_EQUALITY_OPERATORS = ("==", "!=")
_NAME_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z0-9_]+)*\Z")

# --------------------------------------------------------------------------- AST


def _check_bounds(node: object, lo: float, hi: float) -> None:
    lo, hi = float(lo), float(hi)
    if not (0.0 <= lo <= hi) or math.isinf(lo) or math.isnan(hi):
        raise ValueError(f"bad interval [{lo}, {hi}] (need 0 <= lo <= hi, lo finite)")
    object.__setattr__(node, "lo", lo)
    object.__setattr__(node, "hi", hi)


class Node:
    """What every node of the AST (every formula) is and says about itself.

    The tree is walked through these methods only, so a pass that does the same at
    every node (:func:`walk`, :func:`variables_of`, :func:`is_temporal`) is written
    once here; a pass that does something different per operator is a
    :class:`Visitor`.  A node class is defined by its sub-formulas (``children``),
    how to rebuild it with others (``with_children``), the variables it reads
    itself (``variables``) and whether it is a temporal operator (``temporal``).
    """

    __slots__ = ()

    temporal: ClassVar[bool] = False
    """Whether the operator speaks of other instants than the present (``G F U W``)."""

    def children(self) -> tuple[Formula, ...]:
        """The sub-formulas, in the order they are written; ``()`` for an atom."""
        return ()

    def with_children(self, *children: Formula) -> Formula:
        """The same operator (same window, values...) over ``children`` instead."""
        if children:
            raise ValueError(f"{type(self).__name__} has no sub-formulas")
        return self  # type: ignore[return-value]

    def variables(self) -> tuple[str, ...]:
        """The variables this node reads itself (not those of its sub-formulas)."""
        return ()


@dataclass(frozen=True, slots=True)
class Const(Node):
    """``true`` or ``false``."""

    value: bool


@dataclass(frozen=True, slots=True)
class BoolVar(Node):
    """A boolean variable used as a formula."""

    name: str

    def variables(self) -> tuple[str, ...]:
        return (self.name,)


@dataclass(frozen=True, slots=True)
class Compare(Node):
    """``var OP value`` (``other is None``) or ``var OP other`` (``value is None``)."""

    var: str
    op: str
    value: str | float | bool | None = None
    other: str | None = None

    def __post_init__(self) -> None:
        if self.op not in COMPARISON_OPERATORS:
            raise ValueError(f"unknown comparison operator {self.op!r}")
        if (self.value is None) == (self.other is None):
            raise ValueError("Compare needs exactly one of value and other")

    def variables(self) -> tuple[str, ...]:
        return (self.var,) if self.other is None else (self.var, self.other)

    @property
    def threshold(self) -> float | None:
        """The number a variable is compared with (``speed <= 0.5``: 0.5); ``None`` when it is
        compared with a symbol, a boolean or another variable."""
        value = self.value
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return None
        return value


@dataclass(frozen=True, slots=True)
class InSet(Node):
    """``var in {v1, v2, ...}``."""

    var: str
    values: frozenset

    def __post_init__(self) -> None:
        values = frozenset(self.values)
        if not values:
            raise ValueError("InSet needs at least one value")
        object.__setattr__(self, "values", values)

    def variables(self) -> tuple[str, ...]:
        return (self.var,)


@dataclass(frozen=True, slots=True)
class Not(Node):
    arg: Formula

    def children(self) -> tuple[Formula, ...]:
        return (self.arg,)

    def with_children(self, arg: Formula) -> Formula:
        return Not(arg)


def _check_args(node: object, args: object) -> None:
    args = tuple(args)  # type: ignore[arg-type]
    if len(args) < 2:
        raise ValueError(f"{type(node).__name__} needs at least two operands")
    object.__setattr__(node, "args", args)


@dataclass(frozen=True, slots=True)
class And(Node):
    """Conjunction of two or more operands (a chain ``a and b and c`` is one node)."""

    args: tuple[Formula, ...]

    def __post_init__(self) -> None:
        _check_args(self, self.args)

    def children(self) -> tuple[Formula, ...]:
        return self.args

    def with_children(self, *args: Formula) -> Formula:
        return And(args)


@dataclass(frozen=True, slots=True)
class Or(Node):
    """Disjunction of two or more operands."""

    args: tuple[Formula, ...]

    def __post_init__(self) -> None:
        _check_args(self, self.args)

    def children(self) -> tuple[Formula, ...]:
        return self.args

    def with_children(self, *args: Formula) -> Formula:
        return Or(args)


@dataclass(frozen=True, slots=True)
class Implies(Node):
    lhs: Formula
    rhs: Formula

    def children(self) -> tuple[Formula, ...]:
        return (self.lhs, self.rhs)

    def with_children(self, lhs: Formula, rhs: Formula) -> Formula:
        return Implies(lhs, rhs)


@dataclass(frozen=True, slots=True)
class _WindowOf(Node):
    """What ``G`` and ``F`` share: one argument over a window ``[lo, hi]`` (not a node class itself)."""

    arg: Formula
    lo: float = 0.0
    hi: float = math.inf

    temporal: ClassVar[bool] = True

    def __post_init__(self) -> None:
        _check_bounds(self, self.lo, self.hi)

    def children(self) -> tuple[Formula, ...]:
        return (self.arg,)

    def with_children(self, arg: Formula) -> Formula:
        return type(self)(arg, self.lo, self.hi)


@dataclass(frozen=True, slots=True)
class Always(_WindowOf):
    """``G[lo, hi] arg``."""


@dataclass(frozen=True, slots=True)
class Eventually(_WindowOf):
    """``F[lo, hi] arg``."""


@dataclass(frozen=True, slots=True)
class Until(Node):
    """``lhs U[lo, hi] rhs`` (``weak=False``) or ``lhs W[lo, hi] rhs`` (``weak=True``)."""

    lhs: Formula
    rhs: Formula
    lo: float = 0.0
    hi: float = math.inf
    weak: bool = False

    temporal: ClassVar[bool] = True

    def __post_init__(self) -> None:
        _check_bounds(self, self.lo, self.hi)

    def children(self) -> tuple[Formula, ...]:
        return (self.lhs, self.rhs)

    def with_children(self, lhs: Formula, rhs: Formula) -> Formula:
        return Until(lhs, rhs, self.lo, self.hi, self.weak)


Formula: TypeAlias = Union[
    Const, BoolVar, Compare, InSet, Not, And, Or, Implies, Always, Eventually, Until
]
NODE_CLASSES: tuple[type[Node], ...] = (
    Const, BoolVar, Compare, InSet, Not, And, Or, Implies, Always, Eventually, Until
)
"""Every node class, atoms first: what a :class:`Visitor` must handle or refuse."""

# --------------------------------------------------------------------------- traversal


def walk(formula: Formula) -> Iterator[Formula]:
    """Every node of ``formula``: the node, then its children's nodes in order (pre-order).

    A shared sub-formula (a macro used twice) is yielded each time it appears.
    Raises ``TypeError`` on anything that is not a formula.
    """
    stack = [formula]
    while stack:
        node = stack.pop()
        if not isinstance(node, Node):
            raise TypeError(f"not a formula: {node!r}")
        yield node
        stack.extend(reversed(node.children()))


def numeric_comparisons(formula: Formula) -> Iterator[Compare]:
    """The comparisons of a variable with a number (``speed <= 0.5``) in ``formula``, in order:
    the thresholds a margin moves and an abstraction keeps apart."""
    for node in walk(formula):
        if isinstance(node, Compare) and node.threshold is not None:
            yield node


def signed_comparisons(formula: Formula, positive: bool = True) -> Iterator[tuple[Compare, bool]]:
    """The comparisons of a variable with a number in ``formula``, each with its polarity: True where the formula
    is the likelier to hold the likelier the comparison holds (under an even number of negations, counting the
    left side of an implication as one), False where the reverse."""
    if isinstance(formula, Compare):
        if formula.threshold is not None:
            yield formula, positive
        return
    if isinstance(formula, Not):
        yield from signed_comparisons(formula.arg, not positive)
        return
    if isinstance(formula, Implies):
        yield from signed_comparisons(formula.lhs, not positive)
        yield from signed_comparisons(formula.rhs, positive)
        return
    for child in formula.children():
        yield from signed_comparisons(child, positive)


class Visitor:
    """A pass that does something different for each operator of the language.

    ``visit(node, *args)`` calls ``self.visit_<NodeClass>(node, *args)``; the methods
    recurse by calling ``visit`` on the children they need.  A pass either handles
    a node class (defines its method) or refuses it: ``refused`` maps the class's
    name to why, and visiting such a node calls :meth:`refuse`, which a pass
    overrides to raise its own error.  ``tests/test_logic_passes.py`` checks that
    every pass handles or refuses every class of :data:`NODE_CLASSES`, so a new
    operator cannot be forgotten by one.
    """

    refused: ClassVar[Mapping[str, str]] = {}
    """Node class name -> why this pass has no meaning for it."""

    def visit(self, node: Formula, *args: Any) -> Any:
        if not isinstance(node, Node):
            raise TypeError(f"not a formula: {node!r}")
        name = type(node).__name__
        method = getattr(self, "visit_" + name, None)
        if method is not None:
            return method(node, *args)
        if name in self.refused:
            return self.refuse(node, self.refused[name])
        raise NotImplementedError(
            f"{type(self).__name__} has no visit_{name}: the pass neither handles nor refuses {name}"
        )

    def refuse(self, node: Formula, why: str) -> Any:
        """Called on a node of a class in ``refused``; raises (by default a ``TypeError``)."""
        raise TypeError(f"{type(self).__name__}: {why}: {node!r}")

# --------------------------------------------------------------------------- lexer

_TOKEN_RE = re.compile(
    r"""
      (?P<ws>\s+)
    | (?P<number>(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?)
    | (?P<name>[A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z0-9_]+)*)
    | (?P<op>->|==|!=|<=|>=|&&|\|\||[<>!(){}\[\],-])
    """,
    re.VERBOSE,
)


@dataclass(frozen=True, slots=True)
class _Token:
    kind: str  # "number", "name", "kw", "op" or "end"
    text: str
    pos: int

    def is_op(self, *texts: str) -> bool:
        return self.kind == "op" and self.text in texts

    def is_kw(self, *texts: str) -> bool:
        return self.kind == "kw" and self.text in texts

    def describe(self) -> str:
        return "end of input" if self.kind == "end" else repr(self.text)


def _tokenize(text: str) -> tuple[list[_Token], int | None]:
    """Tokens of ``text`` ending with an "end" token; second item: offset of a bad character."""
    tokens: list[_Token] = []
    pos, n = 0, len(text)
    match = _TOKEN_RE.match
    while pos < n:
        m = match(text, pos)
        if m is None:
            return tokens, pos
        kind = m.lastgroup
        if kind != "ws":
            word = m.group()
            if kind == "name" and word in KEYWORDS:
                kind = "kw"
            tokens.append(_Token(kind, word, pos))  # type: ignore[arg-type]
        pos = m.end()
    tokens.append(_Token("end", "", n))
    return tokens, None


# --------------------------------------------------------------------------- parser


class _MacroContext:
    """State shared by the parsers of one :func:`parse` call (macro cache, cycle stack)."""

    def __init__(self, macros: Mapping[str, str]) -> None:
        self.macros = macros
        self.cache: dict[str, Formula] = {}
        self.stack: list[str] = []


def _domain_kind(domain: Domain) -> str:
    if isinstance(domain, EnumDomain):
        return "enumeration"
    if isinstance(domain, BoolDomain):
        return "boolean"
    if isinstance(domain, NumberDomain):
        return "numeric"
    raise TypeError(f"not a domain: {domain!r}")


def _described(domain: Domain) -> str:
    """A domain as an error names it: its kind, and a number's unit."""
    if isinstance(domain, NumberDomain) and domain.unit:
        return f"numeric, in {domain.unit}"
    return _domain_kind(domain)


def _same_domain(a: Domain, b: Domain) -> bool:
    if isinstance(a, EnumDomain) and isinstance(b, EnumDomain):
        return set(a.values) == set(b.values)
    if isinstance(a, NumberDomain) and isinstance(b, NumberDomain):
        return a.unit == b.unit
    return isinstance(a, BoolDomain) and isinstance(b, BoolDomain)


def _not_a_value(value: object, var: str, domain: EnumDomain) -> str:
    return f"{value!r} is not a value of {var} ({', '.join(domain.values)})"


def _suggest(name: str, candidates: list[str]) -> str:
    folded = [c for c in candidates if c.lower() == name.lower()]
    close = folded or difflib.get_close_matches(name, candidates, n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


class _Parser:
    def __init__(
        self,
        text: str,
        vocabulary: Vocabulary,
        ctx: _MacroContext,
        source: str | None,
        line_offset: int,
        allow_temporal: bool,
    ) -> None:
        self.text = text
        self.vocabulary = vocabulary
        self.ctx = ctx
        self.source = source
        self.line_offset = line_offset
        self.allow_temporal = allow_temporal
        self.line_starts = [0] + [m.end() for m in re.finditer("\n", text)]
        tokens, bad = _tokenize(text)
        if bad is not None:
            raise self.error_at(bad, f"unexpected character {text[bad]!r}")
        self.tokens = tokens
        self.i = 0

    # ----- helpers

    def error_at(self, pos: int, message: str, cls: type[FormulaError] = FormulaError):
        line = bisect_right(self.line_starts, pos)
        column = pos - self.line_starts[line - 1] + 1
        return cls(message, self.source, line + self.line_offset, column)

    def error(self, tok: _Token, message: str, cls: type[FormulaError] = FormulaError):
        return self.error_at(tok.pos, message, cls)

    def peek(self) -> _Token:
        return self.tokens[self.i]

    def next(self) -> _Token:
        tok = self.tokens[self.i]
        if tok.kind != "end":
            self.i += 1
        return tok

    # ----- grammar

    def parse_all(self) -> Formula:
        formula = self.parse_implies()
        tok = self.peek()
        if tok.kind != "end":
            if tok.is_op(")"):
                raise self.error(tok, "unbalanced ')': no matching '('")
            raise self.error(tok, f"unexpected {tok.describe()} after a complete formula")
        return formula

    def parse_implies(self) -> Formula:
        lhs = self.parse_or()
        tok = self.peek()
        if tok.is_op("->") or tok.is_kw("implies"):
            self.next()
            return Implies(lhs, self.parse_implies())
        return lhs

    def parse_or(self) -> Formula:
        args = [self.parse_and()]
        while self.peek().is_op("||") or self.peek().is_kw("or"):
            self.next()
            args.append(self.parse_and())
        return args[0] if len(args) == 1 else Or(tuple(args))

    def parse_and(self) -> Formula:
        args = [self.parse_until()]
        while self.peek().is_op("&&") or self.peek().is_kw("and"):
            self.next()
            args.append(self.parse_until())
        return args[0] if len(args) == 1 else And(tuple(args))

    def parse_until(self) -> Formula:
        lhs = self.parse_unary()
        tok = self.peek()
        if tok.is_kw("U", "W"):
            self.check_temporal(tok)
            self.next()
            lo, hi = self.parse_interval()
            rhs = self.parse_until()
            return Until(lhs, rhs, lo, hi, weak=tok.text == "W")
        return lhs

    def parse_unary(self) -> Formula:
        tok = self.peek()
        if tok.is_op("!") or tok.is_kw("not"):
            self.next()
            return Not(self.parse_unary())
        if tok.is_kw("G", "always", "F", "eventually"):
            self.check_temporal(tok)
            self.next()
            lo, hi = self.parse_interval()
            arg = self.parse_unary()
            cls = Always if tok.text in ("G", "always") else Eventually
            return cls(arg, lo, hi)
        return self.parse_atom()

    def check_temporal(self, tok: _Token) -> None:
        if not self.allow_temporal:
            raise self.error(tok, f"temporal operator {tok.text!r} is not allowed here")

    def parse_interval(self) -> tuple[float, float]:
        open_tok = self.peek()
        if not open_tok.is_op("["):
            return 0.0, math.inf
        self.next()
        lo = self.parse_bound(upper=False)
        tok = self.next()
        if not tok.is_op(","):
            raise self.error(
                tok, f"expected ',' between the interval bounds, found {tok.describe()}"
            )
        hi = self.parse_bound(upper=True)
        tok = self.next()
        if not tok.is_op("]"):
            raise self.error(tok, f"expected ']' to close the interval, found {tok.describe()}")
        if lo > hi:
            raise self.error(
                open_tok,
                f"empty interval: the lower bound {_fmt_num(lo)} s exceeds "
                f"the upper bound {_fmt_num(hi)} s",
            )
        return lo, hi

    def parse_bound(self, upper: bool) -> float:
        tok = self.next()
        if tok.is_kw("inf"):
            if not upper:
                raise self.error(tok, "the lower bound of an interval must be finite")
            value = math.inf
        elif tok.kind == "number":
            value = float(tok.text)
        elif tok.is_op("-"):
            raise self.error(tok, "interval bounds must be non-negative")
        else:
            raise self.error(tok, f"expected a number as interval bound, found {tok.describe()}")
        unit = self.peek()
        if unit.kind == "name":
            if unit.text == "s":
                self.next()
            elif unit.text == "ms":
                self.next()
                value = value / 1000.0
            elif self.tokens[self.i + 1].is_op(",", "]"):
                raise self.error(unit, f"unknown time unit {unit.text!r} (use s or ms)")
        if math.isinf(value) and tok.kind == "number":
            raise self.error(tok, f"interval bound {tok.text} is too large (write inf)")
        return value

    def parse_atom(self) -> Formula:
        tok = self.peek()
        if tok.is_kw("true", "false"):
            self.next()
            return Const(tok.text == "true")
        if tok.is_op("("):
            self.next()
            formula = self.parse_implies()
            close = self.peek()
            if not close.is_op(")"):
                line = bisect_right(self.line_starts, tok.pos)
                where = f"{line + self.line_offset}:{tok.pos - self.line_starts[line - 1] + 1}"
                raise self.error(
                    close, f"expected ')' to close the '(' at {where}, found {close.describe()}"
                )
            self.next()
            return formula
        if tok.kind == "name":
            return self.parse_name()
        if tok.is_op(")"):
            raise self.error(tok, "expected a formula, found ')'")
        if tok.kind == "kw":
            raise self.error(tok, f"expected a formula, found keyword {tok.text!r}")
        raise self.error(tok, f"expected a formula, found {tok.describe()}")

    def parse_name(self) -> Formula:
        tok = self.next()
        name = tok.text
        nxt = self.peek()
        compared = nxt.kind == "op" and nxt.text in COMPARISON_OPERATORS
        member = nxt.is_kw("in")
        domain = self.vocabulary.get(name)
        if domain is not None:
            if compared:
                return self.parse_comparison(name, domain)
            if member:
                return self.parse_membership(name, domain)
            if isinstance(domain, BoolDomain):
                return BoolVar(name)
            if isinstance(domain, EnumDomain):
                raise self.error(
                    tok,
                    f"{name} is an enumeration ({', '.join(domain.values)}), not a boolean; "
                    f"compare it, e.g. '{name} == {domain.values[0]}'",
                )
            raise self.error(
                tok, f"{name} is numeric, not a boolean; compare it, e.g. '{name} > 0'"
            )
        if name in self.ctx.macros:
            if compared or member:
                raise self.error(nxt, f"macro {name!r} is a formula and cannot be compared")
            return self.expand_macro(name, tok)
        candidates = sorted(set(self.vocabulary) | set(self.ctx.macros))
        raise self.error(tok, f"unknown variable or macro {name!r}{_suggest(name, candidates)}")

    def parse_comparison(self, name: str, domain: Domain) -> Formula:
        op_tok = self.next()
        op = op_tok.text
        kind = _domain_kind(domain)
        if op not in _EQUALITY_OPERATORS and not isinstance(domain, NumberDomain):
            use = "==, != or in" if isinstance(domain, EnumDomain) else "== or !="
            raise self.error(
                op_tok, f"{op!r} is not defined for {kind} variable {name} (use {use})"
            )
        tok = self.peek()
        if tok.kind == "name" and tok.text in self.vocabulary and not (
            isinstance(domain, EnumDomain) and tok.text in domain.values
        ):
            # comparison with another variable (an enumeration value of the same
            # name takes precedence, see the docs)
            self.next()
            other = self.vocabulary[tok.text]
            if not _same_domain(domain, other):
                raise self.error(tok, f"cannot compare {name} ({_described(domain)}) with {tok.text} "
                                      f"({_described(other)}): the domains differ")
            return Compare(name, op, None, tok.text)
        return Compare(name, op, self.parse_value(name, domain), None)

    def parse_value(self, name: str, domain: Domain) -> str | float | bool:
        tok = self.peek()
        if isinstance(domain, EnumDomain):
            if tok.kind in ("name", "number", "kw") and tok.text in domain.values:
                self.next()
                return tok.text
            if tok.kind in ("name", "number", "kw"):
                raise self.error(tok, _not_a_value(tok.text, name, domain))
            raise self.error(tok, f"expected a value of {name}, found {tok.describe()}")
        if isinstance(domain, BoolDomain):
            if tok.is_kw("true", "false"):
                self.next()
                return tok.text == "true"
            raise self.error(
                tok, f"{name} is boolean: expected true or false, found {tok.describe()}"
            )
        negative = tok.is_op("-")
        if negative:
            self.next()
            tok = self.peek()
        if tok.kind == "number":
            self.next()
            value = float(tok.text)
            if math.isinf(value):
                raise self.error(tok, f"number {tok.text} is too large")
            return -value if negative else value
        raise self.error(tok, f"{name} is numeric: expected a number, found {tok.describe()}")

    def parse_membership(self, name: str, domain: Domain) -> Formula:
        self.next()  # "in"
        open_tok = self.next()
        if not open_tok.is_op("{", "["):
            raise self.error(open_tok, f"expected '{{' after 'in', found {open_tok.describe()}")
        close = "}" if open_tok.text == "{" else "]"
        if self.peek().is_op(close):
            raise self.error(open_tok, f"empty set: {name} in {open_tok.text}{close} is never true")
        values = [self.parse_value(name, domain)]
        while True:
            tok = self.next()
            if tok.is_op(close):
                return InSet(name, frozenset(values))
            if not tok.is_op(","):
                raise self.error(
                    tok, f"expected ',' or '{close}' in the set, found {tok.describe()}"
                )
            values.append(self.parse_value(name, domain))

    def expand_macro(self, name: str, tok: _Token) -> Formula:
        ctx = self.ctx
        cached = ctx.cache.get(name)
        if cached is not None:
            return cached
        if name in ctx.stack:
            chain = " -> ".join(ctx.stack[ctx.stack.index(name) :] + [name])
            raise self.error(tok, f"macro cycle: {chain}", _MacroCycleError)
        text = ctx.macros[name]
        if not isinstance(text, str):
            raise self.error(tok, f"macro {name!r} is not a string: {text!r}")
        ctx.stack.append(name)
        try:
            formula = _Parser(
                text, self.vocabulary, ctx, None, 0, self.allow_temporal
            ).parse_all()
        except _MacroCycleError as e:
            raise self.error(tok, e.message, _MacroCycleError) from None
        except FormulaError as e:
            raise self.error(
                tok, f"in macro {name!r} (at {e.line}:{e.column} of its text): {e.message}"
            ) from None
        finally:
            ctx.stack.pop()
        ctx.cache[name] = formula
        return formula


def parse(
    text: str,
    vocabulary: Vocabulary,
    macros: Mapping[str, str] | None = None,
    *,
    source: str | None = None,
    line_offset: int = 0,
    allow_temporal: bool = True,
) -> Formula:
    """Parse and type-check ``text`` against ``vocabulary``.

    ``macros`` maps names to formula texts, expanded (parsed in the same vocabulary,
    possibly using other macros) wherever the name is used as an atom.  ``source``
    (e.g. a file name) and ``line_offset`` (lines preceding the text in that file)
    only affect error locations.  With ``allow_temporal=False`` the temporal
    operators ``G F U W`` are rejected (guards).  Raises :class:`FormulaError`.
    """
    if not isinstance(text, str):
        raise TypeError(f"formula text must be a str, not {type(text).__name__}")
    macros = dict(macros or {})
    for name in macros:
        if not isinstance(name, str) or not _NAME_RE.match(name) or name in KEYWORDS:
            raise FormulaError(f"invalid macro name {name!r}", source)
        if name in vocabulary:
            raise FormulaError(f"macro {name!r} shadows the variable of the same name", source)
    ctx = _MacroContext(macros)
    return _Parser(text, vocabulary, ctx, source, line_offset, allow_temporal).parse_all()


# --------------------------------------------------------------------------- checks


def check(formula: Formula, vocabulary: Vocabulary, *, allow_temporal: bool = True) -> None:
    """Type-check an AST (e.g. one built in Python) against ``vocabulary``.

    Enforces the same rules as :func:`parse`; raises :class:`FormulaError`
    (without location).
    """

    def domain_of(name: str) -> Domain:
        try:
            return vocabulary[name]
        except KeyError:
            raise FormulaError(
                f"unknown variable {name!r}{_suggest(name, sorted(vocabulary))}"
            ) from None

    def value_ok(name: str, domain: Domain, value: object) -> None:
        if isinstance(domain, EnumDomain):
            if not isinstance(value, str) or value not in domain.values:
                raise FormulaError(_not_a_value(value, name, domain))
        elif isinstance(domain, BoolDomain):
            if not isinstance(value, bool):
                raise FormulaError(f"{name} is boolean: {value!r} is not true or false")
        elif isinstance(value, bool) or not isinstance(value, (int, float)) or math.isnan(value):
            raise FormulaError(f"{name} is numeric: {value!r} is not a number")

    checker = _Checker(domain_of, value_ok, allow_temporal)
    for node in walk(formula):
        checker.visit(node)


class _Checker(Visitor):
    """The typing rules of one node (its children are checked on their own: see :func:`check`)."""

    def __init__(self, domain_of, value_ok, allow_temporal: bool) -> None:
        self.domain_of = domain_of
        self.value_ok = value_ok
        self.allow_temporal = allow_temporal

    def visit_Const(self, node: Const) -> None:
        pass

    def visit_BoolVar(self, node: BoolVar) -> None:
        if not isinstance(self.domain_of(node.name), BoolDomain):
            raise FormulaError(f"{node.name} is not boolean; compare it with a value")

    def visit_Compare(self, node: Compare) -> None:
        domain = self.domain_of(node.var)
        if node.op not in _EQUALITY_OPERATORS and not isinstance(domain, NumberDomain):
            raise FormulaError(
                f"{node.op!r} is not defined for {_domain_kind(domain)} variable {node.var}"
            )
        if node.other is not None:
            if not _same_domain(domain, self.domain_of(node.other)):
                raise FormulaError(
                    f"cannot compare {node.var} with {node.other}: the domains differ"
                )
        else:
            self.value_ok(node.var, domain, node.value)

    def visit_InSet(self, node: InSet) -> None:
        domain = self.domain_of(node.var)
        for value in node.values:
            self.value_ok(node.var, domain, value)

    def visit_Not(self, node: Not) -> None:
        pass

    visit_And = visit_Or = visit_Implies = visit_Not

    def _temporal(self, op: str) -> None:
        if not self.allow_temporal:
            raise FormulaError(f"temporal operator {op!r} is not allowed here")

    def visit_Always(self, node: Always) -> None:
        self._temporal("G")

    def visit_Eventually(self, node: Eventually) -> None:
        self._temporal("F")

    def visit_Until(self, node: Until) -> None:
        self._temporal("W" if node.weak else "U")


def variables_of(formula: Formula) -> frozenset[str]:
    """The variables a formula reads (both sides of variable-variable comparisons)."""
    return frozenset(name for node in walk(formula) for name in node.variables())


def is_temporal(formula: Formula) -> bool:
    """Whether the formula contains a temporal operator (``G``, ``F``, ``U``, ``W``)."""
    return any(node.temporal for node in walk(formula))


# --------------------------------------------------------------------------- printer

_IMPLIES, _OR, _AND, _UNTIL, _PREFIX, _ATOM = range(1, 7)


def _fmt_num(x: float) -> str:
    if math.isinf(x):
        return "inf"
    if x == int(x) and abs(x) < 1e15:
        return str(int(x))
    return repr(float(x))


def _fmt_value(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return _fmt_num(float(value))
    return str(value)


def _sort_key(value: object) -> tuple:
    if isinstance(value, (int, float)):
        return (0, float(value), "")
    return (1, 0.0, str(value))


def _fmt_interval(lo: float, hi: float) -> str:
    if lo == 0.0 and math.isinf(hi):
        return ""
    return f"[{_fmt_num(lo)}, {_fmt_num(hi)}]"


def _fmt(node: Formula, min_prec: int) -> str:
    text, prec = _PRINTER.visit(node)
    return f"({text})" if prec < min_prec else text


class _Printer(Visitor):
    """A node's canonical text and the precedence of its outermost operator."""

    def visit_Const(self, node: Const) -> tuple[str, int]:
        return ("true" if node.value else "false"), _ATOM

    def visit_BoolVar(self, node: BoolVar) -> tuple[str, int]:
        return node.name, _ATOM

    def visit_Compare(self, node: Compare) -> tuple[str, int]:
        rhs = node.other if node.other is not None else _fmt_value(node.value)
        return f"{node.var} {node.op} {rhs}", _ATOM

    def visit_InSet(self, node: InSet) -> tuple[str, int]:
        values = ", ".join(_fmt_value(v) for v in sorted(node.values, key=_sort_key))
        return f"{node.var} in {{{values}}}", _ATOM

    def visit_Not(self, node: Not) -> tuple[str, int]:
        return f"not {_fmt(node.arg, _PREFIX)}", _PREFIX

    def visit_Always(self, node: Always) -> tuple[str, int]:
        return self._prefixed("G" + _fmt_interval(node.lo, node.hi), node.arg), _PREFIX

    def visit_Eventually(self, node: Eventually) -> tuple[str, int]:
        return self._prefixed("F" + _fmt_interval(node.lo, node.hi), node.arg), _PREFIX

    def _prefixed(self, op: str, arg: Formula) -> str:
        """``G``/``F`` applied to ``arg``: ``G x``, ``G F x``, else ``G(...)`` (readability)."""
        text, prec = self.visit(arg)
        if prec == _ATOM or (prec == _PREFIX and arg.temporal):  # an atom, or G/F
            return f"{op} {text}"
        return f"{op}({text})"

    def visit_Until(self, node: Until) -> tuple[str, int]:
        op = ("W" if node.weak else "U") + _fmt_interval(node.lo, node.hi)
        return f"{_fmt(node.lhs, _PREFIX)} {op} {_fmt(node.rhs, _UNTIL)}", _UNTIL

    def visit_And(self, node: And) -> tuple[str, int]:
        return " and ".join(_fmt(a, _UNTIL) for a in node.args), _AND

    def visit_Or(self, node: Or) -> tuple[str, int]:
        return " or ".join(_fmt(a, _AND) for a in node.args), _OR

    def visit_Implies(self, node: Implies) -> tuple[str, int]:
        return f"{_fmt(node.lhs, _OR)} -> {_fmt(node.rhs, _IMPLIES)}", _IMPLIES


_PRINTER = _Printer()


def format_formula(formula: Formula) -> str:
    """Canonical text of ``formula``; ``parse(format_formula(f), voc) == f``.

    Parenthesises only where precedence requires it (and around nested ``and``/``or``
    chains, which the parser would otherwise flatten); intervals are printed in
    seconds and omitted when they are ``[0, inf]``; set members are sorted.
    """
    return _fmt(formula, _IMPLIES)
