"""The guard_door kind in the abstract cell ``cellsim verify`` checks: open while any person is in the doorway.

A sensor offers its measurements (``SensorRole``): the floor stands each person at each of their
poses and calls the door's own ``measure`` on the built cell, so the abstract reading is what the
twin's door switch reads there; several people are combined as the switch does (any)."""

from __future__ import annotations

from cellsim.verify.model import AbstractCell, ModuleAbstraction, SensedSignal, SensorRole, context_of


class GuardDoorAbstraction(ModuleAbstraction):
    """The door open while any person's geometry is in its doorway."""

    def declare(self, cell: AbstractCell) -> None:
        of = context_of(self.system)
        cell.add_sensor(SensorRole(self.name, {"open": SensedSignal(lambda root: self.system.measure(of(root)), any)}))
