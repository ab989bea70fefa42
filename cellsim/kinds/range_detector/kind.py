"""The range_detector kind: a safety scanner at a point, far / near / close."""

from __future__ import annotations

from cellsim.entity import TWIN_CHANNELS
from cellsim.kinds.range_detector.config import RangeDetectorConfig
from cellsim.kinds.range_detector.system import RangeDetector
from cellsim.kinds.sensing import add_sensor
from cellsim.channels import enum_type, number_type
from cellsim.kind import ModuleKind, Protocol
from cellsim.vocabulary import Range


class RangeDetectorKind(ModuleKind):
    name = "range_detector"
    section = "entities"
    config = RangeDetectorConfig
    summary = "A safety scanner: far / near / close from the nearest person's distance; fails safe to close."
    sample_fields = ("range", "distance")
    channels = (
        ("range", "enum", "far / near / close (rngDet)"),
        ("distance", "number, m", "measured distance to the nearest person"),
        ("unseen", "enum", "blind spot: near or close while a person truly is in that zone and the reading (noise, "
                           "or the physical sensor's sample) says farther, else none"),
        *TWIN_CHANNELS,
    )

    def protocol(self, name, cfg):
        return Protocol((("range", enum_type(Range)), ("distance", number_type(None))))

    def build(self, cell, name, cfg):
        return add_sensor(cell, name, RangeDetector(name, cfg, cell.seed, cell.duration))

    def findings(self, name, cfg, blackbox):
        from cellsim.kinds.sensing import blind_spots

        return blind_spots(name, blackbox, f"{name}.unseen")

    def abstraction(self, abstract, name, cfg):
        from cellsim.kinds.range_detector.abstraction import RangeDetectorAbstraction

        return RangeDetectorAbstraction(abstract, name, cfg)
