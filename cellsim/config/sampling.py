"""Samplers: how a test campaign draws values for a scenario's configuration points.

A configuration point names one or more dotted paths into the scenario (for
example the five operator waits ``operator.waypoints.<name>.wait``).  Campaign
config gives each configuration point a sampler, written in YAML as a mapping
with a ``kind``::

    operator_waits: {kind: simplex, total: 20.0, minimum: 0.5}
    range_thresholds: {kind: uniform, low: 0.5, high: 1.5}

Values are in the units of the paths they are written to (seconds for waits,
metres for distances); the samplers themselves are unit-agnostic.

Run ``index`` of a campaign with seed ``seed`` gets its configuration from
:func:`draw_configuration` and its simulation seed from :func:`run_seed`.  Both
are pure functions of their arguments, so any run can be redrawn on its own, in
any process, in any order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from cellsim.config.typed_yaml import FieldError

__all__ = [
    "SIMPLEX_RESOLUTION",
    "ChoiceSampler",
    "Sampler",
    "SimplexSampler",
    "UniformSampler",
    "draw_configuration",
    "run_seed",
    "sample",
]

_STEPS = 1_000_000
SIMPLEX_RESOLUTION = 1.0 / _STEPS
"""Grid of :class:`SimplexSampler` values, in the paths' unit (1e-6, i.e. 1 µs for waits)."""

_SEED_BITS = 31
_SEED_MASK = (1 << _SEED_BITS) - 1


def _finite(name: str, value: float) -> None:
    if not math.isfinite(value):
        raise FieldError(name, f"must be a finite number, got {value}")


def _on_grid(name: str, value: float) -> int:
    """``value`` as a whole number of :data:`SIMPLEX_RESOLUTION` steps, or ``FieldError``."""
    steps = round(value * _STEPS)
    if abs(steps) >= 2**53:
        raise FieldError(name, f"must be below {2**53 / _STEPS:.3g} (so that steps of "
                         f"{SIMPLEX_RESOLUTION:g} are exact), got {value!r}")
    if steps / _STEPS != value:
        raise FieldError(name, f"must be a whole multiple of {SIMPLEX_RESOLUTION:g} "
                         f"(the simplex sampler's resolution), got {value!r}")
    return steps


@dataclass
class UniformSampler:
    """Each path independently uniform in ``[low, high]`` (the paths' unit)."""

    kind: Literal["uniform"]
    low: float
    """Smallest value drawn; in the valid range of every key it is drawn for."""
    high: float
    """Largest value drawn; greater than ``low`` and in the valid range of every key it is drawn for."""

    def __post_init__(self) -> None:
        _finite("low", self.low)
        _finite("high", self.high)
        if not self.low < self.high:
            raise FieldError("high", f"must be greater than low ({self.low}), got {self.high}")


@dataclass
class ChoiceSampler:
    """Each path independently one of ``values``, all equally likely.

    Values keep their YAML type: ``true`` stays a bool, ``3`` an int (``bool`` and
    ``int`` come first in the union so that neither is read as a float).
    """

    kind: Literal["choice"]
    values: list[bool | int | float | str]
    """The candidates: non-empty, no value listed twice, numbers in the valid range of every key drawn for."""

    def __post_init__(self) -> None:
        if not self.values:
            raise FieldError("values", "must list at least one value")
        seen: set[tuple[type, object]] = set()
        for i, value in enumerate(self.values):
            if type(value) not in (bool, int, float, str):
                raise FieldError(f"values.{i}", f"must be a number, true/false or a string, got {value!r}")
            if isinstance(value, float) and not math.isfinite(value):
                raise FieldError(f"values.{i}", f"must be finite, got {value}")
            if (type(value), value) in seen:
                raise FieldError(f"values.{i}", f"{value!r} is listed twice (values are equally "
                                 "likely; list each once)")
            seen.add((type(value), value))


@dataclass
class SimplexSampler:
    """``n`` values, one per path, each ``>= minimum``, summing exactly to ``total``.

    The paper's test vectors: five operator waits (s) summing to 20 s.  The draw
    is uniform over that simplex: ``minimum`` each plus a flat Dirichlet share of
    the remainder ``total - n * minimum``.  Values lie on a grid of
    :data:`SIMPLEX_RESOLUTION` (1e-6): the Dirichlet cut points of the remainder
    are floored to whole steps, so the values sum to ``total`` exactly in whole
    steps and to floating-point accuracy as floats.  ``total`` and ``minimum`` must
    therefore be whole multiples of the resolution (at most 6 decimals).
    """

    kind: Literal["simplex"]
    total: float
    """Sum of the ``n`` values; positive, a multiple of 1e-6, and no value drawn beyond the valid range of its key."""
    minimum: float = 0.0
    """Lower bound of every value; ``n * minimum`` must not exceed ``total``; in the valid range of every key."""

    def __post_init__(self) -> None:
        _finite("total", self.total)
        _finite("minimum", self.minimum)
        if self.total <= 0:
            raise FieldError("total", f"must be positive, got {self.total}")
        if self.minimum < 0:
            raise FieldError("minimum", f"must be non-negative, got {self.minimum}")
        if self.minimum > self.total:
            raise FieldError("minimum", f"must not exceed total ({self.total}), got {self.minimum}")
        _on_grid("total", self.total)
        _on_grid("minimum", self.minimum)


Sampler = UniformSampler | ChoiceSampler | SimplexSampler
"""Any sampler; YAML picks the class by its ``kind``."""


def _uniform(s: UniformSampler, n_paths: int, rng: np.random.Generator) -> list[float]:
    # low + (high - low) * u may round one ulp past high; clamp into [low, high].
    return [min(s.high, max(s.low, float(x))) for x in rng.uniform(s.low, s.high, size=n_paths)]


