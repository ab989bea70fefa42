"""The bridge daemon: a cell's CAN devices and robot controller to its twin, and the twin's commands back.

**In.** Every frame of a configured CAN device passes the black-channel checks
of ``cellsim.bridges.e2e``; a good frame becomes the entity's physical sample on
``cellsim/<cell>/physical/<entity>`` in the live format (``docs/live.md``,
``cellsim.codec``). Any failure (length, CRC, counter, range, watchdog)
publishes a link failure at once instead, naming the fault (``{"failed": "crc"}``,
``cellsim.link.Fault``): the twin's entity fails safe as its kind says, and trusts the device
again after ``recover_after`` good samples (the one debounce, applied by the twin).
A repeated counter is refused and counted. Frames of unknown identifiers are
counted and dropped; nothing a frame holds stops the daemon. A robot controller's
state stream over Zenoh is checked and published the same way
(``cellsim.bridges.robot``).

**Out.** A device whose entity is in twin mode (the twin's ``twin_mode``
channel) gets the twin's latest command in its protected frames, every cycle
and at once when the command changes; when that command is older than the
mapping's watchdog (judged on the daemon's own clock, ``cellsim.link``), or the
twin's liveliness token is gone, it gets the entity kind's *safe command*:
losing the supervisor makes the cell safer. In model
or shadow mode nothing is sent: the device answers to its own controls. A
robot gets requests on its controller's request key the same way. A UR program
and a PLC are told instead, at the command cycle, that the twin does not command
the entity (``release``: no request, their heartbeat still counting), so that
their own watch on the daemon's heartbeat tells a lost daemon from a twin that
only watches. Twin modes are taken only while the twin is alive: a mode heard
while it is lost is refused (the twin republishes its modes every second).

**Diagnostics** per device (``cellsim.bridges.diagnostics``) and the daemon's own
status (frames, added latency) go out on ``cellsim/<cell>/diagnostics/...``.

Threads: python-can's notifier and Zenoh's callbacks only put what arrives in
one queue; the daemon's loop (:func:`run_bridge`) takes it from there, so the
daemon's state belongs to one thread. (Checking a robot's 500 Hz states on
Zenoh's thread instead was measured: the two threads then contend for the
interpreter lock and the p99 latency of frames and commands doubles.)
"""

from __future__ import annotations

import gc
import json
import zlib
import queue
import time
from collections import deque
from dataclasses import dataclass, field

from cellsim.bridges.config import LoadedBridge
from cellsim.bridges.diagnostics import DeviceDiagnostics
from cellsim.bridges.e2e import DeviceChecker, protect
from cellsim.bridges.robot import RobotLink
from cellsim.bridges.ur import UrLink
from cellsim.bridges.secoc import Authenticator, is_authenticated, message_key
from cellsim.link import REFUSALS, Fault, Judgement, LinkTrust
from cellsim import codec
from cellsim.live import keys
from cellsim.vocabulary import TwinMode
from cellsim.codec import CodecError

LATENCY_WINDOW = 100_000
"""Latencies kept for the daemon's status (the newest)."""


@dataclass
class Device:
    entity: str
    mapping: object
    message: object
    checker: DeviceChecker
    publisher: object
    diagnostics: DeviceDiagnostics = None
    signals: object = None
    """Its frame's ``cellsim.bridges.signals.SignalMap``: the frame's signals as the entity's sample fields."""
    seq: int = 0
    published: int = 0
    failures_published: int = 0


