"""The message snooper: a Drake system that writes every channel's messages to the black box.

It has one input port per channel, named after the channel. Channels are
grouped by how often they can change (their publisher's period, or their
``record_period``), and each group is read by a periodic publish event at that
rate, right after the publishers' updates at the same instant: every message is
stamped with the exact simulated time it was published, and nothing is read
more often than it can change.
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
                (spec.name, spec.module, port, spec.type.decode, spec.record == "on_change")
            )
        self._last: dict[str, tuple] = {}
        for period, members in sorted(groups.items()):
            self.DeclarePeriodicPublishEvent(period, 0.0, self._publisher(members))

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
            t = context.get_time()
            for name, source, port, decode, on_change in members:
                vector = port.Eval(context)
                if on_change:
                    key = tuple(vector)
                    if last.get(name) == key:
                        continue
                    last[name] = key
                append((t, name, source, dumps({"value": decode(vector)})))

        return publish
