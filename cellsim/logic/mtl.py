"""Offline evaluation of metric temporal logic conditions on recorded runs.

The semantics (continuous time, finite trace, end-of-trace rules) are specified in
``docs/condition-language.md``; in short, on the observed domain ``D = [start, end)``:

* ``F[a,b] p`` at t: some t' in [t+a, t+b] ∩ D has p.  If b is finite and the window
  is cut by the end of the trace (t+b >= end), it is *not* counted as violated.
  ``F p`` (b = inf) is strong: a witness must be recorded.
* ``G[a,b] p`` at t: p on all of [t+a, t+b] ∩ D (vacuous beyond the end).
* ``p U[a,b] q`` at t: some t' in [t+a, t+b] ∩ D has q, p holds on [t, t') and, if
  a > 0, p also holds at t+a.  If b is finite and t+b >= end, it also holds when p
  holds on all of [t, end) (no violation observed yet).  ``U`` with b = inf is strong.
* ``p W[a,b] q`` = ``(p U[a,b] q) or G[0,b] p``.

Everything is computed exactly, by interval arithmetic on satisfaction sets (finite
unions of half-open intervals, :class:`~cellsim.logic.intervals.IntervalSet`), not
by sampling, on integer time ticks (1 ns), so bounds such as 0.5 s compare exactly.  Each operator is linear in the number of intervals of its operands.
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass

from .intervals import (
    Flat,
    IntervalSet,
    always_flat,
    complement_flat,
    eventually_flat,
    intersection_flat,
    union_flat,
    until0_flat,
)
from .syntax import (
    Always,
    And,
    BoolVar,
    Compare,
    Const,
    Eventually,
    Formula,
    Implies,
    InSet,
    Not,
    Or,
    Until,
    Visitor,
)
from .trace import Trace, to_seconds, to_ticks

__all__ = ["Evaluation", "IntervalSet", "TraceEvaluator", "satisfaction", "evaluate"]

_ORDER = {"<": operator.lt, "<=": operator.le, ">": operator.gt, ">=": operator.ge}
_ALL = {"==": operator.eq, "!=": operator.ne, **_ORDER}


@dataclass
class Evaluation:
    """What evaluating a formula on a trace gives: whether it holds, and where it first failed.

    Two-valued, and about a formula; the verdict of a safety condition on a run
    (which may also be inconclusive, or lack data) is
    :class:`cellsim.validation.verdict.Verdict`, made from this.

    ``holds`` is the truth value at the start of the trace.  ``violated_at`` is
    ``None`` when the condition holds.  Otherwise, for a condition of the form
    ``G[a,b] p`` (in particular ``G p``) it is the earliest instant of
    ``[start+a, start+b] ∩ [start, end)`` at which ``p`` is false - the first
    violation; for any other condition it is ``start``.
    """

    holds: bool
    violated_at: float | None


def _collect(los: list, his: list, truth) -> Flat:
    """Merge the pieces ``[los[i], his[i])`` whose ``truth[i]`` is true."""
    out: Flat = []
    for lo, hi, ok in zip(los, his, truth):
        if ok:
            if out and out[-1] == lo:
                out[-1] = hi
            else:
                out.append(lo)
                out.append(hi)
    return out


DEFAULT, OPTIMISTIC, PESSIMISTIC = 0, 1, -1
"""How the evaluator reads what lies past the end of the trace.

