"""The process kind's configuration: the steps, the robot they move, restarts on request."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from cellsim.config.typed_yaml import FieldError
from cellsim.config.units import Period, PositiveSeconds, Seconds


def check_steps(names: list[str], restart_on_request: dict[str, str]) -> None:
    """A process's steps: at least one, names distinct, restarts naming steps (FieldError)."""
    if not names:
        raise FieldError("steps", "needs at least one step")
    if len(set(names)) != len(names):
        raise FieldError("steps", "step names must differ")
    for activity, step in restart_on_request.items():
        if step not in names:
            raise FieldError(f"restart_on_request.{activity}", f"'{step}' is not a step")


@dataclass
class Operation:
    """A machine kept working for a time."""

    machine: str
    """The machine (one without a cycle_time: it works while commanded)."""
    seconds: PositiveSeconds
    """How long it must work (s): counted while it reports its working activity."""


@dataclass
class ProcessStep:
    """One step: exactly one of move_to, dwell, start, wait_for, wait_until, operate; and the robot's activity."""

    name: str
    """The step's name: the controller's step channel reads it."""
    activity: str
    """The robot activity this step is (one of the robot's activities)."""
    move_to: str | None = None
    """A named pose of the robot to move to."""
    dwell: Seconds = 0.0
    """Seconds to stay put."""
    start: str | None = None
    """A machine whose cycle to start (the process goes on at once)."""
    wait_for: str | None = None
    """A machine whose cycle to wait for."""
    wait_until: str | None = None
    """A condition over the cell's channels (no temporal operators) to wait for, e.g.
    ``loader.reached_pose == clear``."""
    operate: Operation | None = None
    """A machine to keep working for some seconds ({machine, seconds})."""

    def __post_init__(self):
        given = [k for k in ("move_to", "start", "wait_for", "wait_until", "operate") if getattr(self, k) is not None]
        given += ["dwell"] if self.dwell else []
        if len(given) != 1:
            raise FieldError("name", f"step '{self.name}' must have exactly one of move_to, dwell, start, wait_for, "
                                     "wait_until, operate")

    @property
    def machine(self) -> str | None:
        """The machine this step starts, waits for or operates."""
        return self.start or self.wait_for or (self.operate.machine if self.operate else None)


@dataclass
class ProcessConfig:
    """The cell's process: steps of the robot and its machines, repeated."""

    kind: Literal["process"]
    steps: list[ProcessStep]
    """The steps, in order."""
    robot: str = "robot"
    """The robot entity the process moves."""
    restart_on_request: dict[str, str] = field(default_factory=dict)
    """Robot activity requested by the safety controller -> step the process restarts from.
    Any other activity requested pauses the process, and the robot reports it."""
    period: Period = 0.04
    """Update period (s)."""

    def __post_init__(self):
        check_steps([s.name for s in self.steps], self.restart_on_request)

    @property
    def machines(self) -> list[str]:
        """The machines the steps start, wait for or operate, in order of first mention."""
        return list(dict.fromkeys(step.machine for step in self.steps if step.machine is not None))

    @property
    def driven(self) -> list[str]:
        """The machines the steps start or operate: the process drives their command input (one process
        per machine; others may wait_for it)."""
        return list(dict.fromkeys(s.machine for s in self.steps if s.start or s.operate))

    @property
    def cycled(self) -> list[str]:
        """The machines whose cycles the steps start or wait for (whose busy they read)."""
        return list(dict.fromkeys(s.machine for s in self.steps if s.start or s.wait_for))

    @property
    def operated(self) -> list[str]:
        """The machines the steps operate (whose activity they read)."""
        return list(dict.fromkeys(s.machine for s in self.steps if s.operate))
