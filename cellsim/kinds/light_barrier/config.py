"""The light_barrier kind's configuration."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from cellsim.config.twin import TwinSettings
from cellsim.config.units import Period, Size3, Vec3


@dataclass
class LightBarrierConfig:
    """A light curtain; its beams fill a box, broken while a person's geometry is in it."""

    kind: Literal["light_barrier"]
    center: Vec3
    """Centre of the box the beams fill (m)."""
    size: Size3
    """Size of that box along x, y, z (m)."""
    period: Period = 0.04
    """Response time (s). People move every 40 ms in the twin; sampling faster reads the same geometry."""
    restart_interlock: bool = False
    """Once broken it stays tripped, after the beams clear, until a reset (a rising edge of its
    reset input while the beams are clear), as a guard with a manual restart (ISO 13849-1, 5.2.2)."""
    twin: TwinSettings = field(default_factory=TwinSettings)
    """Its twin mode (model, shadow, twin), scheduled changes and when samples go stale."""
