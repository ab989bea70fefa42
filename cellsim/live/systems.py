"""Zenoh inside the diagram: subscribers and publishers as LeafSystems, as Drake's LCM systems are.

A subscriber's callback runs on a network thread: it only puts the raw payload
and its arrival time (the receiver's monotonic and wall clocks) into a system's
inbox, a thread-safe queue. The system drains the inbox in a declared periodic
discrete update and keeps what it took in its context; nothing written by the
network thread is read by a calc method. Publishers are declared periodic
publish events reading their input ports. So a live run is the same diagram
and the same run loop as any other: ``Simulator.AdvanceTo`` paced to the wall.

* :class:`ZenohSampleSource`: an entity's physical samples from its physical key,
  judged by the one link-trust rule (``cellsim.link``) with the entity's
  ``stale_after`` and ``recover_after``; its output is the entity's
  ``physical_sample`` input ``[t, link code, *fields]``.
* :class:`ZenohCommandSource`: the twin's commands for an emulated entity's inputs,
  failing safe to the entity kind's ``safe_command`` when they stop.
* :class:`ChannelPublisher`: every channel of the twin, on change and every ``HEARTBEAT``.
* :class:`CommandPublisher`: an entity's commands, in twin mode only.
* :class:`SampleOutlet`: an emulated entity's physical state, through its outlet
  (its physical key, or its CAN device), with the faults injected.
* :class:`HeldValue`: the latest number a network thread set (an emulated controller's speed
  slider), taken in at each period.
* :class:`TwinModeControl`: twin-mode requests (a Zenoh query), applied through each
  entity's ``twin_mode_request`` input.
* :class:`LiveStatus`: the process's status every second and its pacing lag.
"""

from __future__ import annotations

import logging
import queue
from collections import deque
import zlib
import sys
import time
from dataclasses import dataclass

import numpy as np
from pydrake.systems.framework import LeafSystem

from cellsim.channels import NO_VALUE
from cellsim.link import REFUSALS, Fault, LinkTrust
from cellsim import codec
from cellsim.codec import CodecError, FieldCodec
from cellsim.vocabulary import PhysicalLink, TwinMode

TICK = 0.01
"""How often (s of simulated time) channels and commands are published and requests applied."""
HEARTBEAT = 1.0
"""Every channel is published at least this often (s), changed or not."""
COMMAND_HEARTBEAT = 0.1
"""An entity in twin mode has its commands published at least this often (s): its physical twin
takes a silence longer than its stale_after for a lost supervisor, and stops."""
# Publishers' events come one plant step after the instants they report: a publish event at t
# reads the state from before the discrete updates at t (Drake handles a step's updates at its
# start and its publishes at its end), so one step later it reads what those updates wrote.
LAG_WARNING = 0.1
"""Pacing lag (s) beyond which the process says, once, that it cannot keep up."""
log = logging.getLogger("cellsim.live")


@dataclass
class LiveClock:
    """The receiver's clocks at simulation time 0 of a run paced to the wall clock."""

    mono_at_zero: float = 0.0
    """``time.monotonic()`` at t = 0: arrival times are judged on this clock."""
    wall_at_zero: float = 0.0
    """UNIX time at t = 0 (for people and for the black box's metadata)."""

    started: bool = False

    def start(self) -> None:
        self.mono_at_zero, self.wall_at_zero = time.monotonic(), time.time()
        self.started = True

    def sim_time(self, mono: float) -> float:
        """The simulation time of a ``time.monotonic()`` reading."""
        return mono - self.mono_at_zero

    def lag(self, t: float) -> float:
        """How far (s) simulated time ``t`` is behind the wall."""
        return time.monotonic() - self.mono_at_zero - t

    def now(self, t: float) -> float:
        """The later of simulated time ``t`` and the wall's (once started), on the simulation's clock: a watchdog
        judges a silence by it, so a twin that falls behind the wall does not take longer to see a sample stale."""
        return max(t, self.sim_time(time.monotonic())) if self.started else t

    def wall_of(self, t: float) -> float:
        """The UNIX time simulated time ``t`` stands for: the wall's now, less how far ``t`` is behind it (on the
        monotonic clock, so a step of the host's wall clock moves it as it moves every other stamp; never ahead of
        the wall). A command decided at ``t`` is stamped with it, so one that a twin behind the wall sends late reads
        as late where it arrives."""
        return time.time() - max(0.0, self.lag(t)) if self.started else time.time()


