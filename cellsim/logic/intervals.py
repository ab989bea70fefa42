"""Finite unions of half-open intervals ``[a, b)`` within a domain ``[start, end)``.

These are the satisfaction sets of :mod:`cellsim.logic.mtl`: the set of instants at
which a formula holds on a piecewise-constant, right-continuous trace is always such
a union, so Boolean connectives and the metric shift operations can be computed
exactly, in time linear in the number of intervals.

The representation is a flat, sorted Python list ``[a0, b0, a1, b1, ...]`` with
``start <= a0 < b0 < a1 < b1 < ... <= end``: intervals are non-empty, disjoint and
*not adjacent* (``b_i < a_{i+1}``), hence canonical - two sets are equal iff their
lists are.  The module-level ``*_flat`` functions work on such lists directly and
are what the evaluator uses; :class:`IntervalSet` is the public, checked wrapper.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Iterable, Iterator

__all__ = [
    "IntervalSet",
    "union_flat",
    "intersection_flat",
    "complement_flat",
    "eventually_flat",
    "always_flat",
    "until0_flat",
]

Flat = list  # [a0, b0, a1, b1, ...]


# --------------------------------------------------------------------------- flat kernels


def union_flat(a: Flat, b: Flat) -> Flat:
    """Union of two canonical lists."""
    if not a:
        return b
    if not b:
        return a
    out: Flat = []
    i = j = 0
    na, nb = len(a), len(b)
    while i < na or j < nb:
        if j >= nb or (i < na and a[i] <= b[j]):
            lo, hi = a[i], a[i + 1]
            i += 2
        else:
            lo, hi = b[j], b[j + 1]
            j += 2
        if out and lo <= out[-1]:  # overlapping or adjacent: merge
            if hi > out[-1]:
                out[-1] = hi
        else:
            out.append(lo)
            out.append(hi)
    return out


def intersection_flat(a: Flat, b: Flat) -> Flat:
    """Intersection of two canonical lists (the result is canonical: see module doc)."""
    if not a or not b:
        return []
    out: Flat = []
    i = j = 0
    na, nb = len(a), len(b)
    while i < na and j < nb:
        ai, bj = a[i], b[j]
        lo = ai if ai > bj else bj
        ha, hb = a[i + 1], b[j + 1]
        if ha < hb:
            hi = ha
            i += 2
        else:
            hi = hb
            j += 2
            if ha == hb:
                i += 2
        if lo < hi:
            out.append(lo)
            out.append(hi)
    return out


def complement_flat(a: Flat, start: float, end: float) -> Flat:
    """``[start, end)`` minus ``a``."""
    if not a:
        return [start, end]
    out = [start, *a, end]
    if out[-2] == end:  # a reaches the end: drop the empty last gap
        del out[-2:]
    if out[1] == start:  # a begins at start: drop the empty first gap
        del out[:2]
    return out


def eventually_flat(a: Flat, lo: float, hi: float, start: float) -> Flat:
    """``{t : [t+lo, t+hi] meets a}`` - the *observed-witness* ``F[lo, hi]``.

    An interval ``[l, r)`` of ``a`` is met by the closed window ``[t+lo, t+hi]`` iff
    ``t+lo < r`` and ``t+hi >= l``, i.e. ``t in [l-hi, r-lo)``: half-open again.
    ``hi`` may be ``inf``.  No end-of-trace rule is applied here.
    """
    out: Flat = []
    for k in range(0, len(a), 2):
        l = a[k] - hi
        r = a[k + 1] - lo
        if l < start:
            l = start
        if r <= l:
            continue
        if out and l <= out[-1]:
            if r > out[-1]:
                out[-1] = r
        else:
            out.append(l)
            out.append(r)
    return out


def always_flat(a: Flat, lo: float, hi: float, start: float, end: float) -> Flat:
    """``{t : a holds on all of [t+lo, t+hi] ∩ [start, end)}`` (vacuous past the end)."""
    return complement_flat(
        eventually_flat(complement_flat(a, start, end), lo, hi, start), start, end
    )


def until0_flat(phi: Flat, psi: Flat, hi: float) -> Flat:
    """``phi U[0, hi] psi`` with observed witnesses only.

    ``t`` satisfies it iff some ``t' in [t, t+hi]`` has ``psi(t')`` and ``phi`` holds on
    ``[t, t')``.  For ``t`` in a maximal ``phi``-interval ``[p, q)`` the admissible
    witnesses are the ``psi``-instants in ``[p, q]`` - including ``q`` itself, where
    ``phi`` has just stopped (``t' = q`` needs ``phi`` only on ``[t, q)``).  A
    ``psi``-interval ``[c, d)`` meeting ``[p, q)`` contributes ``[max(p, c-hi), min(d, q))``;
    one starting exactly at ``q`` contributes ``[max(p, q-hi), q)``.  Outside ``phi``
    only ``t' = t`` is possible, so ``psi`` itself is added.
    """
    if not psi:
        return []
    out: Flat = []
    j = 0
    npsi = len(psi)
    for i in range(0, len(phi), 2):
        p, q = phi[i], phi[i + 1]
        while j < npsi and psi[j + 1] <= p:  # psi-intervals entirely before p
            j += 2
        k = j
        while k < npsi:
            c = psi[k]
            if c > q:
                break
            d = psi[k + 1]
            top = d if d < q else q  # == q also when psi starts exactly at q
            lo = c - hi
            if lo < p:
                lo = p
            if lo >= top:  # psi starts at q and hi == 0: no t < q reaches it
                pass
            elif out and lo <= out[-1]:
                if top > out[-1]:
                    out[-1] = top
            else:
                out.append(lo)
                out.append(top)
            k += 2
    return union_flat(out, psi)


# --------------------------------------------------------------------------- public class


class IntervalSet:
    """An immutable finite union of half-open intervals ``[a, b)`` within ``[start, end)``.

    Supports ``|`` (union), ``&`` (intersection), ``-`` (difference), ``~``
    (complement within the domain), ``t in s``, iteration over ``(a, b)`` pairs,
    equality and hashing.  Sets combined with each other must share the domain.
    """

    __slots__ = ("start", "end", "_flat")

    start: float
    end: float
    _flat: Flat

    def __init__(
        self, start: float, end: float, intervals: Iterable[tuple[float, float]] = ()
    ) -> None:
        start, end = float(start), float(end)
        if not (start < end) or math.isinf(start) or math.isinf(end):
            raise ValueError(f"bad domain [{start}, {end})")
        pieces = []
        for a, b in intervals:
            a, b = max(float(a), start), min(float(b), end)
            if a < b:
                pieces.append((a, b))
        pieces.sort()
        flat: Flat = []
        for a, b in pieces:
            if flat and a <= flat[-1]:
                if b > flat[-1]:
                    flat[-1] = b
            else:
                flat.extend((a, b))
        self.start, self.end, self._flat = start, end, flat

    @classmethod
    def from_flat(cls, start: float, end: float, flat: Flat) -> IntervalSet:
        """Wrap a canonical flat list without checking it (used by the evaluator)."""
        obj = cls.__new__(cls)
        obj.start, obj.end, obj._flat = start, end, flat
        return obj

    @classmethod
    def full(cls, start: float, end: float) -> IntervalSet:
        return cls(start, end, [(start, end)])

    @classmethod
    def empty(cls, start: float, end: float) -> IntervalSet:
        return cls(start, end)

    # ----- inspection

    @property
    def flat(self) -> tuple[float, ...]:
        """The boundaries ``(a0, b0, a1, b1, ...)``."""
        return tuple(self._flat)

    @property
    def intervals(self) -> list[tuple[float, float]]:
        f = self._flat
        return [(f[k], f[k + 1]) for k in range(0, len(f), 2)]

    def __iter__(self) -> Iterator[tuple[float, float]]:
        return iter(self.intervals)

    def __len__(self) -> int:
        """Number of (maximal) intervals."""
        return len(self._flat) // 2

    def is_empty(self) -> bool:
        return not self._flat

    def is_full(self) -> bool:
        return self._flat == [self.start, self.end]

    def __contains__(self, t: float) -> bool:
        return bisect_right(self._flat, t) % 2 == 1 and self.start <= t < self.end

    def first(self) -> float | None:
        """The earliest instant in the set (sets are left-closed, so it is attained)."""
        return self._flat[0] if self._flat else None

    def measure(self) -> float:
        f = self._flat
        return sum(f[k + 1] - f[k] for k in range(0, len(f), 2))

    # ----- algebra

    def _same_domain(self, other: IntervalSet) -> None:
        if not isinstance(other, IntervalSet):
            raise TypeError(f"expected an IntervalSet, got {type(other).__name__}")
        if (self.start, self.end) != (other.start, other.end):
            raise ValueError(
                f"domains differ: [{self.start}, {self.end}) vs [{other.start}, {other.end})"
            )

    def union(self, other: IntervalSet) -> IntervalSet:
        self._same_domain(other)
        return IntervalSet.from_flat(self.start, self.end, union_flat(self._flat, other._flat))

    def intersection(self, other: IntervalSet) -> IntervalSet:
        self._same_domain(other)
        return IntervalSet.from_flat(
            self.start, self.end, intersection_flat(self._flat, other._flat)
        )

    def complement(self) -> IntervalSet:
        return IntervalSet.from_flat(
            self.start, self.end, complement_flat(self._flat, self.start, self.end)
        )

    def difference(self, other: IntervalSet) -> IntervalSet:
        return self.intersection(other.complement())

    __or__ = union
    __and__ = intersection
    __sub__ = difference
    __invert__ = complement

    # ----- metric shifts (observed part only; see cellsim.logic.mtl for the
    #       end-of-trace rules built on top of them)

    def eventually(self, lo: float, hi: float) -> IntervalSet:
        """``{t : [t+lo, t+hi] ∩ [start, end) meets self}``."""
        return IntervalSet.from_flat(
            self.start, self.end, eventually_flat(self._flat, lo, hi, self.start)
        )

    def always(self, lo: float, hi: float) -> IntervalSet:
        """``{t : [t+lo, t+hi] ∩ [start, end) ⊆ self}`` (vacuously true past the end)."""
        return IntervalSet.from_flat(
            self.start, self.end, always_flat(self._flat, lo, hi, self.start, self.end)
        )

    # ----- dunder

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, IntervalSet):
            return NotImplemented
        return (self.start, self.end, self._flat) == (other.start, other.end, other._flat)

    def __hash__(self) -> int:
        return hash((self.start, self.end, tuple(self._flat)))

    def __repr__(self) -> str:
        body = ", ".join(f"({a!r}, {b!r})" for a, b in self.intervals)
        return f"IntervalSet({self.start!r}, {self.end!r}, [{body}])"
