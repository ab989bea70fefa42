"""The bridge daemon's configuration (``bridges/welding_cell.yaml``): typed, and loaded with its scenario.

A bridge maps a cell's devices to the entities of the cell's scenario, so it is
loaded *with* the scenario (its ``scenario:`` key): each device's fields must be
exactly its entity kind's physical-sample fields, each command signal must carry
one of the kind's command fields, and every value a frame may carry must be one
the entity takes. What a device is told when its supervisor is lost is the
kind's ``safe_command`` (declared once, by the kind); what the twin assumes when
a device fails is the kind's own fail-safe (the daemon sends a link failure).
Errors name the file, line and key, as the scenario's do.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

from cellsim.bridges.e2e import COUNTER_MODULO, MAX_GAP, sharing_data_ids
from cellsim.bridges.signals import NONE, SignalMap
from cellsim.config.typed_yaml import ConfigError, FieldError, Range, load_file
from cellsim.codec import FieldCodec

Seconds = Annotated[float, Range(0.0, 60.0, lo_open=True, unit="s")]


@dataclass
class CanSettings:
    """The CAN bus: any python-can interface (socketcan on a real cell; remote or virtual in tests)."""

    interface: str = "virtual"
    """python-can interface name: socketcan, remote, virtual..."""
    channel: str = "cellsim"
    """The interface's channel: can0, ws://127.0.0.1:54701/, a virtual bus name..."""


@dataclass
class ZenohSettings:
    """How the daemon reaches the twin (as ``cellsim live``'s clients do)."""

    connect: list[str] = field(default_factory=list)
    """Zenoh endpoints to connect to (default: the twin's tls/127.0.0.1:7447)."""
    config: str | None = None
    """A Zenoh JSON5 configuration file for anything more, relative to this file."""


@dataclass
class DeviceMapping:
    """One CAN device: the DBC message it sends and the entity sample fields its signals fill."""

    message: str
    """The DBC message the device sends, every cycle_time."""
    fields: dict[str, str]
    """Entity sample field -> DBC signal (an enumeration's value names are the field's values)."""
    cycle_time: Seconds = 0.02
    """How often the device sends (s)."""
    watchdog: Seconds = 0.1
    """With no good frame for this long the device is failed (s)."""
    e2e_only: str | None = None
    """Why this device's message is not authenticated (its device cannot compute a MAC): required for a
    message without ``Freshness`` and ``Mac`` signals, said by the daemon at start; none otherwise."""

    def __post_init__(self):
        if self.watchdog <= self.cycle_time:
            raise FieldError("watchdog", "the watchdog must be longer than the cycle time")
        _counter_cannot_wrap(self.watchdog, self.cycle_time)


def _counter_cannot_wrap(watchdog: float, cycle_time: float) -> None:
    """The alive counter runs modulo 16: frames lost for 16 cycles bring it round to where it was, unseen, so the
    watchdog of the frames' receiver must fire first (FieldError otherwise)."""
    most = (COUNTER_MODULO - MAX_GAP) * cycle_time
    if watchdog >= most:
        raise FieldError("watchdog", f"the watchdog must be shorter than {COUNTER_MODULO - MAX_GAP} cycles "
                         f"({most:g} s): frames lost for {COUNTER_MODULO} cycles bring the alive counter round unseen")


@dataclass
class CommandMapping:
    """One CAN frame the daemon sends a device, from the twin's commands to an entity."""

    message: str
    """The DBC message the daemon sends, every cycle_time."""
    fields: dict[str, str]
    """DBC signal -> the entity's command field it carries (a null command field: the signal's ``none``)."""
    cycle_time: Seconds = 0.04
    """How often the frame is sent (s)."""
    watchdog: Seconds = 0.5
    """With no good command from the twin for this long (s) it counts as lost: the entity kind's safe
    command goes out."""
    e2e_only: str | None = None
    """Why this frame is not authenticated (its device cannot check a MAC): required for a message without
    ``Freshness`` and ``Mac`` signals, said by the daemon at start; none otherwise."""

    def __post_init__(self):
        if self.watchdog <= self.cycle_time:
            raise FieldError("watchdog", "the watchdog must be longer than the cycle time")
        _counter_cannot_wrap(self.watchdog, self.cycle_time)  # (a device checks these frames with this watchdog)


