"""``cellsim live``: the scenario twin paced to the wall clock, beside the real cell, on Zenoh.

Every entity takes its physical samples from its physical key through a
``ZenohSampleSource`` (whatever its twin mode now: the mode may change while the
twin runs). Every ``TICK`` of simulated time the twin

* publishes each channel that changed (and every channel every ``HEARTBEAT``);
* publishes the commands of each entity in twin mode, when they change (in
  shadow and model mode nothing is sent);
* applies the twin-mode requests that arrived (a Zenoh query on the control key,
  answered at once: accepted, or refused with the reason), recording who asked;
* publishes its status every second: pacing lag (wall clock minus simulated
  time), the age of each entity's newest sample.

Its clock starts once every entity in shadow or twin mode has been heard from
(at most ``wait_physical`` seconds), so a twin started before the cell does not
record a start-up spent failing safe as safety evidence.

Its black box is recorded as in any run; ``live`` in its metadata holds the mode
requests and the pacing figures.
"""

from __future__ import annotations

import json
import queue
import sys
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from cellsim.channels import NO_VALUE
from cellsim.live import keys
from cellsim.live.codec import encode_fields
from cellsim.live.sources import LiveClock, ZenohSampleSource
from cellsim.vocabulary import TwinMode

TICK = 0.01
"""How often (s of simulated time) the twin publishes, applies requests and checks its pacing."""
HEARTBEAT = 1.0
"""Every channel is published at least this often (s), changed or not."""
COMMAND_HEARTBEAT = 0.1
"""An entity in twin mode has its commands published at least this often (s): its physical twin
takes a silence longer than its stale_after for a lost supervisor, and stops."""
LAG_WARNING = 0.1
"""Pacing lag (s) beyond which the twin says, once, that it cannot keep up."""


@dataclass
class ModeRequest:
    entity: str
    mode: TwinMode
    by: str


