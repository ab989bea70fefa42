"""The scenario's safety evidence section: trace variables, conditions, use cases, coverage.

In a scenario file it is the ``validation:`` mapping, written inline or kept in a
file of its own that the scenario names (``validation: {file: x.yaml}``; entries
written beside ``file`` are added to the file's)::

    variables:               # trace variable -> recorded channel
      safmod: robot.safety_mode
      HS: safety_controller.HS
    macros:                  # named sub-formulas, usable in every formula below
      HS_e: safmod in {normal, hguid, ssmon, pflim} and rngDet in {near, close}
    conditions:              # safety conditions: must hold on every run
      "HS:detected": G((HS_e and HS == inact) -> (HS_e U[0, 0.5s] HS == act))
      "HS:not_mis":            # ... or a formula with a description, shown wherever the condition is
        formula: G(not HS == mis)
        description: The operator is never harmed near the welder.
    use_cases:               # classifiers: a run exercises the use case iff it holds
      U2: F(otab and lgtBar)
    coverage:                # situation coverage criteria
      wact x oloc: {variables: [wact, oloc]}
    bins:                    # domains of numeric variables for coverage
      sep: {edges: [0.5, 1.0, 2.0]}
    domains:                 # the values coverage counts, where not all of them
      safmod: [normal, ssmon, pflim, stopped]
    guides:                  # for `cellsim falsify`: situations whose meeting stresses the controller
      HS while HRW is handled: {meet: [HS_e, HRW != inact], conditions: ["HS:detected"]}
    waive:                   # a default condition this scenario is not judged by, and why
      TrueSSM: the arm has no speed and separation monitoring in this cell

Beside its own conditions, a scenario is judged by the default conditions its modules give
(``ModuleKind.conditions``: the harm service's ``NoHarm`` and ``NoClamping``, each speed and
separation monitor's ``TrueSSM``), unless it waives one with a reason.

Every recorded scalar channel is a trace variable under its own name
(``robot.safety_mode``) too; ``variables`` adds the short names the formulas use.
The formula language is documented in ``docs/condition-language.md``.
"""

from __future__ import annotations

import itertools
import math
from bisect import bisect_right
from dataclasses import dataclass, field



@dataclass
class CoverageCriterion:
    """A coverage criterion: the value combinations of ``variables`` that should be seen.

    * ``variables``: the trace variables combined (one variable: single-variable
      coverage); each must be in the vocabulary, numeric ones need :class:`NumberBins`.
    * ``description``: free text for reports.
    * ``when``: a propositional formula (macros allowed); only instants where it holds
      count as observations.  Empty: all instants count.
    * ``use_case``: only runs classified with this use case count.  Empty: all runs.
    """

    variables: list[str]
    description: str = ""
    when: str = ""
    use_case: str = ""

    def __post_init__(self) -> None:
        if not self.variables:
            raise ValueError("a coverage criterion needs at least one variable")
        for name in self.variables:
            if not isinstance(name, str) or not name:
                raise ValueError(f"coverage variables must be non-empty names, got {name!r}")
        repeated = sorted({v for v in self.variables if self.variables.count(v) > 1})
        if repeated:
            raise ValueError(f"variables listed twice in a criterion: {', '.join(repeated)}")


def number_text(x: float) -> str:
    """Shortest exact text of ``x``: ``1.0 -> "1"``, ``0.25 -> "0.25"``."""
    x += 0.0  # -0.0 -> 0.0
    if x == int(x) and abs(x) < 1e15:
        return str(int(x))
    return repr(x)


