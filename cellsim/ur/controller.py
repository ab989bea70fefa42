"""An emulated UR controller's RTDE server: the emulated arm as a real controller serves it.

``cellsim emulate --bridge CONFIG`` plays a robot whose bridge configuration names
``rtde`` through one of these, on the configured host and port (``--rtde PORT``
overrides the port): any RTDE client, ``ur-rtde``'s or the bridge daemon's, reads
the arm's joints, safety mode and the program's registers (``cellsim.ur.program``)
and writes the speed slider and the input registers, which become the emulated
arm's commands.

As a controller does: a client negotiates protocol version 2, asks for the
controller's version (5.x, an e-Series), sets up an output recipe (one per client,
streamed after ``S`` at the frequency it asked, at most the controller's 500 Hz)
and input recipes (a variable another client already writes is ``IN_USE``; an
unknown one ``NOT_FOUND``). A client that sends what the protocol has no place for
is told so in a text message and disconnected. The server listens on loopback
unless configured otherwise, from the emulated arm's first state on: as on a real
controller, a client that started gets a package every cycle from then on.

Faults, as the arm's outlet (``--fault robot=KIND``): ``silence`` (no packages),
``freeze`` (the last package again: its timestamp repeats), ``corrupt`` (a data
package one byte short), ``replay`` (an old package again: time steps back).
"""

from __future__ import annotations

import logging
import socket
import threading
from collections import deque

from cellsim.ur import rtde

VERSION = (5, 15, 0, 0)
"""The controller version the emulator reports (major, minor, bugfix, build): an e-Series."""
FREQUENCY = 500.0
"""The controller's cycle (Hz): at most this many output packages a second."""
RTDE_FAULTS = ("silence", "freeze", "corrupt", "replay")

log = logging.getLogger("cellsim.ur")


class _Client:
    """One RTDE client's session: its recipes and whether its outputs stream."""

    def __init__(self, sock: socket.socket):
        self.sock = sock
        self.output: rtde.Recipe | None = None
        self.every = 1
        """Send every ``every``-th state (the client's frequency against the controller's)."""
        self.inputs: dict[int, rtde.Recipe] = {}
        self.streaming = False
        self.count = 0
        self.lock = threading.Lock()
        self.history: deque = deque(maxlen=60)

    def send(self, data: bytes) -> None:
        """A reply: never blocking while it holds the lock that :meth:`stream` (the emulated cell's publish) takes."""
        self.stream(data)

    def stream(self, data: bytes) -> None:
        """A package, never blocking the emulated cell: a client that does not read its packages is dropped
        (OSError), as a controller drops one whose buffer is full."""
        with self.lock:
            if self.sock.send(data, socket.MSG_DONTWAIT) != len(data):
                raise OSError("the client does not read its packages")


