"""What feeds the dashboard's model: the running twin over Zenoh, or a recorded run.

Both have one method the dashboard calls several times a second, ``drain()``,
which takes in whatever arrived since. A live feed runs no Python per message
on the network's threads: Zenoh's own channels hold what arrives (every twin
channel message in order, for the trace; of each physical sample stream, a
robot's state at 500 Hz, only the newest: a ring of one), and ``drain`` takes
them out: the dashboard never decodes, let alone renders, every message.
"""

from __future__ import annotations

import time
from collections import deque
from pathlib import Path

from cellsim.dashboard.model import CellModel
from cellsim import codec
from cellsim.live import keys

CHANNEL_BACKLOG = 100_000
"""Twin channel messages held between two drains (minutes of a busy cell, should the screen stall)."""


class ReplayFeed:
    """A recorded run played back at ``speed`` times real time, from ``start`` (s)."""

    def __init__(self, run: str | Path, speed: float = 1.0, start: float = 0.0, clock=time.monotonic):
        from cellsim.blackbox import BlackBox, run_end
        from cellsim.validation.check import locate_run

        blackbox, _ = locate_run(run)
        with BlackBox(blackbox) as bb:
            self.model = CellModel.from_blackbox(bb)
            self.messages = list(bb.iter_values(list(bb.channels())))
            # where the record ends, as check and replay have it: an interrupted or killed run at what it recorded,
            # not at the duration it was planned for
            self.end, self.complete = run_end(bb, bb.metadata(), self.messages[-1][0] if self.messages else 0.0)
        self.speed, self.start, self.clock = speed, start, clock
        self.source = Path(run).name
        self._next = 0
        self._wall0: float | None = None
        self.model.set_twin("replay")

    @property
    def position(self) -> float:
        """The replay's simulated time now (s)."""
        if self._wall0 is None:
            return self.start
        return min(self.end, self.start + (self.clock() - self._wall0) * self.speed)

    def drain(self) -> None:
        if self._wall0 is None:
            self._wall0 = self.clock()
        now = self.position
        messages, model = self.messages, self.model
        while self._next < len(messages) and messages[self._next][0] <= now:
            t, channel, value = messages[self._next]
            model.apply_channel(channel, t, value)
            self._next += 1
        model.sim_time = max(model.sim_time, now)
        if now >= self.end and model.twin != "ended":
            model.complete = self.complete
            model.conditions(force=True)
            model.set_twin("ended")

    def close(self) -> None:
        pass


