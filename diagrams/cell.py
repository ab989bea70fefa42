"""Builds a scenario's Drake Diagram: the one place that decides how a cell is wired.

``build_cell`` turns a loaded scenario into a Diagram, HardwareStation-style:

* a MultibodyPlant (discrete, ``time_step``) with the layout's fixtures as visual
  geometry, and no collision geometry at all: a plant with some asks SceneGraph
  for contacts at every step, and contact is never simulated here;
* one system per entity, behaviour and service of the scenario, each built by
  its module kind (``cellsim.registry``: cellsim's kinds and plug-ins alike;
  a robot kind adds its arm to the plant and its joint controller);
* geometry: operators, sensor volumes and each arm's collision shapes
  (``cellsim.entities.arm_geometry``) are SceneGraph sources of their own,
  posed only when a sensor or the ground truth queries SceneGraph; all contact
  between them is filtered out (the arm is position controlled and collisions
  are *measured*, by sensors and ground truth, not simulated);
* every entity's physical-twin input wired by ``cellsim.physical``;
* the recorder tapping every channel, and optionally Meshcat: the geometry
  (MeshcatVisualizer) and the modules' drawn state (``cellsim.visual``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

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
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlant, MultibodyPlantConfig
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem, OutputPort

from cellsim.physical import connect_physical_twins
from cellsim import registry
from cellsim.channels import ChannelSpec
from cellsim.entities.twin import EntitySystem
from cellsim.scenario import ScenarioFile
from cellsim.services.recorder import Recorder

AFTER_ENTITIES = 10
"""Modules of a stage below this are entities and sensors; hooks that need every
person's or robot's geometry run once they are all built."""


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
    cue_visualizer: LeafSystem | None = None
    """With Meshcat: the system drawing the modules' state (``cellsim.visual.live``)."""

    def entity(self, name: str) -> EntitySystem:
        return self.modules[name]

    def set_initial_state(self, context) -> None:
        """Fix undriven inputs and put each arm at its initial pose in a (root) context."""
        for port, value in self.fixed_inputs:
            port.FixValue(port.get_system().GetMyMutableContextFromRoot(context), value)
        plant_context = self.plant.GetMyMutableContextFromRoot(context)
        for name, instance in self.robots.items():
            self.plant.SetPositions(plant_context, instance, self.modules[name].initial_positions)


@dataclass
class CellBuild:
    """A cell's diagram under construction: what a module kind's builder works with.

    A kind's ``build(cell, name, config)`` adds its system with :meth:`add`, wires
    it to the modules already built (``modules``; entities are built before the
    behaviours wired to them), and may register geometry: people's bodies go to
    ``people`` (sensors detect them), robots' to ``robot_geometry``. Hooks given to
    :meth:`after_entities` run once every entity exists (a sensor learns whom to
    detect).
    """

    sf: ScenarioFile
    builder: DiagramBuilder
    plant: MultibodyPlant
    scene_graph: object
    seed: int
    duration: float
    record: bool
    modules: dict[str, LeafSystem] = field(default_factory=dict)
    entities: dict[str, EntitySystem] = field(default_factory=dict)
    robots: dict[str, object] = field(default_factory=dict)
    """Robot name -> its ModelInstanceIndex in ``plant``."""
    people: list = field(default_factory=list)
    """GeometryIds of every person's body, for the sensors."""
    robot_geometry: list = field(default_factory=list)
    foreign_geometry: list = field(default_factory=list)
    """GeometryIds registered outside the plant (all contact is filtered out)."""
    recorder: Recorder | None = None
    prepared: dict[str, object] = field(default_factory=dict)
    """What a kind's ``prepare`` left for its ``build``, by module name."""
    _hooks: list[Callable[[], None]] = field(default_factory=list)
    _counters: dict[str, int] = field(default_factory=dict)

    @property
    def scenario(self):
        return self.sf.scenario

    def add(self, name: str, system: LeafSystem) -> LeafSystem:
        """Add a module's system to the diagram under the module's name."""
        self.builder.AddSystem(system)
        self.modules[name] = system
        if isinstance(system, EntitySystem):
            self.entities[name] = system
        return system

    def register_geometry(self, system, person: bool = False) -> list:
        """Register a system's own SceneGraph geometry (``system.register_geometry``)."""
        ids = system.register_geometry(self.scene_graph)
        self.foreign_geometry += ids
        if person:
            self.people += ids
        return ids

    def connect_query(self, port) -> None:
        """Give an input port the SceneGraph's query object (a sensor measuring geometry)."""
        self.builder.Connect(self.scene_graph.get_query_output_port(), port)

    def after_entities(self, hook: Callable[[], None]) -> None:
        self._hooks.append(hook)

    def count(self, what: str) -> int:
        """0, 1, 2 ... on successive calls: e.g. each person's own random stream."""
        n = self._counters.get(what, 0)
        self._counters[what] = n + 1
        return n

    def channels(self) -> dict[str, tuple[ChannelSpec, OutputPort]]:
        """Every channel published by the modules built so far, in build order."""
        return _channels(self.modules)

    def _run_hooks(self) -> None:
        hooks, self._hooks = self._hooks, []
        for hook in hooks:
            hook()