@dataclass
class NumberBins:
    """The bins of a numeric variable: finite, strictly increasing ``edges`` e0 < ... < en.

    Bins are half-open, ``[a, b)``, so a value equal to an edge falls in the bin that
    *starts* there; ``n + 1`` edges give ``n + 2`` bins, named (edges in their shortest
    exact form: ``1.0`` is written ``1``)::

        "<e0"        v < e0
        "e0..e1"     e0 <= v < e1      (one per pair of consecutive edges)
        ">=en"       v >= en

    e.g. ``edges: [0.5, 1, 2]`` gives ``<0.5``, ``0.5..1``, ``1..2``, ``>=2``.
    """

    edges: list[float]
    """Finite and strictly increasing, in the variable's unit; n edges give n + 1 bins."""

    def __post_init__(self) -> None:
        if not self.edges:
            raise ValueError("bins need at least one edge")
        for e in self.edges:
            if isinstance(e, bool) or not isinstance(e, (int, float)) or not math.isfinite(e):
                raise ValueError(f"bin edges must be finite numbers, got {e!r}")
        self.edges = [float(e) for e in self.edges]
        for a, b in itertools.pairwise(self.edges):
            if not a < b:
                raise ValueError(
                    f"bin edges must be strictly increasing: {number_text(a)} is followed by "
                    f"{number_text(b)}"
                )

    @property
    def labels(self) -> tuple[str, ...]:
        """The bin names, in increasing order."""
        text = [number_text(e) for e in self.edges]
        inner = [f"{a}..{b}" for a, b in itertools.pairwise(text)]
        return (f"<{text[0]}", *inner, f">={text[-1]}")

    def index(self, value: float) -> int:
        """The position of ``value``'s bin in :attr:`labels`."""
        return bisect_right(self.edges, value)


@dataclass
class Described:
    """A formula with a sentence saying what it means (for a condition or a use case)."""

    formula: str
    """The MTL formula."""
    description: str = ""
    """What it means, in the cell's words: shown wherever the formula is."""


@dataclass
class Guide:
    """Two situations the falsification search steers towards each other (``cellsim falsify``).

    A run's distance to the guide is the time between the moments the two formulas
    held (s), or minus how long they held together; see docs/falsify.md.
    """

    meet: list[str]
    """The two formulas, each over the section's variables and macros."""
    conditions: list[str] = field(default_factory=list)
    """The conditions whose violation their meeting leads to; default: every condition."""
    description: str = ""
    """Why their meeting matters, in the cell's words."""

    def __post_init__(self) -> None:
        from cellsim.config.typed_yaml import FieldError

        if len(self.meet) != 2:
            raise FieldError("meet", f"must list exactly two formulas, got {len(self.meet)}")


def formula_of(entry: str | Described) -> str:
    """The formula text of a condition or use case, written bare or with a description."""
    return entry.formula if isinstance(entry, Described) else entry


def description_of(entry: str | Described) -> str:
    return entry.description if isinstance(entry, Described) else ""


@dataclass
class Validation:
    """Safety conditions, use-case classifiers and coverage criteria of a scenario."""

    file: str = ""
    """A YAML file (relative to the scenario) holding this section; entries written
    beside ``file`` extend the file's and replace those of the same name."""
    variables: dict[str, str] = field(default_factory=dict)
    """Trace variable name -> recorded channel (``<module>.<signal>``)."""
    macros: dict[str, str] = field(default_factory=dict)
    """Name -> a sub-formula, usable by name in every formula of the section."""
    conditions: dict[str, str | Described] = field(default_factory=dict)
    """Condition name -> MTL formula that must hold on every run (or ``{formula, description}``)."""
    use_cases: dict[str, str | Described] = field(default_factory=dict)
    """Use-case name -> MTL formula that holds iff a run exercises the use case (or ``{formula, description}``)."""
    coverage: dict[str, CoverageCriterion] = field(default_factory=dict)
    """Criterion name -> the variables whose value combinations (situations) should be seen;
    at most 100,000 situations each."""
    bins: dict[str, NumberBins] = field(default_factory=dict)
    """Numeric variable -> the bins its coverage counts."""
    domains: dict[str, list[str]] = field(default_factory=dict)
    """Variable -> the values its coverage counts (the designed domain); default: all."""
    verify: dict[str, str | Described] = field(default_factory=dict)
    """Property name -> PCTL checked by ``cellsim verify`` on the abstract model, each double-quoted
    string a formula of the condition language (``Pmax=? [ F "HS == act and oloc == inCell" ]``)."""
    guides: dict[str, Guide] = field(default_factory=dict)
    """Guide name -> two situations ``cellsim falsify`` steers runs to meet (``{meet: [A, B]}``)."""
    waive: dict[str, str] = field(default_factory=dict)
    """A default condition (``NoHarm``, ``NoClamping``, ``TrueSSM``: every cell is judged by them) -> why this
    scenario is not; every check and report prints the reason."""

    @property
    def is_empty(self) -> bool:
        """Whether the section says nothing at all (no variables, macros, conditions, use cases, coverage or bins)."""
        return not (
            self.variables or self.macros or self.conditions or self.use_cases or self.coverage or self.bins
            or self.domains or self.verify or self.guides or self.waive
        )
