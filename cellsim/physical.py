"""Physical-twin samples that do not come from the network: none, or a black box replayed.

Every entity has a ``physical_sample`` input ``[t, link, *fields]``. The builder
(``cellsim.diagrams.cell``) decides what feeds it:

* nothing (a simulated run): the input is fixed to :func:`no_sample`; an entity in
  shadow or twin mode then reads its link stale and fails safe.
* :class:`BlackBoxReplay`: replays channels of a recorded black box as the physical
  twin's samples (a recorded real cell, or another simulated run).
* Zenoh (``cellsim.live.systems.ZenohSampleSource``): the emulator's samples, or the
  bridge daemon's from the real cell's CAN devices and robot controller.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import LeafSystem

from cellsim.channels import ChannelType
from cellsim.blackbox import BlackBox, run_end
from cellsim.vocabulary import PhysicalLink

_OK, _STALE = float(PhysicalLink.OK.code), float(PhysicalLink.STALE.code)


def no_sample(size: int) -> np.ndarray:
    """The value of a physical_sample port of ``size`` that says "no sample": stale since ever."""
    value = np.zeros(size)
    value[0], value[1] = -np.inf, _STALE
    return value


def replay_fields(entity, blackbox: BlackBox) -> list[tuple[str, int, ChannelType]] | None:
    """``(channel, element, type)`` per sample field of ``entity`` as ``blackbox`` recorded them
    (``entity.recorded_as``), or None when one of them was not recorded."""
    recorded = blackbox.channels()
    types = {spec.name: spec.type for spec, _ in entity.channels}
    fields = []
    for name in entity.sample_fields:
        channel, element = entity.recorded_as(name)
        if channel not in recorded or channel not in types:
            return None
        fields.append((channel, element, types[channel]))
    return fields


class BlackBoxReplay(LeafSystem):
    """Replays recorded channels as an entity's physical samples.

    ``fields`` lists, for each sample field of the entity, ``(channel, element,
    type)``: the recorded channel, the element of its vector (0 for scalars), and
    its ChannelType (to encode enum names back into codes). Output
    ``physical_sample`` is ``[t, link, *fields]``: ``t`` now and link ok once every
    field has a recorded value at or before ``t - time_offset`` (the replayed twin's
    whole state is known at every instant), link stale before that, and after the
    record's end (its last values are no news: a replay that ran out is a silent device).
    """

    def __init__(self, blackbox: BlackBox, fields: list[tuple[str, int, ChannelType]], period: float, time_offset: float = 0.0):
        super().__init__()
        self.time_offset = time_offset
        self.end = run_end(blackbox, blackbox.metadata())[0]
        """s: where the record ends, on its own clock."""
        self._series = []
        for channel, element, ctype in fields:
            series = blackbox.series(channel)
            codes = np.array([ctype.encode(v)[element] for v in series.values], float)
            self._series.append((series.times, codes))
        self._state = self.DeclareDiscreteState(no_sample(2 + len(fields)))
        self.DeclareStateOutputPort("physical_sample", self._state)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)

    def _update(self, context, xd):
        t = context.get_time() - self.time_offset
        sample = np.zeros(2 + len(self._series))
        if t > self.end + 1e-9:
            xd.get_mutable_vector(self._state).SetFromVector(no_sample(len(sample)))
            return
        sample[0], sample[1] = context.get_time(), _OK
        for i, (times, codes) in enumerate(self._series):
            k = int(np.searchsorted(times, t, side="right")) - 1
            if k < 0:
                sample = no_sample(len(sample))
                break
            sample[2 + i] = codes[k]
        xd.get_mutable_vector(self._state).SetFromVector(sample)
