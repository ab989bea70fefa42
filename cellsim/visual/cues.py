"""Drawn state: what a module shows in Meshcat, chosen from its channels' values.

A module's system may offer, beside its channels, up to three duck-typed hooks
(the core draws whatever the modules offer and names no module kind):

* ``visual_cues(view: CueView) -> list[Cue]``: pieces of drawn state. A
  :class:`Cue` has named *looks* (Meshcat shapes with colours), of which at
  most one is visible at a time, chosen by ``choose`` from the values of the
  channels it reads (payload values, as the black box stores them: an enum's
  name, a boolean, a list of metres). Only visibility changes over time, so the
  same cue plays live and in a Meshcat recording (where an animation can toggle
  ``visible`` but not recolour a material).
* ``sight() -> Sight``: a sensor's word on whether it sees a person standing at
  a point of the floor, so people can be marked when a sensor sees them.
* ``show_recorded(cell, root_context, values)``: put the module's drawn pose
  (a robot's joints, a person's body) in ``root_context`` from recorded channel
  values, for replaying a black box; ``replay_channels`` names the signals it reads.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from pydrake.geometry import Rgba, Role
from pydrake.math import RigidTransform

PREFIX = "/drake/visualizer"
"""Where MeshcatVisualizer draws SceneGraph's illustration geometry."""
CUES = "/cellsim"
"""Where cues draw geometry of their own (in the cell's frame)."""


@dataclass(frozen=True)
class Part:
    """One shape of a look: ``shape`` at ``pose`` in the frame of Meshcat ``path``'s parent, scaled by ``scale``."""

    path: str
    shape: object
    rgba: Rgba
    pose: RigidTransform = field(default_factory=RigidTransform)
    scale: float = 1.0


@dataclass(frozen=True)
class Cue:
    """A piece of drawn state: its looks (name -> parts), one shown at a time.

    ``choose(values)`` gets the value of each channel in ``channels`` (None
    before its first message) and names the look to show, or None to show none.
    ``replaces`` lists Meshcat paths of plain geometry the cue draws instead
    (hidden once the cue is set up).
    """

    name: str
    channels: tuple[str, ...]
    looks: dict[str, tuple[Part, ...]]
    choose: Callable[[dict], str | None]
    replaces: tuple[str, ...] = ()


@dataclass(frozen=True)
class Sight:
    """A sensor's view of people: ``sees(values, xy)`` says whether the readings
    (values of ``channels``) mean it sees a person standing at ``xy`` (m)."""

    channels: tuple[str, ...]
    sees: Callable[[dict, tuple[float, float]], bool]


@dataclass
class CueView:
    """What a module needs to draw cues: Meshcat paths of SceneGraph geometry, and every sensor's sight."""

    scene_graph: object
    sights: list[Sight] = field(default_factory=list)

    @property
    def inspector(self):
        return self.scene_graph.model_inspector()

    def frame_path(self, frame_id) -> str:
        """The Meshcat path MeshcatVisualizer gives a SceneGraph frame (its transform moves children)."""
        if frame_id == self.inspector.world_frame_id():
            return PREFIX
        return f"{PREFIX}/{self.inspector.GetName(frame_id).replace('::', '/')}"

    def geometry_path(self, geometry_id) -> str:
        """The Meshcat path MeshcatVisualizer draws a SceneGraph geometry at."""
        inspector = self.inspector
        frame = inspector.GetFrameId(geometry_id)
        name = inspector.GetName(geometry_id).replace("::", "/")
        return f"{PREFIX}/{name}" if frame == inspector.world_frame_id() else f"{self.frame_path(frame)}/{name}"

    def shells(self, frame_ids, rgba: Rgba, label: str, scale: float = 1.04) -> tuple[Part, ...]:
        """A coloured copy, a little larger, of every illustration shape on ``frame_ids``, moving with them."""
        inspector = self.inspector
        parts = []
        for frame in frame_ids:
            for i, geometry in enumerate(inspector.GetGeometries(frame, Role.kIllustration)):
                path = f"{self.frame_path(frame)}/{label}/{i}"
                parts.append(Part(path, inspector.GetShape(geometry), rgba, inspector.GetPoseInFrame(geometry), scale))
        return tuple(parts)


def rgba(r: float, g: float, b: float, a: float = 1.0) -> Rgba:
    return Rgba(r, g, b, a)


def parts_of(label: str, shapes, color: Rgba) -> tuple[Part, ...]:
    """Parts at ``CUES/label/i`` from ``(pose in the cell, shape)`` pairs."""
    return tuple(Part(f"{CUES}/{label}/{i}", shape, color, pose) for i, (pose, shape) in enumerate(shapes))


class CueDrawer:
    """Draws cues in a Meshcat: sets their looks up once, then shows the look their channels choose.

    ``draw(values, t)`` takes every channel's value at time ``t`` (s); a look
    that changes is written with ``time_in_recording=t``, so a Meshcat recording
    replays it. Used live (``cellsim.visual.live``) and on a black box
    (``cellsim.visual.replay``).
    """

    def __init__(self, meshcat, cues: list[Cue]):
        self.meshcat = meshcat
        self.cues = cues
        self.shown: dict[str, str | None] = {}
        self.ready = False

    @property
    def channels(self) -> list[str]:
        return list(dict.fromkeys(c for cue in self.cues for c in cue.channels))

    def setup(self) -> None:
        """Draw every look (hidden) and hide what the cues replace."""
        meshcat = self.meshcat
        for cue in self.cues:
            for path in cue.replaces:
                meshcat.SetProperty(path, "visible", False)
            for parts in cue.looks.values():
                for part in parts:
                    meshcat.SetObject(part.path, part.shape, part.rgba)
                    X = part.pose.GetAsMatrix4()
                    if part.scale != 1.0:
                        X = X @ np.diag([part.scale, part.scale, part.scale, 1.0])
                    meshcat.SetTransform(part.path, X)
                    meshcat.SetProperty(part.path, "visible", False)
        self.ready = True

    def draw(self, values: dict, t: float | None = None) -> None:
        if not self.ready:
            self.setup()
        for cue in self.cues:
            look = cue.choose(values)
            if look not in cue.looks:
                look = None
            if cue.name in self.shown and self.shown[cue.name] == look:
                continue
            first, before = cue.name not in self.shown, self.shown.get(cue.name)
            for name, parts in cue.looks.items():
                if first or name in (look, before):  # the first draw gives every look a key frame
                    for part in parts:
                        self.meshcat.SetProperty(part.path, "visible", name == look, time_in_recording=t)
            self.shown[cue.name] = look

    def visible_look(self, cue_name: str) -> str | None:
        """The look shown now for the cue called ``cue_name`` (None: none)."""
        return self.shown.get(cue_name)


def collect(modules: dict, scene_graph) -> list[Cue]:
    """Every module's cues, in build order, each given every sensor's sight."""
    view = CueView(scene_graph, [m.sight() for m in modules.values() if hasattr(m, "sight")])
    cues = []
    for system in modules.values():
        if hasattr(system, "visual_cues"):
            cues += system.visual_cues(view)
    return cues
