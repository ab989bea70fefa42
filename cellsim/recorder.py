"""The message snooper: every channel of the cell, logged in C++ and written to the black box.

All channels are multiplexed into one vector that a Drake ``VectorLogSink``
samples at the shortest channel period; no Python runs while the simulator
steps. ``drain`` (called by the simulation loop after each chunk of simulated
time, and at the end) turns the new samples into messages:

* a channel is looked at at every update of its publisher (its ``period``): never
  less often, so the record holds every value a reader of the channel could have
  acted on, and never more often than it can change;
* ``on_change`` channels give a message when their value differs from the
  last one written, ``every_sample`` channels give one every time they are looked at.

Drake dispatches a periodic publish at time t *before* the discrete updates at
t, so a sample taken at t holds what the publisher's update at t - period
produced (at t - period + offset, for a publisher updated at an offset within
its period). Messages are stamped with that time: the simulated time at which the
value was published. The sample taken at t = 0 holds the initial state, which
the publishers' updates at t = 0 replace at once: the next sample (or, for a
run that ends before it, the final drain's) is stamped 0 too, so the initial one
is dropped (it held for no time) and each channel has one message at t = 0. A
publisher updated at an offset keeps its initial state until then: that one is
written, at 0.

A run that stops between two samples of a channel (a live run stopped, a run
interrupted) would lose what its publisher's last update wrote: the final drain
takes the current values as the sample at the next tick, stamped, as any, with
the time of that update.

Every drain is committed with the simulated time it reached (``recorded_until``
in the metadata), so a killed run keeps everything up to its last drain.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import DiagramBuilder, OutputPort
from pydrake.systems.primitives import Multiplexer, VectorLogSink

from cellsim.channels import ChannelSpec
from cellsim.codec import encode_record
from cellsim.blackbox import BlackBoxWriter


DRAIN_PERIOD = 1.0
"""The simulation loop drains (and commits) the recorder every simulated second:
a killed run loses at most the last second of its record."""


class Recorder:
    """Adds the logging systems for ``channels`` to ``builder``; writes messages on ``drain``."""

    def __init__(self, builder: DiagramBuilder, name: str, channels: list[tuple[ChannelSpec, OutputPort]]):
        self.name = name
        self.specs = [spec for spec, _ in channels]
        self.writer: BlackBoxWriter | None = None
        self.base = base_period([spec.period for spec in self.specs])
        # Channels in the order the messages of one instant are written: by
        # sample period, then as declared. Channels of one period are multiplexed
        # into one log sampled at that period (a module updated at every plant step
        # does not make every channel be logged that often); within it, channels
        # recorded alike form a group, decoded together.
        order = sorted(range(len(self.specs)), key=lambda i: (round(self.specs[i].period, 9), i))
        by_period: dict[int, list[int]] = {}
        for i in order:
            by_period.setdefault(round(self.specs[i].period / self.base), []).append(i)
        self._logs: list[tuple] = []  # (sink, its groups)
        for every, members in by_period.items():
            sizes = [self.specs[i].type.size for i in members]
            suffix = "" if len(by_period) == 1 else f"_{every * self.base:g}s"
            mux = builder.AddNamedSystem(f"{name}.multiplexer{suffix}", Multiplexer(sizes))
            for k, i in enumerate(members):
                builder.Connect(channels[i][1], mux.get_input_port(k))
            sink = builder.AddNamedSystem(f"{name}.log{suffix}", VectorLogSink(sum(sizes), every * self.base))
            builder.Connect(mux.get_output_port(0), sink.get_input_port())
            offsets = np.cumsum([0] + sizes)
            groups: dict[tuple, list[int]] = {}
            for k, i in enumerate(members):
                groups.setdefault((self.specs[i].record, self.specs[i].offset), []).append(k)
            self._logs.append((sink, [
                _Group(every, record, [(order.index(members[k]), self.specs[members[k]], offsets[k], offsets[k + 1])
                                       for k in ks], offset)
                for (record, offset), ks in groups.items()]))

    def attach(self, writer: BlackBoxWriter) -> None:
        """Write to ``writer`` from now on (a diagram is built before its output exists)."""
        self.writer = writer
        writer.add_channels(self.specs)

    def drain(self, root_context, *, final: bool = False) -> int:
        """Write and commit the messages of the samples logged since the last drain; returns how many.

        The commit records the simulated time reached as ``recorded_until``.
        ``final`` marks the last drain of a run, which also writes what the
        publishers' last updates wrote that no sample has taken yet.
        """
        rows: list[tuple] = []  # (sample's tick, channel rank, row)
        for sink, groups in self._logs:
            log = sink.FindMutableLog(root_context)
            if log.num_samples():
                times, data = log.sample_times().copy(), log.data().copy()
                log.Clear()
                ticks = np.rint(times / self.base).astype(np.int64)
                for group in groups:
                    group.decode(ticks, times, data, rows)
            if final:
                current = sink.get_input_port().Eval(sink.GetMyContextFromRoot(root_context))
                for group in groups:
                    group.decode_final(current, root_context.get_time(), self.base, rows)
        if self.writer is None:
            return 0
        rows.sort(key=lambda r: (r[0], r[1]))
        for _, _, row in rows:
            self.writer.append(row)
        self.writer.commit(recorded_until=root_context.get_time())
        return len(rows)


GRID = 1e-9
"""Periods are whole numbers of nanoseconds (a period off that grid is rounded to it)."""


def base_period(periods: list[float]) -> float:
    """The log's tick (s): the greatest common divisor of the channels' periods, so that every channel is
    looked at on a whole number of ticks, exactly at each of its updates (the shortest period would round
    a period of 0.05 s to 0.04 s on ticks of 0.02 s)."""
    import math

    ticks = 0
    for period in periods:
        ticks = math.gcd(ticks, max(1, round(period / GRID)))
    return ticks * GRID


_AFTER_EVERY_SAMPLE = 2**62
"""Sort key of the final drain's messages: after those of every logged sample."""


