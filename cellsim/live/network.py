"""The network side of a live or emulated cell, as its builder made it: clock, start, figures, close.

The builder (``cellsim.diagrams.cell``) adds the Zenoh systems to the diagram
(``cellsim.live.systems``) and gathers here what the run needs of them beyond
``AdvanceTo``: the clock to start, the physical samples to wait for before
starting it, the figures for the black box's metadata, and what to undeclare.
"""

from __future__ import annotations

import sys
import threading
from dataclasses import dataclass, field

from cellsim.live.systems import LiveClock, LiveStatus


@dataclass
class NetworkIO:
    process: str
    clock: LiveClock
    status: LiveStatus
    wait_physical: float = 0.0
    awaited: list[str] = field(default_factory=list)
    """Entities whose samples are waited for before the clock starts (in shadow or twin mode)."""
    figures: dict = field(default_factory=dict)
    """Name -> a callable giving a figure for the metadata (rejected samples, faults...)."""
    handles: list = field(default_factory=list)
    """Zenoh subscribers, publishers, queryables, tokens: undeclared by ``close``."""
    closers: list = field(default_factory=list)
    """Anything else to close (the emulated CAN devices)."""
    primed: list = field(default_factory=list)
    """Sources (``prime(root_context)``) that take what arrived before the clock started, as their state at t = 0."""

    def __post_init__(self):
        self._heard = {name: 0 for name in self.awaited}
        self._all_heard = threading.Event()
        if not self.awaited:
            self._all_heard.set()

    def heard(self, entity: str) -> None:
        """On a network thread: a sample of ``entity`` arrived (counted until all were heard)."""
        if not self._all_heard.is_set() and entity in self._heard:
            self._heard[entity] += 1
            if all(self._heard.values()):
                self._all_heard.set()

    def start(self, root_context=None) -> None:
        """Start the clock once every awaited entity has been heard (or ``wait_physical`` passed), so a
        twin started before the cell does not record a start-up spent failing safe as evidence; then the
        sources take what arrived into ``root_context`` (its state at t = 0): the entities' first updates read
        their physical twins, not the sources' initial stale state."""
        if not self._all_heard.wait(self.wait_physical):
            silent = [n for n, count in self._heard.items() if not count]
            print(f"cellsim live: no physical samples from {', '.join(silent)} within {self.wait_physical:g} s; "
                  "starting anyway, failing safe", file=sys.stderr)
        self.clock.start()
        if root_context is not None:
            for source in self.primed:
                source.prime(root_context)

    def metadata(self) -> dict:
        return {"process": self.process, "wall_at_zero": self.clock.wall_at_zero,
                "pacing_lag_s": self.status.figures(), **{name: get() for name, get in self.figures.items()}}

    def close(self) -> None:
        for handle in self.handles:
            try:
                handle.undeclare()
            except Exception:  # noqa: BLE001 - closing anyway
                pass
        self.handles.clear()
        for close in self.closers:
            close()
        self.closers.clear()
