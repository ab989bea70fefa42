"""An arm's collision shapes as measuring geometry, kept out of the plant.

The cell's plant simulates no contact (people and sensors are measured, not
collided with), yet a MultibodyPlant holding collision geometry asks SceneGraph
for contacts at every 2 ms step, all of them filtered out: a fifth of a
simulation's cost. So the arm is added to the plant *without* its collision
elements (its visual ones stay, for Meshcat), and its collision shapes are
registered with SceneGraph directly on the plant's body frames: the plant's
pose output poses them (in C++), but the plant does not count them as its
collision geometry and asks for no contacts. Distances measured to them are those to the model's collision
shapes, as before.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from pydrake.geometry import GeometryInstance, ProximityProperties, SceneGraph
from pydrake.math import RigidTransform
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.framework import DiagramBuilder

_COLLISION = re.compile(r"<collision\b.*?</collision>|<collision\b[^>]*/>", re.S)
_FILENAME = re.compile(r'(filename|uri)="([^"]+)"')


@dataclass(frozen=True)
class CollisionShape:
    body: str
    """The link (body) the shape is fixed to."""
    shape: object
    """The Drake shape."""
    pose: RigidTransform
    """Its pose in the body's frame."""
    name: str


def model_without_collision(path: Path) -> tuple[str, str]:
    """The model file's text with its collision elements removed, and its type (urdf, sdf).

    Relative mesh paths are made absolute, since the text is parsed from a string.
    """
    text = _COLLISION.sub("", path.read_text())

    def absolute(match):
        target = match.group(2)
        if "://" in target or target.startswith("/"):
            return match.group(0)
        return f'{match.group(1)}="{(path.parent / target).resolve()}"'

    return _FILENAME.sub(absolute, text), path.suffix.lstrip(".").lower()


def collision_shapes(path: Path, prefix: str, strict: bool = True) -> tuple[list[CollisionShape], int]:
    """Every collision shape of the model, with its body and pose on it, and how many models
    the file holds (read with a private plant; a model Drake cannot read raises)."""
    builder = DiagramBuilder()
    plant = builder.AddSystem(MultibodyPlant(0.0))
    scene_graph = builder.AddSystem(SceneGraph())
    plant.RegisterAsSourceForSceneGraph(scene_graph)
    parser = Parser(plant, prefix)
    if strict:
        parser.SetStrictParsing()  # what Drake would only warn about (a massless link) is refused too
    instances = parser.AddModels(str(path))
    if len(instances) != 1:
        return [], len(instances)
    inspector = scene_graph.model_inspector()
    shapes = []
    for index in plant.GetBodyIndices(instances[0]):
        body = plant.get_body(index)
        for geometry in plant.GetCollisionGeometriesForBody(body):
            shapes.append(
                CollisionShape(body.name(), inspector.GetShape(geometry).Clone(), inspector.GetPoseInFrame(geometry), inspector.GetName(geometry))
            )
    return shapes, 1


def add_arm_geometry(cell, name: str, instance, shapes: list[CollisionShape]) -> list:
    """Register the arm's collision shapes with SceneGraph on the plant's own body frames; returns their ids.

    They belong to the plant's geometry source, so the plant's (C++) pose output
    poses them, but the plant does not know them as its collision geometry: it
    asks for no contacts.
    """
    scene_graph, plant = cell.scene_graph, cell.plant
    source = plant.get_source_id()
    ids = []
    for shape in shapes:
        body = plant.GetBodyByName(shape.body, instance)
        geometry = GeometryInstance(shape.pose, shape.shape, f"{name}/collision/{shape.name}")
        geometry.set_proximity_properties(ProximityProperties())
        ids.append(scene_graph.RegisterGeometry(source, plant.GetBodyFrameIdOrThrow(body.index()), geometry))
    return ids
