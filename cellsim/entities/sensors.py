"""The cell's safety sensors, measuring geometry through SceneGraph queries.

Both sensors see the geometries listed by ``set_targets`` (the builder passes
every operator's body), so the twin reports what the geometry says, including
situations nobody scripted (a second operator, a reach from behind).
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.geometry import (
    Box,
    GeometryInstance,
    MakePhongIllustrationProperties,
    ProximityProperties,
    QueryObject,
    Rgba,
    Sphere,
)
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform

from cellsim.channels import BOOL, enum_type, number_type
from cellsim.entities.twin import EntitySystem, TWIN_CHANNELS, valid_code
from cellsim.registry import ModuleKind, deferred
from cellsim.scenario import LightBarrierConfig, RangeDetectorConfig
from cellsim.systems import read_scalar, write_scalar
from cellsim.vocabulary import Range, TwinMode


HEAD_RADIUS = 0.05  # m, the scanner head's sphere
REACH = 1.0
"""How far (m) from a sensor's volume a person may stand and still be the one it sees
(an arm reaching in): used only to mark people in Meshcat."""
BEAMS_CLEAR = Rgba(1.0, 0.15, 0.1, 0.12)
BEAMS_BROKEN = Rgba(1.0, 0.0, 0.0, 0.7)


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


class LightBarrier(GeometrySensor):
    """A light curtain whose beams fill a box.

    Ports:
      geometry_query (input): SceneGraph QueryObject.
      physical_sample (input): [t, link, broken (0/1)].
      reset (input, with restart_interlock): a rising edge resets a tripped curtain whose beams are clear.
      broken (channel, bool): true while any target geometry intersects the beams; with
        restart_interlock, *latched*: from the first break until a reset.
      interrupted (channel, bool, with restart_interlock): the beams interrupted now, latch or not.
    Fails safe (reads broken and interrupted) when its physical sample is stale or corrupt.
    """

    def __init__(self, module: str, cfg: LightBarrierConfig):
        super().__init__(module, cfg.period, cfg.twin, ("broken",))
        self.cfg = cfg
        self.beam_id = None
        self._broken = self.declare_channel(
            "broken", BOOL, False, description="Beams interrupted (with a restart interlock: tripped until reset)"
        )
        if cfg.restart_interlock:
            self.reset_port = self.declare_input("reset", ctype=BOOL, default=0.0)
            self._reset_seen = self.declare_state("reset_seen", [0.0])
            self._interrupted = self.declare_channel(
                "interrupted", BOOL, False, description="Beams interrupted now (the latch aside)")

    def register_geometry(self, scene_graph) -> list:
        source = scene_graph.RegisterSource(self.module)
        beams = GeometryInstance(RigidTransform(list(self.cfg.center)), Box(*self.cfg.size), f"{self.module}/beams")
        beams.set_proximity_properties(ProximityProperties())
        beams.set_illustration_properties(MakePhongIllustrationProperties([1.0, 0.15, 0.1, 0.25]))
        self.beam_id = scene_graph.RegisterAnchoredGeometry(source, beams)
        return [self.beam_id]

    # -- in Meshcat (cellsim.visual.cues) ------------------------------------------------
    def visual_cues(self, view) -> list:
        """The beams: faint while clear, red while broken."""
        from cellsim.visual.cues import Cue, parts_of

        box = [(RigidTransform(list(self.cfg.center)), Box(*self.cfg.size))]
        channel = f"{self.module}.broken"
        looks = {
            "clear": parts_of(f"{self.module}/beams/clear", box, BEAMS_CLEAR),
            "broken": parts_of(f"{self.module}/beams/broken", box, BEAMS_BROKEN),
        }
        choose = lambda values: None if values.get(channel) is None else ("broken" if values[channel] else "clear")  # noqa: E731
        return [Cue(f"{self.module}/beams", (channel,), looks, choose, (view.geometry_path(self.beam_id),))]

    def sight(self):
        """Broken beams see whoever stands within REACH of their footprint."""
        from cellsim.visual.cues import Sight

        channel = f"{self.module}.broken"
        (x, y, _), (sx, sy, _) = self.cfg.center, self.cfg.size
        near = lambda xy: abs(xy[0] - x) <= sx / 2 + REACH and abs(xy[1] - y) <= sy / 2 + REACH  # noqa: E731
        return Sight((channel,), lambda values, xy: bool(values.get(channel)) and near(xy))

    def measure(self, context) -> bool:
        query = self.query_port.Eval(context)
        return any(
            query.ComputeSignedDistancePairClosestPoints(self.beam_id, target).distance <= 0.0
            for target in self.targets
        )

    def update(self, context, xd):
        view = self.consult_physical(context, xd)
        if view.mode is TwinMode.MODEL:
            broken = self.measure(context)
        elif view.sample is None:
            broken = True
        else:
            broken = view.sample[0] > 0.5
        if self.cfg.restart_interlock:
            write_scalar(xd, self._interrupted, 1.0 if broken else 0.0)
            broken = self._interlocked(context, xd, broken)
        write_scalar(xd, self._broken, 1.0 if broken else 0.0)

    def _interlocked(self, context, xd, beams_broken: bool) -> bool:
        """Tripped from the first break until a reset (a rising edge) while the beams are clear."""
        reset = self.reset_port.Eval(context)[0] > 0.5
        seen = read_scalar(context, self._reset_seen) > 0.5
        if reset != seen:
            write_scalar(xd, self._reset_seen, 1.0 if reset else 0.0)
        tripped = read_scalar(context, self._broken) > 0.5
        if beams_broken:
            return True
        return tripped and not (reset and not seen)


class RangeDetector(GeometrySensor):
    """A safety scanner at a point, classifying the nearest person's distance.

    Ports:
      geometry_query (input): SceneGraph QueryObject.
      physical_sample (input): [t, link, range code, distance (m)].
      range (channel, far/near/close): close below ``close_below`` m, near below
        ``near_below`` m, else far (rngDet).
      distance (channel, m): the measured signed distance from the sensor to the
        nearest target surface (``near_below`` + 1 m when nobody is nearer).
    Fails safe (reads close) when its physical sample is stale or corrupt.
    """

    def __init__(self, module: str, cfg: RangeDetectorConfig, seed: int, duration: float):
        super().__init__(module, cfg.period, cfg.twin, ("range", "distance"))
        self.cfg = cfg
        self.reach = cfg.near_below + 1.0
        self.position = np.array(cfg.position, float)
        # measurement noise as a pure function of (seed, tick): a table drawn once
        ticks = int(math.ceil(duration / cfg.period)) + 2
        rng = np.random.default_rng([seed, 0x5CA7])
        self._noise = rng.normal(0.0, cfg.noise_std, ticks) if cfg.noise_std > 0 else None
        self._range = self.declare_channel("range", enum_type(Range), Range.FAR, description="Range class of the nearest person")
        self._distance = self.declare_channel(
            "distance",
            number_type("m"),
            self.reach,
            description="Measured distance to the nearest person",
        )

    def register_geometry(self, scene_graph) -> list:
        source = scene_graph.RegisterSource(self.module)
        self.head_id = self.register_head(scene_graph, source, self.position)
        return [self.head_id]

    def sight(self):
        """Near or close sees whoever stands within that range of the sensor (plus REACH / 2)."""
        from cellsim.visual.cues import Sight

        channel = f"{self.module}.range"
        within = {Range.NEAR.value: self.cfg.near_below, Range.CLOSE.value: self.cfg.close_below}

        def sees(values, xy) -> bool:
            limit = within.get(values.get(channel))
            return limit is not None and math.hypot(xy[0] - self.position[0], xy[1] - self.position[1]) <= limit + REACH / 2

        return Sight((channel,), sees)

    def classify(self, distance: float) -> Range:
        if distance < self.cfg.close_below:
            return Range.CLOSE
        if distance < self.cfg.near_below:
            return Range.NEAR
        return Range.FAR

    def measure(self, context) -> float:
        # The distance from the sensor's point to a target is the distance from the
        # sensor head (a sphere around that point) plus its radius.
        query = self.query_port.Eval(context)
        nearest = self.reach
        for target in self.targets:
            distance = query.ComputeSignedDistancePairClosestPoints(self.head_id, target).distance + HEAD_RADIUS
            if distance < nearest:
                nearest = distance
        if self._noise is not None:
            nearest += self._noise[int(round(context.get_time() / self.period))]
        return nearest

    def sample_is_valid(self, sample) -> bool:
        return valid_code(sample[0], Range)

    def update(self, context, xd):
        view = self.consult_physical(context, xd)
        if view.mode is TwinMode.MODEL:
            distance = self.measure(context)
            reading = self.classify(distance)
        elif view.sample is None:
            distance, reading = 0.0, Range.CLOSE
        else:
            reading, distance = Range.from_code(view.sample[0]), view.sample[1]
        write_scalar(xd, self._range, reading.code)
        write_scalar(xd, self._distance, distance)


def build_sensor(system: GeometrySensor):
    """A sensor's builder: its own geometry, the SceneGraph query, and every person as a target."""

    def build(cell, name, cfg):
        sensor = cell.add(name, system(name, cfg, cell))
        cell.register_geometry(sensor)
        cell.connect_query(sensor.query_port)
        cell.after_entities(lambda: sensor.set_targets(cell.people))
        return sensor

    return build


