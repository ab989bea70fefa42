"""A safety scanner at a point: far / near / close from the nearest person's distance to it."""

from __future__ import annotations

import math

import numpy as np

from cellsim.channels import enum_type, number_type
from cellsim.entity import valid_code
from cellsim.kinds.sensing import HEAD_RADIUS, REACH, SAMPLE_ROUNDING, GeometrySensor
from cellsim.systems import read_scalar, write_scalar
from cellsim.vocabulary import Range, TwinMode, value_set
from cellsim.kinds.range_detector.config import RangeDetectorConfig


class RangeDetector(GeometrySensor):
    """A safety scanner at a point, classifying the nearest person's distance.

    Ports:
      geometry_query (input): SceneGraph QueryObject.
      physical_sample (input): [t, link, range code, distance (m)].
      range (channel, far/near/close): close below ``close_below`` m, near below
        ``near_below`` m, else far (rngDet).
      distance (channel, m): the measured signed distance from the sensor to the
        nearest target surface (``near_below`` + 1 m when nobody is nearer).
      unseen (channel, none/near/close): a blind spot: the zone a person truly is in (by the geometry, with no
        noise) while the reading says farther (its noise, or its physical twin's sample), else none.
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
        self.unseen_readings = value_set(f"{module}_unseen", ["none", Range.NEAR.value, Range.CLOSE.value])
        self._unseen = self.declare_channel(
            "unseen", enum_type(self.unseen_readings), "none",
            description="Blind spot: the zone a person truly is in that the reading does not cover")

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
        """The distance (m) the sensor reads: the true one plus its noise."""
        return self._noisy(context, self.true_distance(context))

    def _noisy(self, context, distance: float) -> float:
        """``distance`` (m) as the sensor reads it at ``context``'s tick: plus its noise there."""
        return distance if self._noise is None else distance + self._noise[int(round(context.get_time() / self.period))]

    def true_distance(self, context) -> float:
        """The distance (m) from the sensor's point to the nearest target, up to ``reach``, with no noise. The
        distance from the point is the distance from the sensor head (a sphere around it) plus its radius."""
        query = self.query_port.Eval(context)
        nearest = self.reach
        for target in self.targets:
            distance = query.ComputeSignedDistancePairClosestPoints(self.head_id, target).distance + HEAD_RADIUS
            if distance < nearest:
                nearest = distance
        return nearest

    def sample_is_valid(self, sample) -> bool:
        """A range code, and a distance it is the class of, within ``SAMPLE_ROUNDING`` (a sample whose two fields
        disagree: one of them is wrong, and a reader of either would act on it)."""
        if not (valid_code(sample[0], Range) and math.isfinite(sample[1])):
            return False
        reported, distance = Range.from_code(int(sample[0])), sample[1]
        return reported in (self.classify(distance - SAMPLE_ROUNDING), self.classify(distance + SAMPLE_ROUNDING))

    def update(self, context, xd):
        view = self.consult_physical(context, xd)
        if view.mode is TwinMode.MODEL:
            true_distance = self.true_distance(context)
            distance = self._noisy(context, true_distance)
            reading = self.classify(distance)
        elif view.sample is None:  # failing safe: close (and the truth kept for the next update's judgement)
            distance, reading = 0.0, Range.CLOSE
            true_distance = self.true_distance(context) if self.query_port.HasValue(context) else None
        else:
            reading, distance = Range.from_code(view.sample[0]), view.sample[1]
            true_distance = self.true_distance(context) if self.query_port.HasValue(context) else None
        write_scalar(xd, self._range, reading.code)
        write_scalar(xd, self._distance, distance)
        # a blind spot: someone truly in a zone more restrictive than the reading (noise, or the physical sensor)
        truly = Range.FAR if true_distance is None else self.classify(true_distance)
        unseen = "none"
        for truth, shown in self.held_to(
                context, xd, float(truly.code), float(reading.code),
                view.mode is not TwinMode.MODEL and view.sample is not None,
                lambda a, b: max(a, b, key=lambda code: _RESTRICTIVE[Range.from_code(int(code))])):
            truth, shown = Range.from_code(int(truth)), Range.from_code(int(shown))
            stricter_than_found = unseen == "none" or _RESTRICTIVE[truth] > _RESTRICTIVE[Range(unseen)]
            if _RESTRICTIVE[truth] > _RESTRICTIVE[shown] and stricter_than_found:
                unseen = truth.value
        code = self.unseen_readings(unseen).code
        if code != read_scalar(context, self._unseen):
            write_scalar(xd, self._unseen, code)


_RESTRICTIVE = {Range.FAR: 0, Range.NEAR: 1, Range.CLOSE: 2}
"""How restrictive each reading is: a person truly nearer than the reading says is unseen."""
