"""Helpers for multi-process live tests: free loopback ports, processes stopped by PID, events with deadlines."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    """A TCP port on 127.0.0.1 nothing listens on now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Process:
    """A cellsim command (or another Python module's) run as a process; ``stop()`` ends it by its PID."""

    def __init__(self, args: list[str], log: Path, module: str = "cellsim", cwd: Path = ROOT):
        self.log = log
        self._file = open(log, "w")
        self.popen = subprocess.Popen(
            [sys.executable, "-m", module, *args], stdout=self._file, stderr=subprocess.STDOUT, cwd=cwd
        )
        self.pid = self.popen.pid

    def wait(self, timeout: float) -> int:
        """Its exit code, waiting at most ``timeout`` s (then it is stopped and the test fails)."""
        try:
            return self.popen.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.stop()
            raise AssertionError(f"{self.popen.args} did not end within {timeout} s; log:\n{self.output()}") from None

    def stop(self, sig: int = signal.SIGINT, grace: float = 15.0) -> int | None:
        if self.popen.poll() is None:
            os.kill(self.pid, sig)
            try:
                self.popen.wait(timeout=grace)
            except subprocess.TimeoutExpired:
                os.kill(self.pid, signal.SIGKILL)
                self.popen.wait(timeout=grace)
        self._file.close()
        return self.popen.returncode

    def output(self) -> str:
        if not self._file.closed:
            self._file.flush()
        return self.log.read_text()


@contextmanager
def processes():
    """Collects processes and stops every one still running at the end, by its PID."""
    started: list[Process] = []

    def start(args: list[str], log: Path, module: str = "cellsim", cwd: Path = ROOT) -> Process:
        process = Process(args, log, module, cwd)
        started.append(process)
        return process

    try:
        yield start
    finally:
        for process in started:
            process.stop(signal.SIGKILL if process.popen.poll() is None else signal.SIGINT)


def can_server(start, log: Path, timeout: float = 30.0) -> str:
    """Start a python-can-remote server of a virtual bus on a free loopback port (never every interface);
    its channel for ``can.Bus(interface="remote", channel=...)`` once it accepts connections."""
    port = free_port()
    server = start(["-i", "virtual", "-c", "0", "-H", "127.0.0.1", "-p", str(port)], log, module="can_remote")
    wait_listening(server, port, timeout, "the CAN server")
    return f"ws://127.0.0.1:{port}/"


