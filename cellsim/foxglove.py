"""A run's black box as Foxglove data: an MCAP file that Foxglove plots and shows in 3D.

``export_mcap(run, file)`` writes

* every black-box channel ``module.signal`` as the JSON topic ``/module/signal`` with a JSON
  schema of its own (its kind, enum values, unit), one MCAP message per black-box message,
  ``{"t": seconds, "value": ...}``, logged at its simulated time;
* ``/tf``: the links of every robot as ``foxglove.FrameTransforms`` (frame ``<robot>/<link>`` in
  ``world``) at each recorded joint state;
* ``/scene``: the cell as ``foxglove.SceneUpdate``: every box, cylinder, sphere and capsule
  SceneGraph holds (fixtures, sensor volumes, the arms' shapes, people's body regions), the whole
  scene at each recorded pose (after a seek Foxglove draws a topic's latest message alone); a
  module with a ``recolour(values)`` hook colours geometry by its recorded channels (the harm
  service: a body region in contact, amber within its limit and red above it).

``/tf`` and ``/scene`` are Foxglove's official messages, declared with the official schemas and encoded as
foxglove-sdk gives them (protobuf): any Foxglove, or any reader with those schemas, reads them.

The poses come from the cell rebuilt from the run's ``scenario.yaml``, put in each recorded
state by its modules (``show_recorded``, as ``cellsim replay`` does): no kind is named here.
The file is written beside its destination and renamed into place: an error leaves nothing.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from pydrake.common.value import AbstractValue
from pydrake.geometry import QueryObject
from pydrake.systems.framework import LeafSystem

from cellsim.live.systems import HEARTBEAT, TICK


FRAME_TRANSFORMS = "foxglove.FrameTransforms"
SCENE_UPDATE = "foxglove.SceneUpdate"
"""The official Foxglove messages the 3D view reads: declared and encoded as foxglove-sdk gives them (protobuf)."""


class ExportError(Exception):
    """A run that cannot be exported (the message is one line)."""


def official(message: str):
    """Foxglove's own message type ``foxglove.<message>`` (from foxglove-sdk: the official schema, protobuf)."""
    import foxglove.messages

    return getattr(foxglove.messages, message.removeprefix("foxglove."))


def official_schema(message: str):
    """(name, encoding, data) of Foxglove's official schema of ``foxglove.<message>``: what the MCAP file and the
    live feed declare, so that any Foxglove reads them (``data``: a protobuf FileDescriptorSet)."""
    schema = official(message).get_schema()
    return schema.name, schema.encoding, bytes(schema.data)


def _message(kind: str, value):
    """``value`` (plain data as :func:`scene_update` and :func:`frame_transforms` build it) as Foxglove's message of
    ``kind``, field by field: the one place our dicts become the official types."""
    import foxglove.messages as m

    if kind == SCENE_UPDATE:
        if value.get("deletions"):
            raise ValueError("scene deletions are not written: every entity is sent whole, with no lifetime")
        return m.SceneUpdate(deletions=[], entities=[_message("entity", e) for e in value["entities"]])
    if kind == FRAME_TRANSFORMS:
        return m.FrameTransforms(transforms=[m.FrameTransform(
            timestamp=_message("time", t["timestamp"]), parent_frame_id=t["parent_frame_id"],
            child_frame_id=t["child_frame_id"], translation=m.Vector3(**t["translation"]),
            rotation=m.Quaternion(**t["rotation"])) for t in value["transforms"]])
    if kind == "entity":
        primitives = {"cubes": m.CubePrimitive, "spheres": m.SpherePrimitive, "cylinders": m.CylinderPrimitive}
        shapes = {name: [make(**{k: _message(k, v) if k in ("pose", "size", "color") else v for k, v in p.items()})
                         for p in value.get(name, [])] for name, make in primitives.items()}
        return m.SceneEntity(timestamp=_message("time", value["timestamp"]), frame_id=value["frame_id"], id=value["id"],
                             lifetime=m.Duration(value["lifetime"]["sec"], value["lifetime"]["nsec"]),
                             frame_locked=value["frame_locked"],
                             metadata=[m.KeyValuePair(key=p["key"], value=p["value"]) for p in value.get("metadata", [])],
                             **shapes)
    if kind == "time":
        return m.Timestamp(value["sec"], value["nsec"])
    if kind == "pose":
        return m.Pose(position=m.Vector3(**value["position"]), orientation=m.Quaternion(**value["orientation"]))
    if kind == "size":
        return m.Vector3(**value)
    if kind == "color":
        return m.Color(**value)
    raise ValueError(f"no Foxglove message for {kind!r}")


