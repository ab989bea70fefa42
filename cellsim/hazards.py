"""A hazard's phases as a run shows them: the one place that decides a mishap was reached.

A risk model's hazard moves through phases (``cellsim.kinds.safety_controller.risk_model``); two of them
matter to every reader of a run: the *initial* one (nothing is wrong) and the *mishap* one (harm was
done). A run's summary counts how often a hazard was raised, handled and reached its mishap, ``verify``'s
witness replay asks whether the twin reached it, the dashboard colours a phase by it: all through
:class:`HazardPhases`, from the ``{initial, mishap}`` a black box's ``hazards`` metadata records.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass


@dataclass
class HazardCounts:
    raised: int = 0
    """Times the hazard left its initial phase (was detected)."""
    handled: int = 0
    """Times it came back to its initial phase."""
    mishaps: int = 0
    """Times it entered its mishap phase."""


@dataclass(frozen=True)
class HazardPhases:
    initial: object
    """The phase in which nothing is wrong."""
    mishap: object | None
    """The phase in which harm was done (None: the risk model names none)."""

    @classmethod
    def of(cls, recorded: Mapping) -> "HazardPhases":
        """From a black box's ``hazards`` metadata entry (``{"initial": ..., "mishap": ...}``)."""
        return cls(recorded.get("initial"), recorded.get("mishap"))

    def is_mishap(self, phase) -> bool:
        return self.mishap is not None and phase == self.mishap

    def reached(self, phases: Sequence) -> bool:
        """Whether a run whose hazard took ``phases`` (in time order) reached its mishap."""
        return any(self.is_mishap(p) for p in phases)

    def counts(self, phases: Sequence) -> HazardCounts:
        """Raised (leaving the initial phase), handled (back to it), mishaps (entering the mishap phase)."""
        before = [None, *phases[:-1]]
        return HazardCounts(
            raised=sum(p != self.initial and (i == 0 or b == self.initial) for i, (p, b) in enumerate(zip(phases, before))),
            handled=sum(p == self.initial and i > 0 and b != self.initial for i, (p, b) in enumerate(zip(phases, before))),
            mishaps=sum(self.is_mishap(p) and (i == 0 or not self.is_mishap(b)) for i, (p, b) in enumerate(zip(phases, before))),
        )

    def level(self, phase) -> str:
        """A status level for a phase: ERROR in the mishap, OK in the initial phase, WARN in between."""
        return "ERROR" if self.is_mishap(phase) else "OK" if phase == self.initial else "WARN"
