"""The emulated cell's devices speaking the real protocols (``cellsim emulate --can``).

Given the bridge daemon's configuration, the emulator plays

* each CAN device as a node following the DBC: its frames at the device's cycle
  time, with the alive counter and CRC of the end-to-end protection
  (``cellsim.bridges.e2e.protect``) and, for an authenticated message, its freshness
  value and MAC (``cellsim.bridges.secoc``, keys from the cell's CAN key); a device with
  command frames takes them from the bus and checks them as the real device
  would (a bad, forged or stale frame: the entity kind's *safe command*);
* each robot's controller over Zenoh: its state stream (``cellsim.bridges.robot``) at
  the controller's rate, and its requests from the controller's request key;
* each robot whose configuration names ``rtde`` as a UR controller: an RTDE server
  (``cellsim.ur.controller``) on the configured host and port (``--rtde PORT``
  overrides), its state at the controller's rate, the program's input registers as
  the arm's commands (under the twin's command) and the speed slider as its
  ``speed_scaling`` (always, as a real controller's slider is);
* the configuration's PLC (``plc``): an OPC UA server (``cellsim.bridges.plc_server``) on
  its endpoint (``--opcua PORT`` overrides the port), the PLC's entities' samples in its
  nodes, their command nodes as their commands (under the twin's command).

Everything else stays on its physical key. Faults on the bus
(``--fault welder=crc@3-5``): ``drop`` (frames not sent), ``crc`` (a corrupted
CRC byte), ``replay`` (the previous frame again, its counter repeated),
``length`` (a byte short), ``flood`` (a babbling node floods the bus with
highest-priority frames, so the device's own frames lose arbitration and never
get through), ``delay`` (frames held back ``DELAY`` s; the held ones are
dropped when it ends). A robot controller has the Zenoh faults of
``cellsim.live.emulator``.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections import deque

from cellsim.bridges.config import LoadedBridge
from cellsim.bridges.e2e import DeviceChecker, protect
from cellsim.bridges.secoc import Authenticator, is_authenticated, message_key
from cellsim.bridges.signals import SignalMap, Unsendable
from cellsim import codec
from cellsim.live.faults import BUS_FAULTS
from cellsim.live import keys
from cellsim.live.emulator import ZenohOutlet

DELAY = 0.5
"""How long (s) the ``delay`` fault holds a frame back: longer than any device's watchdog."""
FLOOD_FRAMES = 20
"""Frames the ``flood`` fault puts on the bus per frame of the device it silences."""


class CanOutlet:
    """One CAN device of the emulated cell: its samples as protected frames, with the bus faults."""

    faults = BUS_FAULTS

    def __init__(self, bus, message, signals: SignalMap, authenticator: Authenticator | None = None):
        self.bus, self.message, self.signals = bus, message, signals
        self.authenticator = authenticator
        self.counter = 0
        self.last: bytes | None = None
        self.held: deque = deque()  # (release time, frame) while delayed
        self.sent = 0

    def send(self, fields: dict, fault: str | None, sim_time: float) -> int:
        import can

        if fault != "delay" and self.held:
            self.held.clear()  # the delay ended: what it held back is lost
        try:
            data = self._frame(fields)
        except Unsendable:
            return 0  # a sample no frame can carry is not sent: the receiver's watchdog fails the device safe
        if fault == "replay" and self.last is not None:
            data = self.last
        elif fault == "crc":
            data = bytes([data[0] ^ 0x5A]) + data[1:]
        elif fault == "length":
            data = data[:-1]
        self.last = data if fault not in ("crc", "length") else self.last
        frames = []
        if fault == "flood":
            frames = [can.Message(arbitration_id=0x000, data=bytes(8), is_extended_id=False)] * FLOOD_FRAMES
        elif fault == "delay":
            self.held.append((time.monotonic() + DELAY, data))
            while self.held and self.held[0][0] <= time.monotonic():
                frames.append(self._message(self.held.popleft()[1]))
        elif fault != "drop":
            frames = [self._message(data)]
        for frame in frames:
            try:
                self.bus.send(frame)
            except Exception:  # noqa: BLE001 - a full or lost bus loses the frame, as on a real one
                continue
            self.sent += 1
        return len(frames)

    def _frame(self, fields: dict) -> bytes:
        data = protect(self.message, self.signals.signals(fields), self.counter, self.authenticator)
        self.counter += 1
        return data

    def _message(self, data: bytes):
        import can

        return can.Message(arbitration_id=self.message.frame_id, data=data, is_extended_id=False)