LIGHT_BARRIER = ModuleKind(
    name="light_barrier",
    abstraction=deferred("cellsim.abstractions.sensors:light_barrier"),
    section="entities",
    config=LightBarrierConfig,
    build=build_sensor(lambda name, cfg, cell: LightBarrier(name, cfg)),
    summary="A light curtain whose beams fill a box: broken while a person's geometry is in it; fails safe to broken.",
    sample_fields=("broken",),
    channels=(
        ("broken", "bool", "true while any person's geometry intersects the beams (lgtBar); with restart_interlock, "
                           "latched: true from the first break until a reset"),
        ("interrupted", "bool", "only with restart_interlock: the beams interrupted now, latch or not"),
        *TWIN_CHANNELS,
    ),
    inputs=(
        ("reset", "bool", "only with restart_interlock: a rising edge resets a tripped curtain whose beams are clear"),
    ),
)

RANGE_DETECTOR = ModuleKind(
    name="range_detector",
    abstraction=deferred("cellsim.abstractions.sensors:range_detector"),
    section="entities",
    config=RangeDetectorConfig,
    build=build_sensor(lambda name, cfg, cell: RangeDetector(name, cfg, cell.seed, cell.duration)),
    summary="A safety scanner: far / near / close from the nearest person's distance; fails safe to close.",
    sample_fields=("range", "distance"),
    channels=(
        ("range", "enum", "far / near / close (rngDet)"),
        ("distance", "number, m", "measured distance to the nearest person"),
        *TWIN_CHANNELS,
    ),
)
