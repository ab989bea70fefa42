"""Situation coverage: which combinations of variable values the recorded runs exercised.

Each trace variable has a finite *domain* for coverage purposes: the values of an
enumeration (in declaration order), ``false``/``true`` for a boolean, and the *bins*
of a number (:class:`NumberBins`), or the values a scenario lists for the variable
(its designed domain: a cell whose risk model never commands hand guiding leaves
``hguid`` out of the safety mode's domain).  A *criterion* (:class:`CoverageCriterion`) is a
list of variables - one for single-variable coverage, several for combinations - and
its *situations* are the tuples of the Cartesian product of their domains (the first
variable varies slowest; this "domain order" is used for every list of situations).

What counts as observed.  A run *covers* a situation of a criterion iff

* the run exercised the criterion's ``use_case`` (when one is given), and
* for a **non-zero duration** of the trace's domain ``[start, end)``, all of the
  criterion's variables simultaneously had the situation's values (numbers: values in
  the situation's bins) and the criterion's ``when`` formula held.

Consequently an instant where values merely touch (one variable changes at the very
instant another one does) covers nothing, and neither does a stretch where a variable
is undefined (before its first sample, or after a ``None`` sample; also a numeric NaN).
If a criterion's variable, or a variable its ``when`` formula reads, is missing from
the trace altogether, the run covers none of that criterion's situations.  A value
left out of a narrowed domain covers nothing; any other recorded value outside the
variable's domain is an error (the vocabulary and the recorder disagree).

:meth:`CoverageModel.observe` computes a run's covered situations exactly, by a sweep
over the change points of the involved signals (and of the ``when`` set), without
sampling; the result is plain JSON data, stored per run.
:meth:`CoverageModel.merge` takes the union over runs and lists what is missing.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from cellsim.config.validation import CoverageCriterion, NumberBins
from cellsim.logic.mtl import TraceEvaluator
from cellsim.logic.syntax import (
    BoolDomain,
    Domain,
    EnumDomain,
    Formula,
    FormulaError,
    NumberDomain,
    parse,
    variables_of,
)
from cellsim.logic.trace import Trace

__all__ = [
    "MAX_SITUATIONS",
    "CoverageModel",
    "CriterionCoverage",
    "CoverageSummary",
    "situation_name",
]

RunCoverage = dict[str, list[list[str]]]
"""Per criterion, the situations one run covered (lists of value names, domain order)."""

_UNDEFINED = -1  # value code of an undefined stretch

MAX_SITUATIONS = 100_000
"""Most situations one criterion may have (reports name every situation never covered)."""




def situation_name(
    variables: list[str] | tuple[str, ...], values: list[str] | tuple[str, ...]
) -> str:
    """The name of a situation, e.g. ``"wact=welding, oloc=inCell"``."""
    if len(variables) != len(values):
        raise ValueError(f"{len(variables)} variables but {len(values)} values")
    return ", ".join(f"{var}={value}" for var, value in zip(variables, values))


# --------------------------------------------------------------------------- compiled model


@dataclass(frozen=True)
class _Axis:
    """A variable's coverage domain: value names and the mapping of recorded values."""

    variable: str
    labels: tuple[str, ...]
    code: Callable[[object], int]  # recorded value -> index in labels, or _UNDEFINED

    def codes(self, values: list) -> np.ndarray:
        return np.fromiter((self.code(v) for v in values), dtype=np.int64, count=len(values))


def _out_of_domain(variable: str, value: object, labels: tuple[str, ...]) -> ValueError:
    return ValueError(
        f"variable {variable!r}: recorded value {value!r} is not in its domain "
        f"({', '.join(labels)})"
    )


