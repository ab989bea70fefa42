"""Builds a scenario's Drake Diagram: the one place that decides how a cell is wired.

``build_cell`` turns a loaded scenario into a Diagram, HardwareStation-style:

* a MultibodyPlant (discrete, ``time_step``) with the layout's fixtures as visual
  geometry, and no collision geometry at all: a plant with some asks SceneGraph
  for contacts at every step, and contact is never simulated here;
* one system per entity, behaviour and service of the scenario, each built by
  its module kind (``cellsim.registry``: cellsim's kinds and plug-ins alike;
  a robot kind adds its arm to the plant and its joint controller);
* geometry: operators, sensor volumes and each arm's collision shapes
  (``cellsim.kinds.robot.geometry``) are SceneGraph sources of their own,
  posed only when a sensor or the ground truth queries SceneGraph; all contact
  between them is filtered out (the arm is position controlled and collisions
  are *measured*, by sensors and ground truth, not simulated);
* the I/O choice (``cellsim.cell_io``): what feeds every entity's physical
  samples and its command inputs, and where channels and commands go
  (simulated, replayed from a black box, live on Zenoh, emulated). This is the
  only place that decides; Zenoh subscribers and publishers are LeafSystems of
  the diagram (``cellsim.live.systems``), so every run is one ``AdvanceTo`` loop;
* the same exported ports whichever I/O: every channel as ``<module>.<signal>``
  and each entity's ``<entity>.physical_command``;
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
    SceneGraph,
)
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlant, MultibodyPlantConfig
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem, OutputPort

from cellsim import registry
from cellsim.cell_io import SIMULATED, CellIO, Emulated, Live, Replayed, Simulated, paced
from cellsim.channels import ChannelSpec
from cellsim.config.typed_yaml import ConfigError
from cellsim.entity import EntitySystem
from cellsim.scenario import ScenarioFile
from cellsim.recorder import Recorder

AFTER_ENTITIES = 10
"""Modules of a stage below this are entities and sensors; hooks that need every
person's or robot's geometry run once they are all built."""
EXTEND_STAGE = 25
"""A script's ``extend`` hook (:func:`build_cell`) runs once every module of a lower stage is built
(entities, sensors, behaviours, controllers) and before those of this stage or above (the recorder),
so the systems it adds as modules are recorded like any other."""


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
    meshcat: Meshcat | None = None
    sf: ScenarioFile | None = None
    """The scenario as built (an emulated cell's: every entity its digital model)."""
    io: CellIO = SIMULATED
    network: "NetworkIO | None" = None
    """Live or emulated: the network side (its clock, start, figures, what to close)."""
    meshcat_wait: tuple | None = None
    """(seconds, say): wait that long for a browser to open Meshcat before starting."""

    @property
    def realtime_rate(self) -> float:
        """1 when the cell runs paced to the wall clock (live, emulated, shown in Meshcat), else 0."""
        return 1.0 if paced(self.io) or self.meshcat_visualizer is not None else 0.0

    def vector_sizes(self) -> dict[str, int]:
        """Each vector channel's length (a recorded run of this cell holds vectors of these lengths)."""
        return {name: spec.type.size for name, (spec, _) in self.channels.items() if spec.type.kind == "vector"}

    @property
    def runs_until_stopped(self) -> bool:
        """A live or emulated cell runs until it is stopped: its record then ends there, complete."""
        return paced(self.io)

    def start(self, root_context=None) -> None:
        """Before simulated time runs (the simulator initialised): wait for what must be there; with the
        simulator's ``root_context``, a live twin's sources take what arrived while it waited as their state at
        t = 0 (without it, its entities start failing safe until their sources' first drain)."""
        if self.meshcat_wait is not None and self.meshcat_visualizer is not None:
            from cellsim.visual.live import wait_for_browser

            wait_for_browser(self.meshcat, *self.meshcat_wait)
        if self.network is not None:
            self.network.start(root_context)

    def metadata(self) -> dict:
        """What the black box records of the run's I/O (the network's figures), at each drain."""
        return {} if self.network is None else {"live": self.network.metadata()}

    def close(self) -> None:
        """Close the network side of a live or emulated cell (nothing for a simulated one)."""
        if self.network is not None:
            self.network.close()

    def entity(self, name: str) -> EntitySystem:
        """The system of entity ``name`` (KeyError if the cell has no module of that name)."""
        return self.modules[name]

    @property
    def entities(self) -> dict[str, EntitySystem]:
        """Every entity's system, by module name: what has a physical twin."""
        return {name: m for name, m in self.modules.items() if isinstance(m, EntitySystem)}

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
    arm_geometry: dict[str, dict] = field(default_factory=dict)
    """Robot name -> each of its GeometryIds -> the name of the arm's body it is fixed to."""
    foreign_geometry: list = field(default_factory=list)
    """GeometryIds registered outside the plant (all contact is filtered out)."""
    bodies: dict[str, LeafSystem] = field(default_factory=dict)
    """Person name -> their system, which has body regions (``regions``: GeometryId -> region name), ``pose_port``
    and ``previous_pose_port`` and ``frame_poses(pose)``: what the harm service measures."""
    arm_mass: dict[str, float] = field(default_factory=dict)
    """Robot name -> its effective mass in a contact (kg): half its moving links' mass plus its payload."""
    fixture_geometry: dict = field(default_factory=dict)
    """The layout's fixtures as proximity geometry: GeometryId -> fixture name (what a body can be pinned against)."""
    measured_pairs: list[tuple[list, list]] = field(default_factory=list)
    """(geometries, geometries) whose pairs a broadphase query returns (:meth:`measure_between`)."""
    recorder: Recorder | None = None
    decision_offset: float = 0.0
    """A live twin: the offset (s) within their periods at which its deciding modules update (one plant step,
    after the entities take the samples), or 0."""
    prepared: dict[str, object] = field(default_factory=dict)
    """What a kind's ``prepare`` left for its ``build``, by module name."""
    _hooks: list[Callable[[], None]] = field(default_factory=list)
    _last_hooks: list[Callable[[], None]] = field(default_factory=list)
    _counters: dict[str, int] = field(default_factory=dict)

    @property
    def scenario(self):
        """The scenario being built (its dataclasses)."""
        return self.sf.scenario

    def add(self, name: str, system: LeafSystem) -> LeafSystem:
        """Add a module's system to the diagram under the module's name; KeyError when a module, or a system of
        the diagram, already has that name (or the system's own)."""
        taken = {other.get_name() for other in self.builder.GetSystems()}
        for clash in (name, system.get_name()):
            if clash in self.modules or clash in taken:
                raise KeyError(f"the cell already has a module or system named '{clash}'; name yours otherwise")
        self.builder.AddSystem(system)
        self.modules[name] = system
        if isinstance(system, EntitySystem):
            self.entities[name] = system
        return system

    def register_geometry(self, system, person: bool = False) -> list:
        """Register a system's own SceneGraph geometry (``system.register_geometry``); a ``person``'s body
        regions are what sensors detect and the harm service judges."""
        ids = system.register_geometry(self.scene_graph)
        self.foreign_geometry += ids
        if person:
            self.people += ids
            self.bodies[system.module] = system
        return ids

    def measure_between(self, these: list, those: list) -> None:
        """Let SceneGraph's broadphase queries (``ComputeSignedDistancePairwiseClosestPoints``) return the pairs of
        one of ``these`` and one of ``those``: every other pair stays filtered out."""
        self.measured_pairs.append((list(these), list(those)))

    def connect_query(self, port) -> None:
        """Give an input port the SceneGraph's query object (a sensor measuring geometry)."""
        self.builder.Connect(self.scene_graph.get_query_output_port(), port)

    def after_entities(self, hook: Callable[[], None]) -> None:
        """Run ``hook`` once every entity is built (a sensor learning every person's geometry)."""
        self._hooks.append(hook)

    def after_all(self, hook: Callable[[], None]) -> None:
        """Run ``hook`` once every module is built (a system reading any module's channel)."""
        self._last_hooks.append(hook)

    def count(self, what: str) -> int:
        """0, 1, 2 ... on successive calls: e.g. each person's own random stream."""
        n = self._counters.get(what, 0)
        self._counters[what] = n + 1
        return n

    def channels(self) -> dict[str, tuple[ChannelSpec, OutputPort]]:
        """Every channel published by the modules built so far, in build order."""
        return _channels(self.modules)

    def channel(self, name: str) -> OutputPort:
        """The output port of channel ``<module>.<signal>`` (e.g. ``range_detector.range``): what a script's system
        reads. KeyError naming the channels there are when there is no such channel."""
        found = self.channels()
        if name not in found:
            raise KeyError(f"no channel '{name}'; channels: {', '.join(found)}")
        return found[name][1]

    def code_of(self, channel: str, value) -> float:
        """The number channel ``<module>.<signal>`` carries for ``value``: an enum's word as its code
        (``code_of("range_detector.range", "close")``), a bool as 0 or 1, a number as itself. What a script's system
        compares a channel's port with, or writes to an input of that type (``robot.safety_mode_request`` takes the
        codes of ``robot.safety_mode``). KeyError for an unknown channel, ValueError for a value it cannot carry or
        a channel of several numbers (a vector)."""
        found = self.channels()
        if channel not in found:
            raise KeyError(f"no channel '{channel}'; channels: {', '.join(found)}")
        ctype = found[channel][0].type
        if ctype.size != 1:
            raise ValueError(f"'{channel}' carries {ctype.size} numbers, not one: compare its elements yourself")
        return float(ctype.encode(value)[0])

    def module_input(self, name: str):
        """The input port ``<module>.<input>`` (e.g. ``robot.safety_mode_request``): what a script's system drives.
        KeyError naming the module's inputs when it has no such input."""
        module, _, port = name.partition(".")
        if module not in self.modules:
            raise KeyError(f"no module '{module}'; modules: {', '.join(self.modules)}")
        system = self.modules[module]
        if not system.HasInputPort(port):
            names = [system.get_input_port(i).get_name() for i in range(system.num_input_ports())]
            raise KeyError(f"module '{module}' has no input '{port}'; inputs: {', '.join(names)}")
        found = system.GetInputPort(port)
        if self.builder.IsConnectedOrExported(found):
            driver = next((f"{source.get_name()}.{source.get_output_port(int(out)).get_name()}"
                           for (sink, index), (source, out) in self.builder.connection_map().items()
                           if sink is system and int(index) == found.get_index()), "the diagram's own input")
            raise KeyError(f"input '{name}' is driven already, by {driver}: remove that module to drive it yourself")
        return found

    def _run_hooks(self) -> None:
        hooks, self._hooks = self._hooks, []
        for hook in hooks:
            hook()


def build_cell(
    sf: ScenarioFile,
    *,
    seed: int,
    duration: float,
    io: CellIO = SIMULATED,
    record: bool = True,
    meshcat: Meshcat | None = None,
    meshcat_wait: tuple | None = None,
    extend: Callable[[CellBuild], None] | None = None,
) -> CellDiagram:
    """Assemble the scenario's Diagram with the I/O ``io``. Raises ConfigError for wiring the scenario gets wrong.

    Each module is built by its kind (:mod:`cellsim.registry`): this function
    names no concrete kind. ``meshcat_wait``: ``(seconds, say)`` to wait for a
    browser to open Meshcat before simulated time runs (``CellDiagram.start``).
    ``extend(cell)``: a script's own systems, added once the cell's modules are built and before the recorder
    (:data:`EXTEND_STAGE`): ``cell.add(name, system)`` makes a system a module (its channels recorded),
    ``cell.builder`` connects it to ``cell.channel(...)`` and ``cell.module_input(...)``.
    """
    sf = scenario_for(sf, io)
    sc = sf.scenario
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(
        MultibodyPlantConfig(time_step=sc.time_step, discrete_contact_approximation="sap", use_sampled_output_ports=False), builder
    )
    plant.set_name("plant")
    _add_fixtures(plant, sf)
    cell = CellBuild(sf, builder, plant, scene_graph, seed, duration, record)
    cell.fixture_geometry = _fixture_geometry(scene_graph, sf)
    cell.foreign_geometry += list(cell.fixture_geometry)
    modules = [
        (registry.kind_of(cfg), section, name, cfg)
        for section in registry.SECTIONS
        for name, cfg in getattr(sc, section).items()
    ]
    for kind, section, name, cfg in modules:
        with registry.plugin_failures(kind, sf, f"{section}.{name}", "prepare"):
            kind.prepare(cell, name, cfg)
    plant.Finalize()

    extended = extend is not None
    hooks_run = False
    on_arrival: dict[str, float] = {}  # the live twin's entities that take each sample on arrival -> how often
    for kind, section, name, cfg in sorted(modules, key=lambda m: m[0].stage):  # stable: scenario order within a stage
        if kind.stage >= AFTER_ENTITIES and not hooks_run:
            if isinstance(io, Live):  # before the recorder: their channels' periods change
                on_arrival = _take_samples_on_arrival(cell)
            cell._run_hooks()
            hooks_run = True
        if kind.stage >= EXTEND_STAGE and extend is not None:
            cell._run_hooks()
            extend(cell)
            extend = None
        with registry.plugin_failures(kind, sf, f"{section}.{name}", "build"):
            kind.build(cell, name, cfg)
        if isinstance(io, Live) and section == "behaviours":  # before the recorder: their channels' offsets change
            _decide_after_takes(cell, name)
    cell._run_hooks()
    if extend is not None:  # a scenario with no recorder
        extend(cell)
        cell._run_hooks()
    for hook in cell._last_hooks:
        hook()
    _filter_all_contact(plant, scene_graph, cell.foreign_geometry, cell.measured_pairs)

    # -- the I/O: the one place that decides what the physical side is ---------------------
    fixed_inputs: list[tuple] = []
    network = None
    match io:
        case Simulated():
            fixed_inputs += _no_physical_samples(cell.entities.values())
        case Replayed():
            fixed_inputs += _replay(builder, cell, io)
        case Live():
            network = _live(builder, cell, io, on_arrival)
        case Emulated():
            fixed_inputs += _no_physical_samples(cell.entities.values())
            network = _emulated(builder, cell, io)
        case _:
            raise TypeError(f"not an I/O choice: {io!r}")
    fixed_inputs += _unconnected_inputs(builder, cell.modules)
    _refuse_dangling_inputs(sf, builder, fixed_inputs, cell.modules, extended)
    channels = cell.channels()
    for spec, port in channels.values():  # the same ports whichever I/O
        builder.ExportOutput(port, spec.name)
    for name, entity in cell.entities.items():
        builder.ExportOutput(entity.physical_command_port, f"{name}.physical_command")

    visualizer = cues = None
    if meshcat is not None:  # the cell drawn (cellsim.visual): geometry, then the modules' drawn state
        from cellsim.visual.live import add_cue_visualizer

        visualizer = MeshcatVisualizer.AddToBuilder(
            builder, scene_graph, meshcat, MeshcatVisualizerParams(role=Role.kIllustration)
        )
        cues = add_cue_visualizer(builder, meshcat, cell.modules, channels, scene_graph, plant, sc.layout.extent())
    diagram = builder.Build()
    diagram.set_name(sc.name)
    return CellDiagram(
        diagram, plant, scene_graph, cell.modules, channels, cell.robots, cell.recorder, visualizer, fixed_inputs,
        cues, meshcat, sf, io, network, meshcat_wait,
    )


def scenario_for(sf: ScenarioFile, io: CellIO) -> ScenarioFile:
    """The scenario a cell with ``io`` runs: the scenario itself, or for an emulated cell a copy where
    every entity is its digital model (it *is* the physical cell) and, commanded by the twin, the
    supervisors and their safety evidence are left out (the twin's supervise instead)."""
    if not isinstance(io, Emulated) or getattr(sf, "emulated", False):
        return sf
    import copy

    from cellsim.config.validation import Validation
    from cellsim.vocabulary import TwinMode

    sf = copy.deepcopy(sf)
    sc = sf.scenario
    for cfg in sc.entities.values():
        twin = getattr(cfg, "twin", None)
        if twin is not None:
            twin.mode, twin.changes = TwinMode.MODEL, []
    if io.commanded_by_twin:
        sc.behaviours = {name: cfg for name, cfg in sc.behaviours.items() if not registry.kind_of(cfg).supervises}
        sc.validation = Validation()
    sf.emulated = True
    return sf


def _no_physical_samples(entities) -> list[tuple]:
    """Every entity's physical_sample reads stale: nothing feeds it (a fixed input costs nothing per step)."""
    from cellsim.physical import no_sample

    return [(e.physical_sample_port, no_sample(e.physical_sample_port.size())) for e in entities]


def _replay(builder: DiagramBuilder, cell: CellBuild, io: Replayed) -> list[tuple]:
    """A black box plays the physical twin of each entity whose sample fields it recorded."""
    from cellsim.physical import BlackBoxReplay, no_sample, replay_fields
    from cellsim.blackbox import BlackBox

    unknown = set(io.entities or ()) - set(cell.entities)
    if unknown:
        raise KeyError(f"replayed entities that the cell does not have: {', '.join(sorted(unknown))}")
    fixed = []
    with BlackBox(io.blackbox) as recorded:
        for name, entity in cell.entities.items():
            fields = replay_fields(entity, recorded) if io.entities is None or name in io.entities else None
            if fields is None:
                if io.entities is not None and name in io.entities:
                    raise KeyError(f"{io.blackbox} did not record every sample field of {name}")
                fixed.append((entity.physical_sample_port, no_sample(entity.physical_sample_port.size())))
                continue
            source = builder.AddSystem(BlackBoxReplay(recorded, fields, entity.period, io.time_offset))
            source.set_name(f"{name}.physical_replay")
            builder.Connect(source.get_output_port(), entity.physical_sample_port)
    return fixed


def _live(builder: DiagramBuilder, cell: CellBuild, io: Live, on_arrival: dict[str, float]):
    """The twin on Zenoh: a sample source per entity (drained before each of the looks of the entities in
    ``on_arrival``), every channel and command published, twin modes switched on request, the status every
    second, the describe queryable and the liveliness token."""
    from cellsim import codec
    from cellsim.live import keys
    from cellsim.live.network import NetworkIO
    from cellsim.live.systems import (ChannelPublisher, CommandPublisher, LiveClock, LiveStatus, TwinModeControl,
                                      ZenohSampleSource)
    from cellsim.live.reaction import ReactionWatch, assumed_reactions, deciding_period
    from cellsim.live.twin import describe
    from cellsim.vocabulary import TwinMode

    session, name, step = io.session, cell.scenario.name, cell.scenario.time_step
    look = cell.decision_offset + step  # the publishers look one step after the decisions, when they are in the state
    clock = LiveClock()
    sources = {}
    for entity_name, entity in cell.entities.items():
        key = keys.physical(name, entity_name)
        sources[entity_name] = builder.AddSystem(ZenohSampleSource(entity, clock, step, key, on_arrival.get(entity_name)))
        builder.Connect(sources[entity_name].get_output_port(), entity.physical_sample_port)
    watch = None
    if (every := deciding_period(cell.scenario)) is not None:  # the twin's own reaction, against its evidence's
        watch = builder.AddSystem(ReactionWatch(sources, assumed_reactions(cell.scenario, cell.entities), every, step,
                                                io.process, look))
        for entity_name in watch.sources:
            builder.Connect(cell.channel(f"{entity_name}.twin_mode"), watch.GetInputPort(entity_name))
    status = builder.AddSystem(LiveStatus(clock, step, session.declare_publisher(keys.status(name, io.process)),
                                          {n: s.get_output_port() for n, s in sources.items()}, io.process, watch))
    for entity_name, source in sources.items():
        builder.Connect(source.get_output_port(), status.GetInputPort(entity_name))
    awaited = [n for n, e in cell.entities.items() if e.twin.mode is not TwinMode.MODEL]
    network = NetworkIO(io.process, clock, status, io.wait_physical, awaited, primed=list(sources.values()))
    if watch is not None:
        network.figures["reaction_s"] = watch.figures
    network.figures["rejected_samples"] = lambda: {n: s.rejected for n, s in sources.items()}
    for entity_name, source in sources.items():
        def on_sample(sample, source=source, entity_name=entity_name):  # the network thread: hand it over, count it
            source.inbox.on_sample(sample)
            network.heard(entity_name)

        network.handles.append(session.declare_subscriber(keys.physical(name, entity_name), on_sample))

    channels = list(cell.channels().values())
    publisher = builder.AddSystem(ChannelPublisher(
        channels, lambda spec: session.declare_publisher(keys.channel(name, spec.module, spec.signal)), look))
    for spec, port in channels:
        builder.Connect(port, publisher.GetInputPort(spec.name))
    for entity_name, entity in cell.entities.items():
        commands = builder.AddSystem(CommandPublisher(
            entity, session.declare_publisher(keys.command(name, entity_name)), step, _decided_every(builder, entity, step),
            look, clock))
        builder.Connect(entity.physical_command_port, commands.command_port)
    control = builder.AddSystem(TwinModeControl(cell.entities))
    for entity_name, entity in cell.entities.items():
        builder.Connect(control.GetOutputPort(entity_name), entity.mode_request_input)
        entity.takes_mode_requests = True
    network.figures["twin_mode_requests"] = lambda: control.applied
    network.handles.append(session.declare_queryable(keys.twin_mode_control(name), control.on_query))
    description = codec.dumps(describe(cell.sf, cell.channels(), cell.modules))
    network.handles.append(session.declare_queryable(
        keys.describe(name), lambda query: query.reply(query.key_expr, description)))
    network.handles.append(session.liveliness().declare_token(keys.alive(name, io.process)))
    if io.foxglove is not None:  # the same twin on Foxglove's WebSocket (cellsim.foxglove.FoxgloveFeed)
        io.foxglove.add_to(builder, cell, step)
    return network


def _take_samples_on_arrival(cell: CellBuild) -> dict[str, float]:
    """The live twin's entities that take each sample on arrival, each with how often it looks (s): those
    updated less often than the cell's fastest deciding module (a behaviour: its controllers and monitors) look
    at that module's period, whose own period would only delay what they pass on. An entity updated as
    often (the robot, read by a controller of its period) keeps its period."""
    from cellsim.live.reaction import deciding_period

    fastest, step = deciding_period(cell.scenario), cell.scenario.time_step
    if fastest is None:
        return {}
    return {name: fastest for name, entity in cell.entities.items() if entity.take_samples_on_arrival(fastest, step)}


def _decide_after_takes(cell: CellBuild, name: str) -> None:
    """In a live twin, a deciding module (a behaviour) updates one plant step after each multiple of its period,
    when the entities have taken the samples that arrived (``EntitySystem.take_samples_on_arrival``), not at it:
    at the multiple it would read them one of its periods later, a period that only adds delay. The command and
    channel publishers look one step after that (``CellBuild.decision_offset``)."""
    from cellsim.systems import CellSystem

    system, step = cell.modules.get(name), cell.scenario.time_step
    if isinstance(system, CellSystem) and system.period > step * (1 + 1e-9):
        system.decide_after(step)
        cell.decision_offset = step


def _decided_every(builder: DiagramBuilder, entity, step: float) -> float:
    """How often an entity's commands may change (s): the common divisor, in plant steps, of its own update period
    (its twin mode) and those of the systems driving its command inputs (its supervisors)."""
    import math

    commanded = {entity.GetInputPort(n).get_index() for n in entity.command_fields if entity.HasInputPort(n)}
    drivers = [system for (sink, index), (system, _) in builder.connection_map().items()
               if sink is entity and index in commanded]
    periods = [entity.period, *(getattr(d, "period", step) for d in drivers)]
    return step * math.gcd(*(max(1, round(p / step)) for p in periods))


def _emulated(builder: DiagramBuilder, cell: CellBuild, io: Emulated):
    """The physical cell played: each entity's state through its outlet at its rate (its physical key,
    or its device's protocol), the faults injected, and, commanded by the twin, the twin's commands
    (from the command keys, or the devices' protocols) into the inputs the supervisors drove."""
    from cellsim.live import keys
    from cellsim.live.emulator import ZenohOutlet, fault_query_handler
    from cellsim.live.network import NetworkIO
    from cellsim.live.systems import LiveClock, LiveStatus, SampleOutlet, ZenohCommandSource

    session, name, step = io.session, cell.scenario.name, cell.scenario.time_step
    devices = io.devices
    rates = {**(devices.rates() if devices is not None else {}), **io.rates}
    clock = LiveClock()
    status = builder.AddSystem(LiveStatus(clock, step, session.declare_publisher(keys.status(name, io.process)),
                                          process=io.process))
    network = NetworkIO(io.process, clock, status)
    outlets = {}
    for entity_name, entity in cell.entities.items():
        outlet = (devices.outlet(entity_name, entity) if devices is not None else None) or ZenohOutlet(
            session.declare_publisher(keys.physical(name, entity_name)), wall_of=clock.wall_of)
        period = 1.0 / rates[entity_name] if entity_name in rates else entity.period
        period = max(step, round(period / step) * step)
        outlets[entity_name] = builder.AddSystem(SampleOutlet(entity, outlet, period, io.faults, step))
        builder.Connect(entity.physical_state_port, outlets[entity_name].state_port)
        if devices is not None:
            devices.add_systems(builder, entity, step)
    network.figures["samples_published"] = lambda: sum(o.sent for o in outlets.values())
    network.figures["faults"] = io.faults.to_json
    network.figures["commanded_by_twin"] = lambda: io.commanded_by_twin
    if io.commanded_by_twin:
        for entity_name, entity in cell.entities.items():
            free = [n for n in entity.command_fields
                    if entity.HasInputPort(n) and not builder.IsConnectedOrExported(entity.GetInputPort(n))]
            if not free:
                continue
            key = keys.command(name, entity_name)
            source = builder.AddSystem(ZenohCommandSource(entity, free, clock, step, key))
            for port_name in free:
                builder.Connect(source.GetOutputPort(port_name), entity.GetInputPort(port_name))
            if devices is None or not devices.feed_commands(entity, source):
                network.handles.append(session.declare_subscriber(key, source.inbox.on_sample))
    if devices is not None:
        network.closers.append(devices.close)
    kinds = {n: (devices.fault_kinds(n) if devices is not None else None) or ZenohOutlet.faults for n in cell.entities}
    network.handles.append(session.declare_queryable(keys.fault_control(name), fault_query_handler(io.faults, kinds)))
    network.handles.append(session.liveliness().declare_token(keys.alive(name, io.process)))
    return network


def _add_fixtures(plant: MultibodyPlant, sf: ScenarioFile) -> None:
    world = plant.world_body()
    for name, fixture in sf.scenario.layout.fixtures.items():
        pose = RigidTransform(RollPitchYaw(0.0, 0.0, np.radians(fixture.yaw_deg)), list(fixture.center))
        shape = Box(*fixture.size)
        plant.RegisterVisualGeometry(world, pose, shape, f"fixture/{name}", np.array(fixture.color))


def _fixture_geometry(scene_graph, sf: ScenarioFile) -> dict:
    """The layout's fixtures as anchored proximity geometry of their own source: GeometryId -> name."""
    from pydrake.geometry import GeometryInstance, ProximityProperties

    source = scene_graph.RegisterSource("layout")
    found = {}
    for name, fixture in sf.scenario.layout.fixtures.items():
        pose = RigidTransform(RollPitchYaw(0.0, 0.0, np.radians(fixture.yaw_deg)), list(fixture.center))
        instance = GeometryInstance(pose, Box(*fixture.size), f"fixture/{name}/proximity")
        instance.set_proximity_properties(ProximityProperties())
        found[scene_graph.RegisterAnchoredGeometry(source, instance)] = name
    return found


def _filter_all_contact(plant: MultibodyPlant, scene_graph, foreign_geometry: list, measured: list) -> None:
    """No geometry pair takes part in contact (geometry is for measuring, not for contact), and broadphase
    queries return only the ``measured`` pairs. The plant has no collision geometry of its own, so it asks
    for no contacts whatever the filters allow."""
    ids = list(foreign_geometry)
    for i in range(plant.num_bodies()):
        ids += plant.GetCollisionGeometriesForBody(plant.get_body(BodyIndex(i)))
    declaration = CollisionFilterDeclaration().ExcludeWithin(GeometrySet(ids))
    for these, those in measured:
        declaration.AllowBetween(GeometrySet(these), GeometrySet(those))
    scene_graph.collision_filter_manager().Apply(declaration)


def _channels(modules: dict[str, LeafSystem]) -> dict[str, tuple[ChannelSpec, OutputPort]]:
    found = {}
    for system in modules.values():
        for spec, port in getattr(system, "channels", []):
            found[spec.name] = (spec, port)
    return found


OPTIONAL_INPUTS = {("MeshcatPointCloudVisualizer", "X_ParentCloud")}
"""(Drake system class, input) pairs Drake documents as optional beyond the plant's and SceneGraph's: left unconnected,
they read as none (the identity pose)."""


def _refuse_dangling_inputs(sf, builder: DiagramBuilder, fixed: list[tuple], modules: dict, extended: bool) -> None:
    """A ConfigError naming an input (of a module's system, a plug-in's or a script's) that no system drives and no
    value is given: Drake would say so only once the run's folder is written, when the input is first read. The
    inputs Drake documents as optional are left alone (:data:`OPTIONAL_INPUTS`; every input of the plant and of
    SceneGraph): they read an unconnected input as none."""
    given = {(port.get_system().get_name(), int(port.get_index())) for port, _ in fixed}  # (names are unique)
    module_of = {system.get_name(): name for name, system in modules.items()}
    for system in builder.GetSystems():
        if isinstance(system, (MultibodyPlant, SceneGraph)):
            continue
        for i in range(system.num_input_ports()):
            port = system.get_input_port(i)
            if (type(system).__name__, port.get_name()) in OPTIONAL_INPUTS:
                continue
            if not builder.IsConnectedOrExported(port) and (system.get_name(), i) not in given:
                module = module_of.get(system.get_name())
                key = module or ("extend" if extended else system.get_name())
                raise ConfigError(str(sf.source), None, key, f"input '{port.get_name()}' of system "
                                  f"'{system.get_name()}' is connected to nothing: connect it (builder.Connect; a "
                                  "ConstantVectorSource for a fixed value) or leave the system out")


def _unconnected_inputs(builder: DiagramBuilder, modules: dict[str, LeafSystem]) -> list[tuple]:
    """Inputs nobody drives, with their declared default (no request, normal...); an entity's twin-mode
    request with none."""
    from cellsim.live.systems import no_request

    fixed = []
    for system in modules.values():
        for port_name, default in getattr(system, "input_defaults", {}).items():
            port = system.GetInputPort(port_name)
            if not builder.IsConnectedOrExported(port):
                fixed.append((port, np.array([default])))
        if isinstance(system, EntitySystem) and not builder.IsConnectedOrExported(system.mode_request_input):
            fixed.append((system.mode_request_input, no_request()))
    return fixed
