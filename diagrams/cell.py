"""Builds a scenario's Drake Diagram: the one place that decides how a cell is wired.

``build_cell`` turns a loaded scenario into a Diagram, HardwareStation-style:

* a MultibodyPlant (discrete, ``time_step``) with the layout's fixtures and each
  robot arm, driven by an InverseDynamicsController;
* one system per entity, behaviour and service of the scenario (``cellsim``);
* geometry: operators and sensor volumes are SceneGraph sources of their own;
  all contact between geometries is filtered out (the arm is position
  controlled and collisions are *measured*, by sensors and ground truth, not
  simulated), which also keeps the plant's step cheap;
* the safety controller's inputs and outputs wired by the scenario's
  ``monitors`` and ``commands``, checked against the channels' types;
* every entity's physical-twin input wired by ``bridges.physical``;
* the recorder tapping every channel, and optionally Meshcat.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydrake.geometry import (
    Box,
    CollisionFilterDeclaration,
    GeometrySet,
    Meshcat,
    MeshcatVisualizer,
    MeshcatVisualizerParams,
    Role,
)
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import AddMultibodyPlant, CoulombFriction, MultibodyPlant, MultibodyPlantConfig
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.controllers import InverseDynamicsController
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem, OutputPort
from pydrake.systems.primitives import Multiplexer

from bridges.physical import connect_physical_twins
from cellsim.behaviours.ground_truth import GroundTruth
from cellsim.behaviours.risk_model import RiskModel, load_risk_model
from cellsim.behaviours.safety_controller import SafetyController
from cellsim.behaviours.work_cycle import WorkCycle
from cellsim.channels import ChannelSpec, ChannelType
from cellsim.entities.operator import Operator
from cellsim.entities.robot import Robot, robot_base_pose
from cellsim.entities.sensors import LightBarrier, RangeDetector
from cellsim.entities.twin import EntitySystem
from cellsim.entities.welder import Welder
from cellsim.scenario import (
    GroundTruthConfig,
    LightBarrierConfig,
    OperatorConfig,
    RangeDetectorConfig,
    RecorderConfig,
    RobotConfig,
    SafetyControllerConfig,
    ScenarioFile,
    WelderConfig,
    WorkCycleConfig,
)
from cellsim.services.recorder import Recorder

# joint controller gains: 20 rad/s bandwidth, critically damped
KP, KI, KD = 400.0, 1.0, 40.0


@dataclass
class CellDiagram:
    """A built cell: the Diagram and handles to its parts."""

    diagram: Diagram
    plant: MultibodyPlant
    scene_graph: object
    modules: dict[str, LeafSystem]
    channels: dict[str, tuple[ChannelSpec, OutputPort]]
    robots: dict[str, object] = field(default_factory=dict)  # name -> ModelInstanceIndex
    recorder: Recorder | None = None
    meshcat_visualizer: MeshcatVisualizer | None = None
    fixed_inputs: list[tuple] = field(default_factory=list)
    """(input port, value) of inputs nothing drives; ``set_initial_state`` fixes them."""

    def entity(self, name: str) -> EntitySystem:
        return self.modules[name]

    def set_initial_state(self, context) -> None:
        """Fix undriven inputs and put each arm at its initial pose in a (root) context."""
        for port, value in self.fixed_inputs:
            port.FixValue(port.get_system().GetMyMutableContextFromRoot(context), value)
        plant_context = self.plant.GetMyMutableContextFromRoot(context)
        for name, instance in self.robots.items():
            self.plant.SetPositions(plant_context, instance, self.modules[name].initial_positions)


def build_cell(
    sf: ScenarioFile,
    *,
    seed: int,
    duration: float,
    record: bool = True,
    meshcat: Meshcat | None = None,
    physical_sources: dict[str, LeafSystem] | None = None,
) -> CellDiagram:
    """Assemble the scenario's Diagram. Raises ConfigError for wiring the scenario gets wrong."""
    sc = sf.scenario
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(
        MultibodyPlantConfig(time_step=sc.time_step, discrete_contact_approximation="sap", use_sampled_output_ports=False), builder
    )
    plant.set_name("plant")
    _add_fixtures(plant, sf)
    robot_configs = {n: c for n, c in sc.entities.items() if isinstance(c, RobotConfig)}
    instances = {}
    for name, cfg in robot_configs.items():
        model = sf.resolve_path(f"entities.{name}.model", cfg.model)
        parser = Parser(plant, name)
        (instance,) = parser.AddModels(str(model))
        plant.WeldFrames(plant.world_frame(), plant.GetBodyByName("base_link", instance).body_frame(), robot_base_pose(cfg))
        instances[name] = instance
    plant.Finalize()

    modules: dict[str, LeafSystem] = {}
    entities: dict[str, EntitySystem] = {}
    operator_index = 0
    foreign_geometry, operator_geometry = [], []
    for name, cfg in sc.entities.items():
        if isinstance(cfg, RobotConfig):
            system = Robot(name, cfg, str(sf.resolve_path(f"entities.{name}.model", cfg.model)), sc.layout)
        elif isinstance(cfg, WelderConfig):
            system = Welder(name, cfg)
        elif isinstance(cfg, LightBarrierConfig):
            system = LightBarrier(name, cfg)
        elif isinstance(cfg, RangeDetectorConfig):
            system = RangeDetector(name, cfg, seed, duration)
        elif isinstance(cfg, OperatorConfig):
            system = Operator(name, cfg, sc.layout, seed, salt=operator_index)
            operator_index += 1
        else:  # pragma: no cover - the schema admits no other kind
            raise TypeError(cfg)
        builder.AddSystem(system)
        modules[name] = entities[name] = system
        if hasattr(system, "register_geometry"):
            ids = system.register_geometry(scene_graph)
            foreign_geometry += ids
            if isinstance(system, Operator):
                operator_geometry += ids
                builder.Connect(system.geometry_pose_port, scene_graph.get_source_pose_port(system.source_id))
        if hasattr(system, "query_port"):
            builder.Connect(scene_graph.get_query_output_port(), system.query_port)
    for system in entities.values():
        if hasattr(system, "set_targets"):  # sensors detect every operator
            system.set_targets(operator_geometry)

    robot_geometry = []
    for name, instance in instances.items():
        robot = modules[name]
        controller = builder.AddNamedSystem(
            f"{name}.joint_controller",
            InverseDynamicsController(robot.kinematics.plant, [KP] * 6, [KI] * 6, [KD] * 6, False),
        )
        builder.Connect(plant.get_state_output_port(instance), controller.get_input_port_estimated_state())
        builder.Connect(plant.get_state_output_port(instance), robot.measured_state_port)
        builder.Connect(robot.desired_state_port, controller.get_input_port_desired_state())
        builder.Connect(controller.get_output_port_control(), plant.get_actuation_input_port(instance))
        for body in plant.GetBodyIndices(instance):
            robot_geometry += plant.GetCollisionGeometriesForBody(plant.get_body(body))
    _filter_all_contact(plant, scene_graph, foreign_geometry)

    for name, cfg in sc.behaviours.items():
        if isinstance(cfg, WorkCycleConfig):
            robot = modules[cfg.robot]
            system = builder.AddSystem(WorkCycle(name, cfg, robot.pose_names))
            welder = modules[cfg.welder]
            builder.Connect(system.target_pose_port, robot.target_port)
            builder.Connect(system.robot_activity_port, robot.activity_port)
            builder.Connect(system.weld_command_port, welder.weld_command_port)
            builder.Connect(robot.GetOutputPort("safety_mode"), system.robot_mode_port)
            builder.Connect(robot.GetOutputPort("reached_pose"), system.reached_pose_port)
            builder.Connect(welder.GetOutputPort("activity"), system.welder_activity_port)
        elif isinstance(cfg, GroundTruthConfig):
            system = builder.AddSystem(GroundTruth(name, cfg))
            builder.Connect(scene_graph.get_query_output_port(), system.query_port)
            system.set_geometries(robot_geometry, operator_geometry)
        elif isinstance(cfg, SafetyControllerConfig):
            continue  # wired below, once every channel exists
        modules[name] = system

    channels = _channels(modules)
    for name, cfg in sc.behaviours.items():
        if isinstance(cfg, SafetyControllerConfig):
            risk_model = load_risk_model(sf.resolve_path(f"behaviours.{name}.risk_model", cfg.risk_model))
            system = _add_safety_controller(builder, sf, name, cfg, risk_model, modules, channels)
            modules[name] = system
            channels.update(_channels({name: system}))

    fixed_inputs = _unconnected_command_inputs(builder, modules)
    fixed_inputs += connect_physical_twins(builder, entities, physical_sources)

    recorder = None
    for name, cfg in sc.services.items():
        if isinstance(cfg, RecorderConfig) and record:
            recorder = Recorder(builder, name, list(channels.values()))

    visualizer = None
    if meshcat is not None:
        visualizer = MeshcatVisualizer.AddToBuilder(
            builder, scene_graph, meshcat, MeshcatVisualizerParams(role=Role.kIllustration)
        )
    diagram = builder.Build()
    diagram.set_name(sc.name)
    return CellDiagram(diagram, plant, scene_graph, modules, channels, instances, recorder, visualizer, fixed_inputs)


