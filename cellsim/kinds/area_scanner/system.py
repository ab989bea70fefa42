"""A safety laser scanner guarding an area with named fields (protective, warning...).

Its fields are volumes of the cell, listed innermost (most restrictive) first:
a box, or a polygon on the floor extruded between two heights. Each field is
SceneGraph geometry (a box, a convex prism, or the prisms of its triangles when
the polygon is not convex), and a person is *in* a field when their geometry
meets it and the scanner sees them: the segment from the scanner to a point of
the person in the field passes through no fixture. The points looked at are the
one deepest in the field and, for a limb (a capsule: the legs), points along it
every ``SIGHT_STEP`` within the beams' heights, each facing the scanner, 30 and
60 degrees either side and at either edge of the limb as the scanner sees it: a
leg half hidden by a fixture's corner is seen by its other half, as by the real
scanner's beams. A person wholly behind the press body is not detected: the
beams do not pass through it, nor through the fixture the scanner is mounted in
deeper than the head sits in it (a scanner in a pedestal's corner sees out past
the corner, not through the pedestal). The beams sweep the heights of the fields
(a floor-level scanner sees legs, not a head above a table).

The ``field`` channel reads the innermost occupied field, else the clear
reading named by the scenario; ``distance`` is the distance to the nearest
point of a person the beams reach, of those looked at (``max_range`` when
none). Shadowing its physical twin with no valid sample, it fails safe: the
innermost field, distance 0.
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.geometry import (
    GeometryInstance,
    MakePhongIllustrationProperties,
    ProximityProperties,
    Rgba,
)

from cellsim.channels import enum_type, number_type
from cellsim.kinds.area_scanner.config import AreaScannerConfig
from cellsim.kinds.sensing import HEAD_RADIUS, SAMPLE_ROUNDING, GeometrySensor
from cellsim.entity import valid_code
from cellsim.floorplan import Box3, SightLines
from cellsim.proximity import height_span, vertical_reach, witness_on
from cellsim.systems import write_changed
from cellsim.vocabulary import TwinMode, value_set

SIGHT_STEP = 0.05
"""m: along a limb, how far apart the points the scanner looks at lie."""
_NO_POINTS = np.empty((0, 3))
_AROUND = [(1.0, 0.0), *((math.cos(a), sign * math.sin(a)) for a in (math.pi / 6, math.pi / 3, math.pi / 2)
                          for sign in (1.0, -1.0))]
"""Around a limb, the points looked at: facing the scanner, 30 and 60 degrees either side, and at its edges (90)."""

class AreaScanner(GeometrySensor):
    """A safety laser scanner.

    Ports:
      geometry_query (input): SceneGraph QueryObject.
      physical_sample (input): [t, link, field code, distance (m)].
      field (channel): the innermost field a person is seen in, else the clear reading.
      distance (channel, m): distance from the head to the nearest person seen, at most max_range.
      unseen (channel): a blind spot: the innermost field a person's body truly meets (by the geometry, through
        fixtures and outside the beams' heights too) when the reading does not cover it (clear, or an outer
        field), else none.
    Fails safe (innermost field, distance 0) when its physical sample is stale or corrupt.
    """

    def __init__(self, module: str, cfg: AreaScannerConfig, fixtures):
        super().__init__(module, cfg.period, cfg.twin, ("field", "distance"))
        self.cfg = cfg
        self.position = np.array(cfg.position, float)
        self.readings = value_set(f"{module}_field", [cfg.clear, *cfg.fields])
        # fixtures block the beams; one the scanner is mounted inside, beyond the head's own depth in it (to the mount's
        # nearest face, and the head's radius: the beams leave within that)
        boxes = list(map(Box3.of, fixtures))
        self.mount_depth = min((float(np.min(box.half - np.abs(box.to_local(self.position)))) for box in boxes
                                if box.contains(self.position)), default=0.0) + HEAD_RADIUS
        self.lines = SightLines(self.position, boxes, self.mount_depth)
        # the heights the scanner's beams sweep: from its lowest field's bottom to its highest's top
        bounds = [corner[2] for spec in cfg.fields.values() for corner in spec.corners()]
        self.band = (min(bounds) - 1e-6, max(bounds) + 1e-6)
        self.field_ids: list[list] = []
        self.cfg_fields = list(cfg.fields.values())
        self._limbs: dict | None = None  # each target that is a capsule (a limb) -> its shape (sight_points)
        self._reaches: dict | None = None  # each target -> (its shape, its vertical_reach): which can meet the beams
        self._sight: dict = {}  # (target, its pose) -> its sight points
        self.field_of: dict = {}
        """Each field piece's GeometryId -> the field's index (0: innermost)."""
        self.unseen_readings = value_set(f"{module}_unseen", ["none", *cfg.fields])
        self._unseen = self.declare_channel(
            "unseen", enum_type(self.unseen_readings), "none",
            description="Blind spot: the innermost field a person truly is in, when the reading does not cover it")
        self._outputs = [
            self.declare_channel("field", enum_type(self.readings), cfg.clear, description="Innermost occupied field"),
            self.declare_channel(
                "distance", number_type("m"), cfg.max_range, description="Distance to the nearest person seen",
            ),
        ]

    @property
    def volumes(self) -> list:
        return list(self.field_of)

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
            self.field_of.update(dict.fromkeys(pieces, k))
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
        """Whether the beams reach ``point``: within the heights they sweep, through no fixture (nor through the
        one the scanner is mounted in, beyond the head's depth in it)."""
        if not self.band[0] <= point[2] <= self.band[1]:
            return False
        return self.lines.reaches(point)

    def sight_points(self, query, target) -> np.ndarray:
        """The points the beams reach of a limb (a capsule), nearest the scanner first: of those along its axis
        every SIGHT_STEP within the beams' heights, the points of its surface facing the scanner, 30 and 60
        degrees either side and at its edges as the scanner sees it, each seen through no fixture (nor deeper than
        the head's own depth through its mount). None for another shape (its deepest or nearest point alone is
        looked at). Kept while the limb stands where they were found (the field test and the distance share
        them)."""
        if self._limbs is None:
            from pydrake.geometry import Capsule

            inspector = query.inspector()
            self._limbs = {g: inspector.GetShape(g) for g in self.targets if isinstance(inspector.GetShape(g), Capsule)}
        shape = self._limbs.get(target)
        if shape is None:
            return _NO_POINTS
        pose = query.GetPoseInWorld(target).GetAsMatrix34()
        key = (target, pose.tobytes())
        points = self._sight.get(key)
        if points is None:
            if len(self._sight) > 64:
                self._sight.clear()
            points = self._sight[key] = self._limb_points(pose, shape.radius(), shape.length() / 2.0)
        return points

    def _limb_points(self, pose: np.ndarray, radius: float, half: float) -> np.ndarray:
        """:meth:`sight_points` of a capsule of ``radius`` and axis half-length ``half`` (m) at ``pose`` (3x4)."""
        a, b = pose[:, 3] - half * pose[:, 2], pose[:, 3] + half * pose[:, 2]
        if min(a[2], b[2]) - radius > self.band[1] or max(a[2], b[2]) + radius < self.band[0]:
            return _NO_POINTS  # wholly above or below the beams
        axis = b - a
        length = float(np.linalg.norm(axis))
        k = axis / length if length > 0 else np.array([0.0, 0.0, 1.0])
        centres = a + np.linspace(0.0, 1.0, max(2, int(np.ceil(length / SIGHT_STEP)) + 1))[:, None] * axis
        centres = centres[(centres[:, 2] >= self.band[0] - radius) & (centres[:, 2] <= self.band[1] + radius)]
        towards = self.position - centres
        towards -= (towards @ k)[:, None] * k  # across the limb, towards the scanner
        norms = np.linalg.norm(towards, axis=1)
        keep = norms > radius  # the head inside a limb's reach: its nearest point says it
        facing = towards[keep] / norms[keep, None]
        centres = centres[keep]
        edge = np.stack([k[1] * facing[:, 2] - k[2] * facing[:, 1], k[2] * facing[:, 0] - k[0] * facing[:, 2],
                         k[0] * facing[:, 1] - k[1] * facing[:, 0]], axis=1)  # k x facing
        points = np.concatenate([centres + radius * (c * facing + s * edge) for c, s in _AROUND])
        points = points[(points[:, 2] >= self.band[0]) & (points[:, 2] <= self.band[1])]
        points = points[self.lines.reach(points)]
        return points[np.argsort(np.linalg.norm(points - self.position, axis=1), kind="stable")]

    def occupancy(self, query) -> tuple[int, int]:
        """(code of the innermost field someone is seen in, else clear; code of the innermost field someone's
        body truly meets, seen or not, else clear), from one broadphase query of the pairs overlapping now."""
        seen = truly = len(self.field_ids) + 1
        targets = self.target_set
        for pair in query.ComputeSignedDistancePairwiseClosestPoints(0.0):
            if pair.distance > 0.0:
                continue
            if pair.id_A in self.field_of and pair.id_B in targets:
                index, target = self.field_of[pair.id_A] + 1, pair.id_B
            elif pair.id_B in self.field_of and pair.id_A in targets:
                index, target = self.field_of[pair.id_B] + 1, pair.id_A
            else:
                continue
            truly = min(truly, index)
            if index < seen and (self.seen(witness_on(query, pair, target)) or any(
                    self.cfg_fields[index - 1].contains(p) for p in self.sight_points(query, target))):
                seen = index
        clear = len(self.field_ids) + 1
        return (0 if seen == clear else seen), (0 if truly == clear else truly)

    def measure(self, context) -> tuple[int, float]:
        """(code of the innermost field someone is seen in, else clear; distance to the nearest seen)."""
        query = self.query_port.Eval(context)
        reading, _ = self.occupancy(query)
        return reading, self.nearest_seen(query)

    def nearest_seen(self, query) -> float:
        """Distance (m) from the head to the nearest point of a person the beams reach, at most max_range.

        Every target's distance first, then their lines of sight nearest first: the first one seen is the answer
        (usually the first looked at), where looking in a fixed order tests most of them."""
        pairs = []
        for target in self.targets:
            if not self._may_meet_band(query, target):
                continue  # wholly above or below the beams: no point of it is seen
            pair = query.ComputeSignedDistancePairClosestPoints(self.head_id, target)
            pairs.append((pair.distance + HEAD_RADIUS, len(pairs), pair, target))
        best = self.cfg.max_range
        for distance, _, pair, target in sorted(pairs, key=lambda found: found[:2]):
            if distance >= best:
                break  # no point of this target or a farther one is nearer than the one seen
            if self.seen(witness_on(query, pair, target)):
                return distance  # its nearest point: nothing seen can be nearer
            visible = self.sight_points(query, target)  # a limb half hidden: its other points, nearest first
            if len(visible):
                best = min(best, float(np.linalg.norm(visible[0] - self.position)))
        return best

    def _may_meet_band(self, query, target) -> bool:
        """Whether some point of ``target`` may lie within the heights the beams sweep (a shape whose heights are not
        known, a mesh: it may)."""
        if self._reaches is None:
            inspector = query.inspector()
            self._reaches = {g: (inspector.GetShape(g), vertical_reach(inspector.GetShape(g))) for g in self.targets}
        shape, reach = self._reaches[target]
        if reach is None:
            return True
        low, high = height_span(shape, query.GetPoseInWorld(target), reach)
        return low <= self.band[1] and high >= self.band[0]

    def sample_is_valid(self, sample) -> bool:
        """A field's code, and a distance the scanner can measure: 0 to its max_range (within ``SAMPLE_ROUNDING``)."""
        return (valid_code(sample[0], self.readings) and np.isfinite(sample[1])
                and 0.0 <= sample[1] <= self.cfg.max_range + SAMPLE_ROUNDING)

    def update(self, context, xd):
        view = self.consult_physical(context, xd)
        query = self.query_port.Eval(context)
        seen, truly = self.occupancy(query)  # the geometry: what the scanner would see, and where people truly are
        if view.mode is TwinMode.MODEL:
            reading, distance = seen, self.nearest_seen(query)
        elif view.sample is None:
            reading, distance = 1, 0.0  # stale or corrupt: someone may be in the innermost field
        else:
            reading, distance = int(view.sample[0]), float(view.sample[1])
        # a blind spot: someone truly in a field more restrictive than the reading (clear reads as beyond them all)
        unseen = 0
        for truth, shown in self.held_to(context, xd, float(truly), float(reading),
                                         view.mode is not TwinMode.MODEL and view.sample is not None, _stricter_field):
            if truth and (shown == 0 or truth < shown):
                unseen = int(_stricter_field(unseen, truth))
        published = [context.get_discrete_state(g)[0] for g in (*self._outputs, self._unseen)]
        write_changed(xd, [*self._outputs, self._unseen], [float(reading), distance, float(unseen)], published)


def _stricter_field(a: float, b: float) -> float:
    """The more restrictive of two field readings (codes; 0, clear, the least; 1, the innermost field, the most)."""
    return b if a == 0 else a if b == 0 else min(a, b)


def _occupied_look(channel: str, field_name: str):
    return lambda values: None if values.get(channel) is None else ("occupied" if values[channel] == field_name else "free")