class Inbox:
    """What a network thread hands a system: (payload, monotonic arrival, wall arrival)."""

    def __init__(self):
        self._queue: queue.SimpleQueue = queue.SimpleQueue()

    def deliver(self, payload: bytes) -> None:
        """Called on the network thread: hand a message over, nothing more."""
        self._queue.put((payload, time.monotonic(), time.time()))

    def on_sample(self, sample) -> None:
        """A Zenoh subscriber's callback."""
        self.deliver(sample.payload.to_bytes())

    def waiting(self) -> int:
        """How many messages wait now (those arriving later are the next drain's)."""
        return self._queue.qsize()

    def take(self, count: int):
        """The ``count`` oldest messages, without blocking (fewer if fewer wait)."""
        for _ in range(count):
            try:
                yield self._queue.get_nowait()
            except queue.Empty:
                return


class _Refusals:
    """Counts and logs messages refused on one key: the first of each kind of refusal is logged, then a
    flood of them says so once in a while (at 10, 100 and every 1000 refused)."""

    def __init__(self, key: str):
        self.key, self.count = key, 0
        self.kinds: set[str] = set()

    def __call__(self, why: str, kind: str | None = None) -> None:
        self.count += 1
        kind = kind or why
        first = kind not in self.kinds
        self.kinds.add(kind)
        if first or self.count in (10, 100) or self.count % 1000 == 0:
            log.warning("%s: refused a message (%s); %d refused so far", self.key, why, self.count)


_FAILURES = (PhysicalLink.STALE, PhysicalLink.CORRUPT)
FLOOD = 2000
"""Messages waiting at one drain beyond which a source is flooded: they are dropped unread and the link goes stale
for the period (its samples could not be taken in time). A device publishing at 500 Hz leaves 10 per 0.02 s drain,
and a twin a second behind the wall 500."""