class _Group:
    """Channels sampled every ``every`` base periods and recorded alike, decoded as one block."""

    def __init__(self, every: int, record: str, channels: list[tuple[int, ChannelSpec, int, int]], offset: float = 0.0):
        self.every = every
        self.offset = offset  # the publishers update at this offset within their period (s)
        self.on_change = record == "on_change"
        self.last_tick = -1  # the newest sample decoded (none yet)
        self.channels = channels  # (rank, spec, first row, end row) in the logged vector
        self.rows = np.concatenate([np.arange(a, b) for _, _, a, b in channels])
        local = np.cumsum([0] + [b - a for _, _, a, b in channels])
        self.starts = local[:-1]
        self.local = [slice(int(a), int(b)) for a, b in zip(local[:-1], local[1:])]
        self.last = np.full(len(self.rows), np.nan)  # nothing recorded yet: the first sample is a change
        # coded channels (enum, bool) have few payloads: encode each once
        self.payloads: list[dict | None] = [{} if spec.type.size == 1 and spec.type.kind in ("enum", "bool") else None
                                            for _, spec, _, _ in channels]

    def decode(self, ticks: np.ndarray, times: np.ndarray, data: np.ndarray, out: list) -> None:
        due = np.flatnonzero(ticks % self.every == 0)
        if len(due) == 0:
            return
        self.last_tick = int(ticks[due[-1]])
        if ticks[due[0]] == 0 and not self.offset:  # the initial state: the sample at tick ``every`` (or the final one), stamped 0 too, replaces it
            due = due[1:]
        if len(due):
            self._decode(due, times, data, out, ticks)

    def decode_final(self, current: np.ndarray, t: float, base: float, out: list) -> None:
        """At the end of a run (``t``): the values its publishers' last updates wrote, which no sample has
        taken yet (a run stopped between two of its samples), as if sampled at the next tick."""
        tick = int(np.ceil(t / base / self.every - 1e-9)) * self.every
        if tick <= self.last_tick:
            return  # sampled already: a run that ends on its grid
        found: list = []
        self._decode(np.array([0]), np.array([tick * base]), current.reshape(-1, 1), found)
        out.extend((_AFTER_EVERY_SAMPLE, rank, row) for _, rank, row in found)

    def _decode(self, due: np.ndarray, times: np.ndarray, data: np.ndarray, out: list, ticks=None) -> None:
        block = data[np.ix_(self.rows, due)]
        if self.on_change:
            with_last = np.concatenate((self.last[:, None], block), axis=1)
            differs = with_last[:, 1:] != with_last[:, :-1]
            changed = np.logical_or.reduceat(differs, self.starts, axis=0)
            self.last = block[:, -1].copy()
            channel_of, sample_of = np.nonzero(changed)
        else:
            channel_of, sample_of = np.divmod(np.arange(len(self.channels) * len(due)), len(due))
        for c, j in zip(channel_of.tolist(), sample_of.tolist()):
            rank, spec, _, _ = self.channels[c]
            k = int(due[j])
            t = times[k] - spec.period + self.offset
            t = round(float(t), 9) if t > 0 else 0.0
            values = block[self.local[c], j]
            cache = self.payloads[c]
            if cache is None:
                payload = encode_record(spec.type.decode(values))
            else:
                code = float(values[0])
                payload = cache.get(code)
                if payload is None:
                    payload = cache[code] = encode_record(spec.type.decode(values))
            out.append((k if ticks is None else int(ticks[k]), rank, (t, spec.name, spec.module, payload)))