def _axis(variable: str, domain: Domain, bins: NumberBins | None, only: list[str] | None = None) -> _Axis:
    if isinstance(domain, NumberDomain):
        assert bins is not None
        labels = bins.labels

        def code(value: object) -> int:
            if value is None:
                return _UNDEFINED
            try:
                x = float(value)  # type: ignore[arg-type]
            except (TypeError, ValueError):
                raise _out_of_domain(variable, value, labels) from None
            return _UNDEFINED if math.isnan(x) else bins.index(x)

        return _Axis(variable, labels, code)
    if isinstance(domain, BoolDomain):
        labels, values = ("false", "true"), (False, True)
    elif isinstance(domain, EnumDomain):
        labels = values = domain.values
    else:
        raise TypeError(f"not a domain: {domain!r}")
    ignored: frozenset = frozenset()
    if only is not None:
        kept = [i for i, label in enumerate(labels) if label in only]
        ignored = frozenset(values[i] for i in range(len(labels)) if i not in kept)
        labels, values = tuple(labels[i] for i in kept), tuple(values[i] for i in kept)
    lookup = {v: i for i, v in enumerate(values)}

    def code(value: object) -> int:
        if value is None:
            return _UNDEFINED
        try:
            return lookup[value]  # type: ignore[index]
        except (KeyError, TypeError):
            if value in ignored:
                return _UNDEFINED  # a value left out of the coverage domain
            raise _out_of_domain(variable, value, labels) from None

    return _Axis(variable, labels, code)


@dataclass(frozen=True)
class _Criterion:
    """A criterion checked against the vocabulary, with its ``when`` formula parsed."""

    name: str
    config: CoverageCriterion
    axes: tuple[_Axis, ...]
    when: Formula | None
    reads: frozenset[str]  # every trace variable needed: the axes' and the when formula's

    @property
    def total(self) -> int:
        return math.prod(len(a.labels) for a in self.axes)

    def key(self, codes: tuple[int, ...]) -> int:
        """Mixed-radix number of a situation (first variable most significant)."""
        k = 0
        for axis, c in zip(self.axes, codes):
            k = k * len(axis.labels) + c
        return k

    def labels_of(self, key: int) -> list[str]:
        out: list[str] = []
        for axis in reversed(self.axes):
            key, c = divmod(key, len(axis.labels))
            out.append(axis.labels[c])
        return out[::-1]

    def key_of_labels(self, values: object) -> int:
        if not isinstance(values, (list, tuple)) or len(values) != len(self.axes):
            raise ValueError(
                f"criterion {self.name!r}: {values!r} is not a situation of "
                f"({', '.join(self.config.variables)})"
            )
        codes = []
        for axis, value in zip(self.axes, values):
            if value not in axis.labels:
                raise ValueError(
                    f"criterion {self.name!r}: {value!r} is not a value of {axis.variable} "
                    f"({', '.join(axis.labels)})"
                )
            codes.append(axis.labels.index(value))
        return self.key(tuple(codes))


class CoverageError(ValueError):
    """A coverage problem at ``key`` (dotted, within the validation section)."""

    def __init__(self, key: str, message: str):
        super().__init__(message)
        self.key = key


