"""The base of cellsim's modules: a periodic LeafSystem whose outputs are channels.

Every module (entity, behaviour, service) is a small Drake LeafSystem that updates
its discrete state in one periodic event. Each channel it publishes is a
discrete-state group exposed through ``DeclareStateOutputPort``, so reading it
costs no Python at all: the robot plant, stepping every few ms, never calls back into the
module, and the module's cost scales with its own update rate.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector, EventStatus, InputPort, LeafSystem, OutputPort

from cellsim.channels import ChannelSpec, ChannelType, RecordPolicy


UNCHANGED = EventStatus.DidNothing()
"""What an update that wrote nothing returns (``CellSystem.update``)."""


class CellSystem(LeafSystem):
    """A module of the cell, updated every ``period`` seconds from t = 0.

    Subclasses declare channels, inputs and internal state in ``__init__`` and
    implement ``update(context, xd)``, reading inputs and their own current state
    from ``context`` and writing the next state into ``xd`` (DiscreteValues).
    Groups not written keep their value. An update that writes nothing may return
    ``UNCHANGED``: Drake then leaves the module's state, and everything computed from
    it, as it was (a module updated at every plant step that mostly has nothing to do).
    """

    def __init__(self, module: str, period: float):
        super().__init__()
        if period <= 0:
            raise ValueError(f"{module}: update period must be positive, got {period}")
        self.set_name(module)
        self.module = module
        self.period = float(period)
        self.channels: list[tuple[ChannelSpec, OutputPort]] = []
        self.input_types: dict[str, ChannelType] = {}
        self.input_defaults: dict[str, float] = {}
        self._groups: dict[str, int] = {}
        self.offset = 0.0
        self.DeclarePeriodicDiscreteUpdateEvent(self.period, 0.0, self._on_update)

    # -- declarations -------------------------------------------------------
    def declare_channel(
        self,
        signal: str,
        ctype: ChannelType,
        initial,
        *,
        record: RecordPolicy = "on_change",
        description: str = "",
    ) -> int:
        """Declare a published channel ``<module>.<signal>``; returns its state group.

        The recorder looks at it at every update of the module (its period): a channel is never recorded
        less often than its publisher can change it, so a check judges the values a reader acted on.
        """
        group = self.declare_state(signal, ctype.encode(initial))
        port = self.DeclareStateOutputPort(signal, group)
        spec = ChannelSpec(self.module, signal, ctype, self.period, record, description, self.offset)
        self.channels.append((spec, port))
        return group

    def declare_state(self, name: str, initial):
        """Declare an internal discrete-state group (not published)."""
        if name in self._groups:
            raise ValueError(f"{self.module}: state '{name}' declared twice")
        group = self.DeclareDiscreteState(BasicVector(np.atleast_1d(np.asarray(initial, float))))
        self._groups[name] = group
        return group

    def declare_input(
        self, name: str, size: int = 1, ctype: ChannelType | None = None, default: float | None = None
    ) -> InputPort:
        """A vector input.

        ``ctype`` says what it expects, so the builder can check what is wired to
        it; ``default`` is the value it gets when the scenario wires nothing to it.
        """
        if ctype is not None:
            self.input_types[name] = ctype
        if default is not None:
            self.input_defaults[name] = default
        return self.DeclareVectorInputPort(name, size)

    def group(self, name: str) -> int:
        """The discrete-state group of a channel or internal state declared under ``name``."""
        return self._groups[name]

    def decide_after(self, offset: float) -> None:
        """Update at ``offset`` (s, less than the period) after each multiple of the period, not at it.

        For a live twin's deciding modules (its behaviours): the entities take the physical samples at the
        multiples, and a module updated then would read them only at its next update (Drake's updates at one
        time read the state before any of them), one period that only adds delay. One plant step later, it
        decides on the samples of its own period. Called by the builder before the recorder is built: the
        module's channels say their offset, and the record stamps each value at the update that wrote it.
        """
        from dataclasses import replace

        if not 0.0 < offset < self.period:
            raise ValueError(f"{self.module}: an update offset must lie within the period, got {offset}")
        self.offset = float(offset)
        self.DeclarePeriodicDiscreteUpdateEvent(self.period, self.offset, self._on_offset_update)
        self.channels = [(replace(spec, offset=self.offset), port) for spec, port in self.channels]

    # -- update -------------------------------------------------------------
    def _on_update(self, context, xd):
        if self.offset:  # the updates are at the offset (``decide_after``)
            return UNCHANGED
        return self.update(context, xd)

    def _on_offset_update(self, context, xd):
        return self.update(context, xd)

    def update(self, context, xd) -> None:  # pragma: no cover - abstract
        """The module's periodic update: read inputs and state from ``context``, write the next state into ``xd``."""
        raise NotImplementedError


def read_scalar(context, group: int) -> float:
    return context.get_discrete_state(group).GetAtIndex(0)


def write_scalar(xd, group: int, value: float) -> None:
    xd.get_mutable_vector(group).SetAtIndex(0, value)


def write_changed(xd, groups: list[int], values: list[float], previous: list[float]) -> None:
    """Write each scalar group whose value differs from what it held (a module's mirror of them)."""
    for group, value, old in zip(groups, values, previous):
        if value != old:
            xd.get_mutable_vector(group).SetAtIndex(0, value)


def hazard_phases(modules) -> dict[str, dict]:
    """Every hazard channel of a cell's modules (``modules``: its systems), with its risk model's
    initial and mishap phases: what the summary, the black box's metadata and a dashboard read."""
    found = {}
    for system in modules:
        found.update(getattr(system, "hazard_phases", dict)())
    return found