@dataclass
class Bridge:
    """Maps one cell's CAN devices and robot controllers to its twin's physical samples, and back."""

    loaded: LoadedBridge
    session: object
    bus: object = None
    """The python-can bus commands are sent on (None: no commands)."""
    clock: object = time.monotonic
    """The daemon's own clock (s): watchdogs and freshness are judged on it."""
    can_key: bytes | None = None
    """The cell's CAN key (``cellsim.live.pki.can_key``): needed when a message is authenticated."""
    wall_clock: object = time.time
    """The wall clock authenticated frames' freshness values count (s since the Unix epoch)."""
    plc_certificates: tuple | None = None
    """(the bridge's OPC UA certificate, its key, the PLC's certificate) files: needed for a PLC with security."""
    plc: object = None
    """The ``cellsim.bridges.plc.PlcLink`` of the configuration's PLC, if it names one."""
    devices: dict = field(default_factory=dict)
    robots: dict = field(default_factory=dict)
    unknown_frames: int = 0
    frames_sent: int = 0
    safe_frames_sent: int = 0
    frame_latencies: deque = field(default_factory=lambda: deque(maxlen=LATENCY_WINDOW))
    """Seconds from a frame's arrival to its sample published."""
    command_latencies: deque = field(default_factory=lambda: deque(maxlen=LATENCY_WINDOW))
    """Seconds from a changed command's arrival to its frames sent."""
    robot_latencies: deque = field(default_factory=lambda: deque(maxlen=LATENCY_WINDOW))
    """Seconds from an RTDE controller's package arriving to its sample published."""
    plc_latencies: deque = field(default_factory=lambda: deque(maxlen=LATENCY_WINDOW))
    """Seconds from a PLC notification arriving to its sample published."""

    def __post_init__(self):
        loaded, cfg, database = self.loaded, self.loaded.config, self.loaded.database
        cell = loaded.cell
        self.inbox: queue.SimpleQueue = queue.SimpleQueue()
        """What the network threads hand over: (kind, entity, payload, arrival time on perf_counter)."""
        if loaded.authenticated() and self.can_key is None:
            raise ValueError(f"{', '.join(loaded.authenticated())} are authenticated: the daemon needs the CAN key")
        for entity, mapping in cfg.devices.items():
            message = database.get_message_by_name(mapping.message)
            checker = DeviceChecker(message=message, timeout=mapping.watchdog, recover_after=cfg.recover_after,
                                    authenticator=self._authenticator(message))
            publisher = self.session.declare_publisher(keys.physical(cell, entity))
            device = Device(entity, mapping, message, checker, publisher, signals=loaded.signals(mapping))
            device.diagnostics = DeviceDiagnostics(entity, mapping.message, checker, 1.0 / mapping.cycle_time,
                                                   self.session.declare_publisher(keys.diagnostics(cell, entity)))
            self.devices[message.frame_id] = device
        for entity, link_cfg in cfg.robots.items():
            if link_cfg.rtde is not None:  # a UR controller, dialled over RTDE
                link = UrLink(cell, entity, link_cfg, self.session, safe=loaded.safe[entity],
                              recover_after=cfg.recover_after, program=loaded.programs[entity], inbox=self.inbox)
            else:
                link = RobotLink(cell, entity, link_cfg, self.session, safe=loaded.safe[entity],
                                 recover_after=cfg.recover_after)
            link.diagnostics = DeviceDiagnostics(entity, "robot controller", link.checker, 1.0 / link_cfg.cycle_time,
                                                 self.session.declare_publisher(keys.diagnostics(cell, entity)))
            self.robots[entity] = link
        if cfg.plc is not None:
            from cellsim.bridges.plc import PlcLink

            if cfg.plc.security != "none" and self.plc_certificates is None:
                raise ValueError("the PLC is read with security: the daemon needs the cell's OPC UA certificates")
            self.plc = PlcLink(cell, cfg.plc, self.session, loaded.samples, loaded.commands, loaded.safe, self.inbox,
                               cfg.recover_after, self.plc_certificates)
        self._frames = {  # each command frame's message, signal map and signer, looked up once
            mapping.message: (message, loaded.signals(mapping), self._authenticator(message))
            for mappings in cfg.commands.values() for mapping in mappings
            for message in [database.get_message_by_name(mapping.message)]
        }
        self._status = self.session.declare_publisher(keys.diagnostics(cell, "bridge"))
        self._token = self.session.liveliness().declare_token(keys.alive(cell, "bridge"))
        # The twin's commands: judged by the link rule on the daemon's clock (a watchdog of the shortest
        # of the entity's frames' watchdogs); the newest good one's fields.
        self._commands: dict[str, dict] = {}
        self._command_links: dict[str, LinkTrust] = {}
        for entity in self.commanded():
            watchdogs = [m.watchdog for m in cfg.commands.get(entity, [])]
            if entity in cfg.robots:
                watchdogs.append(cfg.robots[entity].command_watchdog)
            if self.plc is not None and entity in self.plc.commands:
                watchdogs.append(cfg.plc.command_watchdog)
            self._command_links[entity] = LinkTrust(timeout=min(watchdogs), recover_after=1, max_gap=1_000_000,
                                                    faults=tuple(Fault))
        self._modes: dict[str, TwinMode] = {}  # entity -> its twin mode, as the twin publishes it
        self._twin_alive = False
        self._counters: dict[str, int] = {}
        self._due: dict[tuple, float] = {}  # (entity, frame) -> when it is next sent
        self.refused_messages = 0
        self._subscribers = []
        put = self.inbox.put
        for entity in self.commanded():
            self._subscribers.append(self.session.declare_subscriber(
                keys.command(cell, entity), lambda s, e=entity: put(("command", e, s.payload.to_bytes(), time.perf_counter()))))
            self._subscribers.append(self.session.declare_subscriber(
                keys.channel(cell, entity, "twin_mode"), lambda s, e=entity: put(("mode", e, s.payload.to_bytes(), 0.0))))
        for entity in [e for e, r in cfg.robots.items() if r.rtde is None]:
            self._subscribers.append(self.session.declare_subscriber(
                keys.controller_state(cell, entity), lambda s, e=entity: put(("robot", e, s.payload.to_bytes(), 0.0))))
        if self.commanded():
            self._subscribers.append(self.session.liveliness().declare_subscriber(
                keys.alive(cell, "twin"), lambda s: put(("alive", None, str(s.kind).endswith("PUT"), 0.0)), history=True))
        for link in self.robots.values():
            if isinstance(link, UrLink):
                link.start()
        if self.plc is not None:
            self.plc.start()

    def commanded(self) -> list[str]:
        """The entities the twin may command: CAN command frames, robots, a PLC's entities with command nodes."""
        cfg = self.loaded.config
        return [*cfg.commands, *cfg.robots, *(self.plc.commands if self.plc is not None else ())]

    def _authenticator(self, message) -> Authenticator | None:
        """The signer or verifier of an authenticated message's frames (None: the message is not)."""
        if not is_authenticated(message):
            return None
        return Authenticator(message, message_key(self.can_key, message.frame_id), self.loaded.config.freshness_tick,
                             self.wall_clock)

    # -- in --------------------------------------------------------------------------
    def handle(self, frame_id: int, data: bytes, now: float | None = None, wall: float | None = None) -> Judgement | None:
        """Check one received frame (that arrived at ``now``, the daemon's clock, and ``wall``, the wall clock's
        time then) and publish what it means for the twin: its sample, stamped ``wall``, or a link failure; a
        refused frame (a repeated counter) publishes nothing."""
        now = self.clock() if now is None else now
        device = self.devices.get(frame_id)
        if device is None:
            self.unknown_frames += 1
            return None
        device.diagnostics.frame()
        judgement = device.checker.check(bytes(data), now)
        if judgement.good:
            self._publish(device, codec.encode_fields(time.time() if wall is None else wall, self._next(device),
                                                      device.signals.fields(judgement.values)))
        elif judgement.fault not in REFUSALS:
            self._publish_failure(device, judgement.fault)
        return judgement

    def handle_robot(self, entity: str, payload: bytes, now: float | None = None) -> Judgement:
        """Check one robot controller state and publish what it means for the twin."""
        return self.robots[entity].handle(payload, self.clock() if now is None else now)

    def check_watchdogs(self, now: float | None = None) -> None:
        """Fail every device whose frames stopped (call it at least every cycle time)."""
        now = self.clock() if now is None else now
        for device in self.devices.values():
            judgement = device.checker.watchdog(now)
            if judgement is not None:
                self._publish_failure(device, judgement.fault)
        for link in self.robots.values():
            link.check_watchdog(now)
        if self.plc is not None:
            self.plc.check_watchdog(now)

    # -- out -------------------------------------------------------------------------
    def send_commands(self, now: float | None = None, due_only: bool = False, only: str | None = None) -> None:
        """Send each commanded device its frames: the twin's command in twin mode, the safe command when it is lost.

        ``due_only``: only the frames whose cycle time has come round; ``only``: one entity's frames.
        """
        self.take_inbox()
        self._send_commands(self.clock() if now is None else now, due_only, only)

    def _send_commands(self, now: float, due_only: bool = False, only: str | None = None) -> None:
        cfg = self.loaded.config
        for entity in self.commanded():
            if only is not None and entity != only:
                continue
            mode = self._modes.get(entity)
            robot = self.robots.get(entity)
            plc = self.plc is not None and entity in self.plc.commands
            written = isinstance(robot, UrLink) or plc  # inputs the daemon writes, which hold what it last wrote
            # a written device whose mode is not heard yet (a daemon just started, maybe while the twin commands it,
            # or after the twin was lost in twin mode) takes the safe command, never a release: the twin says so
            twin = mode is TwinMode.TWIN or (mode is None and written)
            if not twin and not written:
                continue  # not in twin mode (or never heard of): the device answers to its own controls
            link = self._command_links[entity]
            link.watchdog(now)
            lost = not self._twin_alive or link.failed or mode is None
            fields = self._commands.get(entity, {})
            targets = [(m.message, m.cycle_time, m) for m in cfg.commands.get(entity, [])] if twin else []
            if robot is not None:
                targets.append(("request", cfg.robots[entity].command_cycle_time, None))
            if plc:
                targets.append(("plc", cfg.plc.command_cycle_time, None))
            for name, cycle, mapping in targets:
                key = (entity, name)
                if due_only and now < self._due.get(key, now):
                    continue
                self._due[key] = max(self._due.get(key, now) + cycle, now)
                if not twin and name == "request":  # told the twin does not command it, the heartbeat counting
                    robot.release(now)
                elif not twin:
                    self.plc.release(entity)
                elif name == "plc":
                    self.plc.send(entity, None if lost else fields)
                elif mapping is None:
                    robot.send(None if lost else fields, now)
                else:
                    signals = self._frames[mapping.message][1]
                    self._send(mapping, signals.safe_signals() if lost else signals.signals(fields), safe=lost)

    def take_inbox(self) -> None:
        """Take in everything the network threads handed over (see :meth:`take`)."""
        while True:
            try:
                item = self.inbox.get_nowait()
            except queue.Empty:
                return
            self.take(item)

    def take(self, item: tuple) -> None:
        """Take in one item of the inbox: a frame, a robot state, a command, a twin mode, the twin's liveliness."""
        kind, entity, payload, arrived = item
        if kind == "frame":  # judged, and stamped, at its arrival, not when it is taken off the inbox
            age = time.perf_counter() - arrived
            self.handle(payload.arbitration_id, bytes(payload.data), self.clock() - age, self.wall_clock() - age)
            self.frame_latencies.append(age)
            return
        if kind == "plc":  # as a frame: judged and stamped at its arrival
            age = time.perf_counter() - arrived
            self.plc.take(*payload, self.clock() - age, age)
            self.plc_latencies.append(age)
            return
        if kind == "robot":
            self.handle_robot(entity, payload)
            if arrived:
                self.robot_latencies.append(time.perf_counter() - arrived)
            return
        if kind == "alive":
            self._twin_alive = payload
            return
        if kind == "mode":
            if not self._twin_alive:
                # only the living twin says what it twins: a mode heard while it is lost (a stale or forged one) could
                # release a device the daemon holds safe; the twin publishes its modes every second, heard once alive
                self.refused_messages += 1
                return
            try:
                _, value = codec.decode_value(payload)
            except CodecError:
                self.refused_messages += 1
                return
            try:
                self._modes[entity] = TwinMode(value)
            except ValueError:  # not a twin mode: refused, the mode as it was
                self.refused_messages += 1
            return
        self._take_command(entity, payload, arrived)

    def _take_command(self, entity: str, payload: bytes, arrived: float) -> None:
        """A command of the twin: decoded, judged on the daemon's clock; a changed one goes out at once."""
        now, link = self.clock(), self._command_links[entity]
        try:
            message = self.loaded.commands[entity].decode(payload)
            if message.failure is not None:
                raise CodecError("a failure in place of a command")
        except CodecError:
            self.refused_messages += 1
            link.fail(Fault.CORRUPT, now)
            return
        if link.receive(now, message.seq, zlib.crc32(payload), stamp=message.t, wall=time.time()).fault is not None:
            self.refused_messages += 1
            return
        fields = self.loaded.commands[entity].fields(message.codes)
        safe = self.loaded.safe[entity]
        if fields.get("safety_mode_request", "") is None and safe.get("safety_mode_request") is not None:
            # commanded, but no mode (a risk model's null): the kind's safe mode, on every protocol; no value is what
            # a device is told when the twin does not command it (a UR program's -1, a PLC's empty node)
            fields["safety_mode_request"] = safe["safety_mode_request"]
        previous = self._commands.get(entity)
        self._commands[entity] = fields
        if entity not in self._modes and self._twin_alive:
            self._modes[entity] = TwinMode.TWIN  # the twin commands only what it twins: its mode, heard sooner
        if fields != previous and self._modes.get(entity) is TwinMode.TWIN and self._twin_alive:
            self._send_commands(now, only=entity)  # a changed command goes out at once
            self.command_latencies.append(time.perf_counter() - arrived)

    def twin_mode(self, entity: str) -> TwinMode | None:
        """The entity's twin mode as the twin last published it (None: not heard yet)."""
        return self._modes.get(entity)

    # -- status ----------------------------------------------------------------------
    def publish_diagnostics(self, now: float | None = None) -> None:
        """Each device's diagnostics (on a change of level at once, else every diagnostics period),
        and the daemon's own status every period."""
        now = self.clock() if now is None else now
        period = self.loaded.config.diagnostics_period
        for device in self.devices.values():
            device.diagnostics.publish(now, period)
        for link in self.robots.values():
            link.publish_diagnostics(now, period)
        if self.plc is not None:
            self.plc.publish_diagnostics(now, period)
        if now - getattr(self, "_status_at", float("-inf")) >= period:
            self._status_at = now
            self._status.put(json.dumps(self.status(now), separators=(",", ":")))

    def status(self, now: float) -> dict:
        """The daemon's own figures: frames, commands, the latency it adds (ms)."""
        return {
            "t": time.time(), "unknown_frames": self.unknown_frames, "frames_sent": self.frames_sent,
            "safe_frames_sent": self.safe_frames_sent, "twin_alive": self._twin_alive,
            "refused_messages": self.refused_messages,
            "received": {d.entity: d.diagnostics.received
                         for d in [*self.devices.values(), *self.robots.values(),
                                   *(self.plc.entities.values() if self.plc is not None else ())]},
            "frame_latency_ms": _percentiles(self.frame_latencies),
            "command_latency_ms": _percentiles(self.command_latencies),
            "robot_latency_ms": _percentiles(self.robot_latencies),
            "plc_latency_ms": _percentiles(self.plc_latencies),
            "plc_connected": None if self.plc is None else self.plc.connected,
            "controllers_connected": {e: r.connected for e, r in self.robots.items() if isinstance(r, UrLink)},
        }

    def close(self) -> None:
        for link in self.robots.values():
            if isinstance(link, UrLink):
                link.close()
        if self.plc is not None:
            self.plc.close()
        for handle in [*self._subscribers, self._token]:
            try:
                handle.undeclare()
            except Exception:  # noqa: BLE001 - closing anyway
                pass

    # -- helpers ---------------------------------------------------------------------
    def _send(self, mapping, values: dict, safe: bool) -> None:
        import can

        message, _, authenticator = self._frames[mapping.message]
        counter = self._counters.get(mapping.message, 0)
        self._counters[mapping.message] = counter + 1
        data = protect(message, values, counter, authenticator)
        if self.bus is not None:
            self.bus.send(can.Message(arbitration_id=message.frame_id, data=data, is_extended_id=False))
        self.frames_sent += 1
        self.safe_frames_sent += 1 if safe else 0

    def _publish_failure(self, device: Device, fault: Fault) -> None:
        device.failures_published += 1
        self._publish(device, codec.encode_failure(time.time(), self._next(device), fault))

    @staticmethod
    def _next(device: Device) -> int:
        device.seq += 1
        return device.seq

    @staticmethod
    def _publish(device: Device, payload: bytes) -> None:
        device.published += 1
        device.publisher.put(payload)


