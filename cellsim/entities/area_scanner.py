"""A safety laser scanner guarding an area with named fields (protective, warning...).

Its fields are volumes of the cell, listed innermost (most restrictive) first:
a box, or a polygon on the floor extruded between two heights. Each field is
SceneGraph geometry (a box, a convex prism, or the prisms of its triangles when
the polygon is not convex), and a person is *in* a field when their geometry
meets it and the scanner sees them: the segment from the scanner to the point
of the person deepest in the field passes through no fixture. A person behind
the press body is not detected, as with the real scanner, whose beams do not
pass through it. The beams sweep the heights of the fields (a floor-level
scanner sees legs, not a head above a table).

The ``field`` channel reads the innermost occupied field, else the clear
reading named by the scenario; ``distance`` is the distance to the nearest
point of a person the beams reach (``max_range`` when none). Shadowing its physical
twin with no valid sample, it fails safe: the innermost field, distance 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Literal

import numpy as np
from pydrake.geometry import (
    Box,
    Convex,
    GeometryInstance,
    MakePhongIllustrationProperties,
    ProximityProperties,
    Rgba,
)
from pydrake.math import RigidTransform

from cellsim.channels import enum_type, number_type
from cellsim.config.typed_yaml import FieldError, Range
from cellsim.entities.sensors import HEAD_RADIUS, GeometrySensor, build_sensor
from cellsim.entities.twin import TWIN_CHANNELS, valid_code
from cellsim.floorplan import Box3, is_convex, is_simple, signed_area, triangulate
from cellsim.registry import ModuleKind, deferred
from cellsim.scenario import Distance, Period, Region, TwinSettings, Vec2, Vec3
from cellsim.systems import write_changed
from cellsim.vocabulary import TwinMode, value_set

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


class AreaScanner(GeometrySensor):
    """A safety laser scanner.

    Ports:
      geometry_query (input): SceneGraph QueryObject.
      physical_sample (input): [t, link, field code, distance (m)].
      field (channel): the innermost field a person is seen in, else the clear reading.
      distance (channel, m): distance from the head to the nearest person seen, at most max_range.
    Fails safe (innermost field, distance 0) when its physical sample is stale or corrupt.
    """

    def __init__(self, module: str, cfg: AreaScannerConfig, fixtures):
        super().__init__(module, cfg.period, cfg.twin, ("field", "distance"))
        self.cfg = cfg
        self.position = np.array(cfg.position, float)
        self.readings = value_set(f"{module}_field", [cfg.clear, *cfg.fields])
        # fixtures block the beams, except one the scanner is mounted inside
        self.walls = [box for box in map(Box3.of, fixtures) if not box.contains(self.position)]
        # the heights the scanner's beams sweep: from its lowest field's bottom to its highest's top
        bounds = [corner[2] for spec in cfg.fields.values() for corner in spec.corners()]
        self.band = (min(bounds) - 1e-6, max(bounds) + 1e-6)
        self.field_ids: list[list] = []
        self._outputs = [
            self.declare_channel("field", enum_type(self.readings), cfg.clear, description="Innermost occupied field"),
            self.declare_channel(
                "distance", number_type("m"), cfg.max_range, description="Distance to the nearest person seen",
            ),
        ]

    def register_geometry(self, scene_graph) -> list:
        source = scene_graph.RegisterSource(self.module)
        self.head_id = self.register_head(scene_graph, source, self.position)
        ids = [self.head_id]
        for k, (name, spec) in enumerate(self.cfg.fields.items()):
            shade = [1.0, 0.2 + 0.6 * k / max(1, len(self.cfg.fields) - 1), 0.1, 0.12]
            pieces = []
            for i, (pose, shape) in enumerate(spec.shapes(f"{self.module}/{name}")):
                instance = GeometryInstance(pose, shape, f"{self.module}/{name}/{i}")
                instance.set_proximity_properties(ProximityProperties())
                instance.set_illustration_properties(MakePhongIllustrationProperties(shade))
                pieces.append(scene_graph.RegisterAnchoredGeometry(source, instance))
            self.field_ids.append(pieces)
            ids += pieces
        return ids

    # -- in Meshcat (cellsim.visual.cues) ------------------------------------------------
    def visual_cues(self, view) -> list:
        """Each field shaded faint while free, strong while it is the field the scanner reports."""
        from cellsim.visual.cues import Cue, parts_of

        channel = f"{self.module}.field"
        cues = []
        for k, (name, spec) in enumerate(self.cfg.fields.items()):
            hue = 0.2 + 0.6 * k / max(1, len(self.cfg.fields) - 1)
            shapes = spec.shapes(f"{self.module}/{name}/cue")
            looks = {
                "free": parts_of(f"{self.module}/{name}/free", shapes, Rgba(1.0, hue, 0.1, 0.08)),
                "occupied": parts_of(f"{self.module}/{name}/occupied", shapes, Rgba(1.0, hue, 0.1, 0.45)),
            }
            replaces = tuple(view.geometry_path(piece) for piece in self.field_ids[k])
            cues.append(Cue(f"{self.module}/{name}", (channel,), looks, _occupied_look(channel, name), replaces))
        return cues

    def sight(self):
        """A field reported occupied sees whoever stands within 0.3 m of its footprint's bounding box."""
        from cellsim.visual.cues import Sight

        channel = f"{self.module}.field"
        boxes = {}
        for name, spec in self.cfg.fields.items():
            corners = np.array(spec.corners())
            boxes[name] = (corners[:, :2].min(axis=0) - 0.3, corners[:, :2].max(axis=0) + 0.3)

        def sees(values, xy) -> bool:
            box = boxes.get(values.get(channel))
            return box is not None and bool(np.all((box[0] <= xy) & (np.asarray(xy) <= box[1])))

        return Sight((channel,), sees)

    def seen(self, point) -> bool:
        """Whether the beams reach ``point``: within the heights they sweep, through no fixture."""
        if not self.band[0] <= point[2] <= self.band[1]:
            return False
        return not any(wall.blocks(self.position, point) for wall in self.walls)

    def measure(self, context) -> tuple[int, float]:
        """(code of the innermost field someone is seen in, else clear; distance to the nearest seen)."""
        query = self.query_port.Eval(context)
        reading = 0
        for index, pieces in enumerate(self.field_ids):
            if self._occupied(query, pieces):
                reading = index + 1
                break
        nearest = self.cfg.max_range
        for target in self.targets:
            pair = query.ComputeSignedDistancePairClosestPoints(self.head_id, target)
            distance = pair.distance + HEAD_RADIUS
            if distance < nearest and self.seen(_witness_on(query, pair, target)):
                nearest = distance
        return reading, nearest

    def _occupied(self, query, pieces) -> bool:
        for piece in pieces:
            for target in self.targets:
                pair = query.ComputeSignedDistancePairClosestPoints(piece, target)
                if pair.distance <= 0.0 and self.seen(_witness_on(query, pair, target)):
                    return True
        return False

    def sample_is_valid(self, sample) -> bool:
        return valid_code(sample[0], self.readings) and np.isfinite(sample[1]) and sample[1] >= 0.0

    def update(self, context, xd):
        view = self.consult_physical(context, xd)
        if view.mode is TwinMode.MODEL:
            reading, distance = self.measure(context)
        elif view.sample is None:
            reading, distance = 1, 0.0  # stale or corrupt: someone may be in the innermost field
        else:
            reading, distance = int(view.sample[0]), float(view.sample[1])
        published = [context.get_discrete_state(g)[0] for g in self._outputs]
        write_changed(xd, self._outputs, [float(reading), distance], published)


