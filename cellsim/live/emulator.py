"""``cellsim emulate``: plays the physical cell in real time, where no hardware is.

The builder makes it (``cellsim.diagrams.cell.build_cell`` with ``cellsim.cell_io.Emulated``):
the scenario's entities run as their digital models with the scenario's own
safety controller, a standalone cell, and each entity's physical state
(``EntitySystem.physical_state``) leaves through an *outlet* at the entity's
update rate (or its ``--rate``) in the format the twin reads
(``cellsim.codec``), the format the bridge daemon publishes too. It keeps its
own black box: the ground truth to compare the twin against.

Commanded by the twin (``--commanded-by-twin``) the scenario's supervisors (its
safety controller) are left out, and the entity inputs they drove take the
commands the twin publishes for its entities in twin mode
(``cellsim.live.systems.ZenohCommandSource``; with no command for ``stale_after``
they take the kind's safe command: a safety-mode request becomes stopped). Its
black box then has no hazard channels: the evidence is the twin's.

An outlet is by default a :class:`ZenohOutlet` on the entity's physical key. With
the bridge daemon's configuration (``cellsim emulate --can``, ``cellsim.bridges.devices``)
an entity that is a CAN device sends protected frames on the bus instead, a robot
its controller's state stream, each at its device's cycle time, and takes its
commands the same way: the emulated cell speaks the real protocols, through the
bridge daemon.

Faults, for tests and demos (``--fault ENTITY=KIND[@T0[-T1]]``, simulated
seconds; the grammar is ``cellsim.live.faults``), as the entity's outlet knows
them. On Zenoh: ``silence`` (stops publishing), ``freeze`` (repeats its last
sample, same sequence number), ``corrupt`` (malformed messages), ``delay``
(samples stamped 1 s in the past), ``replay`` (old samples again, sequence going
back); on CAN, ``cellsim.bridges.devices``. At run time, a query on
``cellsim/<cell>/control/fault`` with ``{"entity", "kind", "seconds"}`` injects
one from the next sample for that long (answered accepted, or refused with the reason).
"""

from __future__ import annotations

import math
import time

from cellsim.live.faults import ZENOH_FAULTS
from cellsim import codec



REPLAYED = 50
"""How many samples back the ``replay`` fault goes (the oldest kept, while fewer were sent)."""


class ZenohOutlet:
    """An entity's samples as Zenoh messages on one key, with the Zenoh faults.

    ``encode(t, seq, fields, sim_time)`` makes a message of a sample (``t``: wall clock, s;
    ``sim_time``: the emulator's simulated time of the sample, s); ``wall_of(sim_time)``: the wall time a sample of
    that simulated time is stamped with (``LiveClock.wall_of``: an emulator behind the wall stamps its samples as old
    as they are, as a device stamps its own when it takes them; default: the wall's now).
    """

    faults = ZENOH_FAULTS

    def __init__(self, publisher, encode=lambda t, seq, fields, sim_time: codec.encode_fields(t, seq, fields),
                 wall_of=lambda sim_time: time.time()):
        self.publisher, self.encode, self.wall_of = publisher, encode, wall_of
        self.seq = 0
        self.history: list[bytes] = []

    def send(self, fields: dict, fault: str | None, sim_time: float) -> int:
        """Send one sample (or what ``fault`` makes of it); the number of messages sent."""
        payload = None if fault == "silence" else self._payload(fields, fault, sim_time)
        if payload is None:
            return 0
        self.publisher.put(payload)
        return 1

    def _payload(self, fields: dict, fault: str | None, sim_time: float) -> bytes | None:
        """The message to send; None where the fault has nothing to send (a freeze or a replay before any sample)."""
        history = self.history
        if fault in ("freeze", "replay"):  # an old message again, never a new one (nothing yet: nothing sent)
            if not history:
                return None
            return history[-1] if fault == "freeze" else history[max(0, len(history) - REPLAYED)]
        if fault == "corrupt":
            return b'{"t": "soon", "fields": [1, 2'
        self.seq += 1
        payload = self.encode(self.wall_of(sim_time) - (1.0 if fault == "delay" else 0.0), self.seq, fields, sim_time)
        history.append(payload)
        del history[:-100]
        return payload


def fault_query_handler(schedule, kinds: dict[str, tuple[str, ...]]):
    """The fault-control queryable's callback: check a request, answer, hand it to ``schedule``."""

    def on_query(query) -> None:  # on the network thread
        try:
            request = codec.loads(query.payload.to_bytes()) if query.payload is not None else {}
            entity, kind = request.get("entity"), request.get("kind")
            seconds = request.get("seconds")
            seconds = math.inf if seconds is None else codec.number(seconds, "'seconds'")
        except codec.CodecError:
            entity = kind = None
            seconds = -1.0
        if not isinstance(entity, str) or entity not in kinds:
            answer = (False, f"no entity named {codec.shown(entity)}")
        elif kind not in kinds[entity]:
            answer = (False, f"{codec.shown(kind)} is not a fault of {entity} ({', '.join(kinds[entity])})")
        elif not seconds > 0:
            answer = (False, "'seconds' must be a positive number")
        else:
            schedule.requests.put((entity, kind, seconds))
            answer = (True, f"{kind} on {entity} for {seconds:g} s from the next sample")
        query.reply(query.key_expr, codec.encode_answer(*answer))

    return on_query