def _add_fixtures(plant: MultibodyPlant, sf: ScenarioFile) -> None:
    world = plant.world_body()
    for name, fixture in sf.scenario.layout.fixtures.items():
        pose = RigidTransform(RollPitchYaw(0.0, 0.0, np.radians(fixture.yaw_deg)), list(fixture.center))
        shape = Box(*fixture.size)
        plant.RegisterVisualGeometry(world, pose, shape, f"fixture/{name}", np.array(fixture.color))
        plant.RegisterCollisionGeometry(world, pose, shape, f"fixture/{name}", CoulombFriction(0.5, 0.5))


def _filter_all_contact(plant: MultibodyPlant, scene_graph, foreign_geometry: list) -> None:
    """No geometry pair takes part in contact: geometry is for measuring, not for contact."""
    ids = list(foreign_geometry)
    for i in range(plant.num_bodies()):
        ids += plant.GetCollisionGeometriesForBody(plant.get_body(BodyIndex(i)))
    scene_graph.collision_filter_manager().Apply(CollisionFilterDeclaration().ExcludeWithin(GeometrySet(ids)))


def _channels(modules: dict[str, LeafSystem]) -> dict[str, tuple[ChannelSpec, OutputPort]]:
    found = {}
    for system in modules.values():
        for spec, port in getattr(system, "channels", []):
            found[spec.name] = (spec, port)
    return found