def encoded(kind: str, value) -> bytes:
    """``value`` encoded as Foxglove's official ``kind`` message (protobuf)."""
    return bytes(_message(kind, value).encode())


@dataclass
class Exported:
    path: Path
    channels: int
    messages: int
    frames: int
    """Moments of the cell in 3D (transforms and scene updates)."""


def topic_of(channel: str) -> str:
    """The MCAP topic of a black-box channel: ``loader.safety_mode`` -> ``/loader/safety_mode``."""
    return "/" + channel.replace(".", "/")


def channel_schema(name: str, kind: str, domain, unit: str | None, description: str = "") -> dict:
    """The JSON schema of one channel's messages, ``{"t": s, "value": ...}``, from what the black box
    (``ChannelInfo``) and a built channel (``ChannelSpec``) both say of it."""
    if kind == "enum":
        value = {"enum": [*domain, None]}
    elif kind == "bool":
        value = {"type": ["boolean", "null"]}
    elif kind == "number":
        value = {"type": ["number", "null"]}
    else:
        value = {"type": "array", "items": {"type": ["number", "null"]}}
    if unit:
        value["description"] = f"in {unit}"
    return {"title": name, "type": "object", "description": description or name,
            "properties": {"t": {"type": "number", "description": "simulated time, s"}, "value": value}}


def _ns(t: float) -> int:
    return int(round(t * 1e9))


def _stamp(t: float) -> dict:
    ns = _ns(t)
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _pose(X) -> dict:
    q = X.rotation().ToQuaternion()
    p = X.translation()
    return {"position": {"x": p[0], "y": p[1], "z": p[2]}, "orientation": {"x": q.x(), "y": q.y(), "z": q.z(), "w": q.w()}}


def export_mcap(run: str | os.PathLike, destination: str | os.PathLike) -> Exported:
    """Write the run at ``run`` (a run folder or its black box) to ``destination`` as MCAP."""
    from mcap.writer import Writer

    from cellsim.version import __version__
    from cellsim.blackbox import BlackBox, BlackBoxError
    from cellsim.atomic import OverwritesInput, refuse_inputs, replacing
    from cellsim.validation.check import CheckError, locate_rebuildable_run, run_files
    from cellsim.blackbox import run_end
    from cellsim.validation.traces import blackbox_domains, checked_values
    from cellsim.diagrams.cell import build_cell

    destination = Path(destination)
    if destination.is_dir():
        raise ExportError(f"{destination} is a folder; name the MCAP file to write")
    if str(destination).startswith("/dev/") or (destination.exists() and not destination.is_file()):
        # (a pipe cannot seek; /dev/stdout sent to a file shares its offset with what the command prints)
        raise ExportError(f"{destination} is no regular file: MCAP's writer seeks back over what it wrote to index it; "
                          "name a file to write")
    try:
        blackbox, sf = locate_rebuildable_run(run, "the export rebuilds the cell from it")
    except CheckError as e:
        raise ExportError(str(e)) from None
    try:
        refuse_inputs(destination, [*run_files(run), *sf.inputs()], "the MCAP file")
    except OverwritesInput as e:
        raise ExportError(str(e)) from None
    try:
        with BlackBox(blackbox) as bb:
            metadata, channels = bb.metadata(), bb.channels()
            end, _ = run_end(bb, metadata)
            cell = build_cell(sf, seed=bb.recorded_seed(sf.scenario.seed), duration=max(end, 1e-3), record=False)
            bb.check_vector_sizes(cell.vector_sizes())
            wanted = sorted(f"{name}.{signal}" for name, system in cell.modules.items()
                            for signal in getattr(system, "replay_channels", ()) if f"{name}.{signal}" in channels)
            with replacing(destination, "wb") as stream:
                writer = Writer(stream)
                writer.start(profile="", library=f"cellsim {__version__}")
                ids = {}
                for name, info in channels.items():
                    schema = writer.register_schema(name=f"cellsim.{name}", encoding="jsonschema",
                                                    data=json.dumps(channel_schema(name, info.kind, info.domain, info.unit,
                                                                                   info.description)).encode())
                    ids[name] = writer.register_channel(topic=topic_of(name), message_encoding="json", schema_id=schema,
                                                        metadata={"kind": info.kind, "unit": info.unit or ""})
                messages = 0
                bb.check_vectors()
                bb.check_channels()
                for t, name, value in checked_values(bb, list(channels), blackbox_domains(bb)):
                    writer.add_message(ids[name], log_time=_ns(t), publish_time=_ns(t), sequence=messages,
                                       data=json.dumps({"t": t, "value": value}).encode())
                    messages += 1
                if not messages:  # as check says it
                    status = metadata.get("status")
                    if status in ("interrupted", "running", "failed"):
                        raise ExportError(f"{blackbox}: the run stopped ({status}) before it recorded anything")
                    raise bb.corrupt("it holds no messages")
                frames = _write_scene(writer, cell, bb.iter_values(wanted) if wanted else iter(()), wanted)
                writer.finish()
    except BlackBoxError as e:
        raise ExportError(str(e)) from None
    return Exported(destination, len(channels), messages, frames)


