"""Why a safety condition is violated, in one sentence.

At the first violation of a condition (``violated_at``; the run's start for a
condition that is not a ``G``), :func:`explain` says what the formula required
and what the record shows then: the macros and atoms that held (a macro by its
name, with the instant from which it held and the atoms that made it), and what
failed to come in the window the condition required, for example::

    HRW_e true from 12.10 s (permissive, working, rloc = sharedTbl, lgtBar); HRW = inact;
    HRW stayed inact; HRW == act required by 12.60 s

The explanation is read off the same satisfaction sets the verdict came from
(``TraceEvaluator``), so it cannot disagree with the verdict.

:meth:`Explainer.evidence` gives the same reading as data, for a timeline to
draw: the window the condition required (``[lo, hi]``, seconds) and, for each
macro and atom of the condition, the intervals over which it held.
"""

from __future__ import annotations

import math

from cellsim.channels import value_text
from cellsim.numbers import instant
from cellsim.logic.mtl import TraceEvaluator
from cellsim.logic.syntax import Always, And, Formula, Not, Until, Visitor, format_formula, variables_of, walk


class Explainer:
    """Explanations of formulas on one trace (sharing the evaluator's satisfaction sets)."""

    def __init__(self, evaluator: TraceEvaluator, macros: dict[str, Formula] | None = None):
        self.evaluator = evaluator
        self.trace = evaluator.trace
        self.names = {formula: name for name, formula in (macros or {}).items()}
        """A macro's expanded formula -> its name (conditions hold macros expanded)."""
        self._window, self._held, self._conjunct = _Window(self), _Held(self), _Conjunct(self)
        self._failed, self._value = _Failed(self), _Value(self)

    def explain(self, formula: Formula, at: float) -> str:
        """Why ``formula`` does not hold at the start (its first violation at ``at``, for a ``G``)."""
        if isinstance(formula, Always):
            return self._false(formula.arg, at)
        return self._false(formula, self.trace.start)

    def evidence(self, formula: Formula, at: float) -> dict:
        """What a timeline draws beside the sentence: ``{"at", "window", "rows"}``.

        ``window`` is ``[lo, hi]`` (s): where the condition required something at its
        first violation ``at`` (an instant, ``lo == hi``, for a state it forbids);
        ``rows`` maps each macro (by name) and atom (as written) of the condition, in
        the order they appear, to the intervals ``[[from, to], ...]`` (s) where it held.
        """
        t, body = (at, formula.arg) if isinstance(formula, Always) else (self.trace.start, formula)
        lo, hi = self._window.visit(body, t) or (t, t)
        rows = {}
        for part in self._parts(formula):  # every one: the atom a condition waited for comes last
            name = self._name(part)
            if name not in rows:
                rows[name] = [[round(a, 6), round(b, 6)] for a, b in self.evaluator.satisfaction(part)]
        return {"at": at, "window": [round(lo, 6), round(hi, 6)], "rows": rows}

    def _parts(self, f: Formula):
        """The macros and atoms of ``f``, outermost first (a macro's own parts follow it)."""
        return (node for node in walk(f) if node in self.names or node.variables())

    # -- what held ---------------------------------------------------------------------------
    def _true(self, f: Formula, t: float) -> str:
        if f in self.names:
            since = self._since(f, t)
            parts = ", ".join(self._part(p, t) for p in _conjuncts(f))
            return f"{self.names[f]} true from {instant(since)} ({parts})"
        return self._held.visit(f, t)

    def _part(self, f: Formula, t: float) -> str:
        """One conjunct of a macro that held: a macro's name, an atom's values."""
        if f in self.names:
            return self.names[f]
        return self._conjunct.visit(f, t)

    # -- what failed ------------------------------------------------------------------------
    def _false(self, f: Formula, t: float, named: bool = True) -> str:
        if named and f in self.names:
            return f"{self.names[f]} false ({self._false(f, t, named=False)})"
        return self._failed.visit(f, t)

    def _until(self, f: Until, t: float) -> str:
        lo, hi = t + f.lo, t + f.hi
        end = min(hi, self.trace.end)
        arrived = self._first(self.evaluator.satisfaction(f.rhs), lo, end)
        lhs_ends = self._first(self._not_sat(f.lhs), t, end if arrived is None else arrived)
        wanted = self._name(f.rhs)
        if lhs_ends is not None and not f.weak:
            return f"{self._name(f.lhs)} ended at {instant(lhs_ends)}, before {wanted}"
        if arrived is None:
            by = f"required by {instant(hi)}" if math.isfinite(hi) else "required before the end of the run"
            return f"{self._stayed(f.rhs, t, end)}; {wanted} {by}"
        return f"{format_formula(f)} does not hold at {instant(t)}"

    # -- helpers -----------------------------------------------------------------------------
    def _name(self, f: Formula) -> str:
        return self.names.get(f) or format_formula(f)

    def _holds(self, f: Formula, t: float) -> bool:
        return t in self.evaluator.satisfaction(f)

    def _not_sat(self, f: Formula):
        return self.evaluator.satisfaction(Not(f))

    def _since(self, f: Formula, t: float) -> float:
        for lo, hi in self.evaluator.satisfaction(f):
            if lo <= t < hi:
                return lo
        return t

    @staticmethod
    def _first(intervals, lo: float, hi: float) -> float | None:
        """The first instant of ``intervals`` within ``[lo, hi]``."""
        for a, b in intervals:
            if b > lo and a <= hi:
                return max(a, lo)
        return None

    def _stayed(self, f: Formula, lo: float, hi: float) -> str:
        """What the variables of ``f`` did over ``[lo, hi]``: stayed a value, or went through values."""
        parts = []
        for name in sorted(variables_of(f)):
            signal = self.trace.signals.get(name)
            if signal is None:
                continue
            values = [signal.value_at(lo)] + [v for s, v in zip(signal.times, signal.values) if lo < s <= hi]
            seen = [v for i, v in enumerate(values) if i == 0 or v != values[i - 1]]
            parts.append(f"{name} stayed {_text(seen[0])}" if len(seen) == 1 else f"{name} went {' -> '.join(_text(v) for v in seen)}")
        return "; ".join(parts) or f"{format_formula(f)} never held"

    def _at(self, name: str, t: float):
        signal = self.trace.signals.get(name)
        return None if signal is None else signal.value_at(t)


