"""A cell's layout: its fixtures and the named volumes its vocabulary is made of (robot regions, operator zones
and flags), in the cell's own words."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from cellsim.config.typed_yaml import FieldError
from cellsim.config.units import Degrees, Rgba, Size3, Vec3

@dataclass
class Fixture:
    """A static box in the cell (table, bench, fence panel, machine body)."""

    size: Size3
    """Its size along x, y, z (m)."""
    center: Vec3
    """Where its centre is in the cell (m)."""
    yaw_deg: Degrees = 0.0
    """Rotation about the vertical axis (degrees)."""
    color: Rgba = (0.55, 0.55, 0.58, 1.0)
    """Red, green, blue and opacity, each from 0 to 1."""

    def __post_init__(self):
        if min(self.size) <= 0:
            raise FieldError("size", "every dimension must be positive")


@dataclass
class Region:
    """An axis-aligned box of space, [min, max] per axis."""

    min: Vec3
    """The corner with the smallest x, y, z (m)."""
    max: Vec3
    """The opposite corner: each coordinate greater than min's (m)."""

    def __post_init__(self):
        if any(lo >= hi for lo, hi in zip(self.min, self.max)):
            raise FieldError("max", "each coordinate of max must exceed min")

    def contains(self, p) -> bool:
        """Whether point ``p`` (x, y, z in m) lies in the box, its faces included."""
        return all(lo <= x <= hi for lo, x, hi in zip(self.min, p, self.max))


@dataclass
class Layout:
    """The cell's fixtures and the named volumes its vocabulary is made of (in the cell's own words)."""

    fixtures: dict[str, Fixture] = field(default_factory=dict)
    """Static boxes: tables, benches, fences, machine bodies."""
    robot_regions: dict[str, Region] = field(default_factory=dict)
    """Robot locations: a robot's ``location`` channel takes the name of the first region holding its tool."""
    robot_elsewhere: str = "elsewhere"
    """A robot's location when its tool is in none of the regions."""
    operator_zones: dict[str, Region] = field(default_factory=dict)
    """Where people are: a person's ``location`` channel takes the name of the first zone they stand in."""
    operator_outside: str = "outside"
    """A person's location when they stand in none of the zones."""
    operator_flags: dict[str, Region] = field(default_factory=dict)
    """Volumes each giving every person a true/false channel of that name (``at_table``: standing there)."""

    def __post_init__(self):
        for key, names, other in (
            ("robot_regions", list(self.robot_regions), [self.robot_elsewhere, UNKNOWN]),
            ("operator_zones", list(self.operator_zones), [self.operator_outside]),
        ):
            for name in names:
                if not name.isidentifier():
                    raise FieldError(f"{key}.{name}", "a location's name must be an identifier (letters, digits, _)")
                if name in other:
                    raise FieldError(f"{key}.{name}", f"'{name}' is already the name of the location outside every {key[:-1].replace('_', ' ')}")
        for key in ("robot_elsewhere", "operator_outside"):
            if not getattr(self, key).isidentifier():
                raise FieldError(key, "a location's name must be an identifier (letters, digits, _)")
        if self.robot_elsewhere == UNKNOWN:
            raise FieldError("robot_elsewhere", f"'{UNKNOWN}' is what a shadowed robot reports; name elsewhere otherwise")
        for name in self.operator_flags:
            if not name.isidentifier() or name in RESERVED_OPERATOR_CHANNELS:
                raise FieldError(f"operator_flags.{name}", f"'{name}' cannot name a person's channel")

    def extent(self) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
        """The box (min, max corners, m) holding every fixture, region, zone and flag: the cell's extent."""
        corners = []
        for fixture in self.fixtures.values():
            reach = math.hypot(fixture.size[0], fixture.size[1]) / 2 if fixture.yaw_deg % 90 else None
            half = [reach, reach, fixture.size[2] / 2] if reach else [s / 2 for s in fixture.size]
            corners += [[c - h for c, h in zip(fixture.center, half)], [c + h for c, h in zip(fixture.center, half)]]
        for volumes in (self.robot_regions, self.operator_zones, self.operator_flags):
            corners += [list(r.min) for r in volumes.values()] + [list(r.max) for r in volumes.values()]
        if not corners:
            return None
        return tuple(min(c[i] for c in corners) for i in range(3)), tuple(max(c[i] for c in corners) for i in range(3))

    def robot_locations(self) -> list[str]:
        """The values of a robot's location channel: the regions, elsewhere, and unknown (no valid sample)."""
        return [*self.robot_regions, self.robot_elsewhere, UNKNOWN]

    def operator_locations(self) -> list[str]:
        """The values of a person's location channel: outside, then the zones."""
        return [self.operator_outside, *self.operator_zones]


UNKNOWN = "unknown"
"""What a shadowed machine reports when its physical samples are stale or corrupt."""
RESERVED_OPERATOR_CHANNELS = ("location", "waypoint", "position", "twin_mode", "physical_link")
