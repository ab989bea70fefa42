"""Risk models: a safety controller's rules as data.

A risk model names the variables the controller monitors and those it controls,
and for each hazard a phase machine (``inact``, ``act``, ``mit``, ``res``,
``mis`` ...) whose transitions are guarded by conditions over the monitored
variables and all hazards' phases, plus what each phase *demands* of the
controlled variables. The generic engine (``safety_controller.SafetyController``)
executes it; a new cell's controller is a new YAML file, not new code.

Semantics, each control period:

1. Every hazard takes at most one transition: the first one listed, leaving its
   current phase, whose guard holds on the values read this period (all
   hazards see the same snapshot) and, with ``after: d``, has held for d s.
2. Each controlled variable is set to the most restrictive value demanded by any
   hazard in its new phase (``values`` are listed from least to most
   restrictive), or to its ``default`` when no hazard demands one (no default:
   "no request", the machine follows its process).

Guards use the condition language (docs/condition-language.md) without temporal
operators; ``macros`` name sub-conditions (a hazard's detection condition), and
each hazard's name is a variable holding its phase. Monitored variables are
enums, booleans or numbers (``type: number``, with the channel's ``unit``), so
speed-and-separation monitoring compares a measured separation with a distance.
The format is documented in docs/risk-model.md.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Annotated, Any, Callable, Literal

from cellsim.config.typed_yaml import ConfigError, FieldError, Loaded, Range, load_file
from cellsim.logic.predicates import compile_predicate
from cellsim.logic.syntax import BoolDomain, EnumDomain, FormulaError, NumberDomain, parse
from cellsim.vocabulary import HazardPhase

PHASES = HazardPhase.names()
"""The phases of a risk model that declares none (those of the published case study)."""


@dataclass
class Variable:
    type: Literal["enum", "bool", "number"] = "enum"
    values: list[str] = field(default_factory=list)
    """Enum values; for a controlled variable, from least to most restrictive."""
    default: Any = None
    """Controlled variables: the value commanded when no hazard demands one (null: no request)."""
    unit: str | None = None
    """Number variables (monitored only): the SI unit of the channel bound to it (m, m/s)."""

    def __post_init__(self):
        if self.type == "enum" and not self.values:
            raise FieldError("values", "an enum variable needs its values")
        if self.type != "enum" and self.values:
            raise FieldError("values", f"a {self.type} variable has no values list")
        if self.type != "number" and self.unit is not None:
            raise FieldError("unit", "only a number variable has a unit")
        repeated = sorted({str(v) for v in self.values if self.values.count(v) > 1})
        if repeated:  # (a controlled variable's order is its restrictiveness: a value twice would rank it twice)
            raise FieldError("values", f"each value once: {', '.join(repeated)} repeated")

    @property
    def domain(self) -> tuple:
        if self.type == "number":
            return ()
        return tuple(self.values) if self.type == "enum" else (False, True)

    def logic_domain(self):
        if self.type == "number":
            return NumberDomain(self.unit)
        return EnumDomain(tuple(self.values)) if self.type == "enum" else BoolDomain()


@dataclass
class Transition:
    phase: str
    """The phase this transition leaves."""
    to: str
    when: str = "true"
    after: Annotated[float, Range(0.0, 3600.0, unit="s")] = 0.0
    """The guard must have held this long (s) before the transition fires."""


@dataclass
class Hazard:
    transitions: list[Transition]
    description: str = ""
    demands: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Phase -> {controlled variable: value} imposed while the hazard is in that phase."""


@dataclass
class Phases:
    """The phases every hazard of the model goes through: the model's own words."""

    values: list[str] = field(default_factory=lambda: list(PHASES))
    initial: str = "inact"
    """The phase every hazard starts in: not present."""
    mishap: str | None = "mis"
    """The phase that means harm happened (null: the model has none)."""

    def __post_init__(self):
        if not self.values:
            raise FieldError("values", "a risk model needs at least one phase")
        if len(set(self.values)) != len(self.values):
            raise FieldError("values", "phases must differ")
        if self.initial not in self.values:
            raise FieldError("initial", f"'{self.initial}' is not one of the phases ({', '.join(self.values)})")
        if self.mishap is not None and self.mishap not in self.values:
            raise FieldError("mishap", f"'{self.mishap}' is not one of the phases ({', '.join(self.values)})")


@dataclass
class RiskModelFile:
    name: str
    monitored: dict[str, Variable]
    controlled: dict[str, Variable]
    hazards: dict[str, Hazard]
    description: str = ""
    macros: dict[str, str] = field(default_factory=dict)
    phases: Phases = field(default_factory=Phases)
    """The hazards' phases, which one is initial and which the mishap."""


