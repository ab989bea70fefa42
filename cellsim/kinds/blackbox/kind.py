"""The blackbox kind: the cell's recorder (``cellsim.recorder``), tapping every channel, built last."""

from __future__ import annotations

from cellsim.kinds.blackbox.config import RecorderConfig
from cellsim.recorder import Recorder
from cellsim.kind import ModuleKind


class BlackBoxKind(ModuleKind):
    """The black box: a scenario listing it records every message of the run."""

    name = "blackbox"
    section = "services"
    config = RecorderConfig
    summary = "The message snooper: records every message of every channel to the run's SQLite black box."
    stage = 30

    def build(self, cell, name, cfg):
        return build_recorder(cell, name, cfg)

    def abstraction(self, abstract, name, cfg):
        """It only watches: nothing of it enters the abstract cell."""
        from cellsim.verify.model import Observer

        return Observer()


def build_recorder(cell, name: str, cfg) -> None:
    """Tap every channel of the cell (the recorder is built last); nothing when not recording."""
    if cell.record:
        cell.recorder = Recorder(cell.builder, name, list(cell.channels().values()))
