"""An interlocked guard door measuring geometry: open while a person's geometry is in its doorway."""

from __future__ import annotations

import math

from pydrake.geometry import Box, GeometryInstance, MakePhongIllustrationProperties, ProximityProperties, Rgba
from pydrake.math import RigidTransform, RotationMatrix

from cellsim.channels import BOOL
from cellsim.kinds.sensing import REACH, GeometrySensor
from cellsim.systems import write_scalar
from cellsim.vocabulary import TwinMode

from cellsim_guard_door.config import GuardDoorConfig

DOOR_CLOSED = Rgba(0.55, 0.6, 0.65, 0.6)
DOOR_OPEN = Rgba(1.0, 0.55, 0.0, 0.8)
PANEL = 0.03
"""The door panel's thickness (m), for drawing it."""


class GuardDoor(GeometrySensor):
    """An interlocked guard door.

    Ports:
      geometry_query (input): SceneGraph QueryObject.
      physical_sample (input): [t, link, open (0/1)].
      open (channel, bool): true while any person's geometry is in the doorway (someone reaching or
        walking through the open door: the interlock switch reads the door open).
    Fails safe (reads open) when its physical sample is stale or corrupt.
    """

    def __init__(self, module: str, cfg: GuardDoorConfig):
        super().__init__(module, cfg.period, cfg.twin, ("open",))
        self.cfg = cfg
        self.doorway_id = None
        self._open = self.declare_channel("open", BOOL, False, description="The door open (its interlock switch)")

    def register_geometry(self, scene_graph) -> list:
        source = scene_graph.RegisterSource(self.module)
        doorway = GeometryInstance(RigidTransform(list(self.cfg.center)), Box(*self.cfg.size), f"{self.module}/doorway")
        doorway.set_proximity_properties(ProximityProperties())
        doorway.set_illustration_properties(MakePhongIllustrationProperties([0.55, 0.6, 0.65, 0.15]))
        self.doorway_id = scene_graph.RegisterAnchoredGeometry(source, doorway)
        return [self.doorway_id]

    def measure(self, context) -> bool:
        """Whether a person's geometry is in the doorway now (a SceneGraph distance query)."""
        query = self.query_port.Eval(context)
        return any(query.ComputeSignedDistancePairClosestPoints(self.doorway_id, target).distance <= 0.0
                   for target in self.targets)

    def update(self, context, xd):
        view = self.consult_physical(context, xd)
        if view.mode is TwinMode.MODEL:
            is_open = self.measure(context)
        elif view.sample is None:
            is_open = True  # no trusted sample: the door may be open
        else:
            is_open = view.sample[0] > 0.5
        write_scalar(xd, self._open, 1.0 if is_open else 0.0)

    # -- in Meshcat (cellsim.visual.cues) ------------------------------------------------
    def panels(self) -> dict[str, list]:
        """The door panel closed (filling the doorway) and open (swung 90 degrees on its hinge)."""
        (x, y, z), (sx, sy, sz) = self.cfg.center, self.cfg.size
        closed = [(RigidTransform([x, y, z]), Box(sx, PANEL, sz))]
        side = -1.0 if self.cfg.hinge == "min_x" else 1.0
        hinge = [x + side * sx / 2, y, z]
        swung = RigidTransform(RotationMatrix.MakeZRotation(math.pi / 2), [hinge[0], hinge[1] + sx / 2, z])
        return {"closed": closed, "open": [(swung, Box(sx, PANEL, sz))]}

    def visual_cues(self, view) -> list:
        """The door: a grey panel across the doorway while closed, an orange one swung open while open."""
        from cellsim.visual.cues import Cue, parts_of

        panels = self.panels()
        channel = f"{self.module}.open"
        looks = {
            "closed": parts_of(f"{self.module}/door/closed", panels["closed"], DOOR_CLOSED),
            "open": parts_of(f"{self.module}/door/open", panels["open"], DOOR_OPEN),
        }
        choose = lambda values: None if values.get(channel) is None else ("open" if values[channel] else "closed")  # noqa: E731
        return [Cue(f"{self.module}/door", (channel,), looks, choose, (view.geometry_path(self.doorway_id),))]

    def sight(self):
        """An open door sees whoever stands within REACH of its doorway."""
        from cellsim.visual.cues import Sight

        channel = f"{self.module}.open"
        (x, y, _), (sx, sy, _) = self.cfg.center, self.cfg.size
        near = lambda xy: abs(xy[0] - x) <= sx / 2 + REACH and abs(xy[1] - y) <= sy / 2 + REACH  # noqa: E731
        return Sight((channel,), lambda values, xy: bool(values.get(channel)) and near(xy))
