"""The light_barrier kind: a light curtain whose beams fill a box."""

from __future__ import annotations

from cellsim.entity import TWIN_CHANNELS
from cellsim.kinds.light_barrier.config import LightBarrierConfig
from cellsim.kinds.light_barrier.system import LightBarrier
from cellsim.kinds.sensing import add_sensor
from cellsim.channels import BOOL
from cellsim.kind import ModuleKind, Protocol


class LightBarrierKind(ModuleKind):
    name = "light_barrier"
    section = "entities"
    config = LightBarrierConfig
    summary = "A light curtain whose beams fill a box: broken while a person's geometry is in it; fails safe to broken."
    sample_fields = ("broken",)
    channels = (
        ("broken", "bool", "true while any person's geometry intersects the beams (lgtBar); with restart_interlock, "
                           "latched: true from the first break until a reset"),
        ("interrupted", "bool", "only with restart_interlock: the beams interrupted now, latch or not"),
        ("unseen", "enum", "blind spot: beams while a person truly meets the beams that the curtain reports clear "
                           "(its physical twin's sample), else none"),
        *TWIN_CHANNELS,
    )
    inputs = (
        ("reset", "bool", "only with restart_interlock: a rising edge resets a tripped curtain whose beams are clear"),
    )

    def protocol(self, name, cfg):
        return Protocol((("broken", BOOL),))

    def build(self, cell, name, cfg):
        return add_sensor(cell, name, LightBarrier(name, cfg))

    def findings(self, name, cfg, blackbox):
        from cellsim.kinds.sensing import blind_spots

        return blind_spots(name, blackbox, f"{name}.unseen")

    def abstraction(self, abstract, name, cfg):
        from cellsim.kinds.light_barrier.abstraction import LightBarrierAbstraction

        return LightBarrierAbstraction(abstract, name, cfg)