class RtdeServer:
    """An RTDE server on ``host:port``: :meth:`publish` streams a state to every started client,
    ``on_inputs(values)`` gets every input data package's values (on the client's thread)."""

    def __init__(self, host: str, port: int, on_inputs=None, version=VERSION, rate: float = FREQUENCY,
                 listen_from_first_state: bool = False):
        """``rate``: how often :meth:`publish` is called (Hz): a client asking for less gets every n-th state.

        The port is bound here (a port already taken fails now). ``listen_from_first_state``: accept clients
        only from the first :meth:`publish` on, as a controller whose arm is up: a started client then gets a
        package every cycle from its start. (ur-rtde's receiver gives up for good after 2.5 s without one,
        so an emulator still building its cell must not take it yet.)"""
        self.on_inputs = on_inputs or (lambda values: None)
        self.rate = rate
        self.version = version
        self._listener = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
        try:
            self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._listener.bind((host, port))
        except OSError as e:
            self._listener.close()
            raise OSError(e.errno, f"RTDE on {host}:{port}: {e.strerror}") from None
        self.address = self._listener.getsockname()[:2]
        self._clients: list[_Client] = []
        self._writers: dict[str, _Client] = {}  # input variable -> the client whose recipe writes it
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self._last_values: dict = {}
        self.packages_sent = 0
        self.inputs_received = 0
        self._thread: threading.Thread | None = None
        if not listen_from_first_state:
            self._listen()

    def _listen(self) -> None:
        self._listener.listen()
        self._thread = threading.Thread(target=self._accept, name="rtde-accept", daemon=True)
        self._thread.start()

    # -- serving -----------------------------------------------------------------------
    def publish(self, values: dict, fault: str | None = None) -> int:
        """Send the state ``values`` (output variables; any other a client asks for reads 0) to every
        started client, as ``fault`` makes of it; the number of packages sent."""
        self._last_values = values
        if self._thread is None and not self._closed.is_set():
            self._listen()
        if fault == "silence":
            return 0
        sent = 0
        with self._lock:
            clients = [c for c in self._clients if c.streaming]
        for client in clients:
            client.count += 1
            if client.count % client.every:
                continue
            data = self._package(client, values, fault)
            try:
                client.stream(data)
            except OSError:
                self._drop(client)
                continue
            sent += 1
        self.packages_sent += sent
        return sent

    def _package(self, client: _Client, values: dict, fault: str | None) -> bytes:
        history = client.history
        if fault == "freeze" and history:
            return history[-1]
        if fault == "replay" and len(history) > 50:
            return history[0]
        data = client.output.pack({name: values.get(name, _zero(kind))
                                   for name, kind in zip(client.output.names, client.output.types)})
        if fault == "corrupt":
            return rtde.HEADER.pack(len(data) - 1, rtde.DATA_PACKAGE) + data[rtde.HEADER.size:-1]
        history.append(data)
        return data

    def _accept(self) -> None:
        while not self._closed.is_set():
            try:
                sock, _ = self._listener.accept()
            except OSError:
                return
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            client = _Client(sock)
            with self._lock:
                self._clients.append(client)
            threading.Thread(target=self._serve, args=(client,), name="rtde-client", daemon=True).start()

    def _serve(self, client: _Client) -> None:
        reader = rtde.PackageReader()
        try:
            while not self._closed.is_set():
                data = client.sock.recv(65536)
                if not data:
                    break
                for kind, payload in reader.feed(data):
                    self._answer(client, kind, payload)
        except Exception as e:  # noqa: BLE001 - whatever a client sends: it is told why, and dropped
            if not self._closed.is_set():
                log.info("RTDE client dropped: %s", e)
                try:
                    client.send(rtde.text_message(str(e)))
                except OSError:
                    pass
        finally:
            self._drop(client)

    def _answer(self, client: _Client, kind: int, payload: bytes) -> None:
        import struct

        if kind == rtde.REQUEST_PROTOCOL_VERSION:
            if len(payload) != 2:
                raise rtde.RtdeError("a protocol version request of other than 2 bytes")
            accepted = struct.unpack(">H", payload)[0] in (1, rtde.PROTOCOL_VERSION)
            client.send(rtde.package(kind, bytes([accepted])))
        elif kind == rtde.GET_URCONTROL_VERSION:
            client.send(rtde.package(kind, struct.pack(">IIII", *self.version)))
        elif kind == rtde.SETUP_OUTPUTS:
            if len(payload) < 8:
                raise rtde.RtdeError("an output setup without its frequency")
            frequency = struct.unpack_from(">d", payload)[0]
            names = rtde.names_of(payload[8:])
            types = [rtde.output_type(n) for n in names]
            if rtde.NOT_FOUND in types or not names or not 0 < frequency <= FREQUENCY:
                client.send(rtde.package(kind, bytes([0]) + rtde.names_payload(types)))
                return
            client.output = rtde.Recipe(1, tuple(names), tuple(types))
            client.every = max(1, round(self.rate / frequency))
            client.send(rtde.package(kind, bytes([1]) + rtde.names_payload(types)))
        elif kind == rtde.SETUP_INPUTS:
            names = rtde.names_of(payload)
            with self._lock:
                types = [rtde.input_type(n) for n in names]
                types = [rtde.IN_USE if t != rtde.NOT_FOUND and self._writers.get(n, client) is not client else t
                         for n, t in zip(names, types)]
                refused = not names or rtde.NOT_FOUND in types or rtde.IN_USE in types or len(client.inputs) >= 254
                recipe_id = 0 if refused else len(client.inputs) + 1
                if not refused:
                    client.inputs[recipe_id] = rtde.Recipe(recipe_id, tuple(names), tuple(types))
                    self._writers.update({n: client for n in names})
            client.send(rtde.package(kind, bytes([recipe_id]) + rtde.names_payload(types)))
        elif kind in (rtde.START, rtde.PAUSE):
            ready = client.output is not None or kind == rtde.PAUSE or client.inputs
            client.streaming = kind == rtde.START and client.output is not None
            client.send(rtde.package(kind, bytes([1 if ready else 0])))
        elif kind == rtde.DATA_PACKAGE:
            recipe = client.inputs.get(payload[0]) if payload else None
            if recipe is None:
                raise rtde.RtdeError(f"a data package of recipe {payload[0] if payload else '?'}, which was not set up")
            values = recipe.unpack(payload)
            self.inputs_received += 1
            self.on_inputs(values)
        elif kind == rtde.TEXT_MESSAGE:
            return
        else:
            raise rtde.RtdeError(f"package type {kind} is not RTDE's")

    def _drop(self, client: _Client) -> None:
        with self._lock:
            if client in self._clients:
                self._clients.remove(client)
            for name in [n for n, c in self._writers.items() if c is client]:
                del self._writers[name]
        try:
            client.sock.close()
        except OSError:
            pass

    @property
    def clients(self) -> int:
        with self._lock:
            return len(self._clients)

    def close(self) -> None:
        self._closed.set()
        try:
            self._listener.shutdown(socket.SHUT_RDWR)  # wakes the accepting thread: the port is free once it ends
        except OSError:
            pass
        self._listener.close()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        with self._lock:
            clients = list(self._clients)
        for client in clients:
            try:
                client.sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            self._drop(client)


def _zero(kind: str):
    if kind.startswith("VECTOR6"):
        return (0,) * 6
    if kind == "VECTOR3D":
        return (0.0,) * 3
    return 0
