"""The ssm kind's configuration: the robot monitored, where separation comes from, the formula's terms."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

from cellsim.config.typed_yaml import Range
from cellsim.config.units import Period, Speed

GEOMETRY = "geometry"
"""``separation: geometry``: measured from the arm's shapes to every person's body."""


Margin = Annotated[float, Range(0.0, 5.0, unit="m")]


@dataclass
class SsmConfig:
    """Speed and separation monitoring of one robot (ISO/TS 15066)."""

    kind: Literal["ssm"]
    robot: str = "robot"
    """The robot monitored: its speed_limit input follows this module in ssmon."""
    separation: str = GEOMETRY
    """Where the separation comes from: ``geometry`` (the arm's shapes to every person's body), or a
    sensor's distance channel in m (``scanner.distance``: measured from the sensor, not the arm)."""
    human_speed: Speed = 1.6
    """v_h: the speed a person may approach at (m/s); 1.6 m/s after ISO 13855."""
    reaction_time: Annotated[float, Range(0.0, 5.0, unit="s")] = 0.1
    """T_r: from the person's measured position to the robot starting to brake (s): the sensor's
    response, this module's period and the robot controller's (at least those two periods: refused below)."""
    deceleration: Annotated[float, Range(0.0, 100.0, lo_open=True, unit="m/s^2")] | None = None
    """a: the robot's guaranteed braking deceleration at the tool (m/s^2); null: what it delivers on a segment its normal
    cap limits, (speed_limits.normal - 0.04) / (1.05 braking_time) (its planned full speed to standstill in
    braking_time). A segment its joints limit brakes slower: measure it and set it here."""
    intrusion_distance: Margin = 0.0
    """C: how far a body part may reach past what the sensor detects (m); ISO 13855 gives it per sensor."""
    sensor_uncertainty: Margin = 0.05
    """Z_d: the person-position measurement's uncertainty (m)."""
    robot_uncertainty: Margin = 0.02
    """Z_r: the robot-position measurement's uncertainty (m)."""
    period: Period = 0.02
    """Control period (s): how often the limit is computed."""
    max_margin_fall: Annotated[float, Range(0.1, 100.0, unit="m/s")] = 10.0
    """The fastest the true margin (``true_margin``, TrueSSM's) is taken to fall between two of its scheduled
    judgements (m/s), one plant step after each update of each person and, in ssmon, of the robot and this monitor:
    while it is nearer 0 than this times their interval, it is judged at every plant step. A fall found faster
    between two judgements (``unwatched_margin_fall``) is a finding of the run. The shipped cells' fastest: 4.5 m/s."""
