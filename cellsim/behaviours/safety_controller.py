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

from cellsim.behaviours.risk_model import RiskModel, load_risk_model
from cellsim.channels import NO_VALUE as NO_REQUEST
from cellsim.channels import ChannelType, enum_type
from cellsim.config.typed_yaml import suggest
from cellsim.registry import ModuleKind, deferred
from cellsim.scenario import SafetyControllerConfig
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
        for name, var in risk_model.controlled.items():
            ctype = replace(command_types[name], optional=var.default is None)
            group = self.declare_channel(name, ctype, var.default, description=f"Commanded {name}")
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

    def _write_commands(self, xd, phases: list[str]) -> None:
        """Commands are a function of the phases alone: the most restrictive demand, or the default."""
        for name, var, group, encode in self._commands:
            demanded = None
            for hazard, phase in zip(self.hazards, phases):
                value = hazard.demands.get(phase, {}).get(name)
                if value is not None and (demanded is None or var.domain.index(value) > var.domain.index(demanded)):
                    demanded = value
            write_scalar(xd, group, encode(var.default if demanded is None else demanded))


# -- the module kind ----------------------------------------------------------------
def build_safety_controller(cell, name: str, cfg: SafetyControllerConfig) -> SafetyController:
    """The controller, its risk model's variables bound to channels and command inputs, checked."""
    from pydrake.systems.primitives import Multiplexer

    sf, builder, modules, channels = cell.sf, cell.builder, cell.modules, cell.channels()
    risk_model = load_risk_model(sf.resolve_path(f"behaviours.{name}.risk_model", cfg.risk_model))
    key = f"behaviours.{name}"
    missing = set(risk_model.monitored) - set(cfg.monitors)
    if missing:
        raise sf.error(f"{key}.monitors", f"the risk model monitors {', '.join(sorted(missing))}: bind them to channels")
    for var in cfg.monitors:
        if var not in risk_model.monitored:
            raise sf.error(f"{key}.monitors.{var}", f"'{var}' is not a monitored variable of the risk model ({', '.join(risk_model.monitored)})")
    for var in cfg.commands:
        if var not in risk_model.controlled:
            raise sf.error(f"{key}.commands.{var}", f"'{var}' is not a controlled variable of the risk model ({', '.join(risk_model.controlled)})")

    command_types: dict[str, ChannelType] = {}
    targets: dict[str, list] = {}
    for var in risk_model.controlled:
        inputs = cfg.commands.get(var, [])
        targets[var] = []
        for i, target in enumerate(inputs):
            where = f"{key}.commands.{var}.{i}"
            module_name, _, port_name = target.partition(".")
            system = modules.get(module_name)
            if system is None or not system.HasInputPort(port_name):
                inputs = [f"{m}.{p}" for m, system in modules.items() for p in getattr(system, "input_types", {})]
                raise sf.error(where, f"no command input '{target}'{suggest(target, inputs)} (inputs are written module.input)")
            ctype = getattr(system, "input_types", {}).get(port_name)
            if ctype is None:
                raise sf.error(where, f"'{target}' is not a command input")
            _check_domain(sf, where, var, risk_model.controlled[var], ctype)
            if var in command_types and command_types[var] != ctype:
                raise sf.error(where, f"'{target}' expects a different type than the other inputs of {var}")
            if builder.IsConnectedOrExported(system.GetInputPort(port_name)):
                raise sf.error(where, f"'{target}' is already driven by another module of the cell: an input has one "
                                      "driver")
            command_types[var] = ctype
            targets[var].append(system.GetInputPort(port_name))
        if var not in command_types:
            raise sf.error(f"{key}.commands", f"controlled variable '{var}' drives no command input")

    monitor_types: dict[str, ChannelType] = {}
    sources = {}
    for var, channel in cfg.monitors.items():
        where = f"{key}.monitors.{var}"
        if channel.partition(".")[0] == name:  # the controller's own command, read back
            signal = channel.partition(".")[2]
            if signal not in command_types:
                raise sf.error(where, f"'{channel}' is not a command of {name}")
            ctype = command_types[signal]
        elif channel in channels:
            ctype = channels[channel][0].type
            sources[var] = channels[channel][1]
        else:
            raise sf.error(where, f"no channel '{channel}'{suggest(channel, channels)}")
        _check_domain(sf, where, var, risk_model.monitored[var], ctype)
        monitor_types[var] = ctype

    controller = cell.add(name, SafetyController(name, cfg.period, risk_model, monitor_types, command_types))
    # one vector input: gathering the monitored channels in C++ costs the controller one read per period
    monitors = builder.AddNamedSystem(f"{name}.monitors", Multiplexer(len(controller.monitored_names)))
    for i, var in enumerate(controller.monitored_names):
        channel = cfg.monitors[var]
        port = sources.get(var) or controller.GetOutputPort(channel.partition(".")[2])
        builder.Connect(port, monitors.get_input_port(i))
    builder.Connect(monitors.get_output_port(0), controller.monitored_port)
    for var, ports in targets.items():
        for port in ports:
            builder.Connect(controller.GetOutputPort(var), port)
    return controller


def _check_domain(sf, where: str, var: str, variable, ctype: ChannelType) -> None:
    """The channel bound to a risk-model variable must carry its values (a number: in its unit)."""
    if variable.type == "number":
        if ctype.kind != "number":
            raise sf.error(where, f"{var} is a number but the channel carries {ctype.domain()}")
        if variable.unit is not None and ctype.unit != variable.unit:
            raise sf.error(where, f"{var} is in {variable.unit} but the channel is in {ctype.unit or 'no unit'}")
        return
    values = variable.domain
    if ctype.kind == "bool":
        ok = set(values) <= {False, True}
    elif ctype.kind == "enum":
        ok = set(values) <= set(ctype.domain())
    else:
        ok = False
    if not ok:
        raise sf.error(where, f"{var} takes {list(values)} but the channel carries {ctype.domain()}")


def _check(sf, name: str, cfg: SafetyControllerConfig) -> None:
    sf.resolve_path(f"behaviours.{name}.risk_model", cfg.risk_model)


KIND = ModuleKind(
    name="safety_controller",
    abstraction=deferred("cellsim.abstractions.controller:controller"),
    section="behaviours",
    config=SafetyControllerConfig,
    build=build_safety_controller,
    stage=20,
    check=_check,
    supervises=True,
    file_fields=("risk_model",),
    summary="A generic engine executing a risk model (docs/risk-model.md): hazard phase machines and their demands.",
    channels=(
        ("<hazard>", "enum", "each hazard's phase, in the phases the risk model declares"),
        ("<controlled variable>", "enum or bool", "the value commanded (null: no request)"),
    ),
)
