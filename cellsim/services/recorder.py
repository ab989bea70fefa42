"""The message snooper: a Drake system that writes every channel's messages to the black box.

It has one input port per channel, named after the channel. Channels are
grouped by how often they are to be read (their publisher's period, or their
``record_period``), and each group is read by a periodic publish event at that
rate, so nothing is read more often than it can change.

Drake dispatches a periodic publish at time t *before* the discrete updates at
t, so what the recorder reads at t was produced by the publisher's update at
t - period (its latest). Messages are stamped with that time: the simulated
time at which the value was published. The initial values are read when the
simulator initialises, at t = 0.
"""

from __future__ import annotations

import json
from collections import defaultdict

from pydrake.systems.framework import LeafSystem

from cellsim.channels import ChannelSpec
from cellsim.services.blackbox import BlackBoxWriter


class Recorder(LeafSystem):
    """Input ports: one per channel (``<module>.<signal>``), the channel's vector."""

    def __init__(self, module: str, channels: list[ChannelSpec]):
        super().__init__()
        self.set_name(module)
        self.writer: BlackBoxWriter | None = None
        self.specs = channels
        groups = defaultdict(list)
        for spec in channels:
            port = self.DeclareVectorInputPort(spec.name, spec.type.size)
            groups[round(spec.sample_period, 9)].append(
                (spec.name, spec.module, port, spec.type.decode, spec.record == "on_change", spec.period)
            )
        self._last: dict[str, tuple] = {}
        # One publish event at the shortest period reads the groups that are due:
        # one callback per tick instead of one per group.
        base = min(groups) if groups else 1.0
        self._schedule = [(max(1, round(period / base)), self._publisher(members)) for period, members in sorted(groups.items())]
        self.DeclarePeriodicPublishEvent(base, 0.0, self._publish_due)
        self._base = base

    def _publish_due(self, context):
        tick = round(context.get_time() / self._base)
        for every, publish in self._schedule:
            if tick % every == 0:
                publish(context)

    def attach(self, writer: BlackBoxWriter) -> None:
        """Write to ``writer`` from now on (a diagram is built before its output exists)."""
        self.writer = writer
        writer.add_channels(self.specs)

    def _publisher(self, members):
        last, dumps = self._last, json.dumps

        def publish(context):
            if self.writer is None:
                return
            append = self.writer.append
            now = context.get_time()
            for name, source, port, decode, on_change, period in members:
                vector = port.Eval(context)
                if on_change:
                    key = vector[0] if len(vector) == 1 else tuple(vector)
                    if last.get(name) == key:
                        continue
                    last[name] = key
                t = round(now - period, 9) if now >= period else 0.0
                append((t, name, source, dumps({"value": decode(vector)})))

        return publish