def scene_shapes(scene_graph) -> list[tuple]:
    """(GeometryId, primitive kind, its fields) of every geometry Foxglove can draw; the fields carry the geometry's
    SceneGraph name (``operator/hand_right/15``, ``fixture/bench``) as the entity's metadata, so that Foxglove's
    entity list tells a hand from a forearm."""
    inspector = scene_graph.model_inspector()
    shapes = []
    for g in inspector.GetAllGeometryIds():
        if inspector.GetProximityProperties(g) is None and inspector.GetIllustrationProperties(g) is None:
            continue  # perception-only geometry
        primitive = _primitive(inspector, g)
        if primitive is not None:
            kind, fields = primitive
            shapes.append((g, kind, {**fields, "metadata": [{"key": "name", "value": inspector.GetName(g)}]}))
    return shapes


def scene_update(t: float, shapes: list[tuple], query, colours: dict | None = None) -> dict:
    """A foxglove.SceneUpdate of ``shapes`` posed by ``query``; ``colours``: GeometryId ->
    (r, g, b, a) drawn instead of a shape's own (a body region in contact)."""
    colours = colours or {}
    return {"deletions": [], "entities": [
        _entity(t, g, kind, fields if g not in colours else {**fields, "color": dict(zip("rgba", colours[g]))},
                query.GetPoseInWorld(g))
        for g, kind, fields in shapes]}


def frame_transforms(t: float, plant, robots: dict, pose_of) -> dict:
    """A foxglove.FrameTransforms of every robot link: ``pose_of(body)`` its pose in the world."""
    transforms = []
    for robot, instance in robots.items():
        for index in plant.GetBodyIndices(instance):
            body = plant.get_body(index)
            pose = _pose(pose_of(body))
            transforms.append({"timestamp": _stamp(t), "parent_frame_id": "world", "child_frame_id": f"{robot}/{body.name()}",
                               "translation": pose["position"], "rotation": pose["orientation"]})
    return {"transforms": transforms}


def _write_scene(writer, cell, recorded, wanted: list[str] = ()) -> int:
    """/scene: the whole scene at t = 0 and at each moment the modules' recorded state
    (``wanted``: joint positions, people's positions) changes; /tf: the arms' frames once per recorded joint
    state (at t = 0 only if no robot's state is recorded)."""
    ids, kinds = {}, {"/tf": FRAME_TRANSFORMS, "/scene": SCENE_UPDATE}
    for topic, kind in kinds.items():
        name, encoding, data = official_schema(kind)
        schema = writer.register_schema(name=name, encoding=encoding, data=data)
        ids[topic] = writer.register_channel(topic=topic, message_encoding=encoding, schema_id=schema)
    context = cell.diagram.CreateDefaultContext()
    cell.set_initial_state(context)
    scene_graph, plant = cell.scene_graph, cell.plant
    shapes = scene_shapes(scene_graph)
    plant_context = plant.GetMyContextFromRoot(context)
    sg_context = scene_graph.GetMyContextFromRoot(context)
    showing = [system for system in cell.modules.values() if hasattr(system, "show_recorded")]
    recolouring = [system for system in cell.modules.values() if hasattr(system, "recolour")]
    sequence = [0]

    def emit(topic: str, t: float, message: dict) -> None:
        writer.add_message(ids[topic], log_time=_ns(t), publish_time=_ns(t), sequence=sequence[0],
                           data=encoded(kinds[topic], message))
        sequence[0] += 1

    def moment(t: float, tf: bool) -> None:
        query = scene_graph.get_query_output_port().Eval(sg_context)
        colours = {g: rgba for system in recolouring for g, rgba in system.recolour(values).items()}
        emit("/scene", t, scene_update(t, shapes, query, colours))
        if tf:
            emit("/tf", t, frame_transforms(t, plant, cell.robots,
                                            lambda body: plant.EvalBodyPoseInWorld(plant_context, body)))

    def shown(t: float, tf: bool) -> None:  # the recorded state up to t, drawn
        for system in showing:
            system.show_recorded(cell, context, values)
        # the whole scene each time, as the live feed sends it: after a seek Foxglove draws only the latest message
        # of a topic, which would otherwise hold the moving entities alone (no fixtures, no sensor volumes)
        moment(t, tf=tf)

    robot_states = {name for name in wanted if name.partition(".")[0] in cell.robots}
    values: dict = {}
    moment(0.0, tf=not robot_states)
    frames, pending, joints_moved = 1, None, False
    for t, name, value in recorded:
        if pending is not None and t > pending:
            shown(pending, joints_moved)
            frames, joints_moved = frames + 1, False
        values[name] = value
        joints_moved |= name in robot_states
        pending = t
    if pending is not None:
        shown(pending, joints_moved)
        frames += 1
    return frames