def _choice(s: ChoiceSampler, n_paths: int, rng: np.random.Generator) -> list[bool | int | float | str]:
    return [s.values[int(i)] for i in rng.integers(len(s.values), size=n_paths)]


def _simplex(s: SimplexSampler, n_paths: int, rng: np.random.Generator) -> list[float]:
    total, minimum = _on_grid("total", s.total), _on_grid("minimum", s.minimum)
    remainder = total - n_paths * minimum
    if remainder < 0:
        raise ValueError(f"simplex sampler: {n_paths} paths x minimum {s.minimum} = "
                         f"{n_paths * minimum / _STEPS:g} exceeds total {s.total}")
    # Cut points of [0, remainder] from a flat Dirichlet, floored to whole steps
    # (monotone, so the shares are >= 0); the last cut is the end itself, so the
    # shares sum to `remainder` exactly.
    cuts = np.cumsum(rng.dirichlet(np.ones(n_paths)))
    ends = np.floor(remainder * (cuts / cuts[-1])).astype(np.int64)
    ends[-1] = remainder
    shares = np.diff(ends, prepend=0)
    return [(minimum + int(k)) / _STEPS for k in shares]


def sample(sampler: Sampler, n_paths: int, rng: np.random.Generator) -> list:
    """One value per path (plain Python float/int/str/bool, JSON-serialisable).

    Raises ``ValueError`` if ``n_paths < 1`` or a simplex cannot fit ``n_paths``
    minimums into its total.
    """
    if n_paths < 1:
        raise ValueError(f"n_paths must be at least 1, got {n_paths}")
    match sampler:
        case UniformSampler():
            return _uniform(sampler, n_paths, rng)
        case ChoiceSampler():
            return _choice(sampler, n_paths, rng)
        case SimplexSampler():
            return _simplex(sampler, n_paths, rng)
    raise TypeError(f"not a sampler: {sampler!r}")


def _check_seed(name: str, value: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"{name} must be a non-negative integer, got {value!r}")


def draw_configuration(samplers: dict[str, Sampler], points: dict[str, list[str]],
                       seed: int, index: int) -> dict[str, object]:
    """The configuration of campaign run ``index``: ``{dotted_path: value}``.

    ``samplers`` maps configuration point names to samplers; ``points`` maps every
    configuration point name of the scenario to its paths.  Only the sampled
    points appear in the result.  The draw is a pure function of the arguments:
    one generator seeded with ``[seed, index]`` serves the sampled points in
    sorted name order, so run ``index`` gets the same configuration however many
    runs are drawn and in whatever order.

    Raises ``ValueError`` for a sampler naming an unknown configuration point, a
    path sampled by two points, or a negative ``seed``/``index``.
    """
    _check_seed("seed", seed)
    _check_seed("index", index)
    unknown = sorted(set(samplers) - set(points))
    if unknown:
        raise ValueError(f"unknown configuration point(s) {', '.join(unknown)}; "
                         f"known: {', '.join(sorted(points)) or 'none'}")
    rng = np.random.default_rng([seed, index])
    config: dict[str, object] = {}
    owner: dict[str, str] = {}
    for name in sorted(samplers):
        paths = points[name]
        for path in paths:
            if path in owner:
                raise ValueError(f"path {path} is sampled by both configuration points "
                                 f"{owner[path]} and {name}")
            owner[path] = name
        config.update(zip(paths, sample(samplers[name], len(paths), rng)))
    return config


def run_seed(seed: int, index: int) -> int:
    """The simulation seed of campaign run ``index``: an integer in ``[0, 2**31)``.

    A key drawn from ``seed`` (NumPy ``SeedSequence``) is added to ``index``
    modulo 2**31 and the sum is scrambled by an invertible integer hash
    (xor-shifts and odd multiplications modulo 2**31).  The map from ``index`` is
    therefore a bijection: for one campaign seed, distinct indices below 2**31
    give distinct simulation seeds, and neighbouring runs get unrelated ones.
    """
    _check_seed("seed", seed)
    _check_seed("index", index)
    key = int(np.random.SeedSequence(seed).generate_state(1, dtype=np.uint32)[0])
    x = (key + index) & _SEED_MASK
    for multiplier in (0x45D9F3B, 0x119DE1F3):
        x ^= x >> 16
        x = (x * multiplier) & _SEED_MASK
    return x ^ (x >> 16)


def describe_sampling(samplers: dict[str, Sampler], points: dict[str, list[str]], duration: float | None = None,
                      overrides: tuple[str, ...] = ()) -> str:
    """The distribution a campaign's runs are drawn from, in words: what a bound on them holds under; ``duration``
    (s) and ``overrides`` (the campaign's ``--set``s), what every run has in common, are part of it."""
    parts = []
    for name in sorted(samplers):
        s, paths = samplers[name], points.get(name, [])
        keys = ", ".join(paths)
        if isinstance(s, UniformSampler):
            parts.append(f"{name} ({keys}): each uniform in [{s.low:g}, {s.high:g}]")
        elif isinstance(s, ChoiceSampler):
            parts.append(f"{name} ({keys}): each one of {', '.join(map(str, s.values))}, equally likely")
        else:
            parts.append(f"{name} ({keys}): uniform over the values of at least {s.minimum:g} summing to {s.total:g}")
    drawn = "; ".join(parts) if parts else "no configuration point is sampled: every run has the scenario's configuration"
    common = [f"{duration:g} s long" if duration is not None else "",
              f"with {', '.join(overrides)}" if overrides else ""]
    common = " ".join(c for c in common if c)
    return f"{drawn}; every run {common}, each with its own simulation seed, drawn from the campaign seed" if common \
        else f"{drawn}; each run with its own simulation seed, drawn from the campaign seed"