class _LinkSource(LeafSystem):
    """What a network source of the diagram is: an inbox drained one plant step before each of its
    entity's updates (so the entity reads what arrived up to then), every message decoded by the one
    codec and judged by the one link rule, whose state the context keeps.

    A subclass declares its own state and output, and says what a good message does (``take``) and
    what the state becomes once the inbox is drained and the watchdog looked at (``settle``).
    """

    def __init__(self, name: str, entity, field_codec: FieldCodec, clock: LiveClock, time_step: float, key: str,
                 recover_after: int, every: float | None = None):
        """``every``: drain one plant step before each multiple of ``every`` seconds (for an entity that takes its
        samples on arrival at that period), not before each of its own updates."""
        super().__init__()
        self.set_name(name)
        self.codec, self.clock = field_codec, clock
        self.inbox = Inbox()
        self.refused = _Refusals(key or entity.module)
        self.trust = LinkTrust(timeout=entity.twin.stale_after, recover_after=recover_after, max_gap=1_000_000)
        self._trust = self.DeclareDiscreteState(self.trust.state())
        period = entity.period if every is None else every
        self.DeclarePeriodicDiscreteUpdateEvent(period, period - time_step, self._drain)

    @property
    def rejected(self) -> int:
        return self.refused.count

    def deliver(self, payload: bytes) -> None:
        self.inbox.deliver(payload)

    def _drain(self, context, xd) -> None:
        trust = self.trust.restore(context.get_discrete_state(self._trust).get_value())
        state = self.begin(context)
        failed = None  # the link's failure, if one happened in this drain: reported for this period
        waiting = self.inbox.waiting()  # (only these: a drain never runs on while a sender keeps sending)
        if waiting > FLOOD:
            dropped = sum(1 for _ in self.inbox.take(waiting))
            self.refused(f"a flood: {dropped} messages waiting at one drain (at most {FLOOD}), dropped unread", "flood")
            trust.fail(Fault.TIMEOUT, self.clock.now(context.get_time()))
            failed, waiting = trust.link, 0
        for payload, mono, wall in self.inbox.take(waiting):
            arrival = self.clock.sim_time(mono)
            try:
                message = self.codec.decode(payload)
            except CodecError as e:
                self.refused(str(e), e.kind)
                trust.fail(Fault.CORRUPT, arrival)
            else:
                judgement = trust.receive(arrival, message.seq, zlib.crc32(payload), stamp=message.t, wall=wall,
                                          values=message, in_range=self.carried_fault)
                if judgement.good:
                    self.take(message, arrival, judgement, state)
                elif message.failure is None or judgement.fault in REFUSALS:
                    self.refused(judgement.fault.value)  # the message itself: its stamp or its order
                elif self.failure_refused:
                    self.refused("a failure in place of a command")
            if trust.link in _FAILURES:
                failed = trust.link
        trust.watchdog(self.clock.now(context.get_time()))
        self.settle(trust, state, xd, trust.link if trust.link in _FAILURES else failed)
        xd.get_mutable_vector(self._trust).SetFromVector(trust.state())
        self.drained(context.get_time())

    def drained(self, t: float) -> None:
        """After a drain at simulated time ``t`` (the entity takes what it wrote at the next step)."""

    def begin(self, context) -> np.ndarray:  # pragma: no cover - abstract
        """A copy of the state the drain writes."""
        raise NotImplementedError

    failure_refused = False
    """Whether a failure message is refused (a command is never one) rather than taken as the link's failure."""

    def carried_fault(self, message) -> Fault | None:  # pragma: no cover - abstract
        """The fault a message in order carries (a failure message's), or None: the link fails by it."""
        raise NotImplementedError

    def take(self, message, arrival: float, judgement, state: np.ndarray) -> None:  # pragma: no cover - abstract
        """Write a good message (trusted, or recovering) into the state the drain writes."""
        raise NotImplementedError

    def settle(self, trust: LinkTrust, state: np.ndarray, xd, failed) -> None:  # pragma: no cover
        """``failed``: the link's failure (stale, corrupt) if one happened in this drain, even if good messages
        came after it: the entity fails safe for this period, as on any bad message."""
        raise NotImplementedError


class ZenohSampleSource(_LinkSource):
    """Physical samples of one entity, from its physical key.

    Ports:
      physical_sample (output): [t (s, simulation clock: the arrival of the newest good
        sample), link (PhysicalLink code), *fields (port codes of the newest good sample)].
    """

    def __init__(self, entity, clock: LiveClock, time_step: float, key: str = "", every: float | None = None):
        super().__init__(f"{entity.module}.physical_source", entity, FieldCodec.samples_of(entity), clock, time_step,
                         key, entity.twin.recover_after, every)
        self.time_step = time_step
        self._changed: float | None = None  # the source stamp of the first changed sample of the drain under way
        self._taken: deque = deque(maxlen=10_000)  # (simulated time the entity takes it, source stamp)
        initial = np.zeros(2 + len(self.codec.names))
        initial[0], initial[1] = -np.inf, float(PhysicalLink.STALE.code)
        self._sample = self.DeclareDiscreteState(initial)
        self.DeclareStateOutputPort("physical_sample", self._sample)

    def begin(self, context) -> np.ndarray:
        return context.get_discrete_state(self._sample).get_value().copy()

    def carried_fault(self, message) -> Fault | None:
        return message.failure  # the bridge's checks refused its device's data: the link fails by that fault

    def take(self, message, arrival: float, judgement, sample: np.ndarray) -> None:
        if judgement.trusted and self._changed is None and not np.array_equal(sample[2:], message.codes):
            self._changed = message.t  # the oldest change of this drain, stamped at its source
        sample[0], sample[2:] = arrival, message.codes

    def prime(self, root_context) -> None:
        """Take what arrived before the clock started into ``root_context``, as this source's state at t = 0
        (no reaction is measured to it: nothing ran before)."""
        context = self.GetMyMutableContextFromRoot(root_context)
        self._drain(context, context.get_mutable_discrete_state())
        self.decided_by(float("inf"))

    def drained(self, t: float) -> None:
        if self._changed is not None:
            self._taken.append((t + self.time_step, self._changed))
            self._changed = None

    def decided_by(self, t: float) -> list[float]:
        """The source stamps (wall clock, s) of the changes the entity took before simulated time ``t`` (a
        controller's update then acts on them), each given once."""
        given = []
        while self._taken and self._taken[0][0] < t - 1e-9:
            given.append(self._taken.popleft()[1])
        return given

    def settle(self, trust: LinkTrust, sample: np.ndarray, xd, failed) -> None:
        sample[1] = float((failed or trust.link).code)
        xd.get_mutable_vector(self._sample).SetFromVector(sample)