Register = Annotated[int, Range(0, 47)]
"""An RTDE integer register's number (0-23 the lower range, 24-47 the upper)."""


@dataclass
class UrRegisters:
    """The integer registers the integrator's UR program and the twin share (``cellsim.ur.program``): each
    holds a value's code, its position in the field's list (``cellsim modules robot``)."""

    safety_mode_request: Register = 18
    """input_int_register: the safety mode the twin requests (the program must act on it: docs/ur.md)."""
    activity_request: Register = 19
    """input_int_register: the activity the twin requests."""
    target_pose: Register = 20
    """input_int_register: the named pose to move to (its index), -1 to hold."""
    heartbeat: Register = 21
    """input_int_register: counts up with every command the daemon sends; the program stops the arm when it
    stalls for longer than the robot's ``command_watchdog`` (the daemon itself lost)."""
    safety_mode: Register = 18
    """output_int_register: the safety mode the program runs the arm in."""
    activity: Register = 19
    """output_int_register: the program's activity."""
    reached_pose: Register = 20
    """output_int_register: the named pose the arm stands at (its code: 0 moving, then the poses in order)."""

    def __post_init__(self):
        inputs = (self.safety_mode_request, self.activity_request, self.target_pose, self.heartbeat)
        if len(set(inputs)) != len(inputs):
            raise FieldError("safety_mode_request", "the input registers must differ from one another")
        outputs = (self.safety_mode, self.activity, self.reached_pose)
        if len(set(outputs)) != len(outputs):
            raise FieldError("safety_mode", "the output registers must differ from one another")


def bad_host(host: str) -> str | None:
    """Why ``host`` is no address a socket can dial (a name with an empty or overlong label, spaces, nothing), or
    None: checked when the configuration is read, not found by the connection's thread."""
    import ipaddress

    if not host or host != host.strip() or any(c.isspace() for c in host):
        return f"'{host}' is not a host name or IP address"
    try:
        ipaddress.ip_address(host)
        return None
    except ValueError:
        pass
    try:
        host.encode("idna")
    except UnicodeError:
        return f"'{host}' is not a host name or IP address (an empty or overlong part between dots)"
    return None


def bad_endpoint(endpoint: str) -> str | None:
    """Why ``endpoint`` is no ``opc.tcp://HOST:PORT`` a client can dial, or None."""
    from urllib.parse import urlsplit

    if not endpoint.startswith("opc.tcp://"):
        return f"'{endpoint}' is not an opc.tcp://HOST:PORT endpoint"
    try:
        parts = urlsplit(endpoint)
        port = parts.port
    except ValueError:
        return f"'{endpoint}': its port is not a number from 1 to 65535"
    if port is not None and not 1 <= port <= 65535:
        return f"'{endpoint}': its port is not a number from 1 to 65535"
    why = bad_host(parts.hostname or "")
    return None if why is None else f"'{endpoint}': {why}"


@dataclass
class RtdeSettings:
    """A Universal Robots controller over RTDE (``cellsim.ur``): where it is and the program's registers."""

    host: str = "127.0.0.1"
    """The controller's address (``--rtde HOST:PORT`` overrides)."""
    port: Annotated[int, Range(1, 65535)] = 30004
    """Its RTDE port (30004 on a real controller)."""
    registers: UrRegisters = field(default_factory=UrRegisters)
    reconnect_after: Seconds = 1.0
    """How long (s) the daemon waits before dialling a lost or refusing controller again."""

    def __post_init__(self):
        why = bad_host(self.host)
        if why is not None:
            raise FieldError("host", why)


