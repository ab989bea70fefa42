"""The area_scanner kind in the abstract cell: the innermost field a person is seen in.

A sensor offers its measurements (``SensorRole``): the floor stands each person at each of its poses
and calls the sensor's own ``measure`` on the built cell, so the abstract reading is what the twin's
sensor computes there; several people are combined as the sensor does."""

from __future__ import annotations

from cellsim.verify.model import AbstractCell, ModuleAbstraction, SensedSignal, SensorRole, context_of, nearest


class _Scan:
    """One scan at a pose, as ``AreaScanner.measure`` gives it, each part measured only when read: the field, the
    distance (the floor measures what somebody reads)."""

    def __init__(self, sensor, query):
        self.sensor, self.query, self._parts = sensor, query, {}

    def __getitem__(self, part: int):
        if part not in self._parts:
            self._parts[part] = self.sensor.occupancy(self.query)[0] if part == 0 else self.sensor.nearest_seen(self.query)
        return self._parts[part]


class AreaScannerAbstraction(ModuleAbstraction):
    """The innermost field a person is seen in, and the distance to the nearest person seen."""

    def declare(self, cell: AbstractCell) -> None:
        sensor, of = self.system, context_of(self.system)
        values = [self.cfg.clear, *self.cfg.fields]  # the field channel's codes: clear, then innermost first
        innermost = [*self.cfg.fields, self.cfg.clear]
        cell.add_sensor(SensorRole(self.name, {  # both from one scan: (field code, distance)
            "field": SensedSignal(lambda scan: values[scan[0]], nearest(innermost)),
            "distance": SensedSignal(lambda scan: scan[1], min),
        }, measure=lambda root: _Scan(sensor, sensor.query_port.Eval(of(root)))))

    def build(self, cell: AbstractCell) -> None:
        """Its readings are the floor's."""