def wait_listening(server: Process, port: int, timeout: float, what: str, ready: str | None = None) -> None:
    """Wait until ``server`` accepts connections on loopback ``port`` and, if given, its log holds
    ``ready``; fail with its output if it exits or the deadline passes."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            if ready is None or ready in server.output():
                socket.create_connection(("127.0.0.1", port), timeout=1.0).close()
                return
        except OSError:
            pass
        if server.popen.poll() is not None or time.monotonic() > deadline:
            raise AssertionError(f"{what} did not start: {server.output()}")
        threading.Event().wait(0.05)


@contextmanager
def observer(port: int, role: str = "observer", keys: Path | None = None):
    """A Zenoh session of the test, connected to the twin's loopback port with ``role``'s certificate
    (of the tests' keys, ``CELLSIM_KEYS``, unless ``keys`` is given)."""
    import zenoh

    from cellsim.live.session import session_config

    session = zenoh.open(session_config(role=role, keys=keys, connect=[f"tls/127.0.0.1:{port}"]))
    try:
        yield session
    finally:
        session.close()


def wait_alive(session, key: str, timeout: float = 60.0) -> None:
    """Wait until a liveliness token matching ``key`` is present (a process is up), with a deadline."""
    seen = threading.Event()

    def on_token(sample) -> None:
        if str(sample.kind).endswith("PUT"):
            seen.set()

    subscriber = session.liveliness().declare_subscriber(key, on_token, history=True)
    try:
        if not seen.wait(timeout):
            raise AssertionError(f"no liveliness token on {key} within {timeout} s")
    finally:
        subscriber.undeclare()


def wait_for(predicate, timeout: float, what: str, poll: threading.Event | None = None) -> None:
    """Wait until ``predicate()`` holds, checking on every set of ``poll`` (or every 50 ms), with a deadline."""
    deadline = time.monotonic() + timeout
    event = poll or threading.Event()
    while not predicate():
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise AssertionError(f"{what}: not within {timeout} s")
        event.wait(min(remaining, 0.05))
        event.clear()


class ChannelWatch:
    """The successive values of one twin channel as published (cellsim/<cell>/twin/<module>/<signal>)."""

    def __init__(self, session, key: str):
        import json

        self.values: list = []
        self._changed = threading.Event()

        def on_value(sample) -> None:
            value = json.loads(sample.payload.to_bytes())["value"]
            if not self.values or self.values[-1] != value:
                self.values.append(value)
                self._changed.set()

        self.subscriber = session.declare_subscriber(key, on_value)

    def wait_for(self, value, timeout: float) -> None:
        """Wait until the channel's latest value is ``value``, with a deadline."""
        deadline = time.monotonic() + timeout
        while not self.values or self.values[-1] != value:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise AssertionError(f"not {value!r} within {timeout} s: {self.values}")
            self._changed.wait(remaining)
            self._changed.clear()

    def close(self) -> None:
        self.subscriber.undeclare()


class TmuxScreen:
    """A cellsim command running in a terminal of its own (tmux, a private server), read as the user sees it.

    ``stop()`` ends the program by its PID, then the tmux server.
    """

    def __init__(self, args: list[str], width: int = 120, height: int = 40, env: dict | None = None, module: str = "cellsim"):
        import shlex

        import tempfile

        self.argv = [module, *args]
        self._folder = tempfile.mkdtemp(prefix="cellsim-tmux-")
        self.socket = str(Path(self._folder) / "tmux.sock")  # a server of its own, its socket removed at stop()
        exports = " ".join(f"{k}={shlex.quote(v)}" for k, v in (env or {}).items())
        # (without the COLUMNS and LINES a test runner may export: they would override the terminal's size)
        command = f"cd {shlex.quote(str(ROOT))} && exec env -u COLUMNS -u LINES {exports} {shlex.quote(sys.executable)} -m {module} " + " ".join(
            shlex.quote(a) for a in args)
        # the pane stays when the program ends, so that a test failing then still shows its last words
        self._tmux("new-session", "-d", "-s", "main", "-x", str(width), "-y", str(height), "cat")
        self._tmux("set-option", "-t", "main", "remain-on-exit", "on")
        self._tmux("respawn-pane", "-k", "-t", "main", command)
        self.pid = int(self._tmux("display-message", "-p", "-t", "main", "#{pane_pid}").strip())

    def _tmux(self, *args: str) -> str:
        return subprocess.run(["tmux", "-S", self.socket, *args], capture_output=True, text=True, check=True, timeout=10).stdout

    def text(self) -> str:
        """The screen now, as text."""
        return self._tmux("capture-pane", "-p", "-t", "main")

    def keys(self, *keys: str) -> None:
        self._tmux("send-keys", "-t", "main", *keys)

    def wait_for(self, predicate, timeout: float, what: str) -> str:
        """The screen once ``predicate(screen)`` holds, polling it every 50 ms, with a deadline."""
        deadline = time.monotonic() + timeout
        pause = threading.Event()
        while True:
            screen = self.text()
            if predicate(screen):
                return screen
            if time.monotonic() > deadline:
                raise AssertionError(f"{what}: not within {timeout} s; the screen:\n{screen}")
            pause.wait(0.05)

    def exit_status(self, timeout: float) -> int:
        """The program's exit status once it has ended (tmux keeps its pane), waiting at most ``timeout`` s."""
        deadline = time.monotonic() + timeout
        while True:
            if self._tmux("display-message", "-p", "-t", "main", "#{pane_dead}").strip() == "1":
                return int(self._tmux("display-message", "-p", "-t", "main", "#{pane_dead_status}").strip())
            if time.monotonic() > deadline:
                raise AssertionError(f"{self.argv}: still running after {timeout} s")
            threading.Event().wait(0.05)

    def running(self) -> bool:
        """Whether the program still runs (a zombie waiting for tmux to reap it does not)."""
        try:
            state = Path(f"/proc/{self.pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except (FileNotFoundError, ProcessLookupError, IndexError):
            return False
        return state != "Z"

    def stop(self) -> None:
        """SIGTERM the program, which must end within 5 s (a review found the dashboard losing a SIGTERM that came
        while it started, and this waiting 10 s before it killed it, unnoticed); then the terminal goes."""
        lost = False
        if self.running():
            os.kill(self.pid, signal.SIGTERM)
            deadline = time.monotonic() + 5
            while self.running() and time.monotonic() < deadline:
                threading.Event().wait(0.05)
            if self.running():
                os.kill(self.pid, signal.SIGKILL)
                lost = True
        subprocess.run(["tmux", "-S", self.socket, "kill-server"], capture_output=True, timeout=10)
        import shutil

        shutil.rmtree(self._folder, ignore_errors=True)
        assert not lost, f"{self.argv}: still running 5 s after SIGTERM (killed)"


def sim_time_reached(t: float):
    """(an event, a callback for the twin's status key that sets it once the twin's clock reaches ``t``)."""
    import json

    reached = threading.Event()

    def on_status(sample) -> None:
        if json.loads(sample.payload.to_bytes())["sim_time"] >= t:
            reached.set()

    return reached, on_status


def offset_of(twin, emulator) -> float:
    """Emulator time + offset = twin time of the same wall-clock instant (two open black boxes of a live run)."""
    return emulator.metadata()["live"]["wall_at_zero"] - twin.metadata()["live"]["wall_at_zero"]


def assert_supervised(twin, emulator, within: float) -> float:
    """The welding cell's supervision outcome, on the black boxes of the twin and of the emulated cell it
    commanded: HS raised when the operator arrives, its ssmon request taken by the emulated robot within
    ``within`` s, which slows to ssmon's cap. Returns the clocks' offset."""
    offset = offset_of(twin, emulator)
    assert "safety_controller.HS" not in emulator.channels()  # the emulated cell has no supervisor of its own
    hs = twin.series("safety_controller.HS")
    # (the twin fails safe for its first updates, until recover_after samples came: HS may be raised then)
    raised = next(t for t, v in zip(hs.times, hs.values) if v == "act" and t > offset + 5.0)
    assert raised - offset > 13.0  # the default walk reaches the cell after 14 s
    mode, speed = emulator.series("robot.safety_mode"), emulator.series("robot.tool_speed")
    slowed = next(t for t, v in zip(mode.times, mode.values) if v == "ssmon" and t > raised - offset - 0.5)
    assert slowed - (raised - offset) < within
    after = [v for t, v in zip(speed.times, speed.values) if slowed + 0.6 <= t and mode.value_at(t) == "ssmon"]
    assert after and max(after) <= 0.5 + 0.05  # ssmon's tool speed cap, once braked
    return offset


def rogue_router(keys: Path, role: str, port: int, timeout: float = 10.0):
    """A Zenoh router on loopback ``port`` serving TLS with ``role``'s certificate and key, configured by hand as
    an attacker holding those files would (cellsim's own session rules refuse to make it); retried until the
    port is free (a killed twin's port), with a deadline."""
    import json

    import zenoh

    config = zenoh.Config()
    for key, value in (("mode", "router"), ("scouting/multicast/enabled", False), ("scouting/gossip/enabled", False),
                       ("listen/endpoints", [f"tls/127.0.0.1:{port}"]),
                       ("transport/link/tls", {"root_ca_certificate": str(keys / "ca.pem"), "enable_mtls": True,
                                               "listen_certificate": str(keys / f"{role}.pem"),
                                               "listen_private_key": str(keys / f"{role}.key"),
                                               "connect_certificate": str(keys / f"{role}.pem"),
                                               "connect_private_key": str(keys / f"{role}.key")})):
        config.insert_json5(key, json.dumps(value))
    deadline = time.monotonic() + timeout
    while True:
        try:
            return zenoh.open(config)
        except zenoh.ZError:
            if time.monotonic() > deadline:
                raise
            threading.Event().wait(0.05)


WELDING_CELL = str(ROOT / "scenarios" / "welding_cell.yaml")
WELDING_BRIDGE = str(ROOT / "bridges" / "welding_cell.yaml")


def start_twin_and_bridge(start, tmp: Path, twin_args, bus: str, endpoint: str, port: int, config: str = WELDING_BRIDGE):
    """The welding cell's twin, then its bridge daemon (with the bridge configuration ``config``) on the CAN
    server ``bus``, each once it is up; returns (twin, bridge)."""
    twin = start(["live", WELDING_CELL, "--out", str(tmp / "twin"), "--listen", endpoint, "--quiet", *twin_args],
                 tmp / "twin.log")
    with observer(port) as session:
        wait_alive(session, "cellsim/welding_cell/alive/twin")
    bridge = start(["bridge", config, "--can", f"remote:{bus}", "--connect", endpoint], tmp / "bridge.log")
    with observer(port) as session:
        wait_alive(session, "cellsim/welding_cell/alive/bridge")
    return twin, bridge


def start_emulator(start, tmp: Path, args, bus: str, endpoint: str):
    """The welding cell's emulator speaking CAN on ``bus``, its black box in ``tmp/emulator``."""
    return start(["emulate", WELDING_CELL, "--can", f"remote:{bus}", "--out", str(tmp / "emulator"),
                  "--connect", endpoint, "--quiet", *args], tmp / "emulator.log")


class CommandFrames:
    """The bridge daemon's command frames of some messages, read off the CAN server's bus as they come and
    checked as the device does (CRC, counter and MAC under the cell's CAN key)."""

    def __init__(self, bus: str, message_names: list[str], keys: Path, config: str = WELDING_BRIDGE):
        import can

        from cellsim.bridges.config import load_bridge
        from cellsim.bridges.e2e import DeviceChecker
        from cellsim.bridges.secoc import Authenticator, message_key
        from cellsim.live.pki import can_key

        loaded = load_bridge(config)
        self.checkers = {}
        for name in message_names:
            message = loaded.database.get_message_by_name(name)
            authenticator = Authenticator(message, message_key(can_key(keys), message.frame_id),
                                          loaded.config.freshness_tick)
            self.checkers[message.frame_id] = DeviceChecker(message=message, timeout=1.0, recover_after=1,
                                                            authenticator=authenticator)
        self.listener = can.Bus(interface="remote", channel=bus)

    def next(self, deadline: float) -> tuple[float, str, dict]:
        """(arrival on the monotonic clock, message name, values) of the next frame of these messages, before
        ``deadline`` (monotonic); a frame that does not check fails the test (the daemon sends nothing else)."""
        while time.monotonic() < deadline:
            frame = self.listener.recv(timeout=max(0.0, deadline - time.monotonic()))
            checker = self.checkers.get(frame.arbitration_id) if frame is not None else None
            if checker is not None:
                judgement = checker.check(bytes(frame.data), time.monotonic())
                assert judgement.trusted, judgement
                decoded = checker.message.decode(bytes(frame.data))  # enumerations by name
                return time.monotonic(), checker.message.name, {  # the values, without Crc, Counter, Freshness, Mac
                    k: v if isinstance(v, (int, float)) else str(v) for k, v in decoded.items() if k in judgement.values}
        raise AssertionError(f"no {', '.join(c.message.name for c in self.checkers.values())} frame before the deadline")

    def close(self) -> None:
        self.listener.shutdown()
