"""A risk model as PRISM modules, exactly as the safety-controller engine executes it.

The engine (``cellsim.kinds.safety_controller.system``) does, each control period,
on the monitored values and the hazards' phases before the period:

1. for every transition with ``after: d``: while its hazard is in the phase it
   leaves and its guard holds, count the periods the guard has held; it has held
   long enough once that count, before this period, is at least
   ``N = ceil(d / period)`` (the engine's ``t - since >= d``); otherwise the count
   restarts;
2. every hazard takes the first transition listed, leaving its phase, whose guard
   holds (a timed one: has held long enough);
3. each controlled variable is the most restrictive value any hazard demands in
   its new phase, else its default (``-1``: no request).

Here each hazard is a module with its phase and one counter per timed transition;
its ``[step]`` commands partition its states by that priority, so exactly one is
enabled in every state (no nondeterminism is added). The guards are the parsed
formulas the engine evaluates (``CompiledTransition.formula``), translated by
``cellsim.verify.expressions``. The controlled variables are PRISM formulas of the
phases (``cmd_<variable>``: the index of the commanded value, ``-1`` for none).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from cellsim.logic.syntax import Const
from cellsim.verify.expressions import Encoding, Thresholds, VerifyError, thresholds_of, to_prism
from cellsim.verify.prism import Command, Enum, Module, Var


@dataclass(frozen=True)
class RiskModules:
    """The risk model's part of the abstract model."""

    modules: list[Module]
    formulas: dict[str, str]
    phases: Enum
    encodings: dict[str, Encoding]
    """How each monitored variable and each hazard's phase is encoded."""
    timers: dict[str, int]
    """Counter variable -> the periods its guard must hold (N)."""


def monitored_encodings(risk_model) -> dict[str, Encoding]:
    """Each monitored variable's encoding: its enumeration, bool, or its guards' thresholds."""
    formulas = [tr.formula for hazard in risk_model.hazards for tr in hazard.transitions]
    encodings: dict[str, Encoding] = {}
    for name, var in risk_model.monitored.items():
        if var.type == "enum":
            encodings[name] = Enum(tuple(var.values))
        elif var.type == "bool":
            encodings[name] = bool
        else:
            encodings[name] = thresholds_of(formulas, name)
    return encodings


def risk_modules(risk_model, period: float, prefix: str = "", monitored: dict[str, str] | None = None,
                 encodings: dict[str, Encoding] | None = None) -> RiskModules:
    """The modules and formulas of ``risk_model`` executed every ``period`` s (the controller's period).

    ``prefix`` is put before every hazard's name and every ``cmd_`` formula in PRISM (the hazard
    ``HS`` is variable ``HS`` by default: the cell's own word, as the conditions use it);
    ``monitored`` names the PRISM expression each monitored variable is read from (default: its
    name); ``encodings`` overrides a monitored number's thresholds (a superset of its guards').
    """
    phases = Enum(tuple(risk_model.phases.values))
    encodings = {**monitored_encodings(risk_model), **(encodings or {})}
    encodings.update({h.name: phases for h in risk_model.hazards})
    names = {**(monitored or {}), **{h.name: prefix + h.name for h in risk_model.hazards}}
    initial = phases.code(risk_model.phases.initial)
    modules, timers = [], {}
    for hazard in risk_model.hazards:
        phase = names[hazard.name]
        variables = [Var(phase, 0, len(phases.values) - 1, initial, enum=phases)]
        guards, counters = [], {}
        for i, tr in enumerate(hazard.transitions):
            if tr.formula is None:
                raise VerifyError(f"hazard {hazard.name}: transition {i} has no parsed guard")
            guard = to_prism(tr.formula, encodings, names) if not _always(tr.formula) else "true"
            held = f"({phase} = {phases.code(tr.phase)} & {guard})"
            if tr.after > 0:
                n = max(1, math.ceil(tr.after / period - 1e-9))
                counter = f"{phase}_t{i}"
                counters[counter] = (held, n)
                timers[counter] = n
                variables.append(Var(counter, 0, n, 0))
                guard = f"({guard} & {counter} >= {n})"
            guards.append((tr, guard))
        timer_updates = {c: f"({held} ? min({c} + 1, {n}) : 0)" for c, (held, n) in counters.items()}
        commands = []
        for code, name in enumerate(phases.values):
            leaving = [(tr, guard) for tr, guard in guards if tr.phase == name]
            earlier: list[str] = []
            for tr, guard in leaving:
                commands.append(Command(
                    f"{phase} = {code} & {_none(earlier)}{guard}",
                    (("1", {phase: str(phases.code(tr.to)), **timer_updates}),)))
                earlier.append(guard)
            commands.append(Command(f"{phase} = {code}{(' & ' + _none(earlier)[:-3]) if earlier else ''}",
                                    (("1", dict(timer_updates)),)))
        modules.append(Module(f"hazard_{phase}", variables, commands,
                              comment=f"hazard {hazard.name}: {getattr(hazard, 'description', '') or ''}".rstrip(": ")))
    formulas = {f"{prefix}cmd_{name}": _command(risk_model, name, var, names, phases) for name, var in risk_model.controlled.items()}
    return RiskModules(modules, formulas, phases, encodings, timers)


def _command(risk_model, variable: str, var, names: dict, phases: Enum) -> str:
    """The commanded value's index: the most restrictive demand in the hazards' phases, else the default."""
    domain = list(var.domain)
    demands = []
    for hazard in risk_model.hazards:
        for phase, demanded in hazard.demands.items():
            if variable in demanded:
                demands.append(f"({names[hazard.name]} = {phases.code(phase)} ? {domain.index(demanded[variable])} : -1)")
    default = -1 if var.default is None else domain.index(var.default)
    if not demands:
        return str(default)
    demanded = demands[0] if len(demands) == 1 else f"max({', '.join(demands)})"
    return f"({demanded} >= 0 ? {demanded} : {default})"


def _none(guards: list[str]) -> str:
    """``!g1 & !g2 & `` (with the trailing conjunction), or nothing."""
    return "".join(f"!({g}) & " for g in guards)


def _always(formula) -> bool:
    return formula == Const(True)


__all__ = ["RiskModules", "Thresholds", "monitored_encodings", "risk_modules"]
