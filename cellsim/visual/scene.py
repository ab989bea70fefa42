"""The cell's scene in Meshcat: a camera outside the fence, and see-through fixtures.

Nothing here names a fixture: the camera is placed from the layout's extent,
and a see-through fixture is any fixture box drawn translucent (a fence panel,
a guard): drawn as its outline with a nearly clear fill, so the panels between
the camera and the cell do not tint everything behind them.
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.geometry import Box, Rgba, Role
from pydrake.math import RigidTransform

from cellsim.visual.cues import PREFIX

FIELD_OF_VIEW = math.radians(75.0)
"""Meshcat's default camera's vertical field of view."""
LOOK_FROM = np.array([-0.55, -1.0, 0.8])
"""Direction (in the cell) from the cell's centre to the camera: from the south-west, above."""
SEE_THROUGH_OPACITY = 0.2
"""Factor on a see-through fixture's opacity (its outline stays opaque)."""


def camera_pose(extent) -> tuple[np.ndarray, np.ndarray]:
    """(camera position, target) in the cell (m): outside the extent's box, the whole extent in view.

    ``extent`` is the layout's (min corner, max corner); the target is the
    centre of its footprint at working height (at most 1 m up).
    """
    lo, hi = np.asarray(extent[0], float), np.asarray(extent[1], float)
    centre = (lo + hi) / 2
    target = np.array([centre[0], centre[1], min(1.0, centre[2])])
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    direction = LOOK_FROM / np.linalg.norm(LOOK_FROM)
    distance = max(radius / math.tan(FIELD_OF_VIEW / 2), 1.0)
    camera = target + distance * direction
    while np.all((lo - 0.5 <= camera) & (camera <= hi + 0.5)):  # a very flat cell: step back out of it
        distance *= 1.25
        camera = target + distance * direction
    return camera, target


def set_camera(meshcat, extent) -> tuple[np.ndarray, np.ndarray]:
    """Point Meshcat's default camera at the cell from outside it; returns (camera, target)."""
    camera, target = camera_pose(extent)
    meshcat.SetCameraPose(camera, target)
    return camera, target


def see_through_fixtures(plant, scene_graph) -> list[tuple[str, Box, RigidTransform, Rgba]]:
    """(Meshcat path, box, pose, colour) of each translucent fixture box the plant draws."""
    inspector = scene_graph.model_inspector()
    world = inspector.world_frame_id()
    found = []
    for geometry in inspector.GetGeometries(world, Role.kIllustration):
        if inspector.GetOwningSourceName(geometry) != inspector.GetName(plant.get_source_id()):
            continue
        shape = inspector.GetShape(geometry)
        props = inspector.GetIllustrationProperties(geometry)
        if not isinstance(shape, Box) or not props.HasProperty("phong", "diffuse"):
            continue
        color = props.GetProperty("phong", "diffuse")
        if color.a() < 1.0:
            path = f"{PREFIX}/{inspector.GetName(geometry).replace('::', '/')}"
            found.append((path, shape, inspector.GetPoseInFrame(geometry), color))
    return found


def draw_see_through(meshcat, fixtures) -> None:
    """Fade each see-through fixture and draw its edges (at ``<path>_outline``)."""
    for path, box, pose, color in fixtures:
        meshcat.SetProperty(path, "modulated_opacity", SEE_THROUGH_OPACITY)
        start, end = box_edges(box, pose)
        edge = Rgba(0.6 * color.r(), 0.6 * color.g(), 0.6 * color.b(), 1.0)
        meshcat.SetLineSegments(f"{path}_outline", start, end, 2.0, edge)


def box_edges(box: Box, pose: RigidTransform) -> tuple[np.ndarray, np.ndarray]:
    """The 12 edges of a posed box as (3 x 12 start points, 3 x 12 end points) in the cell (m)."""
    half = np.array([box.width(), box.depth(), box.height()]) / 2
    corners = {(i, j, k): pose @ (half * [i, j, k]) for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)}
    pairs = [(a, b) for a in corners for b in corners if a < b and sum(x != y for x, y in zip(a, b)) == 1]
    return (np.array([corners[a] for a, _ in pairs]).T, np.array([corners[b] for _, b in pairs]).T)
