"""The human operator: walks waypoints, reaches for things, and has geometry.

The operator is its own SceneGraph geometry source with two frames, the body and
the right arm, carrying the body's named regions (:mod:`cellsim.body`:
head, face, neck, back, chest, abdomen, pelvis, arms, hands, legs) that sensors see
and the harm service judges.
The digital behaviour walks the scenario's waypoints in order at a walking speed
drawn per leg from the run's seed, waits at each, and while waiting at a
waypoint with a ``reach`` point swings the arm towards that point (0.5 s to
extend and 0.5 s to withdraw), turning at most ``turn_rate`` towards each new
direction or reach point. Each leg is the shortest way around the layout's
fixtures (their footprints grown by the body's radius and ``CLEARANCE``;
fixtures overhead, above the person's height, do not count). The whole walk is
planned when the system is built, so the operator's pose is a pure function of
time; a waypoint inside a fixture, or one that cannot be reached, is a load error.
"""

from __future__ import annotations

import bisect
import functools
import math
from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import (
    FramePoseVector,
    GeometryFrame,
    GeometryInstance,
    MakePhongIllustrationProperties,
    ProximityProperties,
    Rgba,
    Sphere,
)
from pydrake.math import RigidTransform, RotationMatrix

from cellsim.channels import BOOL, enum_type, vector_type
from cellsim.entity import EntitySystem
from cellsim.floorplan import Box3, point_in_polygon, shortest_path
from cellsim.body import SHOULDER, body_pieces, shoulder_offset
from cellsim.body import reach as body_reach
from cellsim.kinds.operator.config import OperatorConfig
from cellsim.config.layout import Layout
from cellsim.systems import read_scalar, write_scalar
from cellsim.vocabulary import TwinMode, value_set

REACH_TIME = 0.5  # s to extend or withdraw the arm
PRESS_TIME = 0.5
"""How long (s) a person holds a button pressed on arriving at a waypoint."""
CLEARANCE = 0.05
"""How far (m) a person keeps their body from a fixture when walking round it."""
SEEN = Rgba(1.0, 0.2, 0.1, 0.9)
"""The marker above a person's head in Meshcat while a sensor sees them."""


@dataclass(frozen=True)
class Leg:
    """Walk from ``start`` to waypoint ``index`` during [depart, arrive], then wait until ``leave``."""

    index: int
    start: np.ndarray
    end: np.ndarray
    depart: float
    arrive: float
    leave: float
    reach: np.ndarray | None
    heading: float | None = None
    """Walking direction at the end of the leg (rad), None for a leg of zero length."""
    facing: float | None = None
    """Direction of the reach point from ``end`` (rad), None without a reach."""
    corners: tuple = ()
    """Points walked through between start and end, going round fixtures."""

    def point_at(self, s: float) -> tuple[np.ndarray, float | None]:
        """Where the person is (and heading, rad) a fraction ``s`` of the way along the leg."""
        points = [self.start, *self.corners, self.end]
        lengths = [float(np.linalg.norm(b - a)) for a, b in zip(points, points[1:])]
        along = s * sum(lengths)
        for a, b, length in zip(points, points[1:], lengths):
            if along <= length or b is self.end:
                way = b - a
                heading = float(np.arctan2(way[1], way[0])) if length > 1e-9 else self.heading
                return a + (min(along, length) / length if length > 1e-9 else 0.0) * way, heading
            along -= length
        return self.end, self.heading


class RouteError(ValueError):
    """A waypoint a person cannot stand at or reach: ``key`` is the waypoint's key under the operator."""

    def __init__(self, key: str, problem: str):
        super().__init__(problem)
        self.key = key


def obstacles(cfg: OperatorConfig, layout: Layout) -> list[tuple[str, tuple]]:
    """(name, footprint grown by the body's radius and CLEARANCE) of each fixture a person walks round."""
    grow = cfg.body_radius + CLEARANCE
    return [
        (name, tuple(tuple(c) for c in Box3.of(f).footprint(grow)))
        for name, f in layout.fixtures.items()
        if f.center[2] - f.size[2] / 2 < cfg.height
    ]