@dataclass
class RobotLinkConfig:
    """A robot controller: a Universal Robots controller over RTDE (``rtde``), or one streaming its joint
    state over Zenoh (``cellsim/bridges/robot.py`` says the format)."""

    joints: list[str]
    """The joint names, in the order of the robot entity's q0..q5 (as sensor_msgs/JointState names them)."""
    cycle_time: Seconds = 0.002
    """How often the controller sends its state (s): 500 Hz for a UR e-Series."""
    watchdog: Seconds = 0.05
    """With no good state for this long, or a state older than this on arrival, the link is failed (s)."""
    joint_limit: Annotated[float, Range(0.0, 20.0, lo_open=True, unit="rad")] = 6.2832
    """A joint position beyond +/- this is out of range (rad)."""
    max_joint_speed: Annotated[float, Range(0.0, 20.0, lo_open=True, unit="rad/s")] = 6.2832
    """A joint speed beyond +/- this is out of range (rad/s)."""
    command_cycle_time: Seconds = 0.02
    """How often the robot's requests are sent to the controller in twin mode (s)."""
    command_watchdog: Seconds = 0.5
    """The twin's commands older than this (s) count as lost: a stop is requested."""
    ros_topic: str | None = "/joint_states"
    """The ROS 2 topic the checked joint state is also published on, as CDR sensor_msgs/JointState
    (null: not published)."""
    ros_namespace: str = ""
    """The namespace zenoh-bridge-ros2dds runs with (its key is <namespace>/<topic>)."""
    rtde: RtdeSettings | None = None
    """A UR controller over RTDE, at ``cycle_time`` (0.002: its 500 Hz); null: the Zenoh state stream."""

    def __post_init__(self):
        if len(self.joints) != 6 or len(set(self.joints)) != 6:
            raise FieldError("joints", "name the robot's six joints, each once")
        if self.watchdog <= self.cycle_time:
            raise FieldError("watchdog", "the watchdog must be longer than the cycle time")
        for key, name in (("ros_topic", self.ros_topic), ("ros_namespace", self.ros_namespace)):
            if name and not all(part.replace("_", "a").isalnum() for part in name.strip("/").split("/")):
                raise FieldError(key, f"'{name}' is not a ROS 2 name (letters, digits, _ and /)")
        from cellsim.live.access import ROS_JOINT_STATE_KEYS

        key = self.ros_key
        if key is not None and not any(_key_matches(pattern, key) for pattern in ROS_JOINT_STATE_KEYS):
            raise FieldError("ros_topic", f"the ROS key {key} is not one the twin's access control lets a bridge "
                             f"publish ({' or '.join(ROS_JOINT_STATE_KEYS)}: a topic joint_states, under at most one "
                             "namespace)")

    @property
    def ros_key(self) -> str | None:
        """The Zenoh key zenoh-bridge-ros2dds maps to the ROS topic: the name without its leading /,
        after the bridge's namespace."""
        if not self.ros_topic:
            return None
        return "/".join(p for p in (self.ros_namespace.strip("/"), self.ros_topic.strip("/")) if p)


@dataclass
class PlcEntity:
    """One entity whose physical twin is wired to the PLC: the OPC UA nodes of its sample and commands."""

    fields: dict[str, str]
    """Entity sample field -> the node id holding it (``ns=2;s=Welder.SafetyMode``): an enumeration as its
    value's code (Int32, its position in the field's list), a flag as a Boolean, a number as a Double."""
    commands: dict[str, str] = field(default_factory=dict)
    """Entity command field -> the node id the daemon writes it to (in twin mode), coded the same way."""


@dataclass
class PlcSettings:
    """A PLC over OPC UA (``cellsim.bridges.plc``): the cell's machines and safety signals as it holds them."""

    endpoint: str
    """The PLC's OPC UA server (``opc.tcp://HOST:PORT``; ``cellsim bridge --opcua`` overrides)."""
    heartbeat: str
    """The node id of a counter the PLC's program increments every scan: while it stalls for ``watchdog``
    every entity of the PLC is failed (its data is stale)."""
    command_heartbeat: str
    """The node id the daemon counts up in with every command it writes: the PLC's program puts every
    commanded device in its safe state when it stalls (the daemon lost)."""
    entities: dict[str, PlcEntity]
    """Entity name -> its nodes."""
    security: Literal["sign_encrypt", "none"] = "sign_encrypt"
    """Basic256Sha256, signed and encrypted, with the cell's OPC UA certificates (docs/opcua.md); ``none`` only
    with ``insecure_because``."""
    insecure_because: str | None = None
    """Why this PLC is read without security (said by the daemon at every start); required with ``none``."""
    publishing_interval: Seconds = 0.02
    """The subscription's publishing interval (s): how often changed values come."""
    watchdog: Seconds = 0.2
    """With the heartbeat still for this long (s), or the PLC unreachable, every entity of it is failed."""
    command_cycle_time: Seconds = 0.04
    """How often the command nodes are written in twin mode (s)."""
    command_watchdog: Seconds = 0.5
    """The twin's commands older than this (s) count as lost: the kind's safe command is written."""
    reconnect_after: Seconds = 1.0
    """How long (s) the daemon waits before dialling a lost PLC again."""

    def __post_init__(self):
        why = bad_endpoint(self.endpoint)
        if why is not None:
            raise FieldError("endpoint", why)
        if self.security == "none" and not (self.insecure_because or "").strip():
            raise FieldError("security", "a PLC read without security must say why: insecure_because: REASON")
        if self.security != "none" and self.insecure_because is not None:
            raise FieldError("insecure_because", "the PLC is read with security: insecure_because does not apply")
        if self.watchdog <= self.publishing_interval:
            raise FieldError("watchdog", "the watchdog must be longer than the publishing interval")
        if self.command_cycle_time > self.command_watchdog / 2:
            raise FieldError("command_cycle_time", "commands must be written at least twice per command_watchdog "
                             f"({self.command_watchdog:g} s): the PLC's watchdog on the daemon's heartbeat would trip "
                             "between two writes, and a lost twin's safe command go out a cycle late")


