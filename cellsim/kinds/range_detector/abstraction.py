"""The range_detector kind in the abstract cell: the nearest person's range.

A sensor offers its measurements (``SensorRole``): the floor stands each person at each of its poses
and calls the sensor's own ``measure`` on the built cell, so the abstract reading is what the twin's
sensor computes there; several people are combined as the sensor does."""

from __future__ import annotations

from cellsim.verify.model import AbstractCell, ModuleAbstraction, SensedSignal, SensorRole, context_of, nearest
from cellsim.vocabulary import Range


class RangeDetectorAbstraction(ModuleAbstraction):
    """The nearest person's range class and distance from the sensor head."""

    def declare(self, cell: AbstractCell) -> None:
        sensor, of = self.system, context_of(self.system)
        order = [Range.CLOSE.value, Range.NEAR.value, Range.FAR.value]
        cell.add_sensor(SensorRole(self.name, {  # both from one measured distance (m)
            "range": SensedSignal(lambda distance: sensor.classify(distance).value, nearest(order)),
            "distance": SensedSignal(lambda distance: distance, min),
        }, measure=lambda root: sensor.measure(of(root))))
        if self.cfg.noise_std > 0:
            cell.assume(f"{self.name}'s measurement noise ({self.cfg.noise_std:g} m) is not modelled")

    def build(self, cell: AbstractCell) -> None:
        """Its readings are the floor's."""
