"""``cellsim emulate``: plays the physical cell in real time, where no hardware is.

The scenario's entities run as their digital models (every twin mode forced to
model) with the scenario's own safety controller: a standalone cell. Every
``TICK`` the emulator publishes, for each entity whose update period has come
round, its physical sample (``EntitySystem.physical_state``) on its physical key
in the format the twin reads (``cellsim.live.codec``), the format the bridge
daemon will publish too. It keeps its own black box: the ground truth to
compare the twin against.

With ``commanded_by_twin`` it is a cell under the twin's supervision: the
scenario's supervisors (its safety controller) are left out, and the entity
inputs they drove take the commands the twin publishes for its entities in
twin mode (``ZenohCommandSource``; with no command for ``stale_after`` they fail
safe: a safety-mode request becomes stopped). Its black box then has no hazard
channels: the evidence is the twin's.

Each entity's samples leave through an *outlet*: by default a ``ZenohOutlet``
on its physical key. With ``devices`` (``cellsim emulate --can``: the bridge
daemon's configuration, ``bridges.devices``) an entity that is a CAN device
sends protected frames on the bus instead, a robot its controller's state
stream, each at its device's cycle time, and takes its commands the same way:
the emulated cell speaks the real protocols, through the bridge daemon.

Faults, for tests and demos (``--fault ENTITY=KIND[@T0[-T1]]``, simulated
seconds), as the entity's outlet knows them. On Zenoh: ``silence`` (stops
publishing), ``freeze`` (repeats its last sample, same sequence number),
``corrupt`` (malformed messages), ``delay`` (samples stamped 1 s in the past),
``replay`` (old samples again, sequence going back); on CAN, ``bridges.devices``.
At run time, a query on ``cellsim/<cell>/control/fault`` with ``{"entity",
"kind", "seconds"}`` injects one from the next tick for that long (answered
accepted, or refused with the reason).
"""

from __future__ import annotations

import json
import queue
import time
from dataclasses import dataclass, field

from cellsim.entities.twin import EntitySystem
from cellsim.live import keys
from cellsim.live.codec import encode_fields, field_types, fields_of
from cellsim.live.sources import LiveClock, ZenohCommandSource
from cellsim.vocabulary import TwinMode

TICK = 0.01
"""How often (s of simulated time) the emulator looks for samples to publish."""
FAULTS = ("silence", "freeze", "corrupt", "delay", "replay")
"""The faults of a ZenohOutlet."""


class ZenohOutlet:
    """An entity's samples as Zenoh messages on one key, with the Zenoh faults.

    ``encode(t, seq, fields, sim_time)`` makes a message of a sample (``t``: wall clock, s;
    ``sim_time``: the emulator's simulated time of the sample, s).
    """

    faults = FAULTS

    def __init__(self, publisher, encode=lambda t, seq, fields, sim_time: encode_fields(t, seq, fields)):
        self.publisher, self.encode = publisher, encode
        self.seq = 0
        self.history: list[bytes] = []

    def send(self, fields: dict, fault: str | None, sim_time: float) -> int:
        """Send one sample (or what ``fault`` makes of it); the number of messages sent."""
        if fault == "silence":
            return 0
        self.publisher.put(self._payload(fields, fault, sim_time))
        return 1

    def _payload(self, fields: dict, fault: str | None, sim_time: float) -> bytes:
        history = self.history
        if fault == "freeze" and history:
            return history[-1]
        if fault == "replay" and len(history) > 50:
            return history[-50]
        if fault == "corrupt":
            return b'{"t": "soon", "fields": [1, 2'
        self.seq += 1
        payload = self.encode(time.time() - (1.0 if fault == "delay" else 0.0), self.seq, fields, sim_time)
        history.append(payload)
        del history[:-100]
        return payload


@dataclass
class Fault:
    entity: str
    kind: str
    at: float = 0.0
    """Simulated time (s) from which the fault holds."""
    until: float = float("inf")
    """Simulated time (s) at which it ends."""


