"""A Universal Robots controller beside the twin, over RTDE: its state in, the twin's commands out.

The daemon dials the controller (``robots.<robot>.rtde``: host, port 30004) as an
RTDE client (``cellsim.ur.rtde``): protocol version 2, an output recipe of the
variables the program's registers need (``cellsim.ur.program``) at the robot's
``cycle_time`` (500 Hz on an e-Series), an input recipe of the speed slider and
the program's input registers. A reader thread hands every data package to the
daemon's inbox as it arrives; the daemon's thread judges it, as it judges any
physical twin's data (``RtdeStateChecker``, the link rule of ``cellsim.link``):

* a package that does not decode as the recipe is *corrupt*;
* the controller's ``timestamp`` (s since it started) counts its cycles: a cycle
  not after the last one is refused (a frozen or replayed stream then goes
  stale), a jump of more than 5 cycles is *counter*;
* joints beyond the configured limit or speed, or a register holding a code
  outside its field's list, are *range*; no good package within the watchdog is
  *timeout*;
* a controller whose ``target_speed_fraction`` stays above the speed slider the
  daemon wrote, ``SLIDER_GRACE`` after it was written, does not take the twin's
  slider: its state is still the robot's sample (where the arm is), but its safety
  mode reads ``unknown`` (it may move faster than the twin asked) while it does.

A good state becomes the robot's physical sample (and a ROS 2 JointState, as for
any robot link); any fault publishes a link failure at once. A lost connection
is dialled again every ``reconnect_after`` seconds; until then the watchdog has
failed the link.

Commands go out only while the robot is in twin mode (as for any robot link): the
twin's latest command or, the twin lost, the kind's safe command (stopped: speed
slider 0, the stop requested, hold), with a heartbeat register counting up. RTDE
carries no authentication: a real controller's RTDE port must be reachable from
the cell's own network only (docs/ur.md).
"""

from __future__ import annotations

import logging
import math
import socket
import struct
import threading
import time
import zlib
from collections import deque
from dataclasses import dataclass, field

from cellsim.bridges.robot import JointStateChecker, RobotLink
from cellsim.link import Fault, Judgement
from cellsim.ur import rtde
from cellsim.ur.program import OutOfRange, UrProgram
from cellsim.vocabulary import SafetyMode

log = logging.getLogger("cellsim.bridge")
SETUP_TIMEOUT = 2.0
"""How long (s) the daemon waits for the controller's reply to each setup package."""
RECEIVE_TIMEOUT = 1.0
"""A streaming controller silent for this long (s) is taken as lost and dialled again (the watchdog has failed
the link long before)."""
SLIDER_GRACE = 0.1
"""How long (s) a controller may take to show a speed slider written (its ``target_speed_fraction``): the input's
way, a control cycle and the state's way back, with room."""
SLIDER_TOLERANCE = 1e-3
"""How far above the slider written a controller's ``target_speed_fraction`` may read (a rounding)."""


@dataclass
class RtdeStateChecker(JointStateChecker):
    """The checks of one controller's data packages (see the module docstring), then the link rule."""

    recipe: rtde.Recipe | None = None
    program: UrProgram | None = None
    cycle_time: float = 0.002
    slider_refused: int = 0
    """States read while the controller ran faster than the speed slider the daemon wrote (past the grace)."""
    _written: deque = field(default_factory=deque)
    """(daemon clock, fraction) of the sliders written since the newest one the controller must show by now."""
    _now: float = 0.0
    _taken: bool = True

    def wrote_slider(self, fraction: float | None, now: float) -> None:
        """The daemon wrote the speed slider ``fraction`` at ``now`` (its clock); None: it released the slider (the
        program's own), which then holds no expectation."""
        if fraction is None:
            self._written.clear()
        else:
            self._written.append((now, fraction))
            self._forget(now)  # (also while no package is judged: a controller sending bad ones stays connected)

    def _forget(self, now: float) -> None:
        """Drop the sliders written before the newest one the controller must show by ``now``: at most the grace's
        worth is kept, however long no package reaches the slider check."""
        written = self._written
        while len(written) >= 2 and written[1][0] <= now - SLIDER_GRACE:
            written.popleft()

    def slider_allowed(self, now: float) -> float | None:
        """The fastest slider the controller may show at ``now``: the newest one written at least ``SLIDER_GRACE``
        before, or any written since (it may have taken a later one already); None while nothing written is that
        old."""
        written = self._written
        self._forget(now)
        if not written or written[0][0] > now - SLIDER_GRACE:
            return None
        return max(fraction for _, fraction in written)

    def check(self, payload: bytes, now: float, wall: float | None = None) -> Judgement:
        """Judge one data package's payload (recipe id first) that arrived at ``now`` (the daemon's clock) and
        ``wall`` (UNIX s: the sample's time stamp)."""
        try:
            values = self.recipe.unpack(payload)
            timestamp = values["timestamp"]
            if not all(math.isfinite(x) for x in (timestamp, *values["actual_q"], *values["actual_qd"])):
                raise rtde.RtdeError("a value that is not a number")
            cycle = round(timestamp / self.cycle_time)
        except (rtde.RtdeError, struct.error, AttributeError, OverflowError, ValueError, TypeError, KeyError):
            return self.fail(Fault.CORRUPT, now)
        self._wall = time.time() if wall is None else wall
        self._now = now
        return self.receive(now, cycle, zlib.crc32(payload), values=values, in_range=self._in_range)

    def _in_range(self, values: dict) -> Fault | None:
        if not self.joints_in_range(values["actual_q"], values["actual_qd"]):
            return Fault.RANGE
        try:
            fields = self.program.sample(values)
        except OutOfRange:
            return Fault.RANGE
        allowed = self.slider_allowed(self._now)
        if allowed is not None and not values["target_speed_fraction"] <= allowed + SLIDER_TOLERANCE:
            if not self.slider_refused or self._taken:
                log.warning("the RTDE controller runs at speed fraction %s where the daemon wrote %s: it does not take "
                            "the slider; its safety mode reads unknown", values["target_speed_fraction"], allowed)
            self.slider_refused += 1
            self._taken = False
            fields["safety_mode"] = SafetyMode.UNKNOWN.value
        else:
            self._taken = True
        values.update(t=self._wall, position=list(values["actual_q"]), velocity=list(values["actual_qd"]), **fields)
        return None