# -- compiled form ----------------------------------------------------------------
@dataclass(frozen=True)
class CompiledTransition:
    phase: str
    to: str
    guard: Callable[[dict], bool]
    after: float
    text: str
    formula: object = None
    """The parsed guard (``cellsim.logic.syntax``): what ``guard`` evaluates, and what ``cellsim verify``
    translates into the abstract model: one reading of the model for both."""


@dataclass(frozen=True)
class CompiledHazard:
    name: str
    transitions: tuple[CompiledTransition, ...]
    demands: dict[str, dict[str, Any]]


@dataclass(frozen=True)
class RiskModel:
    """A risk model checked and compiled for execution."""

    name: str
    source: str
    monitored: dict[str, Variable]
    controlled: dict[str, Variable]
    hazards: tuple[CompiledHazard, ...]
    macros: dict[str, str]
    phases: Phases = field(default_factory=Phases)

    def vocabulary(self) -> dict:
        """Variables guards (and safety conditions) may use: monitored ones and phases."""
        vocab = {name: var.logic_domain() for name, var in self.monitored.items()}
        vocab.update({h.name: EnumDomain(tuple(self.phases.values)) for h in self.hazards})
        return vocab

    def demand_rank(self, variable: str, value) -> int:
        return self.controlled[variable].domain.index(value)


def _is_value(value, var: Variable) -> bool:
    """Whether ``value`` is one of ``var``'s values, and of its type (1 is no boolean, true no enum value)."""
    if var.type == "bool":
        return isinstance(value, bool)
    return isinstance(value, str) and value in var.domain


def load_risk_model(path: str | os.PathLike) -> RiskModel:
    """Load and compile a risk model; ConfigError (file, line, key) on any problem."""
    loaded = load_file(RiskModelFile, path)
    return compile_risk_model(loaded)


def compile_risk_model(loaded: Loaded[RiskModelFile]) -> RiskModel:
    rm = loaded.value

    def error(key: str, problem: str) -> ConfigError:
        return ConfigError(loaded.source, loaded.line_of(key), key, problem)

    for name, var in rm.controlled.items():
        if var.type == "number":
            raise error(f"controlled.{name}.type", "a controlled variable is an enum or a bool (numbers are monitored only)")
        if var.default is not None and not _is_value(var.default, var):
            raise error(f"controlled.{name}.default", f"{var.default!r} is not a value of {name}")
    hazard_names = set(rm.hazards)
    clash = hazard_names & (set(rm.monitored) | set(rm.controlled) | set(rm.macros))
    if clash:
        raise error("hazards", f"hazard names must differ from variables and macros: {', '.join(sorted(clash))}")
    phases = rm.phases.values
    vocabulary = {name: var.logic_domain() for name, var in rm.monitored.items()}
    vocabulary.update({h: EnumDomain(tuple(phases)) for h in rm.hazards})

    for name in rm.macros:  # every macro, used or not: a broken one is an error where it is written
        key = f"macros.{name}"
        try:  # (the error names the file and the key's line; the formula's message says where in its text)
            parse(name, vocabulary, rm.macros, allow_temporal=False)
        except FormulaError as e:
            raise error(key, e.message) from None

    hazards = []
    for hname, hazard in rm.hazards.items():
        transitions = []
        for i, tr in enumerate(hazard.transitions):
            for end in ("phase", "to"):
                if getattr(tr, end) not in phases:
                    raise error(f"hazards.{hname}.transitions.{i}.{end}",
                                f"'{getattr(tr, end)}' is not a phase of this model ({', '.join(phases)})")
            key = f"hazards.{hname}.transitions.{i}.when"
            try:
                formula = parse(tr.when, vocabulary, rm.macros, allow_temporal=False)
            except FormulaError as e:
                raise error(key, e.message) from None
            transitions.append(CompiledTransition(tr.phase, tr.to, compile_predicate(formula, vocabulary), tr.after, tr.when,
                                                  formula))
        for phase, demands in hazard.demands.items():
            if phase not in phases:
                raise error(f"hazards.{hname}.demands.{phase}", f"'{phase}' is not a phase of this model ({', '.join(phases)})")
            for var, value in demands.items():
                key = f"hazards.{hname}.demands.{phase}.{var}"
                if var not in rm.controlled:
                    raise error(key, f"'{var}' is not a controlled variable ({', '.join(rm.controlled)})")
                if not _is_value(value, rm.controlled[var]):
                    raise error(key, f"{value!r} is not a value of {var} ({', '.join(map(str, rm.controlled[var].domain))})")
        hazards.append(CompiledHazard(hname, tuple(transitions), hazard.demands))
    return RiskModel(rm.name, loaded.source, rm.monitored, rm.controlled, tuple(hazards), rm.macros, rm.phases)