@dataclass
class BridgeConfig:
    """The bridge daemon of one cell."""

    scenario: str
    """The cell's scenario file, relative to this file: its entities are what the devices are the
    physical twins of, and its name is the cell's (cellsim/<cell>/physical/<entity>)."""
    dbc: str
    """The cell's DBC file, relative to this file."""
    devices: dict[str, DeviceMapping]
    """Entity name -> the CAN device that is its physical twin."""
    commands: dict[str, list[CommandMapping]] = field(default_factory=dict)
    """Entity name -> the frames carrying the twin's commands to its device (sent in twin mode only)."""
    robots: dict[str, RobotLinkConfig] = field(default_factory=dict)
    """Robot entity name -> its controller's link (RTDE or Zenoh)."""
    plc: PlcSettings | None = None
    """A PLC over OPC UA holding some entities' physical twins (docs/opcua.md)."""
    can: CanSettings = field(default_factory=CanSettings)
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)
    recover_after: Annotated[int, Range(1, 1000)] = 3
    """Good frames in a row before a failed device is trusted again."""
    diagnostics_period: Annotated[float, Range(0.05, 60.0, unit="s")] = 1.0
    """How often each device's diagnostics are published (s); a change of level is published at once."""
    freshness_tick: Annotated[float, Range(0.0001, 1.0, unit="s")] = 0.01
    """The unit of an authenticated message's freshness value (s): senders and receivers count wall-clock
    ticks of this length (``cellsim/bridges/secoc.py``); at most any authenticated message's cycle time."""

    def __post_init__(self):
        for entity in (self.plc.entities if self.plc is not None else {}):
            if entity in self.devices or entity in self.commands or entity in self.robots:
                raise FieldError(f"plc.entities.{entity}", f"'{entity}' is also a CAN device or robot link: it has one "
                                 "physical twin")
        for entity in self.robots:
            if entity in self.devices:
                raise FieldError("robots", f"'{entity}' is both a CAN device and a robot link: it has one physical twin")
            if entity in self.commands:
                raise FieldError("robots", f"'{entity}' has CAN command frames and a robot link: give it one")


@dataclass
class LoadedBridge:
    config: BridgeConfig
    database: object
    """The cantools database of the DBC."""
    source: Path
    cell: str
    """The scenario's name."""
    samples: dict
    """Entity -> the codec of its physical samples (``cellsim.codec.FieldCodec``)."""
    commands: dict
    """Entity -> the codec of its command fields."""
    safe: dict
    """Entity -> its kind's safe command, as command fields (what its device is told when the twin is lost)."""
    programs: dict = field(default_factory=dict)
    """Robot entity with an RTDE controller -> its ``cellsim.ur.program.UrProgram``."""
    frames: dict = field(default_factory=dict)
    """DBC message name -> its ``SignalMap`` (``cellsim.bridges.signals``): the fields of a device's sample frame
    or of a command frame, the one conversion the daemon and the emulated devices share."""

    def authenticated(self) -> list[str]:
        """The DBC messages of the configuration that are authenticated (``cellsim.bridges.secoc``)."""
        from cellsim.bridges.secoc import is_authenticated

        return [n for n in dict.fromkeys(m.message for _, m in self.mappings())
                if is_authenticated(self.database.get_message_by_name(n))]

    def mappings(self) -> list[tuple[str, object]]:
        """(entity, mapping) of every device and command frame, devices first."""
        cfg = self.config
        return [*cfg.devices.items(), *((e, m) for e, ms in cfg.commands.items() for m in ms)]

    def e2e_only(self) -> list[str]:
        """One line per message sent without authentication, with its configuration's reason (the daemon
        says these at start)."""
        cfg = self.config
        lines = [f"{m.message} from {e}: {m.e2e_only}" for e, m in cfg.devices.items() if m.e2e_only is not None]
        return lines + [f"{m.message} to {e}: {m.e2e_only}" for e, ms in cfg.commands.items() for m in ms
                        if m.e2e_only is not None]

    def signals(self, mapping: DeviceMapping | CommandMapping):
        """The ``SignalMap`` of a device's or a command's frame."""
        return self.frames[mapping.message]


