"""The range_detector kind: a safety scanner at a point, far / near / close."""

from __future__ import annotations

from cellsim.entity import TWIN_CHANNELS
from cellsim.kinds.range_detector.config import RangeDetectorConfig
from cellsim.kinds.range_detector.system import RangeDetector
from cellsim.kinds.sensing import add_sensor
from cellsim.kind import ModuleKind


class RangeDetectorKind(ModuleKind):
    name = "range_detector"
    section = "entities"
    config = RangeDetectorConfig
    summary = "A safety scanner: far / near / close from the nearest person's distance; fails safe to close."
    sample_fields = ("range", "distance")
    channels = (
        ("range", "enum", "far / near / close (rngDet)"),
        ("distance", "number, m", "measured distance to the nearest person"),
        *TWIN_CHANNELS,
    )

    def build(self, cell, name, cfg):
        return add_sensor(cell, name, RangeDetector(name, cfg, cell.seed, cell.duration))

    def abstraction(self, abstract, name, cfg):
        from cellsim.kinds.range_detector.abstraction import RangeDetectorAbstraction

        return RangeDetectorAbstraction(abstract, name, cfg)
