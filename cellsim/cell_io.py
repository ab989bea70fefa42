"""How a cell meets the physical world: the I/O choice its one builder takes.

``cellsim.diagrams.cell.build_cell(sf, io=...)`` is the only place that decides, from one
of these, what feeds each entity's physical samples and where the cell's
channels and commands go; the diagram exports the same channel and command
ports whichever is chosen (cf. ``MakeHardwareStation(scenario, hardware=...)``).

* :class:`Simulated`: no physical twin. Every entity's ``physical_sample`` reads
  stale (one in shadow or twin mode fails safe); headless, as fast as it goes.
* :class:`Replayed`: a black box plays the physical twin of every entity whose
  sample fields it recorded (a recording of the real cell, or another run).
* :class:`Live`: the twin beside the real cell, paced to the wall clock, on Zenoh:
  samples from the physical keys, channels and commands published, twin modes
  switched on request, its status every second.
* :class:`Emulated`: the physical cell played where no hardware is, paced to the
  wall clock: every entity its digital model, its samples published on its physical
  key (or, with ``devices``, as its CAN device's frames and its robot controller's
  state stream); ``commanded_by_twin`` leaves the scenario's supervisors out and
  takes the twin's commands in their place.
"""

from __future__ import annotations

import math
import queue
from dataclasses import dataclass, field
from pathlib import Path


@dataclass(frozen=True)
class Simulated:
    """No physical twin: a simulated run."""


@dataclass(frozen=True)
class Replayed:
    """A recorded black box as the physical twin."""

    blackbox: Path
    time_offset: float = 0.0
    """The recording is played this many seconds late (s)."""
    entities: tuple[str, ...] | None = None
    """The entities it plays (default: every one whose sample fields it recorded)."""


@dataclass
class Live:
    """The twin beside the real cell, on a Zenoh session."""

    session: object
    wait_physical: float = 10.0
    """Seconds to wait, before the clock starts, for samples of every entity in shadow or twin mode."""
    process: str = "twin"
    foxglove: object | None = None
    """A ``cellsim.foxglove.FoxgloveFeed`` to serve the twin on as well, or None."""


@dataclass
class Fault:
    """A fault injected into one entity's outlet from ``at`` to ``until`` (simulated s)."""

    entity: str
    kind: str
    at: float = 0.0
    until: float = math.inf


@dataclass
class FaultSchedule:
    """The emulator's faults: given at start (``--fault``) or requested at run time (a Zenoh query)."""

    faults: list[Fault] = field(default_factory=list)
    requests: queue.SimpleQueue = field(default_factory=queue.SimpleQueue)
    """(entity, kind, seconds) requested on the network thread, started at the next sample."""

    def __call__(self, entity: str, t: float) -> str | None:
        """The fault on ``entity`` at simulated time ``t`` (the latest given, if several), or None."""
        while True:
            try:
                name, kind, seconds = self.requests.get_nowait()
            except queue.Empty:
                break
            self.faults.append(Fault(name, kind, t, t + seconds))
        active = [f.kind for f in self.faults if f.entity == entity and f.at - 1e-9 <= t < f.until - 1e-9]
        return active[-1] if active else None

    def to_json(self) -> list[dict]:
        return [{**f.__dict__, "until": None if f.until == math.inf else f.until} for f in self.faults]


@dataclass
class Emulated:
    """The physical cell played in real time, on a Zenoh session (and a CAN bus, with ``devices``)."""

    session: object
    commanded_by_twin: bool = False
    rates: dict[str, float] = field(default_factory=dict)
    """Entity name -> samples per second, instead of one per update period (a robot's state at 500 Hz)."""
    devices: object = None
    """The cell's devices speaking their real protocols (``cellsim.bridges.devices.EmulatedDevices``), or None:
    every entity on its physical key."""
    faults: FaultSchedule = field(default_factory=FaultSchedule)
    process: str = "emulator"


CellIO = Simulated | Replayed | Live | Emulated
SIMULATED = Simulated()


def paced(io: CellIO) -> bool:
    """Whether a cell with this I/O runs paced to the wall clock."""
    return isinstance(io, (Live, Emulated))