def plan_routes(cfg: OperatorConfig, layout: Layout) -> list[tuple]:
    """For each waypoint, the corners walked through on the way to it (raises RouteError)."""
    if not cfg.avoid_fixtures:
        return [() for _ in cfg.waypoints]
    found = obstacles(cfg, layout)
    outlines = tuple(outline for _, outline in found)
    places = [("start", tuple(cfg.start))] + [(f"waypoints.{n}.position", tuple(w.position)) for n, w in cfg.waypoints.items()]
    for key, xy in places:
        for name, outline in found:
            if point_in_polygon(xy, outline) and not _on_edge(xy, outline):
                raise RouteError(key, f"{list(xy)} is inside fixture '{name}' or too near it for the body "
                                      f"({cfg.body_radius + CLEARANCE:g} m from its edge)")
    routes = []
    for (_, here), (key, there) in zip(places, places[1:]):
        path = route(here, there, outlines)
        if path is None:
            raise RouteError(key, f"no way round the fixtures leads from {list(here)} to {list(there)}")
        routes.append(path)
    return routes


@functools.lru_cache(maxsize=4096)
def route(start: tuple, goal: tuple, outlines: tuple) -> tuple | None:
    path = shortest_path(start, goal, [[np.array(c) for c in outline] for outline in outlines])
    return None if path is None else tuple(tuple(float(x) for x in p) for p in path[:-1])


def _on_edge(xy, outline) -> bool:
    from cellsim.floorplan import _on_boundary

    return _on_boundary(np.asarray(xy, float), [np.array(c) for c in outline])


@dataclass(frozen=True)
class OperatorPose:
    xy: np.ndarray
    yaw: float
    reach_fraction: float
    reach_target: np.ndarray  # meaningful when reach_fraction > 0
    waypoint: int  # index of the waypoint walked to or waited at; -1 before setting off


def plan_walk(cfg: OperatorConfig, seed: int, salt: int = 0, layout: Layout | None = None) -> list[Leg]:
    """The legs of the operator's walk, round the layout's fixtures, with per-leg speeds drawn from ``seed``."""
    rng = np.random.default_rng([seed, 0x0BE7, salt])
    routes = plan_routes(cfg, layout) if layout is not None else [() for _ in cfg.waypoints]
    legs, here, t = [], np.array(cfg.start, float), cfg.start_delay
    for index, (wp, route) in enumerate(zip(cfg.waypoints.values(), routes)):
        speed = cfg.walking_speed * (1.0 + cfg.speed_jitter * rng.uniform(-1.0, 1.0))
        end = np.array(wp.position, float)
        corners = tuple(np.array(c) for c in route)
        points = [here, *corners, end]
        arrive = t + sum(float(np.linalg.norm(b - a)) for a, b in zip(points, points[1:])) / speed
        reach = None if wp.reach is None else np.array(wp.reach, float)
        way = end - points[-2]
        heading = float(np.arctan2(way[1], way[0])) if np.linalg.norm(way) > 1e-9 else None
        facing = None if reach is None else float(np.arctan2(reach[1] - end[1], reach[0] - end[0]))
        legs.append(Leg(index, here, end, t, arrive, arrive + wp.wait, reach, heading, facing, corners))
        here, t = end, arrive + wp.wait
    return legs


