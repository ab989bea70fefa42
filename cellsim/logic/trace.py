"""Recorded runs as piecewise-constant signals, the input of :mod:`cellsim.logic.mtl`.

A :class:`Signal` is right-continuous and piecewise constant: ``values[i]`` holds on
``[times[i], times[i+1])`` and the last value holds until the end of the trace.  A
:class:`Trace` bundles the signals of a run with its observed time domain
``[start, end)``.

Undefined stretches: a variable whose first sample is after ``start`` is *undefined*
before that sample, and a sample whose value is ``None`` makes it undefined until the
next sample.  Every atom (comparison, membership, boolean variable) that reads an
undefined variable is **false** there - so ``HS == act`` and ``HS != act`` are both
false before ``HS`` is first recorded, and ``not HS == act`` is true.

Time resolution: the evaluator works on a fixed grid of :data:`TICKS_PER_SECOND`
ticks (1 ns). Every time stamp, the trace's bounds and every bound of a formula
are rounded to it once, and all arithmetic after that is on integers, so window
bounds compare exactly: detection 0.5 s after the hazard (7.8 s -> 8.3 s) meets
``U[0, 0.5s]`` although ``8.3 - 0.5 > 7.8`` in binary floating point.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Signal", "Trace", "TICKS_PER_SECOND", "to_ticks", "to_seconds"]

TICKS_PER_SECOND = 1_000_000_000
"""The time resolution of evaluation: 1 ns, the resolution of recorded time stamps."""


def to_ticks(t: float) -> int | float:
    """``t`` seconds on the tick grid (an exact integer); infinities stay infinite."""
    if t == math.inf or t == -math.inf:
        return t
    return round(t * TICKS_PER_SECOND)


def to_seconds(ticks: int) -> float:
    """Ticks back to seconds (the float nearest to the decimal value)."""
    return ticks / TICKS_PER_SECOND


@dataclass
class Signal:
    """A right-continuous piecewise-constant signal.

    ``times`` (float64, strictly increasing) are the instants where the value is
    (re)set; ``values[i]`` holds on ``[times[i], times[i+1])``, the last one until the
    end of the trace.  Values are ``str`` (enumerations), ``bool`` or ``float``;
    ``None`` marks the variable undefined.
    """

    times: np.ndarray
    values: list

    def __post_init__(self) -> None:
        times = np.asarray(self.times, dtype=np.float64)
        if times.ndim != 1:
            raise ValueError("Signal.times must be one-dimensional")
        values = list(self.values)
        if len(values) != len(times):
            raise ValueError(
                f"Signal has {len(times)} times but {len(values)} values"
            )
        if not np.all(np.isfinite(times)):
            raise ValueError("Signal.times must be finite")
        if len(times) > 1 and not np.all(np.diff(times) > 0):
            raise ValueError("Signal.times must be strictly increasing")
        self.times = times
        self.values = values

    @classmethod
    def from_samples(cls, times: Iterable[float], values: Iterable[object]) -> Signal:
        """A signal from periodic samples, dropping samples that repeat the previous value.

        Recording at the control rate gives one sample per step; only the changes
        matter for evaluation, and keeping only them makes evaluation much cheaper.
        """
        kept_t: list[float] = []
        kept_v: list[object] = []
        for t, v in zip(times, values, strict=True):
            if kept_v and kept_v[-1] == v and type(kept_v[-1]) is type(v):
                continue
            kept_t.append(float(t))
            kept_v.append(v)
        return cls(np.asarray(kept_t, dtype=np.float64), kept_v)

    def value_at(self, t: float) -> object:
        """The value at time ``t``; ``None`` before the first sample (undefined)."""
        i = int(np.searchsorted(self.times, t, side="right")) - 1
        return None if i < 0 else self.values[i]

    def __len__(self) -> int:
        return len(self.values)


@dataclass
class Trace:
    """The signals of one run over the observed time domain ``[start, end)``.

    Samples before ``start`` only provide the value at ``start``; samples at or after
    ``end`` are ignored.  A trace must not be mutated while it is being evaluated.
    """

    signals: dict[str, Signal]
    start: float
    end: float
    _segments: dict = field(default_factory=dict, init=False, repr=False, compare=False)
    _ticks: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.start) and np.isfinite(self.end)):
            raise ValueError(f"bad trace domain [{self.start}, {self.end})")
        # the bounds lie on the tick grid, so converting them back and forth is exact
        self.start = to_seconds(to_ticks(float(self.start)))
        self.end = to_seconds(to_ticks(float(self.end)))
        if not self.start < self.end:
            raise ValueError(f"bad trace domain [{self.start}, {self.end})")
        for name, signal in self.signals.items():
            if not isinstance(signal, Signal):
                raise TypeError(f"signal {name!r} is a {type(signal).__name__}, not a Signal")

    def value_at(self, name: str, t: float) -> object:
        """Value of variable ``name`` at ``t`` (``None`` when undefined)."""
        return self.signals[name].value_at(t)

    def segments(self, name: str) -> tuple[list[float], list[float], list[object]]:
        """``(los, his, values)``: the constant pieces of ``name`` clipped to ``[start, end)``.

        Pieces are contiguous from the first (clipped) sample to ``end``; the time
        before the first sample, where the variable is undefined, is not covered.
        Cached per trace.
        """
        cached = self._segments.get(name)
        if cached is not None:
            return cached
        try:
            signal = self.signals[name]
        except KeyError:
            raise KeyError(f"trace has no signal for variable {name!r}") from None
        times: Sequence[float] = signal.times.tolist()
        values = signal.values
        start, end = self.start, self.end
        n = len(times)
        first = max(0, int(np.searchsorted(signal.times, start, side="right")) - 1)
        los: list[float] = []
        his: list[float] = []
        vals: list[object] = []
        for i in range(first, n):
            lo = times[i]
            if lo >= end:
                break
            hi = times[i + 1] if i + 1 < n else end
            if hi > end:
                hi = end
            if lo < start:
                lo = start
            los.append(lo)
            his.append(hi)
            vals.append(values[i])
        result = (los, his, vals)
        self._segments[name] = result
        return result

    def tick_segments(self, name: str) -> tuple[list[int], list[int], list[object]]:
        """:meth:`segments` on the tick grid: integer bounds, pieces shorter than a tick dropped.

        Dropping a piece that rounds to nothing keeps the pieces contiguous: the
        next one starts where the dropped one did. Cached per trace.
        """
        cached = self._ticks.get(name)
        if cached is not None:
            return cached
        los, his, vals = self.segments(name)
        lo_t = np.rint(np.asarray(los, dtype=np.float64) * TICKS_PER_SECOND).astype(np.int64).tolist()
        hi_t = np.rint(np.asarray(his, dtype=np.float64) * TICKS_PER_SECOND).astype(np.int64).tolist()
        keep = [i for i in range(len(lo_t)) if lo_t[i] < hi_t[i]]
        if len(keep) < len(lo_t):
            lo_t, hi_t, vals = [lo_t[i] for i in keep], [hi_t[i] for i in keep], [vals[i] for i in keep]
        result = (lo_t, hi_t, vals)
        self._ticks[name] = result
        return result
