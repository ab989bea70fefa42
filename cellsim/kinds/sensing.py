"""What the geometry sensors share: a system reading the SceneGraph query port, its head, and its builder.

The sensors see the geometries listed by ``set_targets`` (the builder passes every person's
body), so the twin reports what the geometry says, including situations nobody scripted
(a second operator, a reach from behind).
"""

from __future__ import annotations

from pydrake.common.value import AbstractValue
from pydrake.geometry import GeometryInstance, MakePhongIllustrationProperties, ProximityProperties, QueryObject, Sphere
from pydrake.math import RigidTransform

from cellsim.entity import EntitySystem
from cellsim.systems import read_scalar, write_scalar

HEAD_RADIUS = 0.05  # m, the scanner head's sphere
SAMPLE_ROUNDING = 0.01
"""m: how far a physical sample's distance may lie beyond what the sensor can measure (its range code's band, its
maximum range) and still be taken: a transport's rounding of the distance (a CAN signal's resolution is a
millimetre)."""
REACH = 1.0
"""How far (m) from a sensor's volume a person may stand and still be the one it sees
(an arm reaching in): used only to mark people in Meshcat."""


class GeometrySensor(EntitySystem):
    """An entity reading the SceneGraph query port to measure target geometries."""

    def __init__(self, module, period, twin, sample_fields):
        super().__init__(module, period, twin, sample_fields)
        self.query_port = self.DeclareAbstractInputPort("geometry_query", AbstractValue.Make(QueryObject()))
        self.targets: tuple = ()
        self.target_set: frozenset = frozenset()
        self._truth_before = self.declare_state("truth_before", [0.0])  # the truth at the last update (its code)
        self._reading_before = self.declare_state("reading_before", [0.0])  # the reading then (its code)

    def held_to(self, context, xd, truly: float, reading: float, physical: bool, stricter) -> list[tuple[float, float]]:
        """The (truth, reading) pairs a blind spot is judged on, as codes (a blind spot where any pair's truth is
        stricter than its reading): ``truly`` and ``reading`` now for the geometry's own reading (model mode). A
        physical sensor (shadow or twin mode) takes up to its period (its response time) to show what the twin's
        geometry shows at once, so for one: the truth at the last update against the stricter (``stricter(a, b)``)
        of the readings then and now (a person it never showed was in its blind spot, however briefly they were
        there: reported a period after it began), and the looser of the truths then and now against the reading
        now (a person there since the last update is shown by now: one it loses for an update is in it)."""
        truth_before = read_scalar(context, self._truth_before)
        reading_before = read_scalar(context, self._reading_before)
        if truly != truth_before:
            write_scalar(xd, self._truth_before, truly)
        if reading != reading_before:
            write_scalar(xd, self._reading_before, reading)
        if not physical:
            return [(truly, reading)]
        looser = truly if stricter(truth_before, truly) == truth_before else truth_before
        return [(truth_before, stricter(reading_before, reading)), (looser, reading)]

    def register_head(self, scene_graph, source, position) -> object:
        """The sensor head: a small sphere at ``position`` that distances are measured from; its GeometryId."""
        head = GeometryInstance(RigidTransform(position), Sphere(HEAD_RADIUS), f"{self.module}/head")
        head.set_proximity_properties(ProximityProperties())
        head.set_illustration_properties(MakePhongIllustrationProperties([0.9, 0.9, 0.1, 1.0]))
        return scene_graph.RegisterAnchoredGeometry(source, head)

    @property
    def volumes(self) -> list:
        """The sensor's volumes (GeometryIds) whose overlap with a person's body a broadphase query finds; none by
        default (a sensor measuring pair by pair)."""
        return []

    def set_targets(self, geometry_ids) -> None:
        """The geometries this sensor detects (people)."""
        self.targets = tuple(geometry_ids)
        self.target_set = frozenset(self.targets)


def add_sensor(cell, name: str, sensor: GeometrySensor) -> GeometrySensor:
    """Build a geometry sensor into ``cell``: its own geometry, the SceneGraph query, and every person as a target."""
    cell.add(name, sensor)
    cell.register_geometry(sensor)
    cell.connect_query(sensor.query_port)
    cell.after_entities(lambda: sensor.set_targets(cell.people))
    cell.after_entities(lambda: cell.measure_between(list(getattr(sensor, "volumes", ())), cell.people))
    return sensor


def blind_spots(name: str, blackbox, channel: str) -> list:
    """Each interval a sensor's blind-spot channel (``channel``: the field a person truly is in that the reading
    does not cover, ``none`` otherwise) names a field, as findings of the run (:class:`cellsim.kind.Finding`)."""
    from cellsim.kind import Finding

    if channel not in blackbox.channels():
        return []
    series = blackbox.series(channel)
    found, start, current = [], None, "none"
    for t, value in zip(series.times.tolist(), series.values):
        if value != current and current != "none":
            found.append(Finding(name, "blind spot", start, t, _blind_text(name, current), {"field": current}))
        if value != current:
            start, current = t, value
    if current != "none":
        found.append(Finding(name, "blind spot", start, None, _blind_text(name, current), {"field": current}))
    return found


def _blind_text(name: str, field: str) -> str:
    return f"a person truly in {name}'s {field} field, which it reported free"