``DEFAULT`` is the documented semantics (bounded windows cut by the end are not
judged, unbounded eventualities are strong). ``OPTIMISTIC`` gives the set of
instants where the formula holds on *some* continuation of the trace, and
``PESSIMISTIC`` those where it holds on *every* continuation: a verdict at the
start is conclusive when the two agree. Negation swaps them.
"""


class TraceEvaluator(Visitor):
    """Evaluates formulas on one trace, sharing the satisfaction sets of sub-formulas.

    As a :class:`~cellsim.logic.syntax.Visitor`, ``visit(node, mode)`` computes the
    satisfaction set of one operator from its operands' (``_sat``, memoised).

    Sub-formulas are memoised by value (ASTs are hashable), so a macro used twice in
    a condition, or an atom shared by several conditions evaluated with the same
    evaluator, is computed once. Internally every time is an integer number of
    ticks (:data:`~cellsim.logic.trace.TICKS_PER_SECOND`), so window bounds
    compare exactly; results are given back in seconds.
    """

    def __init__(self, trace: Trace) -> None:
        self.trace = trace
        self.start = to_ticks(trace.start)
        self.end = to_ticks(trace.end)
        self._memo: dict[tuple[Formula, int], Flat] = {}

    # ----- public

    def satisfaction(self, formula: Formula) -> IntervalSet:
        """The instants of ``[start, end)`` at which ``formula`` holds."""
        flat = [to_seconds(x) for x in self._sat(formula, DEFAULT)]
        return IntervalSet.from_flat(self.trace.start, self.trace.end, flat)

    def evaluate(self, formula: Formula) -> Evaluation:
        """The :class:`Evaluation` of ``formula`` at the start of the trace."""
        s = self.start
        if isinstance(formula, Always):
            # First violation of G[a,b] p: the earliest instant of the window
            # [s+a, s+b] where p is false (same arithmetic as always_flat).
            bad = complement_flat(self._sat(formula.arg, DEFAULT), s, self.end)
            lo, hi = _bounds(formula)
            for k in range(0, len(bad), 2):
                if bad[k + 1] - lo > s:
                    if bad[k] - hi <= s:
                        return Evaluation(False, to_seconds(max(bad[k], s + lo)))
                    break
            return Evaluation(True, None)
        holds = self._holds_at_start(formula, DEFAULT)
        return Evaluation(holds, None if holds else self.trace.start)

    def conclusive(self, formula: Formula) -> bool:
        """Whether every continuation of the trace past its end gives the same verdict.

        A conservative test: ``True`` means the verdict cannot change however the
        run would have gone on; ``False`` means it might (a recording cut short
        while a hazard was still open, or any safety condition that has held so far).
        """
        return self._holds_at_start(formula, OPTIMISTIC) == self._holds_at_start(formula, PESSIMISTIC)

    def _holds_at_start(self, formula: Formula, mode: int) -> bool:
        flat = self._sat(formula, mode)
        return bool(flat) and flat[0] == self.start

    # ----- recursion

    def _sat(self, node: Formula, mode: int) -> Flat:
        """Canonical flat list of ``node``'s satisfaction set in ticks (memoised; do not mutate)."""
        key = (node, mode)
        result = self._memo.get(key)
        if result is None:
            if mode != DEFAULT and not node.children():
                result = self._sat(node, DEFAULT)  # an atom: what was recorded does not depend on the future
            else:
                result = self.visit(node, mode)
            self._memo[key] = result
        return result

    def visit_Const(self, node: Const, mode: int) -> Flat:
        return [self.start, self.end] if node.value else []

    def visit_BoolVar(self, node: BoolVar, mode: int) -> Flat:
        los, his, vals = self.trace.tick_segments(node.name)
        return _collect(los, his, [v is not None and bool(v) for v in vals])

    def visit_Compare(self, node: Compare, mode: int) -> Flat:
        if node.other is not None:
            return self._compare_vars(node)
        los, his, vals = self.trace.tick_segments(node.var)
        op, c = node.op, node.value
        if op == "==":
            truth = [v == c for v in vals]  # None == c is false
        elif op == "!=":
            truth = [v is not None and v != c for v in vals]
        else:
            f = _ORDER[op]
            truth = [v is not None and f(v, c) for v in vals]
        return _collect(los, his, truth)

    def _compare_vars(self, node: Compare) -> Flat:
        los1, his1, vals1 = self.trace.tick_segments(node.var)
        los2, his2, vals2 = self.trace.tick_segments(node.other)  # type: ignore[arg-type]
        f = _ALL[node.op]
        out: Flat = []
        i = j = 0
        n1, n2 = len(los1), len(los2)
        while i < n1 and j < n2:
            lo = los1[i] if los1[i] > los2[j] else los2[j]
            h1, h2 = his1[i], his2[j]
            hi = h1 if h1 < h2 else h2
            v1, v2 = vals1[i], vals2[j]
            if lo < hi and v1 is not None and v2 is not None and f(v1, v2):
                if out and out[-1] == lo:
                    out[-1] = hi
                else:
                    out.append(lo)
                    out.append(hi)
            if h1 <= h2:
                i += 1
            if h2 <= h1:
                j += 1
        return out

    def visit_InSet(self, node: InSet, mode: int) -> Flat:
        los, his, vals = self.trace.tick_segments(node.var)
        values = node.values
        return _collect(los, his, [v in values for v in vals])

    def visit_Not(self, node: Not, mode: int) -> Flat:
        return complement_flat(self._sat(node.arg, -mode), self.start, self.end)

    def visit_And(self, node: And, mode: int) -> Flat:
        args = node.args
        acc = self._sat(args[0], mode)
        for arg in args[1:]:
            if not acc:
                break
            acc = intersection_flat(acc, self._sat(arg, mode))
        return acc

    def visit_Or(self, node: Or, mode: int) -> Flat:
        full = [self.start, self.end]
        acc = self._sat(node.args[0], mode)
        for arg in node.args[1:]:
            if acc == full:
                break
            acc = union_flat(acc, self._sat(arg, mode))
        return acc

    def visit_Implies(self, node: Implies, mode: int) -> Flat:
        lhs = self._sat(node.lhs, -mode)
        if not lhs:
            return [self.start, self.end]
        return union_flat(complement_flat(lhs, self.start, self.end), self._sat(node.rhs, mode))

    def _cut(self, hi) -> Flat:
        """The instants whose window ``[t+a, t+hi]`` reaches the end: ``t + hi >= end``."""
        s, e = self.start, self.end
        cut = e - hi
        return [cut if cut > s else s, e] if cut < e else []

    def visit_Eventually(self, node: Eventually, mode: int) -> Flat:
        lo, hi = _bounds(node)
        result = eventually_flat(self._sat(node.arg, mode), lo, hi, self.start)
        if mode == OPTIMISTIC or (mode == DEFAULT and hi < math.inf):
            # Windows reaching the end of the trace (t + hi >= end) are not judged.
            result = union_flat(result, self._cut(hi))
        return result

    def visit_Always(self, node: Always, mode: int) -> Flat:
        lo, hi = _bounds(node)
        result = always_flat(self._sat(node.arg, mode), lo, hi, self.start, self.end)
        if mode == PESSIMISTIC:  # only windows seen to the end are sure
            result = intersection_flat(result, complement_flat(self._cut(hi), self.start, self.end))
        return result

    def visit_Until(self, node: Until, mode: int) -> Flat:
        s, e = self.start, self.end
        lo, hi = _bounds(node)
        phi = self._sat(node.lhs, mode)
        psi = self._sat(node.rhs, mode)
        if lo == 0:
            result = until0_flat(phi, psi, hi)
        else:
            # p U[a,b] q  =  G[0,a] p  and  (p U[0,b-a] q) at t+a      (a > 0)
            later = until0_flat(phi, psi, hi - lo)
            result = intersection_flat(
                always_flat(phi, 0, lo, s, e), eventually_flat(later, lo, lo, s)
            )
        if node.weak:
            held = always_flat(phi, 0, hi, s, e)
            if mode == PESSIMISTIC:
                held = intersection_flat(held, complement_flat(self._cut(hi), s, e))
            result = union_flat(result, held)
        elif mode == OPTIMISTIC or (mode == DEFAULT and hi < math.inf):
            # Deadline after the end of the trace: not violated while p has held
            # throughout [t, end).
            cut = e - hi
            if cut < e and phi and phi[-1] == e:
                tail = phi[-2] if phi[-2] > cut else cut
                if tail < s:
                    tail = s
                result = union_flat(result, [tail, e])
        return result


def _bounds(node) -> tuple:
    """A temporal operator's window ``[lo, hi]`` in ticks (``hi`` may be infinite)."""
    return to_ticks(node.lo), to_ticks(node.hi)


def satisfaction(formula: Formula, trace: Trace) -> IntervalSet:
    """The set of instants of ``[trace.start, trace.end)`` at which ``formula`` holds."""
    return TraceEvaluator(trace).satisfaction(formula)


def evaluate(formula: Formula, trace: Trace) -> Evaluation:
    """The :class:`Evaluation` of ``formula`` on ``trace`` (see :class:`Evaluation`)."""
    return TraceEvaluator(trace).evaluate(formula)
