"""Sources of physical-twin samples, and the one place that wires them.

Every entity has a ``physical_sample`` input ``[t, valid, *fields]``. What
feeds it decides whether the entity can shadow a physical twin:

* nothing: the input is fixed to "no sample" (``NO_SAMPLE``); an entity in
  shadow or twin mode then reads its physical link as stale and fails safe.
* ``BlackBoxReplay``: replays channels of a recorded black box as the physical
  twin's samples (a recorded real cell, or another simulated run).
* ``cellsim.live.sources.ZenohSampleSource``: samples from Zenoh (the emulator's,
  or the bridge daemon's from the real cell's CAN devices and robot controller).

``connect_physical_twins`` is the single place where a diagram's entities are
connected to their sources.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import DiagramBuilder, LeafSystem

from cellsim.channels import ChannelType
from cellsim.services.blackbox import BlackBox


def no_sample(size: int) -> np.ndarray:
    """The value of a physical_sample port of ``size`` that says "no sample" (valid = 0)."""
    value = np.zeros(size)
    value[0] = -np.inf
    return value


class BlackBoxReplay(LeafSystem):
    """Replays recorded channels as an entity's physical samples.

    ``fields`` lists, for each sample field of the entity, ``(channel, element,
    type)``: the recorded channel, the element of its vector (0 for scalars), and
    its ChannelType (to encode enum names back into codes). Output
    ``physical_sample`` is ``[t_sample, 1, *fields]`` where ``t_sample`` is the
    time of the latest recorded message at or before ``t - time_offset``; before
    the first message of every field the sample is invalid.
    """

    def __init__(self, blackbox: BlackBox, fields: list[tuple[str, int, ChannelType]], period: float, time_offset: float = 0.0):
        super().__init__()
        self.time_offset = time_offset
        self._series = []
        for channel, element, ctype in fields:
            series = blackbox.series(channel)
            codes = np.array([ctype.encode(v)[element] for v in series.values], float)
            self._series.append((series.times, codes))
        self._state = self.DeclareDiscreteState(2 + len(fields))
        self.DeclareStateOutputPort("physical_sample", self._state)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)

    def _update(self, context, xd):
        # The replayed twin's whole state is known at every instant, so a sample is
        # fresh (stamped now) once every field has a recorded value.
        t = context.get_time() - self.time_offset
        sample = np.zeros(2 + len(self._series))
        sample[0], sample[1] = context.get_time(), 1.0
        for i, (times, codes) in enumerate(self._series):
            k = int(np.searchsorted(times, t, side="right")) - 1
            if k < 0:
                sample[0], sample[1] = -np.inf, 0.0
                break
            sample[2 + i] = codes[k]
        xd.get_mutable_vector(self._state).SetFromVector(sample)


def connect_physical_twins(
    builder: DiagramBuilder, entities: dict, sources: dict[str, LeafSystem] | None = None
) -> list[tuple]:
    """Connect each entity's physical_sample input to its source.

    Returns ``(port, value)`` pairs for the inputs with no source: the caller
    fixes them to "no sample" in the context (a fixed input costs nothing per
    step, a source system would).
    """
    sources = sources or {}
    unknown = set(sources) - set(entities)
    if unknown:
        raise KeyError(f"physical-twin sources for unknown entities: {', '.join(sorted(unknown))}")
    fixed = []
    for name, entity in entities.items():
        source = sources.get(name)
        if source is None:
            fixed.append((entity.physical_sample_port, no_sample(entity.physical_sample_port.size())))
            continue
        if source not in builder.GetSystems():
            builder.AddSystem(source)
        builder.Connect(source.get_output_port(), entity.physical_sample_port)
    return fixed