@dataclass
class Emulator:
    sf: object
    session: object
    faults: list[Fault] = field(default_factory=list)
    process: str = "emulator"
    published: int = 0
    commanded_by_twin: bool = False
    clock: LiveClock = field(default_factory=LiveClock)
    rates: dict = field(default_factory=dict)
    """Entity name -> samples per second, instead of one per update period (a robot's state at 500 Hz)."""
    devices: object = None
    """The cell's devices speaking their real protocols (``bridges.devices.EmulatedDevices``), or None:
    every entity on its physical key."""

    def __post_init__(self):
        if self.devices is not None:
            self.rates = {**self.devices.rates(), **self.rates}

    def fault_kinds(self, entity: str) -> tuple[str, ...]:
        """The faults the outlet of ``entity`` can inject."""
        kinds = self.devices.fault_kinds(entity) if self.devices is not None else None
        return kinds or FAULTS

    def command_source(self, entity, inputs: list[str]):
        """The twin's commands for ``entity``'s free command inputs (see the module docstring):
        from its device's protocol, or from the twin's command key."""
        source = ZenohCommandSource(entity, inputs, self.clock, self.sf.scenario.time_step, entity.twin.stale_after)
        if self.devices is not None and self.devices.feed_commands(entity, source):
            return source
        subscriber = self.session.declare_subscriber(
            keys.command(self.sf.scenario.name, entity.module), lambda sample: source.deliver(sample.payload.to_bytes())
        )
        self._command_subscribers = [*getattr(self, "_command_subscribers", []), subscriber]
        return source

    def attach(self, cell) -> None:
        name = self.sf.scenario.name
        self.cell = cell
        self.entities = {n: m for n, m in cell.modules.items() if isinstance(m, EntitySystem)}
        self._next_due = {n: 0.0 for n in self.entities}
        self._periods = {n: 1.0 / self.rates[n] if n in self.rates else e.period for n, e in self.entities.items()}
        self._outlets = {
            n: (self.devices.outlet(n, e) if self.devices is not None else None)
            or ZenohOutlet(self.session.declare_publisher(keys.physical(name, n)))
            for n, e in self.entities.items()
        }
        self._types = {n: field_types(e) for n, e in self.entities.items()}
        self._token = self.session.liveliness().declare_token(keys.alive(name, self.process))
        self._fault_requests: queue.SimpleQueue = queue.SimpleQueue()
        self._fault_queryable = self.session.declare_queryable(keys.fault_control(name), self._on_fault_query)

    def _on_fault_query(self, query) -> None:
        """On the network thread: check a fault request, answer, queue it for the next tick."""
        try:
            request = json.loads(query.payload.to_bytes()) if query.payload is not None else {}
            entity, kind, seconds = request.get("entity"), request.get("kind"), float(request.get("seconds", "inf"))
        except (ValueError, TypeError, AttributeError):
            entity = kind = None
            seconds = -1.0
        if entity not in self.entities:
            answer = {"accepted": False, "reason": f"no entity named {entity!r}"}
        elif kind not in self.fault_kinds(entity):
            answer = {"accepted": False, "reason": f"{kind!r} is not a fault of {entity} ({', '.join(self.fault_kinds(entity))})"}
        elif not seconds > 0:
            answer = {"accepted": False, "reason": "'seconds' must be a positive number"}
        else:
            self._fault_requests.put((entity, kind, seconds))
            answer = {"accepted": True, "reason": f"{kind} on {entity} for {seconds:g} s from the next tick"}
        query.reply(query.key_expr, json.dumps(answer))

    def hooks(self):
        from cellsim.simulation import LiveHooks

        step = self.sf.scenario.time_step
        fastest = min([TICK, *(1.0 / hz for hz in self.rates.values())])
        return LiveHooks(max(step, round(fastest / step) * step), self.start, self.tick, self.metadata)

    def start(self) -> None:
        self.wall_at_zero = self.clock.wall_at_zero = time.time()

    def tick(self, context) -> None:
        t = context.get_time()
        while not self._fault_requests.empty():
            entity, kind, seconds = self._fault_requests.get_nowait()
            self.faults.append(Fault(entity, kind, t, t + seconds))
        for name, entity in self.entities.items():
            if t < self._next_due[name] - 1e-9:
                continue  # its update period has not come round
            self._next_due[name] += self._periods[name]
            fields = fields_of(entity.sample_fields, self._types[name], entity.physical_state(context))
            self.published += self._outlets[name].send(fields, self._fault(name, t), t)

    def _fault(self, name: str, t: float) -> str | None:
        active = [f.kind for f in self.faults if f.entity == name and f.at - 1e-9 <= t < f.until - 1e-9]
        return active[-1] if active else None

    def metadata(self) -> dict:
        faults = [{**f.__dict__, "until": None if f.until == float("inf") else f.until} for f in self.faults]
        return {"process": self.process, "wall_at_zero": getattr(self, "wall_at_zero", None),
                "samples_published": self.published, "faults": faults, "commanded_by_twin": self.commanded_by_twin}

    def close(self) -> None:
        for subscriber in [*getattr(self, "_command_subscribers", []), getattr(self, "_fault_queryable", None)]:
            if subscriber is None:
                continue
            try:
                subscriber.undeclare()
            except Exception:  # noqa: BLE001 - closing anyway
                pass
        if self.devices is not None:
            self.devices.close()
        token = getattr(self, "_token", None)
        if token is not None:
            try:
                token.undeclare()
            except Exception:  # noqa: BLE001 - closing anyway
                pass


def as_digital_models(sf) -> None:
    """Every entity of the scenario runs as its digital model (the emulated physical cell)."""
    for section in ("entities",):
        for cfg in getattr(sf.scenario, section).values():
            twin = getattr(cfg, "twin", None)
            if twin is not None:
                twin.mode = TwinMode.MODEL
                twin.changes = []


def without_supervisors(sf) -> None:
    """Leave the scenario's supervisors out, and its safety evidence (it is the twin's)."""
    from cellsim import registry
    from cellsim.validation.config import Validation

    sc = sf.scenario
    sc.behaviours = {name: cfg for name, cfg in sc.behaviours.items() if not registry.kind_of(cfg).supervises}
    sc.validation = Validation()


def run_emulator(sf, out_dir, *, session, duration: float, seed: int | None = None, faults=(), on_progress=None,
                 commanded_by_twin: bool = False, rates: dict | None = None, devices=None):
    from cellsim.simulation import simulate

    as_digital_models(sf)
    if commanded_by_twin:
        without_supervisors(sf)
    emulator = Emulator(sf, session, list(faults), commanded_by_twin=commanded_by_twin, rates=dict(rates or {}),
                        devices=devices)
    try:
        summary = simulate(
            sf, out_dir, seed=seed, duration=duration, realtime_rate=1.0,
            on_built=emulator.attach, live=emulator.hooks(), on_progress=on_progress,
            command_sources=emulator.command_source if commanded_by_twin else None,
        )
    finally:
        emulator.close()
    return summary, emulator