# The questions the explainer asks of a formula at an instant ``t``, one operator at a time:
# ``visit(f, t)``. They recurse through the explainer's own methods, which name a macro first.


class _Reading:
    """What the questions share: the explainer ``x`` they are asked for."""

    def __init__(self, explainer: Explainer) -> None:
        self.x = explainer


class _Value(_Reading, Visitor):
    """An atom's variables and their values at ``t``: ``rloc = sharedTbl``, ``lgtBar`` / ``not lgtBar``."""

    refused = {name: "an operator has no value of its own: only an atom has"
               for name in ("Not", "And", "Or", "Implies", "Always", "Eventually", "Until")}

    def visit_Const(self, f, t: float) -> str:
        return "true" if f.value else "false"

    def visit_BoolVar(self, f, t: float) -> str:
        return f.name if self.x._at(f.name, t) else f"not {f.name}"

    def visit_Compare(self, f, t: float) -> str:
        return ", ".join(f"{n} = {_text(self.x._at(n, t))}" for n in f.variables())

    visit_InSet = visit_Compare


class _Window(_Reading, Visitor):
    """The first temporal window of ``f`` evaluated at ``t`` (the consequent's, for ``->``), or None."""

    def visit_Const(self, f, t: float) -> None:
        return None

    visit_BoolVar = visit_Compare = visit_InSet = visit_Const

    def visit_Not(self, f, t: float) -> tuple[float, float] | None:
        return self.visit(f.arg, t)

    def visit_And(self, f, t: float) -> tuple[float, float] | None:
        return next((w for w in (self.visit(a, t) for a in f.args) if w), None)

    visit_Or = visit_And

    def visit_Implies(self, f, t: float) -> tuple[float, float] | None:
        return self.visit(f.rhs, t)

    def visit_Always(self, f, t: float) -> tuple[float, float]:
        return t + f.lo, min(t + f.hi, self.x.trace.end)

    visit_Eventually = visit_Until = visit_Always


class _Held(_Reading, Visitor):
    """What held of ``f`` at ``t`` (``f`` not a macro)."""

    def visit_Const(self, f, t: float) -> str:
        return self.x._value.visit(f, t)

    visit_BoolVar = visit_Compare = visit_InSet = visit_Const

    def visit_And(self, f, t: float) -> str:
        return "; ".join(self.x._true(a, t) for a in f.args)

    def visit_Not(self, f, t: float) -> str:
        return self.x._false(f.arg, t)

    def visit_Or(self, f, t: float) -> str:
        return f"{format_formula(f)} true"

    visit_Implies = visit_Always = visit_Eventually = visit_Until = visit_Or


class _Conjunct(_Reading, Visitor):
    """One conjunct of a macro that held (not itself a macro): an atom's values, the alternative that held."""

    def visit_Const(self, f, t: float) -> str:
        return self.x._value.visit(f, t)

    visit_BoolVar = visit_Compare = visit_InSet = visit_Const

    def visit_Or(self, f, t: float) -> str:
        held = [a for a in f.args if self.x._holds(a, t)]
        return self.x._part(held[0], t) if held else format_formula(f)

    def visit_Not(self, f, t: float) -> str:
        return format_formula(f)

    visit_And = visit_Implies = visit_Always = visit_Eventually = visit_Until = visit_Not


class _Failed(_Reading, Visitor):
    """What failed of ``f`` at ``t`` (``f`` not a macro, or named already)."""

    def visit_Const(self, f, t: float) -> str:
        return self.x._value.visit(f, t)

    visit_BoolVar = visit_Compare = visit_InSet = visit_Const

    def visit_Implies(self, f, t: float) -> str:
        return f"{self.x._true(f.lhs, t)}; {self.x._false(f.rhs, t)}"

    def visit_Until(self, f, t: float) -> str:
        return self.x._until(f, t)

    def visit_Eventually(self, f, t: float) -> str:
        x = self.x
        lo, hi = t + f.lo, t + f.hi
        window = f"from {instant(lo)} " + (f"to {instant(hi)}" if math.isfinite(hi) and hi < x.trace.end else "to the end of the run")
        return f"{x._stayed(f.arg, lo, min(hi, x.trace.end))}; {x._name(f.arg)} never held {window}"

    def visit_Always(self, f, t: float) -> str:
        x = self.x
        first = x._first(x._not_sat(f.arg), t + f.lo, t + f.hi)
        if first is None:
            return f"{format_formula(f)} does not hold"
        return f"{x._name(f.arg)} failed at {instant(first)}: {x._false(f.arg, first)}"

    def visit_Not(self, f, t: float) -> str:
        return self.x._true(f.arg, t)

    def visit_And(self, f, t: float) -> str:
        failed = [a for a in f.args if not self.x._holds(a, t)]
        return "; ".join(self.x._false(a, t) for a in failed) if failed else f"{format_formula(f)} does not hold"

    def visit_Or(self, f, t: float) -> str:
        return "; ".join(self.x._false(a, t) for a in f.args)


def _conjuncts(f: Formula) -> tuple[Formula, ...]:
    return f.args if isinstance(f, And) else (f,)


def _text(value) -> str:
    return value_text(value, none="no value")