def _percentiles(seconds) -> dict:
    if not seconds:
        return {"n": 0}
    import numpy as np

    ms = np.asarray(seconds) * 1e3
    return {"n": int(ms.size), "p50": round(float(np.percentile(ms, 50)), 3), "p99": round(float(np.percentile(ms, 99)), 3),
            "max": round(float(ms.max()), 3)}


def run_bridge(bridge: Bridge, bus, stop, on_cycle=None) -> None:
    """The daemon's loop until ``stop`` (a threading.Event) is set.

    python-can's notifier hands each received frame to the bridge's inbox; the
    loop takes each item as it comes and, every cycle (the shortest cycle time
    of a command frame, a device, or half a robot watchdog), checks the
    watchdogs, sends the frames due and publishes diagnostics. A frame that
    python-can cannot deliver is skipped, never fatal.
    """
    import can

    cfg = bridge.loaded.config
    cycles = [m.cycle_time for mappings in cfg.commands.values() for m in mappings]
    cycles += [d.cycle_time for d in cfg.devices.values()]
    cycles += [min(r.command_cycle_time, r.watchdog / 2) for r in cfg.robots.values()]
    if cfg.plc is not None:
        cycles.append(min(cfg.plc.command_cycle_time, cfg.plc.watchdog / 2))
    period = min(cycles) if cycles else 0.02

    def on_frame(frame) -> None:  # python-can's thread: queue it, nothing more
        if not frame.is_error_frame and not frame.is_remote_frame:
            bridge.inbox.put(("frame", None, frame, time.perf_counter()))

    # Everything allocated so far (modules, the DBC, sessions) lives as long as the daemon: out of the
    # garbage collector's sight, its passes over what a frame allocates take microseconds, not milliseconds.
    gc.collect()
    gc.freeze()
    notifier = can.Notifier(bus, [on_frame], timeout=0.1) if bus is not None else None
    try:
        next_cycle = time.monotonic()
        while not stop.is_set():
            try:
                item = bridge.inbox.get(timeout=max(0.0, next_cycle - time.monotonic()))
            except queue.Empty:
                item = None
            if item is not None:
                try:
                    bridge.take(item)
                except Exception as e:  # noqa: BLE001 - nothing one message holds may stop the daemon
                    import logging

                    logging.getLogger("cellsim.bridge").error("dropped a %s: %s", item[0], e)
            if time.monotonic() >= next_cycle:
                next_cycle = max(next_cycle + period, time.monotonic() - period)
                try:
                    bridge.check_watchdogs()
                    bridge.send_commands(due_only=True)
                    bridge.publish_diagnostics()
                except Exception as e:  # noqa: BLE001 - a full bus or a lost session: said, and the next cycle tries again
                    import logging

                    logging.getLogger("cellsim.bridge").error("cycle: %s: %s", type(e).__name__, e)
                if on_cycle is not None:
                    on_cycle()
    finally:
        if notifier is not None:
            notifier.stop()
