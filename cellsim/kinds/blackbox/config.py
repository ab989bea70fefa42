"""The blackbox kind's configuration (nothing to set: what it records is every channel)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass
class RecorderConfig:
    """The message snooper: writes every message to the black box (SQLite), committed every simulated second."""

    kind: Literal["blackbox"]