def load_bridge(path: str | Path, sf=None) -> LoadedBridge:
    """Read and check a bridge configuration with its scenario (``sf``, or the file its ``scenario:``
    names); raises ConfigError naming file, line and key."""
    import cantools

    from cellsim.scenario import load_scenario

    path = Path(path)
    loaded = load_file(BridgeConfig, path, base_key="base")
    cfg = loaded.value

    def error(key: str, problem: str) -> ConfigError:
        return ConfigError(*loaded.where(key), key, problem)

    if sf is None:
        scenario = relative_to_its_file(loaded, "scenario", cfg.scenario)
        if not scenario.is_file():
            raise error("scenario", f"file not found: {cfg.scenario}")
        sf = load_scenario(scenario)
    protocols = _protocols(sf)
    dbc = relative_to_its_file(loaded, "dbc", cfg.dbc)
    if not dbc.is_file():
        raise error("dbc", f"file not found: {cfg.dbc}")
    try:
        database = cantools.database.load_file(str(dbc))
    except Exception as e:  # noqa: BLE001 - cantools raises several kinds on a bad file
        raise error("dbc", f"not a DBC file cantools can read: {' '.join(str(e).split())[:200]}") from None
    messages = {m.name: m for m in database.messages}

    used: dict[str, str] = {}  # message name -> the key that maps it

    def protected_message(key: str, name: str):
        """The DBC message ``name``, which must exist, be mapped once and carry the end-to-end protection."""
        if name not in messages:
            raise error(f"{key}.message", f"no message '{name}' in {cfg.dbc} ({', '.join(messages)})")
        if name in used:
            raise error(f"{key}.message", f"'{name}' is already the frame of {used[name]}: a message is one frame")
        used[name] = key
        message = messages[name]
        names = {s.name for s in message.signals}
        if not {"Crc", "Counter"} <= names:
            raise error(f"{key}.message", f"'{name}' has no Crc and Counter signals: it is not end-to-end protected")
        if ("Freshness" in names) != ("Mac" in names):
            raise error(f"{key}.message", f"'{name}' has one of the Freshness and Mac signals: an authenticated "
                        "message has both")
        return message

    def check_authentication(key: str, mapping) -> None:
        """An authenticated message's freshness value must span its watchdog, at ticks of at most its cycle."""
        from cellsim.bridges.secoc import is_authenticated, window_problem
        from cellsim.link import LinkTrust

        message = messages[mapping.message]
        if not is_authenticated(message):
            if mapping.e2e_only is None or not mapping.e2e_only.strip():
                raise error(f"{key}.message", f"'{mapping.message}' is not authenticated (no Freshness and Mac "
                            "signals): a forged frame would pass its CRC and counter; use an authenticated message, "
                            "or say why its device cannot compute a MAC with e2e_only: REASON")
            return
        if mapping.e2e_only is not None:
            raise error(f"{key}.e2e_only", f"'{mapping.message}' is authenticated: e2e_only does not apply")
        if cfg.freshness_tick > mapping.cycle_time:
            raise error("freshness_tick", f"{cfg.freshness_tick:g} s is longer than the cycle time of "
                        f"{mapping.message} ({mapping.cycle_time:g} s): its frames would run ahead of the clock")
        problem = window_problem(message, cfg.freshness_tick, mapping.watchdog, LinkTrust.future_skew)
        if problem:
            raise error(f"{key}.message", f"{mapping.message}: {problem}")

    def signal_of(key: str, message, signal_name: str):
        signals = {s.name: s for s in message.signals}
        if signal_name not in signals:
            raise error(key, f"no signal '{signal_name}' in message '{message.name}'")
        return signals[signal_name]

    def protocol_of(key: str, name: str):
        if name not in protocols:
            raise error(key, f"no entity named '{name}' in {sf.source} (entities: {', '.join(protocols)})")
        return protocols[name]

    samples, commands, safe = {}, {}, {}
    for name, device in cfg.devices.items():
        key = f"devices.{name}"
        codec = samples[name] = _samples(protocol_of(key, name))
        if set(device.fields) != set(codec.names):
            raise error(f"{key}.fields", f"map each physical-sample field of {name} exactly once: {', '.join(codec.names)}")
        message = protected_message(key, device.message)
        check_authentication(key, device)
        types = dict(zip(codec.names, codec.types))
        for field_name, signal_name in device.fields.items():
            signal = signal_of(f"{key}.fields.{field_name}", message, signal_name)
            outside = _choices_outside(signal, types[field_name])
            if outside:
                raise error(f"{key}.fields.{field_name}", f"signal {signal_name} can carry {', '.join(outside)}, "
                            f"which {name}.{field_name} never takes ({', '.join(types[field_name].domain())})")
    for name, mappings in cfg.commands.items():
        protocol = protocol_of(f"commands.{name}", name)
        codec = commands[name] = _commands(protocol)
        safe[name] = dict(protocol.safe)
        for i, mapping in enumerate(mappings):
            key = f"commands.{name}.{i}"
            message = protected_message(key, mapping.message)
            check_authentication(key, mapping)
            for signal_name, field_name in mapping.fields.items():
                signal = signal_of(f"{key}.fields.{signal_name}", message, signal_name)
                if field_name not in codec.names:
                    raise error(f"{key}.fields.{signal_name}", f"'{field_name}' is not a command field of {name} "
                                f"({', '.join(codec.names)})")
                value = NONE if safe[name][field_name] is None else safe[name][field_name]
                if not accepts(signal, value):
                    raise error(f"{key}.fields.{signal_name}", f"{name}'s safe command {field_name} = {value} is not "
                                f"a value of signal {signal_name} ({choices_text(signal)})")
    for name in cfg.robots:
        protocol = protocol_of(f"robots.{name}", name)
        samples[name] = _samples(protocol)
        needed = {*(f"q{i}" for i in range(6)), "safety_mode", "activity", "reached_pose"}
        if set(samples[name].names) != needed:
            raise error(f"robots.{name}", f"'{name}' is not a six-axis robot (its sample fields: "
                        f"{', '.join(samples[name].names)})")
        commands[name] = _commands(protocol)
        safe[name] = dict(protocol.safe)
    if cfg.plc is not None:
        _check_plc(cfg.plc, protocol_of, error, samples, commands, safe)
    programs = {}
    for name, robot in cfg.robots.items():
        if robot.rtde is not None:
            caps = getattr(sf.scenario.entities[name], "speed_limits", None)
            if caps is None:
                raise error(f"robots.{name}.rtde", f"'{name}' has no speed_limits: the speed slider follows them")
            programs[name] = _program(robot, caps, samples[name], commands[name])
    shared = sharing_data_ids([messages[name] for name in used])
    if shared:
        first, second = shared
        raise error(used[second.name] + ".message", f"'{second.name}' (0x{second.frame_id:x}) has the data IDs of "
                    f"'{first.name}' (0x{first.frame_id:x}), also {first.length} bytes: a frame of one would check as "
                    "the other's; give one of them another frame id")
    frames = {}
    for name, device in cfg.devices.items():
        frames[device.message] = SignalMap.of_device(messages[device.message], device.fields,
                                                     dict(zip(samples[name].names, samples[name].types)))
    for name, mappings in cfg.commands.items():
        for mapping in mappings:
            frames[mapping.message] = SignalMap.of_command(messages[mapping.message], mapping.fields, safe[name],
                                                           dict(zip(commands[name].names, commands[name].types)))
    return LoadedBridge(cfg, database, path, sf.scenario.name, samples, commands, safe, programs, frames)


