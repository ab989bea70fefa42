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
from .syntax import Always, And, BoolVar, Compare, Const, Eventually, Formula, Implies, InSet, Not, Or, Until
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
    sign = 1.0 if positive else -1.0
    if isinstance(node, (Const, BoolVar, InSet)):
        return node
    if isinstance(node, Compare):
        value = node.value
        if space == 0 or node.op not in _SHIFTABLE or isinstance(value, bool) or not isinstance(value, (int, float)):
            return node
        delta = sign * space
        return replace(node, value=value - delta if node.op in ("<", "<=") else value + delta)
    if isinstance(node, Not):
        return Not(shifted(node.arg, space, time, not positive))
    if isinstance(node, And):
        return And(tuple(shifted(a, space, time, positive) for a in node.args))
    if isinstance(node, Or):
        return Or(tuple(shifted(a, space, time, positive) for a in node.args))
    if isinstance(node, Implies):
        return Implies(shifted(node.lhs, space, time, not positive), shifted(node.rhs, space, time, positive))
    if isinstance(node, Eventually):
        arg = shifted(node.arg, space, time, positive)
        if math.isinf(node.hi):
            return replace(node, arg=arg)
        hi = node.hi - sign * time
        return replace(node, arg=arg, hi=hi) if hi >= node.lo else Const(False)
    if isinstance(node, Always):
        arg = shifted(node.arg, space, time, positive)
        if math.isinf(node.hi):
            return replace(node, arg=arg)
        hi = node.hi + sign * time
        return replace(node, arg=arg, hi=hi) if hi >= node.lo else Const(True)
    if isinstance(node, Until):
        lhs, rhs = shifted(node.lhs, space, time, positive), shifted(node.rhs, space, time, positive)
        if node.weak or math.isinf(node.hi):
            return replace(node, lhs=lhs, rhs=rhs)
        hi = node.hi - sign * time
        return replace(node, lhs=lhs, rhs=rhs, hi=hi) if hi >= node.lo else Const(False)
    raise TypeError(f"not a formula: {node!r}")


def robustness(formula: Formula, trace: Trace) -> Robustness:
    """The space and time robustness of ``formula`` at the start of ``trace`` (see the module)."""

    def holds(space: float = 0.0, time: float = 0.0) -> bool:
        return TraceEvaluator(trace).evaluate(shifted(formula, space, time)).holds

    verdict = holds()
    return Robustness(_space(formula, trace, holds, verdict), _time(formula, trace, holds, verdict))


def _space(formula: Formula, trace: Trace, holds, verdict: bool) -> float:
    """Searched over the only moves at which a verdict can change: the distances from each threshold
    to the values its variable took."""
    moves = sorted(_distances(formula, trace))
    sign = 1.0 if verdict else -1.0  # held: how far it can be tightened; violated: loosened

    def same(r: float) -> bool:
        return holds(space=sign * r) == verdict

    low, high = 0, len(moves)  # the first move at which the verdict is no longer the same
    while low < high:
        middle = (low + high) // 2
        if same(moves[middle]):
            low = middle + 1
        else:
            high = middle
    if low == len(moves):
        return sign * math.inf
    before = moves[low - 1] if low else 0.0
    # between two moves the verdict is constant: it changes just after `before` or at moves[low]
    at = moves[low] if same(0.5 * (before + moves[low])) else before
    return sign * at


def _distances(formula: Formula, trace: Trace) -> set[float]:
    out: set[float] = set()

    def walk(node) -> None:
        if isinstance(node, Compare):
            value = node.value
            if node.op in _SHIFTABLE and not isinstance(value, bool) and isinstance(value, (int, float)) \
                    and node.var in trace.signals:
                _, _, values = trace.segments(node.var)
                out.update(abs(value - v) for v in values
                           if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v != value)
            return
        for child in _children(node):
            walk(child)

    walk(formula)
    return out


def _children(node) -> tuple:
    if isinstance(node, (Not, Eventually, Always)):
        return (node.arg,)
    if isinstance(node, (And, Or)):
        return node.args
    if isinstance(node, (Implies, Until)):
        return (node.lhs, node.rhs)
    return ()


def _time(formula: Formula, trace: Trace, holds, verdict: bool) -> float:
    """Bisected over whole ticks (1 ns), the grid every window is evaluated on: exact."""
    windows = [node.hi for node in _nodes(formula)
               if isinstance(node, (Eventually, Always, Until)) and math.isfinite(node.hi)
               and not (isinstance(node, Until) and node.weak)]
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


def _nodes(node):
    yield node
    for child in _children(node):
        yield from _nodes(child)


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
