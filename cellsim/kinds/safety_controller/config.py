"""The safety_controller kind's configuration: its risk model and how its variables bind to the cell."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from cellsim.config.units import Period


@dataclass
class SafetyControllerConfig:
    """The risk-model safety controller: a generic engine executing a risk model file."""

    kind: Literal["safety_controller"]
    risk_model: str
    """Risk model YAML, relative to the scenario file."""
    monitors: dict[str, str]
    """Risk-model variable -> channel it reads (``module.signal``)."""
    commands: dict[str, list[str]]
    """Controlled variable -> command inputs it drives (``module.input``)."""
    period: Period = 0.02
    """Control period (s): how often the risk model is evaluated."""
