"""The risk-model safety controller in the abstract cell: the engine's own parsed risk model.

Its hazards, guards, ``after:`` delays and demands come from the risk model the
engine executes (``SafetyController.risk_model``), translated by
``cellsim.verify.risk``; each monitored variable reads the channel the scenario
binds it to, and each command drives the inputs it is wired to, in their codes.
It offers one property per hazard: the mishap phase is never reached.
"""

from __future__ import annotations

from cellsim.verify.expressions import thresholds_of
from cellsim.verify.model import ModuleAbstraction, AbstractCell, Property, translate
from cellsim.verify.prism import Enum
from cellsim.verify.risk import risk_modules


class ControllerAbstraction(ModuleAbstraction):
    def __init__(self, cell: AbstractCell, name: str, cfg):
        super().__init__(cell, name, cfg)
        self.risk_model = self.system.risk_model

    def _own(self, channel: str) -> bool:
        return channel.partition(".")[0] == self.name

    def declare(self, cell: AbstractCell) -> None:
        guards = [tr.formula for h in self.risk_model.hazards for tr in h.transitions]
        for var, channel in self.cfg.monitors.items():
            if not self._own(channel):  # its own commands are defined in build
                cell.read(channel, f"{self.name} (monitoring {var})")
            if self.risk_model.monitored[var].type == "number":
                cell.compares(channel, thresholds_of(guards, var).values)

    def build(self, cell: AbstractCell) -> None:
        c, rm = self.name, self.risk_model
        prefix = f"{c}_"
        monitored, encodings = {}, {}
        for var, channel in self.cfg.monitors.items():
            name = f"{c}_m_{var}"
            monitored[var] = name
            source = cell.read(channel, c)  # its own commands too: defined below
            variable = rm.monitored[var]
            if variable.type == "number":  # the channel's regions: its thresholds include the guards'
                target = encodings[var] = cell.encoding(channel)
            else:
                target = bool if variable.type == "bool" else Enum(tuple(variable.values))
            cell.formulas[name] = translate(source, cell.encoding(channel), target)
        own = cell.period * cell.every(c)  # (its after: counters advance at its own updates)
        modules = risk_modules(rm, own, prefix=prefix, monitored=monitored, encodings=encodings)
        for module in modules.modules:
            cell.add(module)
        cell.formulas.update(modules.formulas)
        for hazard in rm.hazards:
            phase = f"{prefix}{hazard.name}"
            cell.define(f"{c}.{hazard.name}", phase, modules.phases)
            cell.properties.append(Property(
                f"{hazard.name}:mishap",
                f"hazard {hazard.name} never reaches its mishap phase '{rm.phases.mishap}'"
                + (f" ({hazard.description})" if getattr(hazard, "description", "") else ""),
                bad=f"{phase} = {modules.phases.code(rm.phases.mishap)}",
                hazard=(f"{c}.{hazard.name}", rm.phases.mishap),
            ))
        for var, controlled in rm.controlled.items():
            encoding = cell.encoding(f"{c}.{var}")
            cmd = f"{prefix}cmd_{var}"
            domain = Enum(tuple(str(v) for v in controlled.domain))
            if encoding is bool:
                cell.define(f"{c}.{var}", f"({cmd} = {list(controlled.domain).index(True)})", bool)
            else:
                cell.define(f"{c}.{var}", translate(cmd, domain, encoding), encoding)

