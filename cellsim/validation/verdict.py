"""The one vocabulary of verdicts: a safety condition's on a run, and a run's over its conditions.

``Verdict`` is a ``str`` enum, so it is written to JSON (results.json, ``check --json``)
as its value. A condition's verdict is one of ``holds``, ``violated``,
``inconclusive`` (the run did not complete and its cut could change the verdict)
and ``missing data`` (it reads a variable never recorded); a run's is the worst of
its conditions' (``Verdict.of_run``), or ``failed`` when it could not be simulated or
checked. Where a page or a screen groups inconclusive and missing data together it
says ``undecided`` (``Verdict.group``): a word of the display, not a verdict.
"""

from __future__ import annotations

from collections.abc import Iterable
from enum import Enum


class Verdict(str, Enum):
    """A condition's verdict on a run (or a run's: the worst of its conditions'): holds, violated, inconclusive
    (the run ended before the formula could be decided), missing data (a channel it reads has no value), failed."""

    HOLDS = "holds"
    VIOLATED = "violated"
    INCONCLUSIVE = "inconclusive"
    MISSING_DATA = "missing data"
    FAILED = "failed"
    """A run that could not be simulated or checked (never a condition's verdict)."""

    @property
    def undecided(self) -> bool:
        """Neither holds nor is violated: inconclusive, or missing data."""
        return self in (Verdict.INCONCLUSIVE, Verdict.MISSING_DATA)

    @property
    def group(self) -> str:
        """The word a report or a screen groups it under: holds, violated, undecided or failed."""
        return "undecided" if self.undecided else self.value

    @classmethod
    def of_run(cls, verdicts: Iterable["Verdict | str"], failed: bool = False) -> "Verdict":
        """A run's verdict: failed, else the worst of its conditions' (violated, missing data,
        inconclusive, holds)."""
        if failed:
            return cls.FAILED
        found = {cls(v) for v in verdicts}
        for verdict in (cls.VIOLATED, cls.MISSING_DATA, cls.INCONCLUSIVE):
            if verdict in found:
                return verdict
        return cls.HOLDS


RUN_GROUPS = ("holds", "undecided", "violated", "failed")
"""The groups of ``Verdict.group``, from best to worst (a report's order and colours)."""