def _primitive(inspector, g):
    """("cubes" | "cylinders" | "spheres", its size and colour fields) of a geometry, or None."""
    from pydrake.geometry import Box, Capsule, Cylinder, Ellipsoid, Sphere

    shape = inspector.GetShape(g)
    color = {"r": 0.6, "g": 0.6, "b": 0.62, "a": 1.0}
    illustration = inspector.GetIllustrationProperties(g)
    if illustration is not None and illustration.HasProperty("phong", "diffuse"):
        rgba = illustration.GetProperty("phong", "diffuse")
        color = {"r": rgba.r(), "g": rgba.g(), "b": rgba.b(), "a": rgba.a()}
    elif illustration is None:
        color = {"r": 0.9, "g": 0.5, "b": 0.1, "a": 0.5}  # measuring geometry: translucent
    if isinstance(shape, Box):
        return "cubes", {"size": {"x": shape.width(), "y": shape.depth(), "z": shape.height()}, "color": color}
    if isinstance(shape, Cylinder):
        d = 2 * shape.radius()
        return "cylinders", {"size": {"x": d, "y": d, "z": shape.length()}, "bottom_scale": 1.0, "top_scale": 1.0,
                             "color": color}
    if isinstance(shape, Capsule):  # drawn as the cylinder that holds it
        d = 2 * shape.radius()
        return "cylinders", {"size": {"x": d, "y": d, "z": shape.length() + d}, "bottom_scale": 1.0, "top_scale": 1.0,
                             "color": color}
    if isinstance(shape, Sphere):
        d = 2 * shape.radius()
        return "spheres", {"size": {"x": d, "y": d, "z": d}, "color": color}
    if isinstance(shape, Ellipsoid):
        return "spheres", {"size": {"x": 2 * shape.a(), "y": 2 * shape.b(), "z": 2 * shape.c()}, "color": color}
    return None


def _entity(t: float, g, kind: str, fields: dict, X) -> dict:
    shape = {key: value for key, value in fields.items() if key != "metadata"}
    return {"timestamp": _stamp(t), "frame_id": "world", "id": f"geometry/{g.get_value()}",
            "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": False, "metadata": fields.get("metadata", []),
            kind: [{"pose": _pose(X), **shape}]}


# -- live: the same on Foxglove's WebSocket ---------------------------------------------
SCENE_PERIOD = 0.1
"""s: how often the live feed sends the arms' frames and the scene (the recorded rate)."""


class FoxgloveFeed:
    """A Foxglove WebSocket server (``foxglove-sdk``, loopback by default) fed by a system of the diagram
    (``FoxgloveFeedSystem``): every channel on ``/module/signal`` when it changes and every second,
    ``/tf`` and the whole ``/scene`` every 0.1 s of the twin's time.

    The port is taken at once (one in use fails here, before anything runs); clients are served from when
    the diagram's system has declared every channel (:meth:`add_to`), so a client sees them all in its first
    advertisement. (foxglove-sdk sends a channel added later to each connected client before it records the
    channel as that client's: a client quick to subscribe, while the thread adding it waits for a core, is
    told "unknown channel". The first advertisement is recorded before the client's messages are read.)"""

    def __init__(self, host: str, port: int, name: str):
        import socket

        self.host, self.name = host, name
        self.context = None
        self.server = None
        family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
        self._reserved = socket.socket(family, kind, proto)
        try:
            self._reserved.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the server's own bind
            self._reserved.bind(address)
        except OSError:
            self._reserved.close()
            raise
        self.port = self._reserved.getsockname()[1]
        import foxglove

        self.context = foxglove.Context()

    def serve(self) -> None:
        """Start serving on the port taken (once every channel is declared)."""
        import foxglove

        if self.server is None:
            self._reserved.close()
            self.server = foxglove.start_server(name=self.name, host=self.host, port=self.port, context=self.context)

    def channel(self, topic: str, schema_name: str, schema: dict):
        """A channel of the feed on ``topic`` whose messages follow ``schema`` (JSON Schema) under ``schema_name``."""
        import foxglove

        return foxglove.Channel(topic, schema=foxglove.Schema(name=schema_name, encoding="jsonschema",
                                                              data=json.dumps(schema).encode()),
                                message_encoding="json", context=self.context)

    def official_channel(self, topic: str, message: str):
        """A channel of the feed on ``topic`` carrying Foxglove's official ``message`` (its schema, protobuf)."""
        import foxglove.channels

        kind = getattr(foxglove.channels, message.removeprefix("foxglove.") + "Channel")
        return kind(topic, context=self.context)

    def close(self) -> None:
        """Stop serving: the WebSocket server closes and its port is freed."""
        if self.server is not None:
            self.server.stop()
        self._reserved.close()

    def add_to(self, builder, cell, time_step: float):
        """Add the system feeding this server to the diagram being built (``cellsim.diagrams.cell`` calls it),
        then serve: every channel is declared."""
        system = add_foxglove_feed(builder, cell, self, time_step)
        self.serve()
        return system