def build_cell(
    sf: ScenarioFile,
    *,
    seed: int,
    duration: float,
    record: bool = True,
    meshcat: Meshcat | None = None,
    physical_sources: dict[str, LeafSystem] | Callable[[dict], dict[str, LeafSystem]] | None = None,
    command_sources: Callable[[EntitySystem, list[str]], LeafSystem] | None = None,
) -> CellDiagram:
    """Assemble the scenario's Diagram. Raises ConfigError for wiring the scenario gets wrong.

    Each module is built by its kind (:mod:`cellsim.registry`): this function
    names no concrete kind.
    """
    sc = sf.scenario
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(
        MultibodyPlantConfig(time_step=sc.time_step, discrete_contact_approximation="sap", use_sampled_output_ports=False), builder
    )
    plant.set_name("plant")
    _add_fixtures(plant, sf)
    cell = CellBuild(sf, builder, plant, scene_graph, seed, duration, record)
    modules = [
        (registry.kind_of(cfg), section, name, cfg)
        for section in registry.SECTIONS
        for name, cfg in getattr(sc, section).items()
    ]
    for kind, _, name, cfg in modules:
        if kind.prepare is not None:
            kind.prepare(cell, name, cfg)
    plant.Finalize()

    hooks_run = False
    for kind, _, name, cfg in sorted(modules, key=lambda m: m[0].stage):  # stable: scenario order within a stage
        if kind.stage >= AFTER_ENTITIES and not hooks_run:
            cell._run_hooks()
            hooks_run = True
        kind.build(cell, name, cfg)
    cell._run_hooks()
    _filter_all_contact(plant, scene_graph, cell.foreign_geometry)

    if command_sources is not None:  # a cell emulated under the twin's command
        _connect_command_sources(builder, cell.entities, command_sources)
    fixed_inputs = _unconnected_command_inputs(builder, cell.modules)
    if callable(physical_sources):  # sources made for the entities built (a live twin's, one per entity)
        physical_sources = physical_sources(cell.entities)
    fixed_inputs += connect_physical_twins(builder, cell.entities, physical_sources)

    visualizer = cues = None
    if meshcat is not None:  # the cell drawn (cellsim.visual): geometry, then the modules' drawn state
        from cellsim.visual.live import add_cue_visualizer

        visualizer = MeshcatVisualizer.AddToBuilder(
            builder, scene_graph, meshcat, MeshcatVisualizerParams(role=Role.kIllustration)
        )
        cues = add_cue_visualizer(
            builder, meshcat, cell.modules, cell.channels(), scene_graph, plant, sc.layout.extent()
        )
    diagram = builder.Build()
    diagram.set_name(sc.name)
    return CellDiagram(
        diagram, plant, scene_graph, cell.modules, cell.channels(), cell.robots, cell.recorder, visualizer, fixed_inputs,
        cues,
    )


def _add_fixtures(plant: MultibodyPlant, sf: ScenarioFile) -> None:
    world = plant.world_body()
    for name, fixture in sf.scenario.layout.fixtures.items():
        pose = RigidTransform(RollPitchYaw(0.0, 0.0, np.radians(fixture.yaw_deg)), list(fixture.center))
        shape = Box(*fixture.size)
        plant.RegisterVisualGeometry(world, pose, shape, f"fixture/{name}", np.array(fixture.color))


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


def _connect_command_sources(builder: DiagramBuilder, entities: dict, make: Callable) -> None:
    """Each entity's command inputs that nothing in the cell drives, fed by ``make(entity, inputs)``."""
    for entity in entities.values():
        free = [
            name for name in entity.command_fields
            if entity.HasInputPort(name) and not builder.IsConnectedOrExported(entity.GetInputPort(name))
        ]
        if free:
            source = builder.AddSystem(make(entity, free))
            for name in free:
                builder.Connect(source.GetOutputPort(name), entity.GetInputPort(name))


def _unconnected_command_inputs(builder: DiagramBuilder, modules: dict[str, LeafSystem]) -> list[tuple]:
    """Command inputs nobody drives, with their declared default (no request, normal...)."""
    fixed = []
    for system in modules.values():
        for port_name, default in getattr(system, "input_defaults", {}).items():
            port = system.GetInputPort(port_name)
            if not builder.IsConnectedOrExported(port):
                fixed.append((port, np.array([default])))
    return fixed