@dataclass
class LiveTwin:
    """The network side of a live twin run (its hooks for ``simulate``)."""

    sf: object
    session: object
    process: str = "twin"
    clock: LiveClock = field(default_factory=LiveClock)
    requests: queue.SimpleQueue = field(default_factory=queue.SimpleQueue)
    applied: list = field(default_factory=list)
    lags: list = field(default_factory=list)
    warned: bool = False
    wait_physical: float = 10.0
    """Seconds to wait, before the clock starts, for samples of every entity in shadow or twin mode."""

    @property
    def cell_name(self) -> str:
        return self.sf.scenario.name

    # -- before the diagram is built -------------------------------------------------
    def sources(self, entities: dict) -> dict:
        """A Zenoh sample source per entity, subscribed to its physical key."""
        self.entities = entities
        step = self.sf.scenario.time_step
        self._sources = {name: ZenohSampleSource(entity, self.clock, step) for name, entity in entities.items()}
        self._heard: dict[str, int] = {name: 0 for name in entities}
        self._all_heard = threading.Event()
        self._awaited = [n for n, e in entities.items() if e.twin.mode is not TwinMode.MODEL]
        if not self._awaited:
            self._all_heard.set()
        self._subscribers = [
            self.session.declare_subscriber(keys.physical(self.cell_name, name), self._deliver_to(name, source))
            for name, source in self._sources.items()
        ]
        return self._sources

    def _deliver_to(self, name: str, source: ZenohSampleSource):
        def on_sample(sample) -> None:  # on the network thread: queue it, count it, nothing more
            source.deliver(sample.payload.to_bytes())
            if not self._all_heard.is_set():
                self._heard[name] += 1
                if all(self._heard[n] > 0 for n in self._awaited):
                    self._all_heard.set()

        return on_sample

    # -- hooks -------------------------------------------------------------------------
    def attach(self, cell) -> None:
        """Publishers for the built cell's channels and commands, the control queryable, liveliness."""
        self.cell = cell
        name = self.cell_name
        self._channels = [
            (spec, port, self.session.declare_publisher(keys.channel(name, spec.module, spec.signal)))
            for spec, port in cell.channels.values()
        ]
        self._last_values: dict[str, object] = {}
        self._last_sent: dict[str, float] = {}
        self._commands = {
            entity_name: (
                entity,
                [entity.input_types.get(f) for f in entity.command_fields],
                self.session.declare_publisher(keys.command(name, entity_name)),
            )
            for entity_name, entity in cell.modules.items()
            if entity_name in self.entities
        }
        self._last_command: dict[str, tuple] = {}
        self._command_seq = 0
        self._status = self.session.declare_publisher(keys.status(name, self.process))
        self._queryable = self.session.declare_queryable(keys.twin_mode_control(name), self._on_mode_query)
        self._description = json.dumps(describe(self.sf, cell))
        self._describe = self.session.declare_queryable(
            keys.describe(name), lambda query: query.reply(query.key_expr, self._description))
        self._token = self.session.liveliness().declare_token(keys.alive(name, self.process))

    def hooks(self):
        from cellsim.simulation import LiveHooks

        return LiveHooks(TICK, self.start, self.tick, self.metadata)

    def start(self) -> None:
        """Start the clock once every entity in shadow or twin mode has been heard (or ``wait_physical`` passed)."""
        if not self._all_heard.wait(self.wait_physical):
            silent = [n for n in self._awaited if not self._heard[n]]
            print(f"cellsim live: no physical samples from {', '.join(silent)} within {self.wait_physical:g} s; "
                  "starting anyway, failing safe", file=sys.stderr)
        self.clock.wall_at_zero = time.time()
        self._next_status = 0.0

    def tick(self, context) -> None:
        t = context.get_time()
        self._apply_mode_requests(context, t)
        self._publish_channels(context, t)
        self._publish_commands(context)
        lag = time.time() - self.clock.wall_at_zero - t
        self.lags.append(lag)
        if lag > LAG_WARNING and not self.warned:
            self.warned = True
            print(f"cellsim live: cannot keep up with the wall clock (lag {lag * 1000:.0f} ms at t = {t:.1f} s)", file=sys.stderr)
        if t >= self._next_status - 1e-9:
            self._next_status += 1.0
            self._publish_status(context, t, lag)

    def metadata(self) -> dict:
        lags = np.array(self.lags) if self.lags else np.zeros(1)
        return {
            "process": self.process,
            "wall_at_zero": self.clock.wall_at_zero,
            "twin_mode_requests": self.applied,
            "pacing_lag_s": {"p50": float(np.percentile(lags, 50)), "p99": float(np.percentile(lags, 99)), "max": float(lags.max())},
            "rejected_samples": {name: source.rejected for name, source in self._sources.items()},
        }

    def close(self) -> None:
        for thing in [*getattr(self, "_subscribers", []), getattr(self, "_queryable", None), getattr(self, "_describe", None),
                      getattr(self, "_token", None)]:
            if thing is not None:
                try:
                    thing.undeclare()
                except Exception:  # noqa: BLE001 - closing anyway
                    pass

    # -- channels and commands --------------------------------------------------------
    def _publish_channels(self, context, t: float) -> None:
        wall = time.time()
        for spec, port, publisher in self._channels:
            value = spec.type.decode(port.Eval(port.get_system().GetMyContextFromRoot(context)))
            name = spec.name
            if value != self._last_values.get(name, _UNSET) or t - self._last_sent.get(name, -HEARTBEAT) >= HEARTBEAT - 1e-9:
                self._last_values[name], self._last_sent[name] = value, t
                publisher.put(json.dumps({"t": wall, "sim_time": round(t, 6), "value": value}, separators=(",", ":")))

    def _publish_commands(self, context) -> None:
        for name, (entity, types, publisher) in self._commands.items():
            vector = entity.physical_command_port.Eval(entity.GetMyContextFromRoot(context))
            if vector[0] < 0.5:  # not in twin mode: nothing goes out
                self._last_command.pop(name, None)
                continue
            codes = tuple(float(x) for x in vector[1:])
            t = context.get_time()
            last = self._last_command.get(name)
            if last is not None and last[0] == codes and t - last[1] < COMMAND_HEARTBEAT - 1e-9:
                continue
            self._last_command[name] = (codes, t)
            self._command_seq += 1
            fields = {
                f: (None if code == NO_VALUE and ctype is not None and ctype.kind == "enum" else
                    ctype.decode([code]) if ctype is not None else code)
                for f, ctype, code in zip(entity.command_fields, types, codes)
            }
            publisher.put(encode_fields(time.time(), self._command_seq, fields))

    def _publish_status(self, context, t: float, lag: float) -> None:
        ages = {}
        for name, entity in self.entities.items():
            stamp = entity.physical_sample_port.Eval(entity.GetMyContextFromRoot(context))[0]
            ages[name] = None if not np.isfinite(stamp) else round(t - stamp, 4)
        self._status.put(json.dumps({"t": time.time(), "sim_time": round(t, 3), "lag": round(lag, 5), "sample_age": ages}))

    # -- twin modes -------------------------------------------------------------------
    def _on_mode_query(self, query) -> None:
        """On the network thread: check the request, answer at once, queue it for the next tick."""
        try:
            request = json.loads(query.payload.to_bytes()) if query.payload is not None else {}
            entity, mode, by = request.get("entity"), request.get("mode"), str(request.get("by", "unknown"))
        except (ValueError, AttributeError):
            entity = mode = None
            by = "unknown"
        if entity not in self.entities:
            answer = {"accepted": False, "reason": f"no entity named {entity!r} (entities: {', '.join(self.entities)})"}
        elif mode not in [m.value for m in TwinMode]:
            answer = {"accepted": False, "reason": f"{mode!r} is not a twin mode (model, shadow, twin)"}
        else:
            self.requests.put(ModeRequest(entity, TwinMode(mode), by))
            answer = {"accepted": True, "reason": f"{entity} goes to {mode} at its next update"}
        query.reply(query.key_expr, json.dumps(answer))

    def _apply_mode_requests(self, context, t: float) -> None:
        while True:
            try:
                request = self.requests.get_nowait()
            except queue.Empty:
                return
            self.entities[request.entity].set_twin_mode(context, request.mode)
            self.applied.append({"t": round(t, 4), "entity": request.entity, "mode": request.mode.value, "by": request.by})


