"""The safety_controller kind: its risk model loaded, each variable bound to a channel or command input and checked."""

from __future__ import annotations

from cellsim.channels import ChannelType
from cellsim.config.typed_yaml import suggest
from cellsim.kinds.safety_controller.config import SafetyControllerConfig
from cellsim.kinds.safety_controller.risk_model import RiskModelFile, load_risk_model
from cellsim.kinds.safety_controller.system import SafetyController
from cellsim.kind import ModuleKind


class SafetyControllerKind(ModuleKind):
    """The risk-model safety controller: reads every channel, drives the command inputs."""

    name = "safety_controller"
    section = "behaviours"
    config = SafetyControllerConfig
    summary = "A generic engine executing a risk model (docs/risk-model.md): hazard phase machines and their demands."
    stage = 20
    supervises = True
    files = {"risk_model": "risk model"}
    formats = (("Risk model file", "The file a `safety_controller` names (format: docs/risk-model.md).", RiskModelFile),)
    channels = (
        ("<hazard>", "enum", "each hazard's phase, in the phases the risk model declares"),
        ("<controlled variable>", "enum or bool", "the value commanded (null: no request)"),
    )

    def build(self, cell, name, cfg):
        return build_safety_controller(cell, name, cfg)

    def check(self, sf, name, cfg):
        _check(sf, name, cfg)

    def abstraction(self, abstract, name, cfg):
        from cellsim.kinds.safety_controller.abstraction import ControllerAbstraction

        # (glue, not the safety argument: verify's own tests, too slow for the mutation run's selection, reach it)
        return ControllerAbstraction(abstract, name, cfg)  # pragma: no mutate


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
            _check_domain(sf, where, var, risk_model.controlled[var], ctype, monitored=False)
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
        _check_domain(sf, where, var, risk_model.monitored[var], ctype, monitored=True)
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


def _check_domain(sf, where: str, var: str, variable, ctype: ChannelType, monitored: bool) -> None:
    """The channel bound to a risk-model variable must carry its values (a number: in its unit); a ``monitored`` one's
    values must also be all the channel carries: a value the model does not list (a stale robot's ``unknown``) would
    make every guard on it false, which reads as no hazard."""
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
    unlisted = [v for v in ctype.domain() if v not in values] if monitored and ctype.kind == "enum" else []
    if unlisted:
        raise sf.error(where, f"the channel also carries {', '.join(map(str, unlisted))}, which the risk model's {var} "
                              "does not list: every guard on it would be false there, as if no hazard (list them)")


def _check(sf, name: str, cfg: SafetyControllerConfig) -> None:
    sf.resolve_path(f"behaviours.{name}.risk_model", cfg.risk_model)
