"""How an entity relates to its physical twin: its twin mode, scheduled changes, and when samples go stale."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated

from cellsim.config.typed_yaml import FieldError, Range
from cellsim.config.units import Seconds
from cellsim.vocabulary import TwinMode

@dataclass
class TwinModeChange:
    at: Seconds
    """When the mode changes (s of simulated time)."""
    mode: TwinMode
    """The mode from then on."""


@dataclass
class TwinSettings:
    """How an entity relates to its physical twin, and when that changes."""

    mode: TwinMode = TwinMode.MODEL
    """model: the digital behaviour drives the entity; shadow: it follows its physical twin;
    twin: as shadow, and its commands go out to the physical twin."""
    changes: list[TwinModeChange] = field(default_factory=list)
    """Mode changes at given simulated times, in time order."""
    stale_after: Annotated[float, Range(0.0, 60.0, lo_open=True, unit="s")] = 0.5
    """A physical sample older than this (s) is stale: the entity fails safe."""
    recover_after: Annotated[int, Range(1, 1000)] = 3
    """Good samples in a row (each newer than the last) before a failing-safe entity trusts its
    physical twin again: not the first good one after a fault, nor the very first one."""

    def __post_init__(self):
        times = [c.at for c in self.changes]
        if times != sorted(times):
            raise FieldError("changes", "twin-mode changes must be in time order")