_UNSET = object()


def describe(sf, cell) -> dict:
    """What a running twin tells a dashboard about itself (the ``describe`` query's answer): the
    resolved scenario, every channel as the black box lists it, and the hazards' phases."""
    from cellsim.config.typed_yaml import to_data
    from cellsim.simulation import hazard_channels

    channels = {
        spec.name: {"source": spec.module, "kind": spec.type.kind, "domain": spec.type.domain(), "unit": spec.type.unit,
                    "period": spec.sample_period, "description": spec.description}
        for spec, _ in cell.channels.values()
    }
    return {"scenario": to_data(sf.scenario), "channels": channels, "hazards": hazard_channels(cell)}


def run_live(sf, out_dir, *, session, duration: float, seed: int | None = None, on_progress=None, wait_physical: float = 10.0):
    """Run the twin of ``sf`` in real time on ``session``, recording to ``out_dir``."""
    from cellsim.simulation import simulate

    twin = LiveTwin(sf, session, wait_physical=wait_physical)
    try:
        summary = simulate(
            sf, out_dir, seed=seed, duration=duration, realtime_rate=1.0,
            physical_sources=lambda entities: twin.sources(entities),
            on_built=twin.attach, live=twin.hooks(), on_progress=on_progress,
        )
    finally:
        twin.close()
    return summary, twin