class FoxgloveFeedSystem(LeafSystem):
    """Publishes the twin to a ``FoxgloveFeed``.

    Ports:
      <module.signal> (input), per channel: the channel's port vector; sent as ``/module/signal`` when
        it changes and every ``HEARTBEAT`` (a client that connects late gets every value within 1 s).
      geometry_query (input): SceneGraph's QueryObject (the scene's poses).
      body_poses (input): the plant's body poses (the robots' links).
    """

    def __init__(self, cell, feed: FoxgloveFeed, time_step: float):
        """``cell``: the cell being built (its channels, plant, scene graph, robots)."""
        super().__init__()
        self.set_name("foxglove_feed")
        self.plant, self.robots = cell.plant, dict(cell.robots)
        self.shapes = scene_shapes(cell.scene_graph)
        self.inputs = []
        for spec, port in cell.channels().values():
            schema = channel_schema(spec.name, spec.type.kind, spec.type.domain(), spec.type.unit, spec.description)
            topic = feed.channel(topic_of(spec.name), f"cellsim.{spec.name}", schema)
            self.inputs.append((spec, self.DeclareVectorInputPort(spec.name, port.size()), topic))
        self.query_port = self.DeclareAbstractInputPort("geometry_query", AbstractValue.Make(QueryObject()))
        self.poses_port = self.DeclareAbstractInputPort("body_poses", self.plant.get_body_poses_output_port().Allocate())
        self.tf = feed.official_channel("/tf", FRAME_TRANSFORMS)
        self.scene = feed.official_channel("/scene", SCENE_UPDATE)
        self._last: dict[str, tuple] = {}
        self.DeclarePeriodicPublishEvent(TICK, time_step, self._publish_channels)  # as the Zenoh publisher
        self.DeclarePeriodicPublishEvent(SCENE_PERIOD, 0.0, self._publish_scene)

    def _publish_channels(self, context) -> None:
        t = context.get_time()
        for spec, port, topic in self.inputs:
            value = spec.type.decode(port.Eval(context))
            previous = self._last.get(spec.name)
            if previous is None or value != previous[0] or t - previous[1] >= HEARTBEAT - 1e-9:
                self._last[spec.name] = (value, t)
                topic.log(json.dumps({"t": t, "value": value}), log_time=_ns(t))

    def _publish_scene(self, context) -> None:
        t = context.get_time()
        # the whole scene every time: a client that connects late sees the still geometry too
        query = self.query_port.Eval(context)
        self.scene.log(_message(SCENE_UPDATE, scene_update(t, self.shapes, query)), log_time=_ns(t))
        poses = self.poses_port.Eval(context)
        transforms = frame_transforms(t, self.plant, self.robots, lambda body: poses[int(body.index())])
        self.tf.log(_message(FRAME_TRANSFORMS, transforms), log_time=_ns(t))


def add_foxglove_feed(builder, cell, feed: FoxgloveFeed, time_step: float) -> FoxgloveFeedSystem:
    """The diagram's system publishing to ``feed``, wired to every channel, the scene graph and the plant."""
    system = builder.AddSystem(FoxgloveFeedSystem(cell, feed, time_step))
    for spec, port in cell.channels().values():
        builder.Connect(port, system.GetInputPort(spec.name))
    builder.Connect(cell.scene_graph.get_query_output_port(), system.query_port)
    builder.Connect(cell.plant.get_body_poses_output_port(), system.poses_port)
    return system
