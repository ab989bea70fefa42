"""The operator kind's configuration: where the person walks, waits, reaches and presses."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Literal

from cellsim.config.typed_yaml import FieldError, Range
from cellsim.config.twin import TwinSettings
from cellsim.config.units import Period, Seconds, Speed, Vec2, Vec3


@dataclass
class Waypoint:
    position: Vec2
    """Where the person stands (x, y in m)."""
    wait: Seconds = 0.0
    """Seconds spent at the waypoint."""
    reach: Vec3 | None = None
    """A point the operator reaches for with one hand while waiting here."""
    press: str | None = None
    """A button pressed on arriving here (held 0.5 s): an entity's input, ``module.input``
    (a light curtain's restart: ``pallet_curtain.reset``)."""

    def __post_init__(self):
        if self.press is not None and (self.press.count(".") != 1 or not all(p.isidentifier() for p in self.press.split("."))):
            raise FieldError("press", f"'{self.press}' is not module.input (an entity and one of its inputs)")


@dataclass
class OperatorConfig:
    """A person walking an ordered list of waypoints, with body geometry."""

    kind: Literal["operator"]
    start: Vec2
    """Where the person stands at t = 0 (x, y in m)."""
    waypoints: dict[str, Waypoint]
    """The places walked to, in order, each with a wait and an optional reach."""
    notifications: list[str] = field(default_factory=lambda: ["none"])
    """What the cell can tell this person (its notification command input), in the cell's
    words; the first means there is nothing to say."""
    alerts: list[str] = field(default_factory=list)
    """True/false alerts the cell can give this person, each a command input of that name."""
    start_delay: Seconds = 0.0
    """Seconds before the person starts walking."""
    walking_speed: Speed = 1.2
    """Mean walking speed (m/s)."""
    speed_jitter: Annotated[float, Range(0.0, 1.0, hi_open=True)] = 0.1
    """Each leg's speed is drawn uniformly within +-this fraction, from the run's seed."""
    height: Annotated[float, Range(0.5, 2.5, unit="m")] = 1.75
    """Body height (m)."""
    body_radius: Annotated[float, Range(0.05, 1.0, unit="m")] = 0.2
    """Radius of the torso's capsule (m)."""
    arm_length: Annotated[float, Range(0.15, 2.0, unit="m")] = 0.7
    """Reach of the arm from the shoulder (m)."""
    turn_rate: Annotated[float, Range(0.5, 6.3, unit="rad/s")] = 3.14
    """How fast the body turns (rad/s) to a new walking direction or towards a reach point: a turn takes time, as
    a person's does (half a turn in a second by default, a whole one at most), so a hand swings at most this times
    its distance from the body's axis (up to about 1 m, reaching out) per second: at the default and a 0.04 s
    period, 13 cm per update at most, where a turn in one update swung a hand half a metre. The harm service sees
    the body where each update puts it (docs/harm.md): a longer period or a faster turn moves it farther between."""
    avoid_fixtures: bool = True
    """Walk around the layout's fixtures (their footprints grown by body_radius + 5 cm), by the
    shortest way; false: straight lines, through them. Only fixtures are walked round: a robot whose base stands
    on the floor with no fixture for it (a pedestal) is walked through, so give each base a fixture."""
    period: Period = 0.04
    """Update period (s): how often the body moves in the twin."""
    twin: TwinSettings = field(default_factory=TwinSettings)
    """Its twin mode (model, shadow, twin), scheduled changes and when samples go stale."""

    def __post_init__(self):
        for key, names in (("notifications", self.notifications), ("alerts", self.alerts)):
            if len(set(names)) != len(names) or not all(n.isidentifier() for n in names):
                raise FieldError(key, f"{key} must be distinct identifiers")
        if not self.notifications:
            raise FieldError("notifications", "list at least the notification meaning 'nothing to say'")
        clash = set(self.alerts) & {"notification", "physical_sample"}
        if clash:
            raise FieldError("alerts", f"'{clash.pop()}' is already an input of a person")
        if "start" in self.waypoints:
            raise FieldError("waypoints.start", "'start' is the waypoint channel's value before the walk; name it otherwise")
