"""The bridge daemon's CAN side: device frames in, the twin's physical samples out.

Every frame of a configured device passes the black-channel checks of
``bridges.e2e``; a trusted frame becomes the entity's physical sample on
``cellsim/<cell>/physical/<entity>`` in the live format (``docs/live.md``). Any
failure (length, CRC, counter, range, watchdog), and every frame while the device
recovers, publishes the device's fail-safe sample at once instead: the twin sees
the state it must assume. Frames of unknown identifiers are counted and
dropped; nothing a frame holds stops the daemon.

The twin's commands go the other way (:meth:`Bridge.send_commands`, every
cycle): a device whose entity is in twin mode (the twin's ``twin_mode`` channel)
gets the twin's latest command in its protected frames; when that command is
older than the mapping's watchdog, or the twin's liveliness token is gone while
the entity was in twin mode, it gets the mapping's *safe* values: losing the
supervisor makes the cell safer. In model or shadow mode nothing is sent: the
device answers to its own controls. Network callbacks only queue what arrives;
``send_commands`` takes it in.

Still to come (issue "The bridge daemon"): the robot over Zenoh, diagnostics,
the daemon's command line.
"""

from __future__ import annotations

import json
import queue
import time
from dataclasses import dataclass, field

from bridges.config import LoadedBridge, accepts
from bridges.e2e import DeviceChecker, Verdict, protect
from cellsim.live import keys
from cellsim.live.codec import encode_fields


@dataclass
class Device:
    entity: str
    mapping: object
    message: object
    checker: DeviceChecker
    publisher: object
    seq: int = 0
    published: int = 0
    fail_safe_published: int = 0


