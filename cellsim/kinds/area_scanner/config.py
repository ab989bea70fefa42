"""The area_scanner kind's configuration: its fields (boxes, or polygons extruded), innermost first."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Literal

import numpy as np
from pydrake.geometry import Box, Convex
from pydrake.math import RigidTransform

from cellsim.config.typed_yaml import FieldError, Range
from cellsim.floorplan import is_convex, is_simple, point_in_polygon, signed_area, triangulate
from cellsim.config.layout import Region
from cellsim.config.twin import TwinSettings
from cellsim.config.units import Distance, Period, Vec2, Vec3

Height = Annotated[float, Range(0.0, 10.0, unit="m")]


@dataclass
class ScannerField:
    """One field: a ``box``, or a ``polygon`` on the floor extruded between ``heights``."""

    box: Region | None = None
    """An axis-aligned box {min: [x, y, z], max: [x, y, z]} (m)."""
    polygon: list[Vec2] | None = None
    """The field's outline on the floor, [x, y] corners in order (m); it need not be convex."""
    heights: tuple[Height, Height] = (0.0, 0.3)
    """Bottom and top of the extruded polygon (m); a scanner's plane is near the floor."""

    def __post_init__(self):
        if (self.box is None) == (self.polygon is None):
            raise FieldError("box", "give a field exactly one of box or polygon")
        if self.polygon is not None:
            if len(self.polygon) < 3:
                raise FieldError("polygon", "a polygon needs at least 3 corners")
            if not is_simple(self.polygon):
                raise FieldError("polygon", "the polygon's edges cross, or a corner repeats")
            if abs(signed_area(self.polygon)) < 1e-6:
                raise FieldError("polygon", "the polygon has no area")
        if not self.heights[0] < self.heights[1]:
            raise FieldError("heights", "the bottom height must be below the top")

    def contains(self, point) -> bool:
        """Whether ``point`` (x, y, z in m) lies in the field's volume (its boundary included)."""
        if self.box is not None:
            return all(lo <= p <= hi for lo, p, hi in zip(self.box.min, point, self.box.max))
        return self.heights[0] <= point[2] <= self.heights[1] and point_in_polygon(point[:2], self.polygon)

    def corners(self) -> list[tuple[float, float, float]]:
        """Every corner of the field's volume (m)."""
        if self.box is not None:
            (x0, y0, z0), (x1, y1, z1) = self.box.min, self.box.max
            return [(x, y, z) for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)]
        return [(x, y, z) for x, y in self.polygon for z in self.heights]

    def shapes(self, label: str) -> list[tuple[RigidTransform, object]]:
        """The field as SceneGraph shapes, each with its pose in the cell."""
        if self.box is not None:
            lo, hi = np.array(self.box.min), np.array(self.box.max)
            return [(RigidTransform((lo + hi) / 2), Box(*(hi - lo)))]
        pieces = [self.polygon] if is_convex(self.polygon) else triangulate(self.polygon)
        z0, z1 = self.heights
        return [
            (RigidTransform(), Convex(np.array([[x, y, z] for x, y in piece for z in (z0, z1)], float).T, f"{label}/{i}"))
            for i, piece in enumerate(pieces)
        ]


@dataclass
class AreaScannerConfig:
    """A safety laser scanner with named fields; reports the innermost field a person is in."""

    kind: Literal["area_scanner"]
    position: Vec3
    """Where the scanner's head is (m): its line of sight and distances start there."""
    fields: dict[str, ScannerField]
    """The fields, innermost (most restrictive, e.g. protective) first, each named in the cell's words."""
    clear: str = "clear"
    """What the field channel reads while no field is occupied."""
    max_range: Distance = 10.0
    """Farthest the scanner sees (m): the distance reads this while nobody is nearer."""
    period: Period = 0.04
    """Response time (s)."""
    twin: TwinSettings = field(default_factory=TwinSettings)
    """Its twin mode (model, shadow, twin), scheduled changes and when samples go stale."""

    def __post_init__(self):
        if not self.fields:
            raise FieldError("fields", "name at least one field")
        for name in [*self.fields, self.clear]:
            if not name.isidentifier():
                raise FieldError(f"fields.{name}", "a field's name must be an identifier (letters, digits, _)")
        if self.clear in self.fields:
            raise FieldError("clear", f"'{self.clear}' is also the name of a field")
