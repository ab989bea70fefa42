"""The numbers a scenario is written in, with their valid ranges (checked at load time and by ``--set``), in SI
units: metres, seconds, radians (degrees where a person writes them), metres per second."""

from __future__ import annotations

import math
from typing import Annotated

from cellsim.config.typed_yaml import Range

MAX_EXTENT = 100.0
"""How far from the cell's origin (m) any position may be."""
MAX_DURATION = 86400.0
"""Longest run, and longest wait or delay (s): one day."""
MAX_PLANT_STEPS = 50_000_000
"""Most plant steps a run may take (a day at 2 ms): beyond, its cost is refused."""
MAX_MODULE_UPDATES = 100_000_000
"""Most periodic module updates a run may take, summed over its modules (the welding
cell makes 2e7 in a day; eight modules at 500 Hz reach 1e8 in 3.5 h): beyond, its cost is refused."""

SEEDS = Range(0, 2**32 - 1)
"""Valid random seeds."""

Vec2 = Annotated[tuple[float, float], Range(-MAX_EXTENT, MAX_EXTENT, unit="m")]
Vec3 = Annotated[tuple[float, float, float], Range(-MAX_EXTENT, MAX_EXTENT, unit="m")]
Size3 = Annotated[tuple[float, float, float], Range(0.0, 50.0, lo_open=True, unit="m")]
Rgba = Annotated[tuple[float, float, float, float], Range(0.0, 1.0)]
Degrees = Annotated[float, Range(-360.0, 360.0, unit="deg")]
JointAngle = Annotated[float, Range(-2 * math.pi, 2 * math.pi, unit="rad")]
Period = Annotated[float, Range(0.0001, 10.0, unit="s")]
"""A module's update period: also a whole number of plant steps (checked with the scenario)."""
Seconds = Annotated[float, Range(0.0, MAX_DURATION, unit="s")]
PositiveSeconds = Annotated[float, Range(0.0, MAX_DURATION, lo_open=True, unit="s")]
Speed = Annotated[float, Range(0.0, 10.0, lo_open=True, unit="m/s")]
Distance = Annotated[float, Range(0.0, MAX_EXTENT, lo_open=True, unit="m")]