def _key_matches(pattern: str, key: str) -> bool:
    """Whether the Zenoh key ``key`` matches ``pattern`` (chunks equal, ``*`` any one chunk; no ``**``)."""
    parts, chunks = pattern.split("/"), key.split("/")
    return len(parts) == len(chunks) and all(p == "*" or p == c for p, c in zip(parts, chunks))


def relative_to_its_file(loaded, key: str, value: str) -> Path:
    """A path a key names, relative to the file that wrote the key (a base's key: the base's folder)."""
    return Path(loaded.where(key)[0]).parent / value


def _check_plc(plc: PlcSettings, protocol_of, error, samples: dict, commands: dict, safe: dict) -> None:
    """The PLC's entities are the scenario's, each sample field mapped once, commands its kind's; every node id
    is one OPC UA parses, and no node carries two things."""
    from asyncua import ua

    nodes: dict[str, str] = {}

    def node(key: str, text: str) -> None:
        try:
            ua.NodeId.from_string(text)
        except Exception:  # noqa: BLE001 - asyncua raises several kinds for a malformed id
            raise error(key, f"'{text}' is not an OPC UA node id (e.g. ns=2;s=Welder.SafetyMode)") from None
        if text in nodes:
            raise error(key, f"node {text} is already {nodes[text]}: a node carries one thing")
        nodes[text] = key

    node("plc.heartbeat", plc.heartbeat)
    node("plc.command_heartbeat", plc.command_heartbeat)
    for name, entity in plc.entities.items():
        key = f"plc.entities.{name}"
        protocol = protocol_of(key, name)
        samples[name] = _samples(protocol)
        if set(entity.fields) != set(samples[name].names):
            raise error(f"{key}.fields", f"map each physical-sample field of {name} exactly once: "
                        f"{', '.join(samples[name].names)}")
        for field_name, text in entity.fields.items():
            node(f"{key}.fields.{field_name}", text)
        if entity.commands:
            commands[name] = _commands(protocol)
            safe[name] = dict(protocol.safe)
        for field_name, text in entity.commands.items():
            if field_name not in commands[name].names:
                raise error(f"{key}.commands.{field_name}", f"'{field_name}' is not a command field of {name} "
                            f"({', '.join(commands[name].names)})")
            node(f"{key}.commands.{field_name}", text)