def _suggestion(name: str, candidates: list[str]) -> str:
    folded = [c for c in candidates if c.lower() == name.lower()]
    close = folded or difflib.get_close_matches(name, candidates, n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


# --------------------------------------------------------------------------- summary


@dataclass
class CriterionCoverage:
    """Merged coverage of one criterion: counts and the missing situations' names."""

    variables: list[str]
    description: str
    covered: int
    total: int
    missing: list[str]
    axes: list[list[str]] = field(default_factory=list)
    """Each variable's values (or bins), in domain order: the criterion's situations are their product."""
    runs: list[int] = field(default_factory=list)
    """How many runs covered each situation, in the order of the product of ``axes`` (first varies slowest)."""

    @property
    def fraction(self) -> float:
        return self.covered / self.total


@dataclass
class CoverageSummary:
    """Coverage of all criteria merged over a set of runs."""

    criteria: dict[str, CriterionCoverage] = field(default_factory=dict)

    @property
    def covered(self) -> int:
        return sum(c.covered for c in self.criteria.values())

    @property
    def total(self) -> int:
        return sum(c.total for c in self.criteria.values())

    @property
    def overall(self) -> float:
        """Covered situations over all situations of all criteria (1.0 with no criteria)."""
        return self.covered / self.total if self.total else 1.0

    def to_json(self) -> dict:
        """``{"overall": {covered, total, fraction}, "criteria": {name: {...}}}``."""
        return {
            "overall": {"covered": self.covered, "total": self.total, "fraction": self.overall},
            "criteria": {
                name: {
                    "variables": list(c.variables),
                    "description": c.description,
                    "covered": c.covered,
                    "total": c.total,
                    "fraction": c.fraction,
                    "missing": list(c.missing),
                    "axes": [list(a) for a in c.axes],
                    "runs": list(c.runs),
                }
                for name, c in self.criteria.items()
            },
        }


# --------------------------------------------------------------------------- model


class CoverageModel:
    """Coverage criteria compiled against a vocabulary; see the module docstring."""

    def __init__(self, criteria: dict[str, _Criterion]) -> None:
        self._criteria = criteria

    @classmethod
    def compile(
        cls,
        criteria: Mapping[str, CoverageCriterion],
        vocabulary: Mapping[str, Domain],
        macros: Mapping[str, str] | None = None,
        bins: Mapping[str, NumberBins] | None = None,
        domains: Mapping[str, list[str]] | None = None,
    ) -> CoverageModel:
        """Check ``criteria`` against ``vocabulary`` and parse their ``when`` formulas.

        ``bins`` gives the bins of the numeric variables (every numeric variable used by
        a criterion needs some; bins of other variables are an error).  ``domains``
        narrows the coverage domain of an enumeration or boolean to the listed values
        (``true``/``false`` for booleans): the situations a cell is designed to reach.
        Other recorded values of that variable then cover nothing.  Raises
        :class:`ValueError` naming the criterion (or variable) at fault.
        """
        bins = dict(bins or {})
        domains = dict(domains or {})
        for var, only in domains.items():
            key = f"domains.{var}"
            domain = vocabulary.get(var)
            if not isinstance(domain, (EnumDomain, BoolDomain)):
                what = "unknown" if domain is None else "numeric (give it bins)"
                raise CoverageError(key, f"domain given for variable {var!r}, which is {what}" + _suggestion(var, list(vocabulary)))
            allowed = domain.values if isinstance(domain, EnumDomain) else ("false", "true")
            wrong = [v for v in only if v not in allowed]
            if wrong or not only:
                raise CoverageError(
                    f"{key}.{list(only).index(wrong[0])}" if wrong else key,
                    f"domain of {var!r}: {', '.join(map(repr, wrong)) or 'no values'}; "
                    f"choose among {', '.join(allowed)}"
                )
        for var in bins:
            if not isinstance(vocabulary.get(var), NumberDomain):
                what = "unknown" if var not in vocabulary else "not numeric"
                numeric = [v for v, d in vocabulary.items() if isinstance(d, NumberDomain)]
                raise CoverageError(
                    f"bins.{var}",
                    f"bins given for variable {var!r}, which is {what}"
                    + _suggestion(var, numeric)
                )
        axes: dict[str, _Axis] = {}
        compiled: dict[str, _Criterion] = {}
        for name, crit in criteria.items():
            for i, var in enumerate(crit.variables):
                if var in axes:
                    continue
                if var not in vocabulary:
                    raise CoverageError(
                        f"coverage.{name}.variables.{i}",
                        f"coverage criterion {name!r}: unknown variable {var!r}"
                        + _suggestion(var, list(vocabulary))
                    )
                domain = vocabulary[var]
                if isinstance(domain, NumberDomain) and var not in bins:
                    raise CoverageError(
                        f"coverage.{name}.variables.{i}",
                        f"coverage criterion {name!r}: numeric variable {var!r} needs bins "
                        f"(give its bin edges, e.g. {var}: {{edges: [0.5, 1]}})"
                    )
                axes[var] = _axis(var, domain, bins.get(var), domains.get(var))
            when: Formula | None = None
            reads = frozenset(crit.variables)
            if crit.when.strip():
                try:
                    when = parse(crit.when, vocabulary, macros, allow_temporal=False)
                except FormulaError as e:
                    raise CoverageError(f"coverage.{name}.when", f"coverage criterion {name!r}: when: {e}") from e
                reads |= variables_of(when)
            compiled[name] = _Criterion(
                name, crit, tuple(axes[v] for v in crit.variables), when, reads
            )
            if compiled[name].total > MAX_SITUATIONS:
                sizes = " x ".join(f"{len(axes[v].labels)} {v}" for v in crit.variables)
                raise CoverageError(
                    f"coverage.{name}",
                    f"coverage criterion {name!r} has {compiled[name].total:,} situations ({sizes}), "
                    f"more than the {MAX_SITUATIONS:,} a criterion may have: use fewer variables, bins or values",
                )
        return cls(compiled)

    @property
    def criteria(self) -> dict[str, CoverageCriterion]:
        """The criteria, by name."""
        return {name: c.config for name, c in self._criteria.items()}

    def observe(
        self,
        trace: Trace,
        use_cases: set[str],
        evaluator: TraceEvaluator | None = None,
    ) -> RunCoverage:
        """Per criterion, the situations ``trace`` covers, in domain order.

        ``use_cases`` are the use cases the run was classified with; ``evaluator``, if
        given, must be a :class:`TraceEvaluator` of ``trace`` (to share sub-formulas
        with other conditions).  Each situation is a list of value names (enumeration
        value, ``"true"``/``"false"``, bin name).
        """
        if evaluator is None:
            evaluator = TraceEvaluator(trace)
        elif evaluator.trace is not trace:
            raise ValueError("the evaluator was made for another trace")
        pieces: dict[str, tuple[np.ndarray, np.ndarray]] = {}

        def pieces_of(axis: _Axis) -> tuple[np.ndarray, np.ndarray]:
            """Start times of ``axis``'s constant pieces and their value codes (cached)."""
            got = pieces.get(axis.variable)
            if got is None:
                los, _, values = trace.segments(axis.variable)
                got = (np.asarray(los, dtype=np.float64), axis.codes(values))
                pieces[axis.variable] = got
            return got

        result: RunCoverage = {}
        for name, crit in self._criteria.items():
            if (
                crit.config.use_case and crit.config.use_case not in use_cases
            ) or not crit.reads.issubset(trace.signals):
                result[name] = []
                continue
            keys = _covered_keys(crit, trace, evaluator, pieces_of)
            result[name] = [crit.labels_of(k) for k in keys]
        return result

    def merge(self, per_run: list[RunCoverage]) -> CoverageSummary:
        """The union of the runs' coverage, with the missing situations named.

        Every run must have an entry for every criterion (entries for other criteria
        are ignored); a recorded situation that is not in the criterion's universe is
        an error - both mean the runs were recorded with a different coverage model.
        """
        summary = CoverageSummary()
        for name, crit in self._criteria.items():
            counts = [0] * crit.total
            for i, run in enumerate(per_run):
                if name not in run:
                    raise ValueError(f"run {i} has no coverage for criterion {name!r}")
                for k in {crit.key_of_labels(s) for s in run[name]}:
                    counts[k] += 1
            covered = {k for k, n in enumerate(counts) if n}
            missing = [
                situation_name(crit.config.variables, crit.labels_of(k))
                for k in range(crit.total)
                if k not in covered
            ]
            summary.criteria[name] = CriterionCoverage(
                variables=list(crit.config.variables),
                description=crit.config.description,
                covered=len(covered),
                total=crit.total,
                missing=missing,
                axes=[list(a.labels) for a in crit.axes],
                runs=counts,
            )
        return summary


def _covered_keys(
    crit: _Criterion,
    trace: Trace,
    evaluator: TraceEvaluator,
    pieces_of: Callable[[_Axis], tuple[np.ndarray, np.ndarray]],
) -> list[int]:
    """Sweep: the situation keys that hold on a non-empty piece of ``trace``.

    Between consecutive points of the union of all change points (and of the ``when``
    boundaries) every variable is constant, so each such elementary piece - of
    positive length, the points being distinct - is classified by its left end.
    """
    columns = [pieces_of(axis) for axis in crit.axes]
    if any(len(los) == 0 for los, _ in columns):  # a variable never defined in [start, end)
        return []
    bounds = [np.array([trace.start, trace.end]), *(los for los, _ in columns)]
    when_flat = None
    if crit.when is not None:
        when_flat = np.asarray(evaluator.satisfaction(crit.when).flat, dtype=np.float64)
        bounds.append(when_flat)
    lefts = np.unique(np.concatenate(bounds))[:-1]
    keep = np.ones(len(lefts), dtype=bool)
    if when_flat is not None:
        keep &= np.searchsorted(when_flat, lefts, side="right") % 2 == 1
    key = np.zeros(len(lefts), dtype=np.int64)
    for axis, (los, codes) in zip(crit.axes, columns):
        i = np.searchsorted(los, lefts, side="right") - 1
        code = np.where(i >= 0, codes[np.maximum(i, 0)], _UNDEFINED)
        keep &= code != _UNDEFINED
        key = key * len(axis.labels) + code
    return np.unique(key[keep]).tolist()