class Turns:
    """The body's yaw over time: it turns towards each new aim (the start's, each stretch's walking direction, a
    reach point's) at most ``rate`` rad/s, the short way round, from the time the aim is taken."""

    def __init__(self, legs: list[Leg], start_yaw: float, rate: float):
        aims = [(0.0, start_yaw)]
        walked = start_yaw  # the way the person last walked
        for leg in legs:
            points = [leg.start, *leg.corners, leg.end]
            lengths = [float(np.linalg.norm(b - a)) for a, b in zip(points, points[1:])]
            total, t = sum(lengths), leg.depart
            for a, b, length in zip(points, points[1:], lengths):
                if length > 1e-9:
                    aims.append((t, float(np.arctan2(b[1] - a[1], b[0] - a[0]))))
                    t += length / total * (leg.arrive - leg.depart)
            walked = walked if leg.heading is None else leg.heading
            if leg.reach is not None:
                aims.append((leg.arrive, leg.facing))
                aims.append((leg.leave, walked))  # the arm withdrawn, back to the way it walked (here or before)
        self.rate = rate
        self.times = [t for t, _ in aims]
        self.aims = [aim for _, aim in aims]
        self.starts = [start_yaw]  # the yaw as each aim is taken
        for i in range(1, len(aims)):
            self.starts.append(self._towards(self.starts[-1], self.aims[i - 1], self.times[i] - self.times[i - 1]))

    def _towards(self, yaw: float, aim: float, seconds: float) -> float:
        """``yaw`` turned towards ``aim`` for ``seconds`` (rad, in (-pi, pi])."""
        left = (aim - yaw + math.pi) % (2.0 * math.pi) - math.pi
        turn = self.rate * max(seconds, 0.0)
        if abs(left) <= turn:
            return aim
        return (yaw + math.copysign(turn, left) + math.pi) % (2.0 * math.pi) - math.pi

    def yaw_at(self, t: float) -> float:
        """The yaw (rad) at time ``t``."""
        i = max(bisect.bisect_right(self.times, t) - 1, 0)
        return self._towards(self.starts[i], self.aims[i], t - self.times[i])


def pose_at(legs: list[Leg], start_yaw: float, t: float, turns: Turns | None = None) -> OperatorPose:
    """Where the operator is at time ``t``; turned as ``turns`` says (None: at once, each aim as it is taken)."""
    turned = None if turns is None else turns.yaw_at(t)
    yaw, xy = start_yaw, legs[0].start if legs else np.zeros(2)
    waypoint = -1
    for leg in legs:
        if t < leg.depart:
            break
        if leg.heading is not None:
            yaw = leg.heading
        waypoint = leg.index
        if t < leg.arrive:
            xy, heading = leg.point_at((t - leg.depart) / (leg.arrive - leg.depart))
            yaw = yaw if heading is None else heading
            return OperatorPose(xy, yaw if turned is None else turned, 0.0, _NO_REACH, waypoint)
        xy = leg.end
        if leg.reach is not None and t < leg.leave:
            fraction = min((t - leg.arrive) / REACH_TIME, (leg.leave - t) / REACH_TIME, 1.0)
            return OperatorPose(xy, leg.facing if turned is None else turned, max(fraction, 0.0), leg.reach, waypoint)
    return OperatorPose(np.asarray(xy, float), yaw if turned is None else turned, 0.0, _NO_REACH, waypoint)


_NO_REACH = np.zeros(3)


