"""Safety sensors in the abstract cell: what their own SceneGraph queries read of a person, per place.

A sensor offers its measurements (``SensorRole``): the floor stands each person at
each of its poses and calls the sensor's own ``measure`` on the built cell, so the
abstract reading is what the twin's sensor computes there. Several people are
combined as the sensor does: a curtain is broken by any of them, a scanner reads
the nearest and the innermost field.
"""

from __future__ import annotations

from cellsim.verify.model import ModuleAbstraction, AbstractCell, SensedSignal, SensorRole
from cellsim.verify.prism import Command, Module, Var
from cellsim.vocabulary import Range


def _context_of(system):
    return lambda root: system.GetMyContextFromRoot(root)


def _nearest(order):
    return lambda values: min(values, key=order.index)


class LightBarrierAbstraction(ModuleAbstraction):
    """Beams broken by any person's geometry; with a restart interlock, tripped until a reset."""

    def declare(self, cell: AbstractCell) -> None:
        of = _context_of(self.system)
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


class RangeDetectorAbstraction(ModuleAbstraction):
    """The nearest person's range class and distance from the sensor head."""

    def declare(self, cell: AbstractCell) -> None:
        sensor, of = self.system, _context_of(self.system)
        order = [Range.CLOSE.value, Range.NEAR.value, Range.FAR.value]
        cell.add_sensor(SensorRole(self.name, {
            "range": SensedSignal(lambda root: sensor.classify(sensor.measure(of(root))).value, _nearest(order)),
            "distance": SensedSignal(lambda root: sensor.measure(of(root)), min),
        }))
        if self.cfg.noise_std > 0:
            cell.assume(f"{self.name}'s measurement noise ({self.cfg.noise_std:g} m) is not modelled")

    def build(self, cell: AbstractCell) -> None:
        """Its readings are the floor's."""


class AreaScannerAbstraction(ModuleAbstraction):
    """The innermost field a person is seen in, and the distance to the nearest person seen."""

    def declare(self, cell: AbstractCell) -> None:
        sensor, of = self.system, _context_of(self.system)
        values = [self.cfg.clear, *self.cfg.fields]  # the field channel's codes: clear, then innermost first
        innermost = [*self.cfg.fields, self.cfg.clear]
        cell.add_sensor(SensorRole(self.name, {
            "field": SensedSignal(lambda root: values[sensor.measure(of(root))[0]], _nearest(innermost)),
            "distance": SensedSignal(lambda root: sensor.measure(of(root))[1], min),
        }))

    def build(self, cell: AbstractCell) -> None:
        """Its readings are the floor's."""


def light_barrier(cell, name, cfg):
    return LightBarrierAbstraction(cell, name, cfg)


def range_detector(cell, name, cfg):
    return RangeDetectorAbstraction(cell, name, cfg)


def area_scanner(cell, name, cfg):
    return AreaScannerAbstraction(cell, name, cfg)