class ZenohCommandSource(_LinkSource):
    """Commands from the twin into an emulated entity's inputs.

    For a cell emulated under the twin's command: the inputs the twin's supervisor
    drives (a safety-mode request, an activity request, a person's notification),
    one output port per input, of the same name. Fed from the entity's command key
    (``inbox``), or by its device's protocol. Judged by the one link-trust rule with
    the entity's ``stale_after`` (a command is trusted at once): without a good command
    for that long (the twin stopped, or was never there) every output takes the entity
    kind's ``safe_command`` (a safety-mode request reads stopped: losing the supervisor
    makes the cell safer).

    Ports:
      <input> (output), per input: the commanded code.
    """

    def __init__(self, entity, inputs: list[str], clock: LiveClock, time_step: float, key: str = ""):
        self.inputs = list(inputs)
        super().__init__(f"{entity.module}.command_source", entity, FieldCodec.commands_of(entity, self.inputs), clock,
                         time_step, key, 1)
        safe = entity.safe_command()
        self.safe = [safe[name] for name in self.inputs]
        self._values = self.DeclareDiscreteState(np.array(self.safe, float))
        for i, name in enumerate(self.inputs):
            self.DeclareVectorOutputPort(name, 1, lambda context, out, i=i: out.SetAtIndex(
                0, context.get_discrete_state(self._values).GetAtIndex(i)))

    def begin(self, context) -> np.ndarray:
        return context.get_discrete_state(self._values).get_value().copy()

    failure_refused = True

    def carried_fault(self, message) -> Fault | None:
        return None if message.failure is None else Fault.CORRUPT  # a command is never a failure

    def take(self, message, arrival: float, judgement, values: np.ndarray) -> None:
        if judgement.trusted:
            values[:] = message.codes

    def settle(self, trust: LinkTrust, values: np.ndarray, xd, failed) -> None:
        if trust.failed or failed is not None:
            values[:] = self.safe  # the supervisor is gone, or its commands are bad: fail safe
        xd.get_mutable_vector(self._values).SetFromVector(values)


class HeldValue(LeafSystem):
    """The latest number a network thread :meth:`set`, taken into the context every ``period``.

    Ports:
      value (output): the number as last taken in (``initial`` until one is set).
    """

    def __init__(self, name: str, initial: float, period: float, time_step: float):
        super().__init__()
        self.set_name(name)
        self._latest = float(initial)
        self._value = self.DeclareDiscreteState(np.array([float(initial)]))
        self.DeclareStateOutputPort("value", self._value)
        self.DeclarePeriodicDiscreteUpdateEvent(period, time_step, self._take)

    def set(self, value: float) -> None:
        """Called on a network thread: the value from the next period on (a float's store is atomic)."""
        self._latest = float(value)

    def _take(self, context, xd) -> None:
        xd.get_mutable_vector(0).SetAtIndex(0, self._latest)


class ChannelPublisher(LeafSystem):
    """Every channel of the twin on its key, when it changes and every HEARTBEAT.

    Ports:
      <module.signal> (input), per channel: the channel's port vector.
    """

    def __init__(self, channels: list, publisher_of, look: float):
        """``channels``: (ChannelSpec, output port) pairs; ``publisher_of(spec)``: its Zenoh publisher;
        ``look``: how long after each TICK it looks (s): after the updates then (the deciding modules' too)."""
        super().__init__()
        self.set_name("channel_publisher")
        self._channels = []
        for spec, port in channels:
            self._channels.append((spec, self.DeclareVectorInputPort(spec.name, port.size()), publisher_of(spec)))
        self._last: dict[str, tuple] = {}
        self.DeclarePeriodicPublishEvent(TICK, look, self._publish)

    def _publish(self, context) -> None:
        t = context.get_time()
        wall = time.time()
        last = self._last
        for spec, port, publisher in self._channels:
            value = spec.type.decode(port.Eval(context))
            previous = last.get(spec.name)
            if previous is None or value != previous[0] or t - previous[1] >= HEARTBEAT - 1e-9:
                last[spec.name] = (value, t)
                publisher.put(codec.encode_value(wall, t, value))


