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
from cellsim.logic.syntax import (
    Always, And, BoolVar, Compare, Const, Eventually, Formula, Implies, InSet, Not, Or, Until, format_formula,
    variables_of,
)

_ATOMS = (Compare, InSet, BoolVar, Const)


class Explainer:
    """Explanations of formulas on one trace (sharing the evaluator's satisfaction sets)."""

    def __init__(self, evaluator: TraceEvaluator, macros: dict[str, Formula] | None = None):
        self.evaluator = evaluator
        self.trace = evaluator.trace
        self.names = {formula: name for name, formula in (macros or {}).items()}
        """A macro's expanded formula -> its name (conditions hold macros expanded)."""

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
        t = at if isinstance(formula, Always) else self.trace.start
        body = formula.arg if isinstance(formula, Always) else formula
        lo, hi = self._window(body, t) or (t, t)
        rows = {}
        for part in self._parts(formula):  # every one: the atom a condition waited for comes last
            name = self._name(part)
            if name not in rows:
                rows[name] = [[round(a, 6), round(b, 6)] for a, b in self.evaluator.satisfaction(part)]
        return {"at": at, "window": [round(lo, 6), round(hi, 6)], "rows": rows}

    def _window(self, f: Formula, t: float) -> tuple[float, float] | None:
        """The first temporal window of ``f`` evaluated at ``t`` (the consequent's, for ``->``)."""
        if isinstance(f, Implies):
            return self._window(f.rhs, t)
        if isinstance(f, (Until, Eventually, Always)):
            return t + f.lo, min(t + f.hi, self.trace.end)
        if isinstance(f, Not):
            return self._window(f.arg, t)
        if isinstance(f, (And, Or)):
            return next((w for w in (self._window(a, t) for a in f.args) if w), None)
        return None

    def _parts(self, f: Formula):
        """The macros and atoms of ``f``, outermost first (a macro's own parts follow it)."""
        if f in self.names or (isinstance(f, _ATOMS) and not isinstance(f, Const)):
            yield f
        if isinstance(f, _ATOMS):
            return
        for child in _children(f):
            yield from self._parts(child)

    # -- what held --------------------------------------------------------------------------
    def _true(self, f: Formula, t: float) -> str:
        if f in self.names:
            since = self._since(f, t)
            parts = ", ".join(self._part(p, t) for p in _conjuncts(f))
            return f"{self.names[f]} true from {instant(since)} ({parts})"
        if isinstance(f, And):
            return "; ".join(self._true(a, t) for a in f.args)
        if isinstance(f, _ATOMS):
            return self._value(f, t)
        if isinstance(f, Not):
            return self._false(f.arg, t)
        return f"{format_formula(f)} true"

    def _part(self, f: Formula, t: float) -> str:
        """One conjunct of a macro that held: a macro's name, an atom's values."""
        if f in self.names:
            return self.names[f]
        if isinstance(f, _ATOMS):
            return self._value(f, t)
        if isinstance(f, Or):  # the alternative that held
            held = [a for a in f.args if self._holds(a, t)]
            return self._part(held[0], t) if held else format_formula(f)
        return format_formula(f)

    # -- what failed ------------------------------------------------------------------------
    def _false(self, f: Formula, t: float, named: bool = True) -> str:
        if named and f in self.names:
            return f"{self.names[f]} false ({self._false(f, t, named=False)})"
        if isinstance(f, Implies):
            return f"{self._true(f.lhs, t)}; {self._false(f.rhs, t)}"
        if isinstance(f, Until):
            return self._until(f, t)
        if isinstance(f, Eventually):
            lo, hi = t + f.lo, t + f.hi
            window = f"from {instant(lo)} " + (f"to {instant(hi)}" if math.isfinite(hi) and hi < self.trace.end else "to the end of the run")
            return f"{self._stayed(f.arg, lo, min(hi, self.trace.end))}; {self._name(f.arg)} never held {window}"
        if isinstance(f, Always):
            first = self._first(self._not_sat(f.arg), t + f.lo, t + f.hi)
            if first is None:
                return f"{format_formula(f)} does not hold"
            return f"{self._name(f.arg)} failed at {instant(first)}: {self._false(f.arg, first)}"
        if isinstance(f, Not):
            return self._true(f.arg, t)
        if isinstance(f, And):
            failed = [a for a in f.args if not self._holds(a, t)]
            return "; ".join(self._false(a, t) for a in failed) if failed else f"{format_formula(f)} does not hold"
        if isinstance(f, Or):
            return "; ".join(self._false(a, t) for a in f.args)
        if isinstance(f, _ATOMS):
            return self._value(f, t)
        return f"{format_formula(f)} does not hold at {instant(t)}"

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

    def _value(self, f: Formula, t: float) -> str:
        """An atom's variables and their values at ``t``: ``rloc = sharedTbl``, ``lgtBar`` / ``not lgtBar``."""
        if isinstance(f, Const):
            return "true" if f.value else "false"
        if isinstance(f, BoolVar):
            return f.name if self._at(f.name, t) else f"not {f.name}"
        names = [f.var] + ([f.other] if isinstance(f, Compare) and f.other else [])
        return ", ".join(f"{n} = {_text(self._at(n, t))}" for n in names)

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


def _children(f: Formula) -> tuple[Formula, ...]:
    if isinstance(f, (And, Or)):
        return f.args
    if isinstance(f, (Implies, Until)):
        return (f.lhs, f.rhs)
    if isinstance(f, (Not, Always, Eventually)):
        return (f.arg,)
    return ()


def _conjuncts(f: Formula) -> tuple[Formula, ...]:
    return f.args if isinstance(f, And) else (f,)


def _text(value) -> str:
    return value_text(value, none="no value")
