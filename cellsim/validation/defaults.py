"""The default conditions: what every cell is judged by beside its own (no harm, no clamping, true SSM).

Each module's kind may give conditions (``ModuleKind.conditions``): the harm service gives ``NoHarm``
and ``NoClamping``, each speed and separation monitor ``TrueSSM``. They are added to the scenario's
own conditions when the built cell has the channels they read (a cell without a person has no harm
to judge), several modules' conditions of one name are judged together, and a scenario is spared
one only by waiving it with a reason (``validation.waive``), which every check and report prints.
"""

from __future__ import annotations

import copy
import re
from dataclasses import dataclass

from cellsim import registry
from cellsim.config.typed_yaml import suggest
from cellsim.config.validation import Described, Validation, formula_of

CHANNEL = re.compile(r"\b[A-Za-z_]\w*\.[A-Za-z_]\w*\b")
"""A channel named in a formula (``harm.severity``): default conditions name channels, not aliases."""


@dataclass(frozen=True)
class Waiver:
    condition: str
    reason: str


def default_conditions(sc) -> dict[str, Described]:
    """Every default condition the scenario's modules give, by name (several modules' joined by ``and``)."""
    found: dict[str, list[Described]] = {}
    for section in registry.SECTIONS:
        for name, cfg in getattr(sc, section).items():
            for condition, described in registry.kind_of(cfg).conditions(name, cfg).items():
                found.setdefault(condition, []).append(described)
    return {
        condition: parts[0] if len(parts) == 1 else Described(
            " and ".join(f"({p.formula})" for p in parts), " ".join(dict.fromkeys(p.description for p in parts)))
        for condition, parts in found.items()
    }


def judged_validation(sf, channels) -> Validation:
    """The scenario's validation with the default conditions its cell can be judged by (those whose channels
    ``channels`` has) added and its waivers applied; a ConfigError for a waiver of no default condition, or
    a condition of the scenario's own under a default's name."""
    validation = sf.scenario.validation
    defaults = default_conditions(sf.scenario)
    for condition in validation.waive:
        if condition not in defaults:
            known = ", ".join(defaults) or "none in this cell"
            raise sf.error(f"validation.waive.{condition}",
                           f"'{condition}' is no default condition{suggest(condition, defaults)} (default conditions: {known})")
        if not validation.waive[condition].strip():
            raise sf.error(f"validation.waive.{condition}", "say why the scenario is not judged by it")
    for condition in validation.conditions:
        if condition in defaults:
            raise sf.error(f"validation.conditions.{condition}",
                           f"'{condition}' is a default condition every cell is judged by; name yours otherwise "
                           f"(or waive the default in validation.waive, with a reason)")
    return with_defaults(validation, defaults, channels)


def with_defaults(validation: Validation, defaults: dict[str, Described], channels) -> Validation:
    """``validation`` with each of ``defaults`` it does not waive added, where ``channels`` has what it reads (the
    one rule for which defaults judge a cell: its check, its campaign, its dashboard)."""
    added = {name: d for name, d in defaults.items()
             if name not in validation.waive and name not in validation.conditions
             and set(CHANNEL.findall(formula_of(d))) <= set(channels)}
    if not added:
        return validation
    judged = copy.copy(validation)
    judged.conditions = {**validation.conditions, **added}
    return judged


def waivers(sf) -> list[Waiver]:
    """The default conditions the scenario waives, with its reasons (for every check and report)."""
    return [Waiver(name, reason) for name, reason in sf.scenario.validation.waive.items()]