class CommandPublisher(LeafSystem):
    """An entity's commands on its command key: in twin mode only, one plant step after the update that changed
    them, and every COMMAND_HEARTBEAT (a period of its own would only add delay to the twin's reaction).

    Ports:
      physical_command (input): the entity's ``physical_command`` ([active, *command codes]).
    """

    def __init__(self, entity, publisher, time_step: float, period: float | None = None, look: float | None = None,
                 clock: LiveClock | None = None):
        """``period``: how often a change is looked for (s): the period at which the cell's modules may update
        (default: every plant step); ``look``: when within it (s; default one step): after those updates (the
        deciding modules' too, which may come one step after the others), when they are in the state; ``clock``:
        the run's, whose wall time of the decision stamps each command (:meth:`LiveClock.wall_of`; default: the
        wall's when sent)."""
        super().__init__()
        self.set_name(f"{entity.module}.command_publisher")
        self.clock = clock or LiveClock()
        period = time_step if period is None else period
        self.codec = FieldCodec.commands_of(entity)
        self.publisher = publisher
        self.command_port = self.DeclareVectorInputPort("physical_command", 1 + len(entity.command_fields))
        self._last: tuple | None = None
        self._seq = 0
        self.DeclarePeriodicPublishEvent(period, time_step if look is None else look, self._publish)

    def _publish(self, context) -> None:
        vector = self.command_port.Eval(context)
        if vector[0] < 0.5:  # not in twin mode: nothing goes out
            self._last = None
            return
        codes, t = tuple(vector[1:].tolist()), context.get_time()
        if self._last is not None and self._last[0] == codes and t - self._last[1] < COMMAND_HEARTBEAT - 1e-9:
            return
        self._last = (codes, t)
        self._seq += 1
        self.publisher.put(self.codec.encode_codes(self.clock.wall_of(t), self._seq, codes))


class SampleOutlet(LeafSystem):
    """An emulated entity's physical state, sent through its outlet at its rate, with injected faults.

    ``outlet.send(fields, fault, sim_time)`` sends one sample (a Zenoh message on the
    entity's physical key, or its CAN device's frame); ``faults(entity, t)`` says which
    fault holds now (None: none).

    Ports:
      physical_state (input): the entity's ``physical_state`` (its sample fields as port codes).
    """

    def __init__(self, entity, outlet, period: float, faults, time_step: float):
        super().__init__()
        self.set_name(f"{entity.module}.outlet")
        self.entity, self.outlet, self.faults = entity.module, outlet, faults
        self.codec = FieldCodec.samples_of(entity)
        self.state_port = self.DeclareVectorInputPort("physical_state", len(entity.sample_fields))
        self.sent = 0
        self.DeclarePeriodicPublishEvent(period, time_step, self._publish)

    def _publish(self, context) -> None:
        t = context.get_time()
        fields = self.codec.fields(self.state_port.Eval(context))
        self.sent += self.outlet.send(fields, self.faults(self.entity, t), t)