class LiveFeed:
    """The running twin of ``cell`` (None: the first twin found) on a Zenoh session.

    ``session`` is an open session, or a function opening one: it is then called
    on a thread of its own, again every second until a twin is reachable, so the
    dashboard can say that it waits instead of blocking.
    """

    def __init__(self, session, cell: str | None = None, may_switch: bool = True):
        import threading

        self.session = None if callable(session) else session
        self.cell = cell
        self.may_switch = may_switch
        """False for an observer's certificate: the twin would not answer its mode requests."""
        self.model: CellModel | None = None
        self._inbox: deque = deque()
        self._channels: list = []
        self._alive: deque = deque()
        self._subscribers = []
        self._carried: list = []  # the log of the twin's earlier runs, carried into the next run's model
        self.source = "the running twin"
        # Finding the twin (opening the session, its liveliness token, its describe answer) blocks for
        # seconds while no twin runs: a thread of its own does it, and the screen keeps saying it waits.
        self._owns_session = callable(session)
        self._closed = threading.Event()
        self._finding = threading.Thread(target=self._find, args=(session if callable(session) else None,), daemon=True)
        self._finding.start()

    def _find(self, opener) -> None:
        while not self._closed.is_set() and self.model is None:
            try:
                if self.session is None:
                    self.session = opener()
                self._connect()
            except Exception:  # noqa: BLE001 - no twin reachable yet: try again
                pass
            if self.model is None:
                self._closed.wait(1.0)

    def drain(self) -> None:
        if self.model is None:
            return
        latest_physical: dict[str, bytes] = {}
        inbox, model = self._inbox, self.model
        for channel in self._channels:
            while (sample := channel.try_recv()) is not None:
                inbox.append((str(sample.key_expr), sample.payload.to_bytes()))
        while inbox:
            key, payload = inbox.popleft()
            parts = key.split("/")
            kind = parts[2] if len(parts) > 2 else ""
            if kind == "physical":
                latest_physical[parts[3]] = payload  # only the newest of a fast stream is decoded
                continue
            try:
                message = codec.loads(payload)
            except codec.CodecError:
                model.dropped += 1
                continue
            if kind == "twin" and len(parts) == 5 and isinstance(message, dict):
                model.apply_channel(f"{parts[3]}.{parts[4]}", message.get("sim_time"), message.get("value"))
            elif kind == "status":
                model.apply_status(message)
            elif kind == "diagnostics" and len(parts) == 4:
                model.apply_diagnostics(parts[3], message)
            else:
                model.dropped += 1
        for entity, payload in latest_physical.items():
            try:
                model.apply_physical(entity, codec.loads(payload))
            except codec.CodecError:
                model.dropped += 1
        while self._alive:
            alive = self._alive.popleft()
            if alive and model.twin == "gone":  # a twin again after one went: a new run, from t = 0
                self._new_run(model)
                return
            model.set_twin("running" if alive else "gone")

    def _new_run(self, previous: CellModel) -> None:
        """The twin came back after it went (restarted, or another run of the cell): forget the last run's values,
        times and description, and find the new one as at the start (its description asked again), its log kept."""
        import threading

        self._undeclare()
        self._channels, self._inbox, self._alive = [], deque(), deque()
        self._carried = list(previous.events)
        self.model = None
        self._finding.join(timeout=5)  # (finished: it made the previous model)
        self._finding = threading.Thread(target=self._find, args=(None,), daemon=True)
        self._finding.start()

    def _connect(self) -> None:
        """Find the twin (its liveliness token), ask what it runs, subscribe to everything it says."""
        if self.cell is None:
            for reply in self.session.liveliness().get(f"{keys.ROOT}/*/alive/twin", timeout=0.5):
                if reply.ok is not None:
                    self.cell = str(reply.ok.key_expr).split("/")[1]
                    break
            if self.cell is None:
                return
        description = None
        for reply in self.session.get(keys.describe(self.cell), timeout=1.0):
            if reply.ok is not None:
                try:
                    description = codec.loads(reply.ok.payload.to_bytes(), codec.MAX_DESCRIPTION)
                except codec.CodecError:
                    description = None
        if not isinstance(description, dict):
            return
        model = CellModel(description)
        if self._carried:  # (a new run of the twin: the log goes on, the values and times start again)
            model.events.extend(self._carried)
            model.log("a new run of the twin: its values and times start again from its description")
        model.set_twin("running")
        import zenoh

        prefix = keys.cell_prefix(self.cell)
        channels = [(f"{prefix}/twin/**", zenoh.handlers.FifoChannel(CHANNEL_BACKLOG)),
                    (f"{prefix}/diagnostics/*", zenoh.handlers.FifoChannel(1000)),
                    (keys.status(self.cell, "twin"), zenoh.handlers.RingChannel(1))]
        channels += [(keys.physical(self.cell, entity), zenoh.handlers.RingChannel(1)) for entity in model.entities]
        self._channels = [self.session.declare_subscriber(selector, handler) for selector, handler in channels]
        self._subscribers.extend(self._channels)
        self._subscribers.append(self.session.liveliness().declare_subscriber(
            keys.alive(self.cell, "twin"), lambda sample: self._alive.append(str(sample.kind).endswith("PUT")), history=True))
        self.model = model  # last: the screen's thread takes it from here

    def request_mode(self, entity: str, mode: str, timeout: float = 5.0) -> dict:
        """Ask the twin to switch ``entity`` to ``mode`` (blocking: call it off the interface's thread)."""
        request = codec.encode_mode_request(entity, mode, f"cellsim dashboard ({self.session.zid()})")
        for reply in self.session.get(keys.twin_mode_control(self.cell), payload=request, timeout=timeout):
            if reply.ok is not None:
                return codec.decode_answer(reply.ok.payload.to_bytes())
        return {"accepted": False, "reason": f"no answer from the twin within {timeout:g} s"}

    def _undeclare(self) -> None:
        for subscriber in self._subscribers:
            try:
                subscriber.undeclare()
            except Exception:  # noqa: BLE001 - closing anyway
                pass
        self._subscribers = []

    def close(self) -> None:
        self._undeclare()
        self._closed.set()
        self._finding.join(timeout=5)
        if self._owns_session and self.session is not None:
            self.session.close()