def _add_safety_controller(builder, sf, name, cfg, risk_model: RiskModel, modules, channels) -> SafetyController:
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
                raise sf.error(where, f"no command input '{target}' (inputs are written module.input)")
            ctype = getattr(system, "input_types", {}).get(port_name)
            if ctype is None:
                raise sf.error(where, f"'{target}' is not a command input")
            _check_domain(sf, where, var, risk_model.controlled[var], ctype)
            if var in command_types and command_types[var] != ctype:
                raise sf.error(where, f"'{target}' expects a different type than the other inputs of {var}")
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
            raise sf.error(where, f"no channel '{channel}' (known: {', '.join(sorted(channels))})")
        _check_domain(sf, where, var, risk_model.monitored[var], ctype)
        monitor_types[var] = ctype

    controller = builder.AddSystem(SafetyController(name, cfg.period, risk_model, monitor_types, command_types))
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


def _unconnected_command_inputs(builder: DiagramBuilder, modules: dict[str, LeafSystem]) -> list[tuple]:
    """Command inputs nobody drives, with their declared default (no request, normal...)."""
    fixed = []
    for system in modules.values():
        for port_name, default in getattr(system, "input_defaults", {}).items():
            port = system.GetInputPort(port_name)
            if not builder.IsConnectedOrExported(port):
                fixed.append((port, np.array([default])))
    return fixed
