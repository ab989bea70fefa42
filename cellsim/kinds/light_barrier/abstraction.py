"""The light_barrier kind in the abstract cell: beams broken by any person.

A sensor offers its measurements (``SensorRole``): the floor stands each person at each of its poses
and calls the sensor's own ``measure`` on the built cell, so the abstract reading is what the twin's
sensor computes there; several people are combined as the sensor does."""

from __future__ import annotations

from cellsim.verify.model import AbstractCell, ModuleAbstraction, SensedSignal, SensorRole, context_of
from cellsim.verify.prism import Command, Module, Var


class LightBarrierAbstraction(ModuleAbstraction):
    """Beams broken by any person's geometry; with a restart interlock, tripped until a reset."""

    def declare(self, cell: AbstractCell) -> None:
        of = context_of(self.system)
        port = "beams" if self.cfg.restart_interlock else "broken"
        cell.add_sensor(SensorRole(self.name, {port: SensedSignal(lambda root: self.system.measure(of(root)), any)}))
        if self.cfg.restart_interlock:  # the beams themselves, before the interlock
            cell.internal[f"{self.name}.beams"] = bool
            cell.read(f"{self.name}.beams", self.name)

    def build(self, cell: AbstractCell) -> None:
        if not self.cfg.restart_interlock:
            return
        tripped, seen = f"{self.name}_tripped", f"{self.name}_reset_seen"
        reset = f"({cell.input(self.name, 'reset')} = 1)"
        beams = cell.read(f"{self.name}.beams", self.name)
        cell.add(Module(self.name, [Var(tripped, boolean=True), Var(seen, boolean=True)], [
            Command("true", (("1", {tripped: f"{beams} | ({tripped} & !({reset} & !{seen}))", seen: reset}),)),
        ], comment=f"{self.name}: tripped from the first break until a reset (a rising edge) while the beams are clear"))
        cell.define(f"{self.name}.broken", tripped)