class JointMotion:
    """A robot's joints from its samples, and their velocities by difference over simulated time (the wall-clock
    times of two states of a run catching up may be microseconds apart)."""

    def __init__(self):
        self._last: tuple[float, list[float]] | None = None

    def __call__(self, fields: dict, sim_time: float) -> tuple[list[float], list[float]]:
        """(positions in rad, velocities in rad/s) of the sample ``fields`` at ``sim_time`` (s)."""
        position = [float(fields[f"q{i}"]) for i in range(6)]
        velocity = [0.0] * 6
        if self._last is not None and sim_time > self._last[0]:
            dt = sim_time - self._last[0]
            velocity = [(q - q0) / dt for q, q0 in zip(position, self._last[1])]
        self._last = (sim_time, position)
        return position, velocity


class RobotStateEncoder:
    """A robot entity's sample as its controller's state message (``cellsim.bridges.robot``)."""

    def __init__(self):
        self._motion = JointMotion()

    def __call__(self, t: float, seq: int, fields: dict, sim_time: float) -> bytes:
        position, velocity = self._motion(fields, sim_time)
        state = {"t": t, "seq": seq, "position": position, "velocity": velocity,
                 "safety_mode": fields["safety_mode"], "activity": fields["activity"], "reached_pose": fields["reached_pose"]}
        return json.dumps(state, separators=(",", ":")).encode()


class RtdeOutlet:
    """A robot's samples as an emulated UR controller's RTDE state packages, with the RTDE faults."""

    def __init__(self, controller):
        self.controller = controller
        self._motion = JointMotion()

    @property
    def faults(self):
        from cellsim.ur.controller import RTDE_FAULTS

        return RTDE_FAULTS

    def send(self, fields: dict, fault: str | None, sim_time: float) -> int:
        _, velocity = self._motion(fields, sim_time)
        c = self.controller
        return c.server.publish(c.program.state(fields, velocity, sim_time, c.slider), fault)


class EmulatedController:
    """One emulated UR controller: its RTDE server, the program's registers, the slider and the arm's commands.

    The program (as docs/ur.md asks of a real one) takes a command only when the heartbeat register
    moved: a daemon that stops counting is a lost supervisor, and the arm's command source then fails
    safe after the robot's ``stale_after``.
    """

    def __init__(self, host: str, port: int, program, rate: float):
        """``rate``: how often the arm's state is published (Hz): the robot's cycle time."""
        from cellsim.ur.controller import RtdeServer

        self.program = program
        self.slider = 1.0
        self.inputs: dict = {}
        self.scaling = None
        """The robot's speed_scaling source (a ``HeldValue``), once the diagram has one."""
        self.source = None
        """The arm's command source (a ``ZenohCommandSource``), under the twin's command."""
        self._seq = 0
        self._heartbeat = None
        self._lock = threading.Lock()
        self.server = RtdeServer(host, port, on_inputs=self._on_inputs, rate=rate, listen_from_first_state=True)

    def _on_inputs(self, values: dict) -> None:  # on the client's thread
        heartbeat = rtde_register(self.program.registers.heartbeat)
        with self._lock:
            self.inputs.update(values)
            if values.get("speed_slider_mask", 0) & 1 and "speed_slider_fraction" in values:
                fraction = float(values["speed_slider_fraction"])
                self.slider = min(1.0, max(0.0, fraction)) if math.isfinite(fraction) else 0.0
                if self.scaling is not None:
                    self.scaling.set(self.slider)
            if self.source is None or heartbeat not in values or values[heartbeat] == self._heartbeat:
                return
            self._heartbeat = values[heartbeat]
            fields, _ = self.program.command(self.inputs)
            if fields is None:
                return  # the twin does not command the arm: no command (its source goes stale, and fails safe)
            self._seq += 1
            payload = codec.encode_fields(time.time(), self._seq, fields)
        self.source.deliver(payload)


