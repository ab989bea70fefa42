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

HEAD_RADIUS = 0.05  # m, the scanner head's sphere
REACH = 1.0
"""How far (m) from a sensor's volume a person may stand and still be the one it sees
(an arm reaching in): used only to mark people in Meshcat."""


class GeometrySensor(EntitySystem):
    """An entity reading the SceneGraph query port to measure target geometries."""

    def __init__(self, module, period, twin, sample_fields):
        super().__init__(module, period, twin, sample_fields)
        self.query_port = self.DeclareAbstractInputPort("geometry_query", AbstractValue.Make(QueryObject()))
        self.targets: tuple = ()

    def register_head(self, scene_graph, source, position) -> object:
        """The sensor head: a small sphere at ``position`` that distances are measured from; its GeometryId."""
        head = GeometryInstance(RigidTransform(position), Sphere(HEAD_RADIUS), f"{self.module}/head")
        head.set_proximity_properties(ProximityProperties())
        head.set_illustration_properties(MakePhongIllustrationProperties([0.9, 0.9, 0.1, 1.0]))
        return scene_graph.RegisterAnchoredGeometry(source, head)

    def set_targets(self, geometry_ids) -> None:
        """The geometries this sensor detects (people)."""
        self.targets = tuple(geometry_ids)


def add_sensor(cell, name: str, sensor: GeometrySensor) -> GeometrySensor:
    """Build a geometry sensor into ``cell``: its own geometry, the SceneGraph query, and every person as a target."""
    cell.add(name, sensor)
    cell.register_geometry(sensor)
    cell.connect_query(sensor.query_port)
    cell.after_entities(lambda: sensor.set_targets(cell.people))
    return sensor