@dataclass
class Bridge:
    """Maps one cell's CAN devices to its twin's physical samples."""

    loaded: LoadedBridge
    session: object
    bus: object = None
    """The python-can bus commands are sent on (None: no commands)."""
    clock: object = time.time
    devices: dict = field(default_factory=dict)
    unknown_frames: int = 0
    frames_sent: int = 0
    safe_frames_sent: int = 0

    def __post_init__(self):
        cfg, database = self.loaded.config, self.loaded.database
        for entity, mapping in cfg.devices.items():
            message = database.get_message_by_name(mapping.message)
            checker = DeviceChecker(message, mapping.watchdog, recover_after=cfg.recover_after)
            publisher = self.session.declare_publisher(keys.physical(cfg.cell, entity))
            self.devices[message.frame_id] = Device(entity, mapping, message, checker, publisher)
        # the command side: what arrives is queued by the network callbacks
        self._inbox: queue.SimpleQueue = queue.SimpleQueue()
        self._commands: dict[str, tuple[float, dict]] = {}  # entity -> (wall time, fields)
        self._modes: dict[str, str] = {}  # entity -> its twin mode, as the twin publishes it
        self._twin_alive = False
        self._counters: dict[str, int] = {}
        self._subscribers = []
        for entity in cfg.commands:
            self._subscribers.append(self.session.declare_subscriber(
                keys.command(cfg.cell, entity), lambda s, e=entity: self._inbox.put(("command", e, s.payload.to_bytes()))))
            self._subscribers.append(self.session.declare_subscriber(
                keys.channel(cfg.cell, entity, "twin_mode"), lambda s, e=entity: self._inbox.put(("mode", e, s.payload.to_bytes()))))
        if cfg.commands:
            self._subscribers.append(self.session.liveliness().declare_subscriber(
                keys.alive(cfg.cell, "twin"), lambda s: self._inbox.put(("alive", None, str(s.kind).endswith("PUT"))), history=True))

    def handle(self, frame_id: int, data: bytes, now: float | None = None) -> Verdict | None:
        """Check one received frame and publish what it means for the twin."""
        now = self.clock() if now is None else now
        device = self.devices.get(frame_id)
        if device is None:
            self.unknown_frames += 1
            return None
        verdict = device.checker.check(bytes(data), now)
        if verdict.trusted:
            self._publish(device, self._fields(device, verdict.values), now)
        else:
            self._publish_fail_safe(device, now)
        return verdict

    def check_watchdogs(self, now: float | None = None) -> None:
        """Fail every device whose frames stopped (call it at least every cycle time)."""
        now = self.clock() if now is None else now
        for device in self.devices.values():
            if device.checker.watchdog(now) is not None:
                self._publish_fail_safe(device, now)

    def send_commands(self, now: float | None = None) -> None:
        """Send each commanded device its frame: the twin's command in twin mode, safe values when it is lost."""
        now = self.clock() if now is None else now
        self._take_inbox()
        for entity, mappings in self.loaded.config.commands.items():
            if self._modes.get(entity) != "twin":
                continue  # not in twin mode (or never heard of): the device answers to its own controls
            stamp, fields = self._commands.get(entity, (None, {}))
            for mapping in mappings:
                lost = not self._twin_alive or stamp is None or now - stamp > mapping.watchdog
                values = dict(mapping.safe) if lost else self._signals(mapping, fields)
                self._send(mapping, values, safe=lost)

    def close(self) -> None:
        for subscriber in self._subscribers:
            try:
                subscriber.undeclare()
            except Exception:  # noqa: BLE001 - closing anyway
                pass

    def _take_inbox(self) -> None:
        while not self._inbox.empty():
            kind, entity, payload = self._inbox.get_nowait()
            if kind == "alive":
                self._twin_alive = payload
                continue
            try:
                message = json.loads(payload)
            except ValueError:
                continue  # a malformed message changes nothing
            if not isinstance(message, dict):
                continue
            if kind == "mode" and isinstance(message.get("value"), str):
                self._modes[entity] = message["value"]
            elif kind == "command" and isinstance(message.get("fields"), dict) and isinstance(message.get("t"), (int, float)):
                if message["t"] > self._commands.get(entity, (float("-inf"), None))[0]:
                    self._commands[entity] = (float(message["t"]), message["fields"])

    def _signals(self, mapping, fields: dict) -> dict:
        """The frame's signal values for the twin's command ``fields`` (safe values for what is missing)."""
        message = self.loaded.database.get_message_by_name(mapping.message)
        values = {}
        for signal_name, field_name in mapping.fields.items():
            value = fields.get(field_name, mapping.safe[signal_name])
            signal = message.get_signal_by_name(signal_name)
            if value is None and signal.choices is not None:
                value = "none"
            if not accepts(signal, value):
                value = mapping.safe[signal_name]  # not a value of the signal: the safe one
            values[signal_name] = value if signal.choices is not None else float(value)
        return values

    def _send(self, mapping, values: dict, safe: bool) -> None:
        import can

        message = self.loaded.database.get_message_by_name(mapping.message)
        counter = self._counters.get(mapping.message, 0)
        self._counters[mapping.message] = counter + 1
        data = protect(message, values, counter)
        if self.bus is not None:
            self.bus.send(can.Message(arbitration_id=message.frame_id, data=data, is_extended_id=False))
        self.frames_sent += 1
        self.safe_frames_sent += 1 if safe else 0

    def _fields(self, device: Device, values: dict) -> dict:
        fields = {}
        for name, signal_name in device.mapping.fields.items():
            signal = device.message.get_signal_by_name(signal_name)
            value = values[signal_name]
            if signal.choices is not None:
                fields[name] = str(signal.choices[int(value)])
            elif signal.length == 1:
                fields[name] = bool(value)
            else:
                fields[name] = float(value)
        return fields

    def _publish_fail_safe(self, device: Device, now: float) -> None:
        device.fail_safe_published += 1
        self._publish(device, dict(device.mapping.fail_safe), now)

    def _publish(self, device: Device, fields: dict, now: float) -> None:
        device.seq += 1
        device.published += 1
        device.publisher.put(encode_fields(now, device.seq, fields))


def run_bridge(bridge: Bridge, bus, stop, poll: float | None = None) -> None:
    """The daemon's loop until ``stop`` (a threading.Event) is set: frames in, watchdogs, commands out.

    Commands go out every shortest command cycle; watchdogs are checked at least
    that often. A frame python-can cannot deliver is skipped, never fatal.
    """
    cfg = bridge.loaded.config
    cycles = [m.cycle_time for mappings in cfg.commands.values() for m in mappings] + [d.cycle_time for d in cfg.devices.values()]
    period = min(cycles) if cycles else 0.02
    poll = period / 4 if poll is None else poll
    next_cycle = time.monotonic()
    while not stop.is_set():
        try:
            frame = bus.recv(timeout=poll)
        except Exception:  # noqa: BLE001 - a bus error on one frame must not stop the daemon
            frame = None
        if frame is not None and not frame.is_error_frame and not frame.is_remote_frame:
            bridge.handle(frame.arbitration_id, bytes(frame.data))
        if time.monotonic() >= next_cycle:
            next_cycle += period
            bridge.check_watchdogs()
            bridge.send_commands()
