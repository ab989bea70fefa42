"""The ground_truth kind's configuration."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from cellsim.config.units import Period


@dataclass
class GroundTruthConfig:
    """Measures what no sensor reports: the true operator-robot separation."""

    kind: Literal["ground_truth"]
    period: Period = 0.1
    """How often the separation is measured (s)."""