class Operator(EntitySystem):
    """A person in the cell.

    Ports:
      notification (input): code of one of the person's notifications; and one
        true/false input per alert: what the safety controller tells this person, forwarded to the physical twin's
        wearable in twin mode.
      physical_sample (input): [t, link, x, y, yaw, reach_fraction, reach_x, reach_y, reach_z].
      geometry_pose (output): FramePoseVector of the body and arm frames, for SceneGraph.
      pose, previous_pose (outputs): the pose state [x, y (m), yaw (rad), reach fraction, reach point (m)]
        now and before the last update (equal while standing still): how the body moves, for the harm service.
      location (channel): the name of the layout's operator zone the body stands in, else
        layout.operator_outside (oloc; the welding cell: inCell / none).
      <flag> (channel, bool), for each of the layout's operator_flags: whether the body
        stands in that volume (the welding cell: at_table, otab).
      waypoint (channel): the waypoint walked to or waited at.
      position (channel, m): [x, y] of the body, at every update.
      posture (channel): [yaw (rad), reach fraction, reach point x, y, z (m)]: how the body turns and reaches.
      press_<module>_<input> (output), per button a waypoint presses: 1 for PRESS_TIME
        after arriving there (model mode only: a physical person presses the real button).
    """

    POSE_FIELDS = ("x", "y", "yaw", "reach_fraction", "reach_x", "reach_y", "reach_z")
    takes_samples_on_arrival = False  # the harm service reads pose minus previous_pose as motion over one period

    def __init__(self, module: str, cfg: OperatorConfig, layout: Layout, seed: int, salt: int = 0):
        super().__init__(module, cfg.period, cfg.twin, self.POSE_FIELDS, ("notification", *cfg.alerts))
        self.cfg = cfg
        self.layout = layout
        self.legs = plan_walk(cfg, seed, salt, layout)
        first = self.legs[0].end - np.array(cfg.start) if self.legs else np.array([1.0, 0.0])
        self.start_yaw = float(np.arctan2(first[1], first[0]))
        self.turns = Turns(self.legs, self.start_yaw, cfg.turn_rate)
        self.waypoints = value_set(f"{module}_waypoint", ["start", *cfg.waypoints])
        # what the cell can tell this person, in its own words
        self.notification_type = value_set(f"{module}_notification", cfg.notifications)
        self.notification_port = self.declare_input("notification", ctype=enum_type(self.notification_type), default=0.0)
        self.alert_ports = [self.declare_input(name, ctype=BOOL, default=0.0) for name in cfg.alerts]
        initial = pose_at(self.legs, self.start_yaw, 0.0, self.turns)
        self._pose = self.declare_state("pose", self._pose_vector(initial))
        self._previous_pose = self.declare_state("previous_pose", self._pose_vector(initial))
        self.pose_port = self.DeclareStateOutputPort("pose", self._pose)
        self.previous_pose_port = self.DeclareStateOutputPort("previous_pose", self._previous_pose)
        # the cell's own words for where a person is: outside, or one of the layout's zones
        self.locations = value_set(f"{module}_location", layout.operator_locations())
        self._zones = [(self.locations(name).code, zone) for name, zone in layout.operator_zones.items()]
        # from the start pose: a person who stands still there all run is where it stands, not outside
        standing = (float(initial.xy[0]), float(initial.xy[1]), 1.0)
        self._location = self.declare_channel(
            "location", enum_type(self.locations),
            next((name for name, zone in layout.operator_zones.items() if zone.contains(standing)), layout.operator_outside),
            description="Where the person stands: a zone of the layout, or outside"
        )
        self._flags = [
            (self.declare_channel(name, BOOL, zone.contains(standing), description=f"Standing in the layout's {name} volume"), zone)
            for name, zone in layout.operator_flags.items()
        ]
        self._waypoint = self.declare_channel("waypoint", enum_type(self.waypoints), "start")
        self._position = self.declare_channel(
            "position", vector_type(2, "m"), initial.xy)
        self._posture = self.declare_channel(
            "posture", vector_type(5, None), self._pose_vector(initial)[2:],
            description="yaw (rad), reach fraction, reach point (m): how the body turns and reaches")
        # the buttons this person presses, and where: (button index, leg) per pressing waypoint
        self.buttons = list(dict.fromkeys(w.press for w in cfg.waypoints.values() if w.press))
        self._presses = [
            (self.buttons.index(w.press), leg) for w, leg in zip(cfg.waypoints.values(), self.legs) if w.press
        ]
        self._pressing = [self.declare_state(f"press_{b.replace('.', '_')}", [0.0]) for b in self.buttons]
        self.button_ports = [
            self.DeclareStateOutputPort(f"press_{b.replace('.', '_')}", g) for b, g in zip(self.buttons, self._pressing)
        ]
        self.body_frame = self.arm_frame = None
        self._last_frame_poses: tuple | None = None  # (pose state, FramePoseVector)
        self.geometry_ids: list = []
        self.regions: dict = {}
        """Each body GeometryId -> the name of its region (``cellsim.body.REGIONS``)."""
        self.reach = body_reach(cfg.body_radius, cfg.arm_length)
        """m: no region of the body lies farther than this from its vertical axis (at x, y of the pose)."""
        self.geometry_pose_port = None

    # -- geometry --------------------------------------------------------------
    def register_geometry(self, scene_graph) -> list:
        """Register the body's regions (:mod:`cellsim.body`); returns their proximity geometries
        (for sensors and the harm service; ``regions`` maps each to its region's name)."""
        cfg = self.cfg
        self.source_id = scene_graph.RegisterSource(self.module)
        self.body_frame = scene_graph.RegisterFrame(self.source_id, GeometryFrame(f"{self.module}/body"))
        self.arm_frame = scene_graph.RegisterFrame(self.source_id, GeometryFrame(f"{self.module}/arm"))
        frames = {"body": self.body_frame, "arm": self.arm_frame}
        for piece in body_pieces(cfg.height, cfg.body_radius, cfg.arm_length):
            instance = GeometryInstance(piece.pose, piece.shape, f"{self.module}/{piece.name}/{len(self.geometry_ids)}")
            instance.set_proximity_properties(ProximityProperties())
            instance.set_illustration_properties(MakePhongIllustrationProperties(list(piece.color)))
            geometry = scene_graph.RegisterGeometry(self.source_id, frames[piece.frame], instance)
            self.geometry_ids.append(geometry)
            self.regions[geometry] = piece.region
        self.geometry_pose_port = self.DeclareAbstractOutputPort(
            "geometry_pose",
            lambda: AbstractValue.Make(FramePoseVector()),
            self._calc_geometry_pose,
            prerequisites_of_calc={self.discrete_state_ticket(self._pose)},
        )
        return list(self.geometry_ids)

    def _shoulder(self, xy, yaw) -> np.ndarray:
        side = -shoulder_offset(self.cfg.body_radius)  # the right shoulder
        c, s = np.cos(yaw), np.sin(yaw)
        return np.array([xy[0] - s * side, xy[1] + c * side, (SHOULDER - 0.02) * self.cfg.height])

    def _calc_geometry_pose(self, context, output):
        # Drake recomputes this port after every update of the operator, moved or
        # not; the frame poses are a function of the pose state alone, so the
        # last ones are kept and reused while the operator holds still.
        pose = tuple(context.get_discrete_state(self._pose).get_value().tolist())
        if self._last_frame_poses is None or self._last_frame_poses[0] != pose:
            self._last_frame_poses = (pose, self.frame_poses(pose))
        output.set_value(self._last_frame_poses[1])

    def frame_poses(self, pose: tuple) -> FramePoseVector:
        """The body and arm frames' poses for a pose state ``(x, y, yaw, reach_fraction, *reach_target)``."""
        x, y, yaw, fraction, rx, ry, rz = pose
        poses = FramePoseVector()
        poses.set_value(self.body_frame, RigidTransform(RotationMatrix.MakeZRotation(yaw), [x, y, 0.0]))
        shoulder = self._shoulder((x, y), yaw)
        down = np.array([0.0, 0.0, -1.0])
        direction = down
        if fraction > 0:
            towards = np.array([rx, ry, rz]) - shoulder
            direction = (1 - fraction) * down + fraction * towards / np.linalg.norm(towards)
            direction /= np.linalg.norm(direction)
        poses.set_value(self.arm_frame, RigidTransform(RotationMatrix.MakeFromOneVector(-direction, 2), shoulder))
        return poses

    def set_pose(self, root_context, vector) -> None:
        """Stand the body in ``root_context`` at ``vector``: x, y (m), yaw (rad), reach fraction and reach point (m);
        still (its previous pose the same)."""
        own = self.GetMyMutableContextFromRoot(root_context)
        for group in (self._pose, self._previous_pose):
            own.get_mutable_discrete_state(group).SetFromVector(np.array(vector, float))

    def physical_state(self, context) -> list[float]:
        """x, y (m), yaw (rad), reach fraction and reach point (m): the pose state."""
        return context.get_discrete_state(self._pose).get_value().tolist()

    # -- in Meshcat (cellsim.visual.cues) --------------------------------------------
    def visual_cues(self, view) -> list:
        """A marker above the head while a sensor sees this person (a sensor's sight, at their position)."""
        from cellsim.visual.cues import Cue, Part

        position = f"{self.module}.position"
        sights = list(view.sights)
        marker = Part(
            f"{view.frame_path(self.body_frame)}/seen", Sphere(0.09), SEEN, RigidTransform([0.0, 0.0, self.cfg.height + 0.2])
        )
        channels = tuple(dict.fromkeys([position, *(c for sight in sights for c in sight.channels)]))

        def choose(values):
            xy = values.get(position)
            if xy is None or any(v is None for v in xy):
                return None
            return "seen" if any(sight.sees(values, tuple(xy)) for sight in sights) else None

        return [Cue(f"{self.module}/seen", channels, {"seen": (marker,)}, choose)]

    replay_channels = ("position", "posture")

    def show_recorded(self, cell, root_context, values: dict) -> None:
        """Stand the body at its recorded position (m), turned and reaching as recorded (a black box without the
        posture: facing the way it last walked, arm down)."""
        xy = values.get(f"{self.module}.position")
        if xy is None or any(v is None for v in xy):
            return
        state = self.GetMyMutableContextFromRoot(root_context).get_mutable_discrete_state(self._pose)
        posture = values.get(f"{self.module}.posture")
        if posture is None or any(v is None for v in posture):
            x0, y0, yaw = state.get_value()[:3]
            if np.hypot(xy[0] - x0, xy[1] - y0) > 0.01:
                yaw = float(np.arctan2(xy[1] - y0, xy[0] - x0))
            posture = [yaw, 0.0, 0.0, 0.0, 0.0]
        state.SetFromVector(np.array([xy[0], xy[1], *posture], float))

    # -- behaviour ---------------------------------------------------------------
    def _press_buttons(self, context, xd, digital: bool) -> None:
        t = context.get_time()
        held = [0.0] * len(self.buttons)
        if digital:
            for button, leg in self._presses:
                if leg.arrive <= t < leg.arrive + PRESS_TIME - 1e-9:
                    held[button] = 1.0
        for group, value in zip(self._pressing, held):
            if read_scalar(context, group) != value:
                write_scalar(xd, group, value)

    @staticmethod
    def _pose_vector(pose: OperatorPose) -> list[float]:
        x, y = pose.xy.tolist()
        return [x, y, pose.yaw, pose.reach_fraction, *pose.reach_target.tolist()]

    def update(self, context, xd):
        view = self.consult_physical(context, xd)
        current = context.get_discrete_state(self._pose).get_value().tolist()
        if view.mode is TwinMode.MODEL:
            pose = pose_at(self.legs, self.start_yaw, context.get_time(), self.turns)
            vector, waypoint = self._pose_vector(pose), pose.waypoint
        elif view.sample is None:  # stale or corrupt: hold the last known pose
            vector, waypoint = current, None
        else:
            vector, waypoint = view.sample.tolist(), None
        if waypoint is not None and waypoint + 1 != read_scalar(context, self._waypoint):
            write_scalar(xd, self._waypoint, waypoint + 1)
        if self.buttons:
            self._press_buttons(context, xd, view.mode is TwinMode.MODEL)
        if vector == current:
            if context.get_discrete_state(self._previous_pose).get_value().tolist() != current:
                xd.get_mutable_vector(self._previous_pose).SetFromVector(np.array(current))  # still since then
            return  # standing still: nothing derived from the pose changes
        xd.get_mutable_vector(self._previous_pose).SetFromVector(np.array(current))
        xd.get_mutable_vector(self._pose).SetFromVector(np.array(vector))
        standing = (vector[0], vector[1], 1.0)  # the body, a metre above the floor
        write_scalar(xd, self._location, next((code for code, zone in self._zones if zone.contains(standing)), 0.0))
        for group, zone in self._flags:
            write_scalar(xd, group, 1.0 if zone.contains(standing) else 0.0)
        xd.get_mutable_vector(self._position).SetFromVector(np.array(vector[:2]))
        xd.get_mutable_vector(self._posture).SetFromVector(np.array(vector[2:]))
