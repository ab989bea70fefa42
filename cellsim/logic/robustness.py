"""How far a condition was from changing its verdict on a run: its robustness, in space and in time.

A verdict says whether a condition held; a search for violations needs to know how
close a run came. Both readings here are defined from the boolean semantics itself,
by moving the condition's own constants, so the end-of-trace rules carry over
unchanged and the sign always agrees with the verdict (positive: held, negative:
violated, zero: on the boundary):

* **space** (the units of the quantities compared, m or m/s): the largest ``r``
  by which every numeric threshold can be moved against the condition and it still
  holds (``speed <= 0.5`` read as ``speed <= 0.5 - r`` where it counts for the
  condition, ``speed <= 0.5 + r`` where it is negated); when it is violated, minus
  the least such move in its favour that makes it hold. ``inf`` (``-inf``) when no
  threshold could change the verdict: a condition on phases and modes only.
* **time** (s): the largest ``r`` by which every bounded deadline can be shortened
  and the condition still holds (``F[a, b]`` and ``U[a, b]`` read with ``b - r``;
  ``G[a, b]``, whose window is what must hold, with ``b + r``; the other way round
  where negated); when violated, minus the least lengthening that makes it hold.
  For a detection condition ``G(e -> (e U[0, w] detected))`` it is the slack of the
  slowest detection against ``w``, Donze and Maler's time robustness for that one
  event (how much later it could have come).

Not moved (and so contributing no margin): ``==`` and ``!=`` on numbers, a
comparison between two variables, unbounded windows, and ``W``'s window (its two
readings move in opposite directions).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from .mtl import TraceEvaluator
from .syntax import (Always, And, Compare, Const, Eventually, Formula, Implies, Not, Until, Visitor,
                     numeric_comparisons, walk)
from .trace import TICKS_PER_SECOND, Trace, to_ticks

_SHIFTABLE = {"<", "<=", ">", ">="}


@dataclass(frozen=True)
class Robustness:
    """A condition's margins on a run: ``space`` in the compared quantities' units, ``time`` in seconds."""

    space: float
    time: float

    def to_json(self) -> dict:
        return {"space": _finite_or_text(self.space), "time": _finite_or_text(self.time)}


def _finite_or_text(x: float) -> float | str:
    return x if math.isfinite(x) else ("inf" if x > 0 else "-inf")


def shifted(node: Formula, space: float, time: float, positive: bool = True) -> Formula:
    """``node`` made harder by ``space`` on every numeric threshold and ``time`` on every bounded
    deadline (easier for negative amounts); ``positive``: whether ``node`` counts for the condition
    (False under a negation or on the left of ``->``)."""
    return _Shift(space, time).visit(node, positive)


class _Shift(Visitor):
    """:func:`shifted`, one operator at a time: ``visit(node, positive)``."""

    def __init__(self, space: float, time: float) -> None:
        self.space, self.time = space, time

    def _children(self, node: Formula, positive: bool) -> Formula:
        """``node`` with each of its sub-formulas shifted, all counting as ``node`` does."""
        return node.with_children(*(self.visit(child, positive) for child in node.children()))

    def visit_Const(self, node: Const, positive: bool) -> Formula:
        return node

    visit_BoolVar = visit_InSet = visit_Const

    def visit_Compare(self, node: Compare, positive: bool) -> Formula:
        value = node.threshold
        if self.space == 0 or node.op not in _SHIFTABLE or value is None:
            return node
        delta = (1.0 if positive else -1.0) * self.space
        return replace(node, value=value - delta if node.op in ("<", "<=") else value + delta)

    def visit_Not(self, node: Not, positive: bool) -> Formula:
        return Not(self.visit(node.arg, not positive))

    def visit_And(self, node: And, positive: bool) -> Formula:
        return self._children(node, positive)

    visit_Or = visit_And

    def visit_Implies(self, node: Implies, positive: bool) -> Formula:
        return Implies(self.visit(node.lhs, not positive), self.visit(node.rhs, positive))

    def visit_Eventually(self, node: Eventually, positive: bool) -> Formula:
        moved = self._children(node, positive)
        if math.isinf(node.hi):
            return moved
        hi = node.hi - (1.0 if positive else -1.0) * self.time
        return replace(moved, hi=hi) if hi >= node.lo else Const(False)

    def visit_Always(self, node: Always, positive: bool) -> Formula:
        moved = self._children(node, positive)
        if math.isinf(node.hi):
            return moved
        hi = node.hi + (1.0 if positive else -1.0) * self.time
        return replace(moved, hi=hi) if hi >= node.lo else Const(True)

    def visit_Until(self, node: Until, positive: bool) -> Formula:
        moved = self._children(node, positive)
        if node.weak or math.isinf(node.hi):
            return moved
        hi = node.hi - (1.0 if positive else -1.0) * self.time
        return replace(moved, hi=hi) if hi >= node.lo else Const(False)


def robustness(formula: Formula, trace: Trace) -> Robustness:
    """The space and time robustness of ``formula`` at the start of ``trace`` (see the module)."""

    def holds(space: float = 0.0, time: float = 0.0) -> bool:
        return TraceEvaluator(trace).evaluate(shifted(formula, space, time)).holds

    verdict = holds()
    return Robustness(_space(formula, trace, holds, verdict), _time(formula, trace, holds, verdict))


def _space(formula: Formula, trace: Trace, holds, verdict: bool) -> float:
    """Searched over the only moves at which a verdict can change: the distances from each threshold to the values its
    variable took (0 too: a value on its threshold). The verdict changes at a move (a strict comparison) or just after
    it (a non-strict one), so each move is tried, and a point between it and the next (past the largest: beyond it);
    tightening a held formula (loosening a violated one) never brings its verdict back, so the first change is
    bisected for."""
    moves = sorted(_distances(formula, trace) | {0.0})
    sign = 1.0 if verdict else -1.0  # held: how far it can be tightened; violated: loosened

    def same(r: float) -> bool:
        return holds(space=sign * r) == verdict

    points = []  # (a move to try, the robustness if the verdict has changed there)
    for k, move in enumerate(moves):
        points.append((move, move))
        after = 0.5 * (move + moves[k + 1]) if k + 1 < len(moves) else move + max(1.0, move)
        points.append((after, move))
    low, high = 0, len(points)  # the first point at which the verdict is no longer the same
    while low < high:
        middle = (low + high) // 2
        if same(points[middle][0]):
            low = middle + 1
        else:
            high = middle
    return sign * (math.inf if low == len(points) else points[low][1])


def _distances(formula: Formula, trace: Trace) -> set[float]:
    out: set[float] = set()
    for node in numeric_comparisons(formula):
        value = node.threshold
        if node.op in _SHIFTABLE and node.var in trace.signals:
            _, _, values = trace.segments(node.var)
            out.update(abs(value - v) for v in values
                       if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v != value)
    return out


def _time(formula: Formula, trace: Trace, holds, verdict: bool) -> float:
    """Bisected over whole ticks (1 ns), the grid every window is evaluated on: exact."""
    windows = [node.hi for node in walk(formula) if _moved_window(node)]
    if not windows:
        return math.inf if verdict else -math.inf
    sign = 1.0 if verdict else -1.0
    # beyond this, every deadline is past the trace's end or shorter than its window's start
    furthest = to_ticks(trace.end - trace.start) + to_ticks(max(windows)) + 1

    def same(ticks: int) -> bool:
        return holds(time=sign * ticks / TICKS_PER_SECOND) == verdict

    if same(furthest):
        return sign * math.inf
    low, high = 0, furthest  # the verdict is the same at low, changed at high
    while high - low > 1:
        middle = (low + high) // 2
        if same(middle):
            low = middle
        else:
            high = middle
    return low / TICKS_PER_SECOND if verdict else -high / TICKS_PER_SECOND


def _moved_window(node: Formula) -> bool:
    """Whether ``node`` has a deadline the time margin moves: a bounded window, not ``W``'s."""
    return node.temporal and math.isfinite(node.hi) and not (isinstance(node, Until) and node.weak)


def meeting(first: Formula, second: Formula, trace: Trace) -> float:
    """How far two situations were from holding together on ``trace`` (s): a falsification guide.

    Positive: the shortest time between an instant where ``first`` held and one where
    ``second`` did (``inf`` when either never held); zero: one began as the other
    ended; negative: they held together, for minus that long in total. Smaller is
    closer to their meeting.
    """
    evaluator = TraceEvaluator(trace)
    a, b = evaluator.satisfaction(first), evaluator.satisfaction(second)
    together = a.intersection(b)
    if not together.is_empty():
        return -together.measure()
    gaps = [max(lo2 - hi1, lo1 - hi2) for lo1, hi1 in a for lo2, hi2 in b]
    return min(gaps, default=math.inf)
