"""The guard_door kind's configuration."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from cellsim.config.twin import TwinSettings
from cellsim.config.units import Period, Size3, Vec3


@dataclass
class GuardDoorConfig:
    """An interlocked guard door in a fence: its switch reads open while a person's geometry is in the doorway."""

    kind: Literal["guard_door"]
    center: Vec3
    """Centre of the doorway (m)."""
    size: Size3
    """The doorway's extent along x, y, z (m): its width, the fence's depth, its height."""
    hinge: Literal["min_x", "max_x"] = "min_x"
    """The doorway's side the door swings on (for drawing it open)."""
    period: Period = 0.02
    """The interlock switch's response time (s)."""
    twin: TwinSettings = field(default_factory=TwinSettings)
    """Its twin mode (model, shadow, twin), scheduled changes and when samples go stale."""
