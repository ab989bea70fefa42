"""The safety controller: a discrete Drake system executing a risk model.

Ports (for each controlled variable ``c`` of the risk model, and each hazard ``H``):
  monitored (input): the codes (enum code, 0/1, or the number in its unit) of the
    risk model's monitored variables, in the order the risk model lists them (``monitored_names``); the
    builder gathers the monitored channels into it with a Multiplexer.
  c (channel): the commanded value, coded for the machines that receive it
    (-1 when the risk model's default is "no request").
  H (channel): the hazard's phase (inact, act, mit, ..., mis).
See ``risk_model`` for the semantics of one control period.

A control period whose inputs equal the previous period's, after a period that
changed nothing and left no ``after`` timer running, cannot change anything
either (the rules are a function of the inputs, the phases and those timers),
so the engine skips it: the controller costs almost nothing while the cell is
quiet, and what it computes is exactly what a full evaluation would.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from cellsim.kinds.safety_controller.risk_model import RiskModel
from cellsim.channels import NO_VALUE as NO_REQUEST
from cellsim.channels import ChannelType, enum_type
from cellsim.systems import CellSystem, write_scalar
from cellsim.vocabulary import value_set


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
        self.monitored_names = list(risk_model.monitored)
        self.monitored_types = [monitor_types[name] for name in self.monitored_names]
        self._decoders = [
            (name, ctype.domain() if ctype.kind == "enum" else (False, True) if ctype.kind == "bool" else None)
            for name, ctype in zip(self.monitored_names, self.monitored_types)
        ]
        self.monitored_port = self.declare_input("monitored", len(self.monitored_names))
        # the risk model's own phases, in its words
        self.phases = tuple(risk_model.phases.values)
        self.phase_type = value_set(f"{module}_phase", self.phases)
        self._phase_groups = [
            self.declare_channel(h.name, enum_type(self.phase_type), risk_model.phases.initial, description=f"Phase of hazard {h.name}")
            for h in self.hazards
        ]
        self._commands = []
        # from the start, what the initial phases demand (a model may start every hazard in a phase that stops the arm)
        initially = self.commanded([risk_model.phases.initial] * len(self.hazards))
        for name, var in risk_model.controlled.items():
            ctype = replace(command_types[name], optional=initially[name] is None)
            group = self.declare_channel(name, ctype, initially[name], description=f"Commanded {name}")
            self._commands.append((name, var, group, self._encoder(ctype)))
        # each hazard's transitions by the phase they leave, in the order listed
        self._leaving = [
            {phase: [(ti, tr) for ti, tr in enumerate(h.transitions) if tr.phase == phase] for phase in self.phases}
            for h in self.hazards
        ]
        self._timed = [
            (hi, ti) for hi, h in enumerate(self.hazards) for ti, tr in enumerate(h.transitions) if tr.after > 0
        ]
        self._since = self.declare_state("guard_since", np.full(max(len(self._timed), 1), np.nan))
        # [settled (0/1), the inputs it settled on]: see the module docstring
        self._memory = self.declare_state("settled_on", np.full(1 + len(self.monitored_names), np.nan))

    def hazard_phases(self) -> dict[str, dict]:
        """Each hazard's channel with its initial and mishap phases (recorded in the black box)."""
        phases = self.risk_model.phases
        return {f"{self.module}.{h.name}": {"initial": phases.initial, "mishap": phases.mishap} for h in self.hazards}

    @staticmethod
    def _encoder(ctype: ChannelType):
        if ctype.kind == "bool":
            return lambda v: NO_REQUEST if v is None else (1.0 if v else 0.0)
        codes = {value: float(i) for i, value in enumerate(ctype.domain())}
        return lambda v: NO_REQUEST if v is None else codes[v]

    def encode_monitored(self, values: dict) -> np.ndarray:
        """The ``monitored`` input vector for named values (tests, replays)."""
        return np.array([ctype.encode(values[name])[0] for name, ctype in zip(self.monitored_names, self.monitored_types)])

    def update(self, context, xd):
        codes = self.monitored_port.Eval(context).tolist()
        memory = context.get_discrete_state(self._memory).get_value().tolist()
        if memory[0] == 1.0 and codes == memory[1:]:
            return  # the same inputs as a period that changed nothing: nothing changes
        values = {}
        for (name, decode), code in zip(self._decoders, codes):
            if decode is None:  # a number, in its unit; NaN (no value) makes every comparison false
                values[name] = code
            else:
                values[name] = decode[int(code)] if 0 <= code < len(decode) else None
        phases = [self.phases[int(context.get_discrete_state(g)[0])] for g in self._phase_groups]
        for hazard, phase in zip(self.hazards, phases):
            values[hazard.name] = phase
        held, timing = self._timers(context, xd, values, phases) if self._timed else ({}, False)

        new_phases = []
        for hi, phase in enumerate(phases):
            for ti, tr in self._leaving[hi][phase]:
                if held.get((hi, ti), False) if tr.after > 0 else tr.guard(values):
                    phase = tr.to
                    write_scalar(xd, self._phase_groups[hi], self.phases.index(phase))
                    break
            new_phases.append(phase)
        changed = new_phases != phases
        if changed:
            self._write_commands(xd, new_phases)
        settled = not changed and not timing
        if settled or memory[0] == 1.0:
            xd.get_mutable_vector(self._memory).SetFromVector(np.array([1.0 if settled else 0.0, *codes]))

    def _timers(self, context, xd, values: dict, phases: list[str]) -> tuple[dict, bool]:
        """Track how long the guards of ``after`` transitions have held.

        Returns which have held long enough, and whether any guard is being timed.
        """
        t = context.get_time()
        since = context.get_discrete_state(self._since).get_value().copy()
        held, timing = {}, False
        for k, (hi, ti) in enumerate(self._timed):
            tr = self.hazards[hi].transitions[ti]
            if phases[hi] == tr.phase and tr.guard(values):
                since[k] = t if math.isnan(since[k]) else since[k]
                held[(hi, ti)] = t - since[k] >= tr.after - 1e-9
                timing = True
            else:
                since[k] = np.nan
        xd.get_mutable_vector(self._since).SetFromVector(since)
        return held, timing

    def commanded(self, phases: list[str]) -> dict:
        """Each controlled variable's command when the hazards are in ``phases``: the most restrictive demand of
        theirs, or its default (None: no request). Commands are a function of the phases alone."""
        commands = {}
        for name, var in self.risk_model.controlled.items():
            demanded = None
            for hazard, phase in zip(self.hazards, phases):
                value = hazard.demands.get(phase, {}).get(name)
                if value is not None and (demanded is None or var.domain.index(value) > var.domain.index(demanded)):
                    demanded = value
            commands[name] = var.default if demanded is None else demanded
        return commands

    def _write_commands(self, xd, phases: list[str]) -> None:
        commands = self.commanded(phases)
        for name, _, group, encode in self._commands:
            write_scalar(xd, group, encode(commands[name]))