@dataclass
class UrLink(RobotLink):
    """The daemon's side of one UR controller over RTDE (states in, commands out)."""

    program: UrProgram = None
    inbox: object = None
    """Where data packages go as they arrive: the daemon's inbox (items ``("robot", entity, payload, t)``)."""
    connected: bool = False
    connections: int = 0
    _sock: socket.socket | None = None
    _input: rtde.Recipe | None = None
    _heartbeat: int = 0
    _send_lock: threading.Lock = field(default_factory=threading.Lock)
    _stop: threading.Event = field(default_factory=threading.Event)

    def __post_init__(self):
        super().__post_init__()
        self.settings = self.config.rtde
        self.checker = RtdeStateChecker(timeout=self.config.watchdog, recover_after=self.recover_after,
                                        joint_limit=self.config.joint_limit,
                                        max_joint_speed=self.config.max_joint_speed,
                                        program=self.program, cycle_time=self.config.cycle_time)
        self._thread = threading.Thread(target=self._run, name=f"rtde-{self.entity}", daemon=True)

    def start(self) -> None:
        """Dial the controller and keep dialling while it is lost (a thread of its own)."""
        self._thread.start()

    def handle(self, arrival: tuple, now: float | None = None) -> Judgement:
        """Judge one package as it arrived: ``(payload, wall clock, daemon clock)`` at its arrival, so that a
        package taken late is judged (and stamped) by when it came, not by when it was taken."""
        payload, wall, arrived = arrival
        return super().handle(payload, arrived, wall)

    # -- the connection ----------------------------------------------------------------
    def _run(self) -> None:
        said = None  # the last reason the controller could not be reached: said once, until it changes
        while not self._stop.is_set():
            try:
                sock, reader = self._connect()
            except (OSError, rtde.RtdeError) as e:
                if str(e) != said:
                    said = str(e)
                    log.warning("%s: RTDE controller at %s:%s: %s (dialling again every %g s)", self.entity,
                                self.settings.host, self.settings.port, e, self.settings.reconnect_after)
                self._stop.wait(self.settings.reconnect_after)
                continue
            said = None
            try:
                self._receive(sock, reader)
            except (OSError, rtde.RtdeError) as e:
                if not self._stop.is_set():
                    log.warning("%s: RTDE connection lost: %s", self.entity, e)
            finally:
                with self._send_lock:
                    self.connected, self._sock = False, None
                sock.close()
            self._stop.wait(self.settings.reconnect_after)

    def _connect(self) -> tuple[socket.socket, rtde.PackageReader]:
        settings, program = self.settings, self.program
        sock = socket.create_connection((settings.host, settings.port), timeout=SETUP_TIMEOUT)
        try:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            reader = rtde.PackageReader()
            accepted = self._ask(sock, reader, rtde.REQUEST_PROTOCOL_VERSION, struct.pack(">H", rtde.PROTOCOL_VERSION))
            if not accepted or accepted[0] != 1:
                raise rtde.RtdeError("the controller refused RTDE protocol version 2")
            outputs = program.outputs()
            reply = self._ask(sock, reader, rtde.SETUP_OUTPUTS,
                              struct.pack(">d", 1.0 / self.config.cycle_time) + rtde.names_payload(outputs))
            output = self._recipe(reply, outputs, "output")
            inputs = program.inputs()
            self._input = self._recipe(self._ask(sock, reader, rtde.SETUP_INPUTS, rtde.names_payload(inputs)),
                                       inputs, "input")
            started = self._ask(sock, reader, rtde.START)
            if not started or started[0] != 1:
                raise rtde.RtdeError("the controller refused to start streaming")
        except BaseException:
            sock.close()
            raise
        sock.settimeout(RECEIVE_TIMEOUT)  # a controller silent this long (powered off, cut off) is dialled again
        self.checker.recipe = output
        with self._send_lock:
            self._sock, self.connected = sock, True
        self.connections += 1
        log.info("%s: RTDE controller at %s:%s streaming", self.entity, settings.host, settings.port)
        return sock, reader

    @staticmethod
    def _recipe(reply: bytes, names: list[str], direction: str) -> rtde.Recipe:
        types = rtde.names_of(reply[1:]) if reply else []
        missing = [n for n, t in zip(names, types) if t in (rtde.NOT_FOUND, rtde.IN_USE)]
        if not reply or reply[0] == 0 or len(types) != len(names) or missing:
            said = ", ".join(f"{n} {t}" for n, t in zip(names, types) if t in (rtde.NOT_FOUND, rtde.IN_USE))
            raise rtde.RtdeError(f"the controller refused the {direction} recipe ({said or 'no reason given'})")
        expected = rtde.output_type if direction == "output" else rtde.input_type
        wrong = [f"{n} {t} (expected {expected(n)})" for n, t in zip(names, types) if t != expected(n)]
        if wrong:  # a field of another type would be read as what it is not
            raise rtde.RtdeError(f"the controller gave the {direction} recipe other types: {', '.join(wrong)}")
        return rtde.Recipe(reply[0], tuple(names), tuple(types))

    @staticmethod
    def _ask(sock: socket.socket, reader: rtde.PackageReader, kind: int, payload: bytes = b"") -> bytes:
        """Send a setup package and return its reply's payload (text messages on the way are logged)."""
        sock.sendall(rtde.package(kind, payload))
        deadline = time.monotonic() + SETUP_TIMEOUT
        while True:
            if time.monotonic() >= deadline:
                raise rtde.RtdeError(f"no reply to setup package {chr(kind)!r} within {SETUP_TIMEOUT:g} s")
            sock.settimeout(max(0.01, deadline - time.monotonic()))
            data = sock.recv(65536)
            if not data:
                raise rtde.RtdeError("the controller closed the connection during setup")
            for got, body in reader.feed(data):
                if got == kind:
                    return body
                if got == rtde.TEXT_MESSAGE:
                    log.warning("RTDE controller says: %r", body)

    def _receive(self, sock: socket.socket, reader: rtde.PackageReader) -> None:
        put, entity = self.inbox.put, self.entity
        while not self._stop.is_set():
            data = sock.recv(65536)
            if not data:
                raise rtde.RtdeError("the controller closed the connection")
            arrived, mono, wall = time.perf_counter(), time.monotonic(), time.time()
            for kind, payload in reader.feed(data):
                if kind == rtde.DATA_PACKAGE:
                    put(("robot", entity, (payload, wall, mono), arrived))
                elif kind == rtde.TEXT_MESSAGE:
                    log.warning("%s: the RTDE controller says: %r", entity, payload)

    # -- commands ------------------------------------------------------------------------
    def send(self, fields: dict | None, now: float) -> None:
        """Write the twin's command ``fields`` (None: the twin is lost, the kind's safe command) into the
        controller's inputs; nothing while it is not connected."""
        self.requests_sent += 1
        if fields is None:
            self.safe_requests_sent += 1
            fields = self.safe
        self._write({**self.safe, **fields})

    def release(self, now: float) -> None:
        """The twin does not command the robot (model or shadow mode): every request register -1, the slider
        left alone, the heartbeat counting (the program runs on its own, and knows the daemon is there)."""
        self._write(None)

    def _write(self, command: dict | None) -> None:
        self._heartbeat += 1
        values = self.program.input_values(command, self._heartbeat)
        data = self._input.pack(values) if self._input is not None else b""
        with self._send_lock:
            sock = self._sock
            if sock is None:
                return
            self.checker.wrote_slider(values["speed_slider_fraction"] if values["speed_slider_mask"] & 1 else None,
                                      time.monotonic())
            try:  # never blocks the daemon's thread: a controller that does not take its inputs is dropped
                sent = sock.send(data, socket.MSG_DONTWAIT)
            except (BlockingIOError, InterruptedError):
                sent = 0
            except OSError as e:
                log.warning("%s: RTDE send failed: %s", self.entity, e)
                sent = -1
            if sent != len(data):
                if sent >= 0:
                    log.warning("%s: the RTDE controller does not take its inputs: dialling it again", self.entity)
                self._sock = None
                try:
                    sock.shutdown(socket.SHUT_RDWR)  # the reader thread sees it, closes and dials again
                except OSError:
                    pass

    def close(self) -> None:
        self._stop.set()
        with self._send_lock:
            sock = self._sock
        if sock is not None:
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)
