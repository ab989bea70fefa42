"""The safety controller: a discrete Drake system executing a risk model.

Ports (for each monitored variable ``v`` and controlled variable ``c`` of the
risk model, and each hazard ``H``):
  v (input): the monitored channel's code (enum code or 0/1).
  c (channel): the commanded value, coded for the machines that receive it
    (-1 when the risk model's default is "no request").
  H (channel): the hazard's phase (inact, act, mit, ..., mis).
See ``risk_model`` for the semantics of one control period.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from cellsim.behaviours.risk_model import RiskModel
from cellsim.channels import NO_VALUE as NO_REQUEST
from cellsim.channels import ChannelType, enum_type
from cellsim.systems import CellSystem, write_scalar
from cellsim.vocabulary import HazardPhase

_PHASES = HazardPhase.names()


class SafetyController(CellSystem):
    def __init__(
        self,
        module: str,
        period: float,
        risk_model: RiskModel,
        monitor_types: dict[str, ChannelType],
        command_types: dict[str, ChannelType],
    ):
        """``monitor_types``/``command_types``: channel type of each monitored / controlled variable."""
        super().__init__(module, period)
        self.risk_model = risk_model
        self.hazards = risk_model.hazards
        self._inputs = []
        for name in risk_model.monitored:
            ctype = monitor_types[name]
            port = self.declare_input(name, ctype=ctype)
            decode = ctype.domain() if ctype.kind == "enum" else (False, True)
            self._inputs.append((name, port, decode))
        self._phase_groups = [
            self.declare_channel(h.name, enum_type(HazardPhase), HazardPhase.INACTIVE, description=f"Phase of hazard {h.name}")
            for h in self.hazards
        ]
        self._commands = []
        for name, var in risk_model.controlled.items():
            ctype = replace(command_types[name], optional=var.default is None)
            group = self.declare_channel(name, ctype, var.default, description=f"Commanded {name}")
            self._commands.append((name, var, group, self._encoder(ctype)))
        self._timed = [
            (hi, ti) for hi, h in enumerate(self.hazards) for ti, tr in enumerate(h.transitions) if tr.after > 0
        ]
        self._since = self.declare_state("guard_since", np.full(max(len(self._timed), 1), np.nan))

    @staticmethod
    def _encoder(ctype: ChannelType):
        if ctype.kind == "bool":
            return lambda v: NO_REQUEST if v is None else (1.0 if v else 0.0)
        codes = {value: float(i) for i, value in enumerate(ctype.domain())}
        return lambda v: NO_REQUEST if v is None else codes[v]

    def update(self, context, xd):
        values = {}
        for name, port, decode in self._inputs:
            code = port.Eval(context)[0]
            values[name] = decode[int(code)] if 0 <= code < len(decode) else None
        phases = [_PHASES[int(context.get_discrete_state(g).GetAtIndex(0))] for g in self._phase_groups]
        for hazard, phase in zip(self.hazards, phases):
            values[hazard.name] = phase
        held = self._timers(context, xd, values, phases) if self._timed else {}

        new_phases = []
        for hi, (hazard, phase) in enumerate(zip(self.hazards, phases)):
            for ti, tr in enumerate(hazard.transitions):
                if tr.phase == phase and (held.get((hi, ti), False) if tr.after > 0 else tr.guard(values)):
                    phase = tr.to
                    write_scalar(xd, self._phase_groups[hi], _PHASES.index(phase))
                    break
            new_phases.append(phase)
        if new_phases != phases:
            self._write_commands(xd, new_phases)

    def _timers(self, context, xd, values: dict, phases: list[str]) -> dict:
        """Track how long the guards of ``after`` transitions have held; which have held long enough."""
        t = context.get_time()
        since = context.get_discrete_state(self._since).get_value().copy()
        held = {}
        for k, (hi, ti) in enumerate(self._timed):
            tr = self.hazards[hi].transitions[ti]
            if phases[hi] == tr.phase and tr.guard(values):
                since[k] = t if math.isnan(since[k]) else since[k]
                held[(hi, ti)] = t - since[k] >= tr.after - 1e-9
            else:
                since[k] = np.nan
        xd.get_mutable_vector(self._since).SetFromVector(since)
        return held

    def _write_commands(self, xd, phases: list[str]) -> None:
        """Commands are a function of the phases alone: the most restrictive demand, or the default."""
        for name, var, group, encode in self._commands:
            demanded = None
            for hazard, phase in zip(self.hazards, phases):
                value = hazard.demands.get(phase, {}).get(name)
                if value is not None and (demanded is None or var.domain.index(value) > var.domain.index(demanded)):
                    demanded = value
            write_scalar(xd, group, encode(var.default if demanded is None else demanded))
