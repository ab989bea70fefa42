"""The message snooper: every channel of the cell, logged in C++ and written to the black box.

All channels are multiplexed into one vector that a Drake ``VectorLogSink``
samples at the shortest channel period; no Python runs while the simulator
steps. ``drain`` (called by the simulation loop after each chunk of simulated
time, and at the end) turns the new samples into messages:

* a channel is looked at every ``sample_period`` (its publisher's period, or
  its ``record_period``), so nothing is read more often than it can change;
* ``on_change`` channels give a message when their value differs from the
  last one written, ``every_sample`` channels give one every time they are looked at.

Drake dispatches a periodic publish at time t *before* the discrete updates at
t, so a sample taken at t holds what the publisher's update at t - period
produced. Messages are stamped with that time: the simulated time at which the
value was published. The initial values are sampled at t = 0.
"""

from __future__ import annotations

import json

import numpy as np
from pydrake.systems.framework import DiagramBuilder, OutputPort
from pydrake.systems.primitives import Multiplexer, VectorLogSink

from cellsim.channels import ChannelSpec
from cellsim.services.blackbox import BlackBoxWriter


class Recorder:
    """Adds the logging systems for ``channels`` to ``builder``; writes messages on ``drain``."""

    def __init__(self, builder: DiagramBuilder, name: str, channels: list[tuple[ChannelSpec, OutputPort]]):
        self.name = name
        self.specs = [spec for spec, _ in channels]
        self.writer: BlackBoxWriter | None = None
        sizes = [spec.type.size for spec in self.specs]
        self.base = min(spec.sample_period for spec in self.specs)
        mux = builder.AddNamedSystem(f"{name}.multiplexer", Multiplexer(sizes))
        for i, (_, port) in enumerate(channels):
            builder.Connect(port, mux.get_input_port(i))
        self.sink = builder.AddNamedSystem(f"{name}.log", VectorLogSink(sum(sizes), self.base))
        builder.Connect(mux.get_output_port(0), self.sink.get_input_port())
        offsets = np.cumsum([0] + sizes)
        # Channels in the order the messages of one instant are written: by
        # sample period, then as declared.
        order = sorted(range(len(self.specs)), key=lambda i: (round(self.specs[i].sample_period, 9), i))
        self._channels = [
            (
                self.specs[i],
                slice(int(offsets[i]), int(offsets[i + 1])),
                max(1, round(self.specs[i].sample_period / self.base)),
            )
            for i in order
        ]
        self._last: dict[str, np.ndarray] = {}

    def attach(self, writer: BlackBoxWriter) -> None:
        """Write to ``writer`` from now on (a diagram is built before its output exists)."""
        self.writer = writer
        writer.add_channels(self.specs)

    def drain(self, root_context) -> int:
        """Write the messages of the samples logged since the last drain; returns how many."""
        log = self.sink.FindMutableLog(root_context)
        times, data = log.sample_times().copy(), log.data().copy()
        log.Clear()
        if self.writer is None or len(times) == 0:
            return 0
        ticks = np.rint(times / self.base).astype(np.int64)
        rows: list[tuple] = []  # (sample index, channel rank, row)
        dumps = json.dumps
        for rank, (spec, rows_of, every) in enumerate(self._channels):
            due = np.flatnonzero(ticks % every == 0)
            if len(due) == 0:
                continue
            values = data[rows_of, :][:, due]
            if spec.record == "on_change":
                previous = self._last.get(spec.name)
                first = previous is None or not np.array_equal(values[:, 0], previous)
                changed = np.concatenate(([first], np.any(values[:, 1:] != values[:, :-1], axis=0)))
                self._last[spec.name] = values[:, -1].copy()
                picked = np.flatnonzero(changed)
            else:
                picked = np.arange(len(due))
            for j in picked:
                k = int(due[j])
                t = times[k] - spec.period
                t = round(float(t), 9) if t > 0 else 0.0
                payload = dumps({"value": spec.type.decode(values[:, j])})
                rows.append((k, rank, (t, spec.name, spec.module, payload)))
        rows.sort(key=lambda r: (r[0], r[1]))
        for _, _, row in rows:
            self.writer.append(row)
        return len(rows)