def _program(robot: RobotLinkConfig, caps, samples: FieldCodec, commands: FieldCodec):
    """The UR program's registers with the robot entity's fields, and the speed slider's fraction in each
    safety mode: the mode's tool speed cap over the normal cap (srmst and stopped: 0)."""
    from cellsim.ur.program import STOP_MODES, UrProgram

    fractions = {mode: (0.0 if mode in STOP_MODES else min(1.0, getattr(caps, mode) / caps.normal))
                 for mode in ("normal", "hguid", "ssmon", "pflim", *STOP_MODES)}
    return UrProgram(robot.rtde.registers, dict(zip(samples.names, samples.types)),
                     dict(zip(commands.names, commands.types)), fractions, caps.normal)


def _protocols(sf) -> dict:
    """Each entity's physical protocol (``cellsim.kind.Protocol``), as its kind declares it from its config:
    fields, types and safe commands, learnt without building the cell."""
    from cellsim.registry import kind_of

    found = {}
    for name, cfg in sf.scenario.entities.items():
        protocol = kind_of(cfg).protocol(name, cfg)
        if protocol is not None:
            found[name] = protocol
    return found


def _samples(protocol) -> FieldCodec:
    return FieldCodec(tuple(n for n, _ in protocol.samples), tuple(t for _, t in protocol.samples))


def _commands(protocol) -> FieldCodec:
    return FieldCodec(tuple(n for n, _ in protocol.commands), tuple(t for _, t in protocol.commands), nullable=True)


def _choices_outside(signal, ctype) -> list[str]:
    """The values an enumerated signal can carry that a field of type ``ctype`` never takes."""
    if signal.choices is None or ctype.kind != "enum":
        return []
    domain = set(ctype.domain())
    return [str(v) for v in signal.choices.values() if str(v) not in domain]


def accepts(signal, value) -> bool:
    """Whether an enumerated signal has ``value`` among its named values (any value, for a number)."""
    return signal.choices is None or str(value) in {str(v) for v in signal.choices.values()}


def choices_text(signal) -> str:
    return ", ".join(str(v) for v in signal.choices.values())