def _occupied_look(channel: str, field_name: str):
    return lambda values: None if values.get(channel) is None else ("occupied" if values[channel] == field_name else "free")


def _witness_on(query, pair, geometry) -> np.ndarray:
    """The pair's witness point on ``geometry``, in the cell (SceneGraph may order the pair either way)."""
    if pair.id_A == geometry:
        return query.GetPoseInWorld(geometry) @ pair.p_ACa
    return query.GetPoseInWorld(geometry) @ pair.p_BCb


def _check(sf, name: str, cfg: AreaScannerConfig) -> None:
    """The scanner and every corner of its fields lie within the cell (its layout's extent)."""
    extent = sf.scenario.layout.extent()
    if extent is None:
        return
    lo, hi = extent
    key = f"entities.{name}"
    if not all(a - 1e-9 <= x <= b + 1e-9 for a, x, b in zip(lo, cfg.position, hi)):
        raise sf.error(f"{key}.position", f"{list(cfg.position)} is outside the cell (its layout spans {list(lo)} to {list(hi)})")
    for field_name, spec in cfg.fields.items():
        for corner in spec.corners():
            if not all(a - 1e-9 <= x <= b + 1e-9 for a, x, b in zip(lo, corner, hi)):
                raise sf.error(
                    f"{key}.fields.{field_name}",
                    f"the field reaches {list(corner)}, outside the cell (its layout spans {list(lo)} to {list(hi)})",
                )


KIND = ModuleKind(
    name="area_scanner",
    abstraction=deferred("cellsim.abstractions.sensors:area_scanner"),
    section="entities",
    config=AreaScannerConfig,
    build=build_sensor(lambda name, cfg, cell: AreaScanner(name, cfg, cell.scenario.layout.fixtures.values())),
    check=_check,
    summary="A safety laser scanner with named fields (boxes or extruded polygons): the innermost field a person is seen in.",
    sample_fields=("field", "distance"),
    channels=(
        ("field", "enum", "the innermost field a person is seen in (not through fixtures), else the clear reading"),
        ("distance", "number, m", "distance to the nearest person seen, at most max_range"),
        *TWIN_CHANNELS,
    ),
)