def rtde_register(number: int) -> str:
    from cellsim.ur import rtde

    return rtde.int_register("input", number)


def protocols_of(config) -> dict[str, tuple[str, tuple[str, ...]]]:
    """The entities of a bridge configuration speaking a protocol other than CAN -> (what they are, their
    faults): a UR controller's RTDE, a PLC's OPC UA."""
    from cellsim.bridges.plc_server import PLC_FAULTS
    from cellsim.ur.controller import RTDE_FAULTS

    found = {e: ("a UR controller over RTDE", RTDE_FAULTS) for e, r in config.robots.items() if r.rtde is not None}
    found.update({e: ("wired to the PLC (OPC UA)", PLC_FAULTS) for e in (config.plc.entities if config.plc else ())})
    return found


class EmulatedDevices:
    """The emulated cell's CAN devices and robot controllers, as the bridge configuration describes them."""

    def __init__(self, loaded: LoadedBridge, bus, session, can_key: bytes | None = None, rtde_port: int | None = None,
                 opcua_endpoint: str | None = None, plc_certificates: tuple | None = None):
        """``opcua_endpoint``: where the PLC is served (default: the configuration's); ``plc_certificates``: (the
        PLC's OPC UA certificate, its key, the bridge's certificate), for a PLC with security."""
        self.loaded, self.bus, self.session, self.can_key = loaded, bus, session, can_key
        self.config = loaded.config
        self.controllers: dict[str, EmulatedController] = {}
        self.plc = None
        try:
            for name, robot in self.config.robots.items():
                if robot.rtde is not None:
                    port = robot.rtde.port if rtde_port is None else rtde_port
                    self.controllers[name] = EmulatedController(robot.rtde.host, port, loaded.programs[name],
                                                                1.0 / robot.cycle_time)
            if self.config.plc is not None:
                from cellsim.bridges.plc_server import EmulatedPlc

                self.plc = EmulatedPlc(self.config.plc, loaded.samples, loaded.commands, loaded.safe, opcua_endpoint,
                                       plc_certificates)
        except BaseException:
            self.close()
            raise
        if loaded.authenticated() and can_key is None:
            raise ValueError(f"{', '.join(loaded.authenticated())} are authenticated: the devices need the CAN key")
        self._feeds: dict[int, tuple] = {}  # frame id -> (entity, mapping, checker)
        self._entities: dict[str, dict] = {}  # entity -> {"source", "names", "seq", "checkers", "fields", "values"}
        self.clock = time.monotonic
        """The devices' clock (s) their frames' watchdogs run on."""
        self._subscribers = []
        self._lock = threading.Lock()
        self._notifier = None
        self.command_frames = 0

    def rates(self) -> dict[str, float]:
        """Each device's sending rate (Hz): its cycle time (a PLC's entities: its scan)."""
        from cellsim.bridges.plc_server import SCAN

        cfg = self.config
        plc = {e: 1.0 / SCAN for e in cfg.plc.entities} if cfg.plc is not None else {}
        return {**{e: 1.0 / d.cycle_time for e, d in cfg.devices.items()}, **{e: 1.0 / r.cycle_time for e, r in cfg.robots.items()},
                **plc}

    def fault_kinds(self, entity: str) -> tuple[str, ...] | None:
        if self.plc is not None and entity in self.config.plc.entities:
            from cellsim.bridges.plc_server import PLC_FAULTS

            return PLC_FAULTS
        if entity in self.controllers:
            from cellsim.ur.controller import RTDE_FAULTS

            return RTDE_FAULTS
        return BUS_FAULTS if entity in self.config.devices else None

    def add_systems(self, builder, entity, time_step: float) -> None:
        """What an entity's device adds to the emulated diagram: a UR controller's speed slider, into the
        robot's ``speed_scaling``."""
        controller = self.controllers.get(entity.module)
        if controller is None:
            return
        from cellsim.live.systems import HeldValue

        scaling = builder.AddSystem(HeldValue(f"{entity.module}.speed_slider", controller.slider,
                                              self.config.robots[entity.module].cycle_time, time_step))
        builder.Connect(scaling.get_output_port(0), entity.GetInputPort("speed_scaling"))
        controller.scaling = scaling

    def outlet(self, name: str, entity):
        cfg = self.config
        if name in self.controllers:
            return RtdeOutlet(self.controllers[name])
        if self.plc is not None and name in cfg.plc.entities:
            return self.plc.outlet(name)
        if name in cfg.devices:
            device = cfg.devices[name]
            message = self.loaded.database.get_message_by_name(device.message)
            return CanOutlet(self.bus, message, self.loaded.signals(device), self._authenticator(message))
        if name in cfg.robots:
            return ZenohOutlet(self.session.declare_publisher(keys.controller_state(self.loaded.cell, name)), RobotStateEncoder())
        return None

    def feed_commands(self, entity, source) -> bool:
        """Feed ``source`` (a ZenohCommandSource) from the entity's device protocol, if it has one."""
        cfg, name = self.config, entity.module
        if name in self.controllers:
            self.controllers[name].source = source
            return True
        if self.plc is not None and name in self.plc.command_types:
            self.plc.sources[name] = source
            return True
        if name in cfg.robots:
            self._subscribers.append(self.session.declare_subscriber(
                keys.controller_request(self.loaded.cell, name), lambda sample: source.deliver(sample.payload.to_bytes())))
            return True
        if name not in cfg.commands:
            return False
        mappings = cfg.commands[name]
        safe = self.loaded.safe[name]
        state = self._entities[name] = {
            "source": source, "names": source.inputs, "seq": 0, "checkers": {},
            "fields": {m.message: list(m.fields.values()) for m in mappings},
            "values": {m.message: {f: safe[f] for f in m.fields.values()} for m in mappings}}
        for mapping in mappings:
            message = self.loaded.database.get_message_by_name(mapping.message)
            checker = DeviceChecker(message=message, timeout=mapping.watchdog, recover_after=cfg.recover_after,
                                    authenticator=self._authenticator(message))
            self._feeds[message.frame_id] = (name, mapping, checker)
            state["checkers"][mapping.message] = checker
        if self._notifier is None:
            import can

            self._notifier = can.Notifier(self.bus, [self._on_frame], timeout=0.1)
        return True

    def _authenticator(self, message) -> Authenticator | None:
        """The device's signer or verifier of an authenticated message (None: the message is not)."""
        if not is_authenticated(message):
            return None
        return Authenticator(message, message_key(self.can_key, message.frame_id), self.config.freshness_tick)

    def _on_frame(self, frame) -> None:
        """On python-can's thread: check a command frame as the device would, hand the command over."""
        feed = self._feeds.get(frame.arbitration_id)
        if feed is None or frame.is_error_frame or frame.is_remote_frame:
            return
        name, mapping, checker = feed
        now = self.clock()
        verdict = checker.check(bytes(frame.data), now)
        safe = self.loaded.safe[name]
        carried = self.loaded.signals(mapping).fields(verdict.values) if verdict.trusted else None
        with self._lock:
            state = self._entities[name]
            self.command_frames += 1
            # each of the entity's messages as its own link has it now: one whose frames stopped (its watchdog) or
            # failed reads its safe values, whatever its other messages still bring
            for other, other_checker in state["checkers"].items():
                other_checker.watchdog(now)  # (this frame's own too: a frozen stream's repeats are refused, not good)
                if other_checker.failed:
                    state["values"][other] = {f: safe[f] for f in state["fields"][other]}
            if carried is not None:
                state["values"][mapping.message] = carried
            state["seq"] += 1
            fields = {k: v for values in state["values"].values() for k, v in values.items()}
            fields = {n: fields.get(n) for n in state["names"]}
            payload = codec.encode_fields(time.time(), state["seq"], fields)
        state["source"].deliver(payload)

    def close(self) -> None:
        for controller in self.controllers.values():
            controller.server.close()
        if self.plc is not None:
            self.plc.close()
        if getattr(self, "_notifier", None) is not None:  # (closing a half-made one too)
            self._notifier.stop()
        for subscriber in getattr(self, "_subscribers", []):
            try:
                subscriber.undeclare()
            except Exception:  # noqa: BLE001 - closing anyway
                pass
