"""The range_detector kind's configuration."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Literal

from cellsim.config.typed_yaml import FieldError, Range
from cellsim.config.twin import TwinSettings
from cellsim.config.units import Distance, Period, Vec3


@dataclass
class RangeDetectorConfig:
    """A safety scanner: far / near / close from the nearest person's distance to it."""

    kind: Literal["range_detector"]
    position: Vec3
    """Where the scanner head is (m); distances are measured from it."""
    near_below: Distance = 2.0
    """Below this distance (m) the range reads near."""
    close_below: Distance = 1.0
    """Below this distance (m) the range reads close."""
    noise_std: Annotated[float, Range(0.0, 10.0, unit="m")] = 0.0
    """Standard deviation of the measured distance (m); drawn from the run's seed."""
    period: Period = 0.04
    """Response time (s)."""
    twin: TwinSettings = field(default_factory=TwinSettings)
    """Its twin mode (model, shadow, twin), scheduled changes and when samples go stale."""

    def __post_init__(self):
        if not 0 < self.close_below < self.near_below:
            raise FieldError("close_below", "needs 0 < close_below < near_below")
