"""An arm's collision shapes as measuring geometry, kept out of the plant.

The cell's plant simulates no contact (people and sensors are measured, not
collided with), yet a MultibodyPlant holding collision geometry asks SceneGraph
for contacts at every 2 ms step, all of them filtered out: a fifth of a
simulation's cost. So the arm is added to the plant *without* its collision
elements (its visual ones stay, for Meshcat), and its collision shapes are
registered as a SceneGraph source of their own, posed from the plant's body
poses by :class:`ArmGeometry` only when a sensor or the ground truth queries
SceneGraph. Distances measured to them are those to the model's collision
shapes, as before.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from pydrake.common.value import AbstractValue
from pydrake.geometry import FramePoseVector, GeometryFrame, GeometryInstance, ProximityProperties, SceneGraph
from pydrake.math import RigidTransform
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.framework import DiagramBuilder, LeafSystem

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


class ArmGeometry(LeafSystem):
    """Poses an arm's collision shapes from the plant's body poses.

    Ports:
      body_poses (input): the plant's body poses (world frame), indexed by BodyIndex.
      geometry_pose (output): FramePoseVector of one frame per body carrying shapes.
    """

    def __init__(self, name: str, frames: list[tuple[object, int]]):
        """``frames``: (FrameId, BodyIndex) of each frame this source poses."""
        super().__init__()
        self.set_name(name)
        self.frames = frames
        self.body_poses_port = self.DeclareAbstractInputPort("body_poses", AbstractValue.Make([RigidTransform()]))
        self.geometry_pose_port = self.DeclareAbstractOutputPort(
            "geometry_pose", lambda: AbstractValue.Make(FramePoseVector()), self._calc
        )

    def _calc(self, context, output):
        poses = self.body_poses_port.Eval(context)
        vector = output.get_mutable_value()
        for frame, body in self.frames:
            vector.set_value(frame, poses[body])


def add_arm_geometry(cell, name: str, instance, shapes: list[CollisionShape]) -> list:
    """Register the arm's collision shapes with SceneGraph, posed from the plant; returns their ids."""
    scene_graph, plant = cell.scene_graph, cell.plant
    source = scene_graph.RegisterSource(f"{name}/collision")
    frames, ids, frame_of = [], [], {}
    for shape in shapes:
        if shape.body not in frame_of:
            body = plant.GetBodyByName(shape.body, instance)
            frame = scene_graph.RegisterFrame(source, GeometryFrame(f"{name}/{shape.body}"))
            frame_of[shape.body] = frame
            frames.append((frame, int(body.index())))
        geometry = GeometryInstance(shape.pose, shape.shape, f"{name}/collision/{shape.name}")
        geometry.set_proximity_properties(ProximityProperties())
        ids.append(scene_graph.RegisterGeometry(source, frame_of[shape.body], geometry))
    poser = cell.builder.AddSystem(ArmGeometry(f"{name}.collision_geometry", frames))
    cell.builder.Connect(plant.get_body_poses_output_port(), poser.body_poses_port)
    cell.builder.Connect(poser.geometry_pose_port, scene_graph.get_source_pose_port(source))
    return ids
