"""The operator kind: a person walking waypoints, with body geometry the sensors measure."""

from __future__ import annotations

from cellsim.entity import TWIN_CHANNELS
from cellsim.kinds.operator.config import OperatorConfig
from cellsim.kinds.operator.system import Operator, RouteError, plan_routes
from cellsim.channels import BOOL, enum_type, number_type
from cellsim.kind import ModuleKind, Protocol
from cellsim.vocabulary import value_set


class OperatorKind(ModuleKind):
    name = "operator"
    section = "entities"
    config = OperatorConfig
    summary = "A person walking an ordered list of waypoints, waiting and reaching, with body geometry the sensors measure."
    sample_fields = Operator.POSE_FIELDS
    command_fields = ("notification", "<alert>")
    inputs = (
        ("notification", "enum", "what a safety controller tells the person (one of notifications)"),
        ("<alert>", "bool", "for each of alerts: a safety controller's alert the person reacts to"),
    )
    channels = (
        ("location", "enum", "the layout.operator_zones zone stood in, else layout.operator_outside (oloc)"),
        ("<flag>", "bool", "for each of layout.operator_flags: standing in that volume (otab)"),
        ("waypoint", "enum", "the waypoint walked to or waited at"),
        ("position", "vector, m", "x, y of the body, at every update"),
        ("posture", "vector", "yaw (rad), reach fraction, reach point x, y, z (m): how the body turns and reaches"),
        *TWIN_CHANNELS,
    )

    def protocol(self, name, cfg):
        notifications = enum_type(value_set(f"{name}_notification", cfg.notifications))
        return Protocol(
            tuple((field, number_type(None)) for field in Operator.POSE_FIELDS),
            (("notification", notifications), *((alert, BOOL) for alert in cfg.alerts)),
            # the supervisor lost: the first notification (no request), no alert
            {"notification": cfg.notifications[0], **{alert: False for alert in cfg.alerts}},
        )

    def build(self, cell, name, cfg):
        return build_operator(cell, name, cfg)

    def check(self, sf, name, cfg):
        _check(sf, name, cfg)

    def abstraction(self, abstract, name, cfg):
        from cellsim.kinds.operator.abstraction import PersonAbstraction

        return PersonAbstraction(abstract, name, cfg)


def build_operator(cell, name: str, cfg: OperatorConfig) -> Operator:
    """A person: their own random stream (salted by their order), body geometry the sensors see."""
    person = cell.add(name, Operator(name, cfg, cell.scenario.layout, cell.seed, salt=cell.count("person")))
    cell.register_geometry(person, person=True)
    cell.builder.Connect(person.geometry_pose_port, cell.scene_graph.get_source_pose_port(person.source_id))
    if person.buttons:
        cell.after_entities(lambda: _wire_buttons(cell, name, cfg, person))
    return person


def _wire_buttons(cell, name: str, cfg: OperatorConfig, person: Operator) -> None:
    """Each button the person presses drives that entity's input."""
    for button, port in zip(person.buttons, person.button_ports):
        key = next(f"entities.{name}.waypoints.{w}.press" for w, wp in cfg.waypoints.items() if wp.press == button)
        module, input_name = button.split(".")
        target = cell.modules[module]
        if not target.HasInputPort(input_name):
            inputs = [target.get_input_port(i).get_name() for i in range(target.num_input_ports())]
            raise cell.sf.error(key, f"{module} has no input '{input_name}' (its inputs: {', '.join(inputs)})")
        if cell.builder.IsConnectedOrExported(target.GetInputPort(input_name)):
            raise cell.sf.error(key, f"{button} is already driven by someone else")
        cell.builder.Connect(port, target.GetInputPort(input_name))


def _check(sf, name: str, cfg: OperatorConfig) -> None:
    """Every place the person stands is clear of the fixtures, and reachable round them;
    every button pressed belongs to an entity."""
    for waypoint, wp in cfg.waypoints.items():
        if wp.press is not None and wp.press.split(".")[0] not in sf.scenario.entities:
            raise sf.error(f"entities.{name}.waypoints.{waypoint}.press", f"no entity named '{wp.press.split('.')[0]}'")
    try:
        plan_routes(cfg, sf.scenario.layout)
    except RouteError as e:
        raise sf.error(f"entities.{name}.{e.key}", str(e)) from None