class TwinModeControl(LeafSystem):
    """Twin-mode requests, answered at once on the network thread and applied at the next TICK.

    Ports:
      <entity> (output), per entity: [serial, TwinMode code] of the newest request for it
        (serial 0: none yet); the entity switches when the serial changes.
    """

    def __init__(self, entities: dict):
        super().__init__()
        self.set_name("twin_mode_control")
        self.names = list(entities)
        self.requests: queue.SimpleQueue = queue.SimpleQueue()
        self.applied: list[dict] = []
        self._state = self.DeclareDiscreteState(np.zeros(2 * len(self.names)))
        for i, name in enumerate(self.names):
            self.DeclareVectorOutputPort(name, 2, lambda context, out, i=i: out.SetFromVector(
                context.get_discrete_state(self._state).get_value()[2 * i: 2 * i + 2]))
        self.DeclarePeriodicDiscreteUpdateEvent(TICK, 0.0, self._apply)

    def on_query(self, query) -> None:
        """On the network thread: check the request, answer at once, queue it for the next tick."""
        try:
            entity, mode, by = codec.decode_mode_request(query.payload.to_bytes() if query.payload is not None else None)
        except CodecError:
            entity = mode = None
            by = "unknown"
        if not isinstance(entity, str) or entity not in self.names:
            answer = (False, f"no entity named {codec.shown(entity)} (entities: {', '.join(self.names)})")
        elif mode not in [m.value for m in TwinMode]:
            answer = (False, f"{codec.shown(mode)} is not a twin mode (model, shadow, twin)")
        else:
            self.requests.put((entity, TwinMode(mode), by))
            answer = (True, f"{entity} goes to {mode} at its next update")
        query.reply(query.key_expr, codec.encode_answer(*answer))

    def _apply(self, context, xd) -> None:
        state = None
        while True:
            try:
                entity, mode, by = self.requests.get_nowait()
            except queue.Empty:
                break
            if state is None:
                state = context.get_discrete_state(self._state).get_value().copy()
            i = self.names.index(entity)
            state[2 * i], state[2 * i + 1] = state[2 * i] + 1.0, float(mode.code)
            self.applied.append({"t": round(context.get_time(), 4), "entity": entity, "mode": mode.value, "by": by})
        if state is not None:
            xd.get_mutable_vector(self._state).SetFromVector(state)


class LiveStatus(LeafSystem):
    """A live process's pacing: its lag every TICK and, with ``publisher``, its status every second (with the
    twin's reaction, the slowest since the last status and the entities slower than assumed).

    Ports:
      <entity> (input), per entity with a sample source: its ``physical_sample`` (for the age of
        its newest sample).
    """

    def __init__(self, clock: LiveClock, time_step: float, publisher=None, sources: dict | None = None,
                 process: str = "twin", reaction=None):
        """``reaction``: the twin's ``ReactionWatch`` (``cellsim.live.reaction``), whose figures the status carries."""
        super().__init__()
        self.set_name(f"{process}_status")
        self.clock, self.publisher, self.process, self.reaction = clock, publisher, process, reaction
        self.lags: list[float] = []
        self.warned = False
        self._samples = {name: self.DeclareVectorInputPort(name, port.size()) for name, port in (sources or {}).items()}
        self.DeclarePeriodicPublishEvent(TICK, 0.0, self._pace)
        if publisher is not None:
            self.DeclarePeriodicPublishEvent(1.0, time_step, self._status)

    def _pace(self, context) -> None:
        if not self.clock.started:
            return  # the simulator's initialisation, before the clock starts
        t = context.get_time()
        lag = self.clock.lag(t)
        self.lags.append(lag)
        if lag > LAG_WARNING and not self.warned and t > 0.0:
            self.warned = True
            print(f"cellsim {self.process}: cannot keep up with the wall clock (lag {lag * 1000:.0f} ms at "
                  f"t = {t:.1f} s)", file=sys.stderr)

    def _status(self, context) -> None:
        if not self.clock.started:
            return
        t = context.get_time()
        ages = {}
        for name, port in self._samples.items():
            stamp = port.Eval(context)[0]
            ages[name] = None if not np.isfinite(stamp) else round(t - stamp, 4)
        lag = self.lags[-1] if self.lags else 0.0
        status = {"t": time.time(), "sim_time": round(t, 3), "lag": round(lag, 5), "sample_age": ages}
        if self.reaction is not None:
            status["reaction"] = self.reaction.status()
        self.publisher.put(codec.dumps(status))

    def figures(self) -> dict:
        lags = np.array(self.lags) if self.lags else np.zeros(1)
        return {"p50": float(np.percentile(lags, 50)), "p99": float(np.percentile(lags, 99)), "max": float(lags.max())}


def no_request() -> np.ndarray:
    """The value of an entity's ``twin_mode_request`` input when nothing drives it."""
    return np.array([0.0, NO_VALUE])
