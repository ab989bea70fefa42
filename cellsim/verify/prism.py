"""MDPs in the PRISM language: modules of bounded variables and guarded commands, formulas, labels.

A small writer, not a parser: the program is built in Python and written as text,
so Storm (``stormpy.parse_prism_program``) or PRISM itself reads it (only a guard is read
back, against a witness's state: :func:`holds`). Enumerations
are integer variables; ``Enum`` keeps the names of their values, so a state read
back from Storm speaks the cell's words again.

One synchronising action, ``step``, is one control period: every module takes
exactly one ``[step]`` command per period, and all of them read the state before
the period (PRISM's synchronous semantics), as the cell's discrete updates do.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

STEP = "step"
"""The action every module synchronises on: one control period."""


@dataclass(frozen=True)
class Enum:
    """An integer variable whose values have names (index = code)."""

    values: tuple[str, ...]

    def code(self, value: str) -> int:
        return self.values.index(value)


@dataclass(frozen=True)
class Var:
    """A module variable: an integer in [low, high] (an Enum's codes), or a boolean."""

    name: str
    low: int = 0
    high: int = 1
    init: int | bool = 0
    boolean: bool = False
    enum: Enum | None = None

    def declaration(self) -> str:
        if self.boolean:
            return f"{self.name} : bool init {'true' if self.init else 'false'};"
        return f"{self.name} : [{self.low}..{self.high}] init {int(self.init)};"

    def value_of(self, code) -> object:
        """A state's value of this variable, in the cell's words."""
        if self.enum is not None:
            return self.enum.values[int(code)]
        return bool(code) if self.boolean else int(code)


@dataclass(frozen=True)
class Command:
    """``[action] guard -> p1: (x'=e) & ... + p2: ...;`` (one update with probability 1 when ``updates`` has one)."""

    guard: str
    updates: tuple[tuple[str, dict[str, str]], ...]
    """(probability expression, {variable: its next value's expression}); no assignment: ``true``."""
    action: str = STEP

    def text(self) -> str:
        def update(assignments: dict[str, str]) -> str:
            return " & ".join(f"({name}'={expr})" for name, expr in assignments.items()) or "true"

        if len(self.updates) == 1 and self.updates[0][0] in ("1", "1.0"):
            body = update(self.updates[0][1])
        else:
            body = " + ".join(f"{p}:{update(a)}" for p, a in self.updates)
        return f"[{self.action}] {self.guard} -> {body};"


@dataclass
class Module:
    name: str
    variables: list[Var] = field(default_factory=list)
    commands: list[Command] = field(default_factory=list)
    comment: str = ""

    def text(self) -> str:
        lines = [f"// {line}" for line in self.comment.splitlines()] + [f"module {self.name}"]
        lines += [f"  {v.declaration()}" for v in self.variables]
        lines += [""] + [f"  {c.text()}" for c in self.commands]
        return "\n".join(lines + ["endmodule"])


@dataclass
class Program:
    """An MDP: modules, formulas (named expressions) and labels (named state sets), and the reward
    structure "periods" (1 a step): ``R{"periods"}min=? [ F "bad0" ]`` is how soon a bad state can come."""

    modules: list[Module] = field(default_factory=list)
    formulas: dict[str, str] = field(default_factory=dict)
    labels: dict[str, str] = field(default_factory=dict)
    header: str = ""

    def variables(self) -> dict[str, Var]:
        return {v.name: v for m in self.modules for v in m.variables}

    def text(self) -> str:
        """The program in PRISM, its modules in the order given (which is its decision diagrams' variable order)."""
        parts = [f"// {line}" for line in self.header.splitlines()] + ["mdp", ""]
        parts += [f"formula {name} = {expr};" for name, expr in self.formulas.items()]
        parts += [""] + [m.text() + "\n" for m in self.modules]
        parts += [f'label "{name}" = {expr};' for name, expr in self.labels.items()]
        parts += ["", f'rewards "{PERIODS}"', "  true : 1;", "endrewards"]
        return "\n".join(parts) + "\n"


PERIODS = "periods"
"""The reward structure counting steps (periods)."""


_TOKEN = re.compile(r"\s*(?:(\d+)|([A-Za-z_]\w*)|(<=|>=|!=|[=<>!&|()+\-]))")


def holds(expr: str, state: dict) -> bool:
    """Whether a PRISM guard ``expr`` (variables, integers, true/false, ``! & | = != < <= > >= + -`` and brackets)
    holds in a witness's ``state`` (variable -> value): for an abstraction asking which of its guards a witness ends
    in. A variable the state does not hold (outside the property's cone) is an error."""
    tokens = []
    at = 0
    while at < len(expr):
        match = _TOKEN.match(expr, at)
        if match is None or match.end() == at:
            if expr[at:].strip() == "":
                break
            raise ValueError(f"cannot read the guard {expr!r} at {expr[at:]!r}")
        tokens.append(match.group(1) or match.group(2) or match.group(3))
        at = match.end()
    position = 0

    def peek():
        return tokens[position] if position < len(tokens) else None

    def take():
        nonlocal position
        position += 1
        return tokens[position - 1]

    def disjunction():
        value = conjunction()
        while peek() == "|":
            take()
            value = conjunction() or value
        return value

    def conjunction():
        value = negation()
        while peek() == "&":
            take()
            value = negation() and value
        return value

    def negation():
        if peek() == "!":
            take()
            return not negation()
        return comparison()

    def comparison():
        left = sum_()
        op = peek()
        if op in ("=", "!=", "<", "<=", ">", ">="):
            take()
            right = sum_()
            return {"=": left == right, "!=": left != right, "<": left < right, "<=": left <= right,
                    ">": left > right, ">=": left >= right}[op]
        return left

    def sum_():
        value = atom()
        while peek() in ("+", "-"):
            value = value + atom() if take() == "+" else value - atom()
        return value

    def atom():
        token = take()
        if token == "(":
            value = disjunction()
            if take() != ")":
                raise ValueError(f"unbalanced brackets in the guard {expr!r}")
            return value
        if token == "-":
            return -atom()
        if token.isdigit():
            return int(token)
        if token in ("true", "false"):
            return token == "true"
        if token not in state:
            raise KeyError(token)
        return state[token]

    value = disjunction()
    if position != len(tokens):
        raise ValueError(f"cannot read the guard {expr!r} past {tokens[position]!r}")
    return bool(value)
