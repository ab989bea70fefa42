"""Physical samples from Zenoh into an entity's ``physical_sample`` input.

A Zenoh subscriber's callback runs on a network thread: it only puts the raw
payload and its arrival time into the source's inbox (a thread-safe queue).
The source system drains the inbox in a periodic discrete update, at the
entity's rate, and copies the newest acceptable sample into its state, which its
``physical_sample`` output port reads. Nothing written by the network thread is
read by a calc method.

Acceptable: a message that decodes (else the entity reads its link corrupt) and
was taken after the last one taken, by its time stamp: a repeat or an older
message is dropped, so a frozen, replayed or duplicated stream goes stale,
while a restarted sender (its ``seq`` counting from 1 again) is heard at once. The
sample's time stamp is its sender's wall-clock time on the twin's simulation
clock (``LiveClock``), so an entity judges its age as in any run.

A failure message (the bridge daemon refused its device's data, ``codec``) is
taken like a sample: the entity reads its link stale or corrupt at once.
"""

from __future__ import annotations

import math
import queue
from dataclasses import dataclass

import numpy as np
from pydrake.systems.framework import LeafSystem

from cellsim.live.codec import CodecError, decode_sample, field_types


@dataclass
class LiveClock:
    """The wall-clock time (UNIX s) at simulation time 0 of a run paced to the wall clock."""

    wall_at_zero: float = 0.0

    def sim_time(self, wall: float) -> float:
        return wall - self.wall_at_zero


class ZenohSampleSource(LeafSystem):
    """Physical samples of one entity, from its physical key.

    Ports:
      physical_sample (output): [t (s, simulation clock), valid (0/1), *fields]; fields
        NaN when the newest message was malformed or said the link failed (the entity
        reads its link corrupt; stale, valid 0, for a failure saying so).
    """

    def __init__(self, entity, clock: LiveClock, time_step: float):
        super().__init__()
        self.set_name(f"{entity.module}.physical_source")
        self.names = tuple(entity.sample_fields)
        self.types = field_types(entity)
        self.clock = clock
        self.inbox: queue.SimpleQueue = queue.SimpleQueue()
        self.rejected = 0
        n = len(self.names)
        initial = np.zeros(2 + n)
        initial[0] = -np.inf
        self._sample = self.DeclareDiscreteState(initial)
        self._memory = self.DeclareDiscreteState(np.array([-1.0, -np.inf]))  # [last seq, last wall time]
        self.DeclareStateOutputPort("physical_sample", self._sample)
        # drained one plant step before each of the entity's updates, so the entity reads
        # what arrived up to then (discrete updates at one instant read the old state)
        self.DeclarePeriodicDiscreteUpdateEvent(entity.period, entity.period - time_step, self._drain)

    def deliver(self, payload: bytes) -> None:
        """Called on the network thread: hand a message over, nothing more."""
        self.inbox.put(payload)

    def _drain(self, context, xd) -> None:
        last_seq, last_wall = context.get_discrete_state(self._memory).get_value()
        taken = None
        corrupt = False
        for payload in _received(self.inbox):
            try:
                wall, seq, failure, codes = decode_sample(payload, self.names, self.types)
            except CodecError:
                corrupt, self.rejected = True, self.rejected + 1
                continue
            if wall <= last_wall:  # a repeat, or back in time
                self.rejected += 1
                continue
            valid = 0.0 if failure == "stale" else 1.0
            taken, last_seq, last_wall, corrupt = (wall, valid, codes), seq, wall, False
        if taken is not None:
            wall, valid, codes = taken
            xd.get_mutable_vector(self._sample).SetFromVector(np.array([self.clock.sim_time(wall), valid, *codes]))
            xd.get_mutable_vector(self._memory).SetFromVector(np.array([last_seq, last_wall]))
        elif corrupt:  # the newest message was malformed: fresh, but unusable
            sample = np.full(2 + len(self.names), math.nan)
            sample[0], sample[1] = context.get_time(), 1.0
            xd.get_mutable_vector(self._sample).SetFromVector(sample)


def _received(inbox: queue.SimpleQueue):
    """Every payload waiting in ``inbox``, oldest first, without blocking."""
    while True:
        try:
            yield inbox.get_nowait()
        except queue.Empty:
            return


class ZenohCommandSource(LeafSystem):
    """Commands from the twin (an entity's command key) into an emulated entity's inputs.

    For a cell emulated under the twin's command: the inputs the twin's
    supervisor drives (a safety-mode request, an activity request, a person's
    notification), one output port per input, of the same name. Without a valid
    command for ``stale_after`` (the twin stopped, or was never there) each
    output takes its *fail-safe* value: a safety-mode request becomes ``stopped``
    (losing the supervisor makes the cell safer), any other its no-request default.

    Ports:
      <input> (output), per input: the commanded code.
    """

    def __init__(self, entity, inputs: list[str], clock: LiveClock, time_step: float, stale_after: float):
        super().__init__()
        from cellsim.channels import NO_VALUE, number_type
        from cellsim.vocabulary import SafetyMode

        self.set_name(f"{entity.module}.command_source")
        self.inputs = list(inputs)
        self.types = [entity.input_types.get(name, number_type(None)) for name in self.inputs]
        self.safe = [
            float(SafetyMode.STOPPED.code) if t.kind == "enum" and t.enum is SafetyMode else float(entity.input_defaults.get(name, NO_VALUE))
            for name, t in zip(self.inputs, self.types)
        ]
        self.clock, self.stale_after = clock, stale_after
        self.inbox: queue.SimpleQueue = queue.SimpleQueue()
        self.rejected = 0
        self._values = [self.DeclareDiscreteState(np.array([v])) for v in self.safe]
        self._memory = self.DeclareDiscreteState(np.array([-np.inf]))  # wall time of the last command taken
        for name, group in zip(self.inputs, self._values):
            self.DeclareStateOutputPort(name, group)
        self.DeclarePeriodicDiscreteUpdateEvent(entity.period, entity.period - time_step, self._drain)

    def deliver(self, payload: bytes) -> None:
        self.inbox.put(payload)

    def _drain(self, context, xd) -> None:
        from cellsim.live.codec import decode_command

        (last_wall,) = context.get_discrete_state(self._memory).get_value()
        taken = None
        for payload in _received(self.inbox):
            try:
                wall, codes = decode_command(payload, self.inputs, self.types)
            except CodecError:
                self.rejected += 1
                continue
            if wall <= last_wall:
                self.rejected += 1
                continue
            taken, last_wall = codes, wall
        if taken is not None:
            xd.get_mutable_vector(self._memory).SetFromVector([last_wall])
        elif context.get_time() - self.clock.sim_time(last_wall) > self.stale_after:
            taken = self.safe  # the supervisor is gone: fail safe
        if taken is not None:
            for group, value in zip(self._values, taken):
                xd.get_mutable_vector(group).SetFromVector([value])
