"""The machine kind's configuration."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from cellsim.config.typed_yaml import FieldError
from cellsim.config.units import Period, Seconds
from cellsim.config.twin import TwinSettings
from cellsim.vocabulary import SafetyMode


@dataclass
class MachineConfig:
    """A machine with named activities, the safety modes it supports, and an optional cycle."""

    kind: Literal["machine"]
    activities: list[str] = field(default_factory=lambda: ["idle", "working", "off"])
    """Its activities in the cell's words; its activity channel takes these names."""
    rest: str = "idle"
    """The activity while it waits for work."""
    working: str = "working"
    """The activity while it works (the hazardous one: reported when its state is unknown)."""
    off: str = "off"
    """The activity while stopped or switched off."""
    cycle_time: Seconds = 0.0
    """Seconds a cycle takes once started by its command (0: it works while commanded)."""
    safety_modes: list[SafetyMode] = field(default_factory=lambda: [SafetyMode.NORMAL, SafetyMode.STOPPED])
    """The safety modes it supports."""
    unsupported_request: Literal["restrict", "ignore"] = "restrict"
    """A request for a mode it does not support: ``restrict`` takes the next more restrictive
    mode it supports; ``ignore`` keeps it normal (a machine that only obeys a stop)."""
    period: Period = 0.04
    """Update period (s)."""
    twin: TwinSettings = field(default_factory=TwinSettings)
    """Its twin mode (model, shadow, twin), scheduled changes and when samples go stale."""

    def __post_init__(self):
        if len(set(self.activities)) != len(self.activities) or not all(a.isidentifier() for a in self.activities):
            raise FieldError("activities", "activities must be distinct identifiers")
        for key in ("rest", "working", "off"):
            if getattr(self, key) not in self.activities:
                raise FieldError(key, f"'{getattr(self, key)}' is not one of its activities ({', '.join(self.activities)})")
        if len({self.rest, self.working, self.off}) != 3:
            raise FieldError("working", "rest, working and off must be three different activities")
        if SafetyMode.STOPPED not in self.safety_modes:
            raise FieldError("safety_modes", "every machine supports stopped")
        if SafetyMode.UNKNOWN in self.safety_modes:
            raise FieldError("safety_modes", "unknown is what a shadowed machine reports, not a mode it supports")
