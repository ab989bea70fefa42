"""A property's final verdict: the one rule that turns what Storm and the twin said into holds, violated or undecided.

``cellsim verify`` checks an abstraction, which allows more than the cell does. Its answer about the cell is:

* **holds**: Storm proved the property in the abstraction, so it holds in every behaviour the abstraction covers
  (its assumptions say which);
* **violated**: Storm found a witness and the twin, running it, violates the property too: a path the cell takes;
* **undecided**: Storm found a witness the twin does not confirm (refuted: the abstraction is too coarse there, and
  refinement ran out of budget or no module found where the witness departs from the cell), or one nobody tried on
  the twin (not replayed, or no witness at all from decision diagrams). Never reported as a violation: the reason
  says what blocks a verdict.

The exit code follows the endings (:func:`exit_code`): 0 every property holds, 1 one is violated, 3 none is
violated but one is undecided; 2 stays bad input.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum


class Ending(str, Enum):
    """A property's final verdict."""

    HOLDS = "holds"
    VIOLATED = "violated"
    UNDECIDED = "undecided"


EXIT_UNDECIDED = 3
"""``cellsim verify``'s exit code when no property is violated and one is undecided."""


@dataclass(frozen=True)
class Final:
    """One property's ending and why."""

    name: str
    ending: Ending | None
    """None: a numeric query (its value is the answer, with no verdict)."""
    reason: str


def ending_of(checked, replay, *, replayed: bool, symbolic: bool, refinements: list[str] = (),
              earlier: list[str] = ()) -> Final:
    """The ending of one checked property (``checked``: :class:`cellsim.verify.storm.Checked`), given its witness's
    replay on the twin (``replay``: :class:`cellsim.verify.witness.Replay` or None), whether witnesses were replayed
    at all, whether the model was checked as decision diagrams, the refinements tried on it, and what the twin said
    of the witnesses of coarser rounds run at the end (``earlier``: each in words), which an undecided ending adds."""
    final = _ending(checked, replay, replayed, symbolic, refinements)
    if final.ending is Ending.UNDECIDED and earlier:
        return Final(final.name, final.ending, f"{final.reason}; {'; '.join(earlier)}")
    return final


def _ending(checked, replay, replayed: bool, symbolic: bool, refinements) -> Final:
    name = checked.prop.name
    if checked.holds is None:
        return Final(name, None, "a value, not a verdict")
    within = getattr(checked.prop, "within", None)
    if checked.holds:
        return Final(name, Ending.HOLDS, "proved in the abstraction" if within is None else
                     f"proved in the abstraction: the response comes within {within:g} s, whatever the rest does")
    if within is not None:
        slower = f"the response may take longer than {within:g} s (a person who stays, a dwell that goes on)"
        fair = getattr(checked, "fair", None)
        if fair:
            return Final(name, Ending.HOLDS, f"proved in the abstraction under fairness: {slower}, but it can always "
                         "still come, so it comes on every path where what can be done again and again is done")
        if getattr(checked, "owed_at_end", False):
            return Final(name, Ending.UNDECIDED, f"{slower}, and a run may end owing it: it can always still come, but "
                         "not while the people stand where their scripts leave them, and the twin's runs end with them "
                         "there (a response still owed at the end violates the condition); no witness of that is built "
                         "or run on the twin yet")
        return Final(name, Ending.UNDECIDED, f"{slower}, and the abstraction reaches a state from which it can never "
                     "come: no witness of that is built or run on the twin yet")
    tried = f"; refinement: {', '.join(refinements)}" if refinements else ""
    if getattr(checked.prop, "pctl", ""):  # the user's own PCTL (a condition's or a hazard's property has none)
        return Final(name, Ending.UNDECIDED, "a PCTL property of your own is judged in the model only: no witness of it "
                     "is run on the twin, so its violation is the model's, not confirmed (a condition of the validation "
                     "file, G(...), gets its witness run on the twin)")
    if checked.witness is None:
        why = ("no witness: the model was checked as decision diagrams, which give none" if symbolic
               else "no witness")
        return Final(name, Ending.UNDECIDED, why + tried)
    if replay is None:
        why = ("the witness was not replayed on the twin (--no-replay)" if not replayed
               else "the witness has no replay")
        return Final(name, Ending.UNDECIDED, why + tried)
    source = getattr(checked, "witness_from", "")
    source = f" (from {source}: a path of the whole cell's model too)" if source else ""
    if replay.confirmed:
        return Final(name, Ending.VIOLATED, f"the twin confirms the witness{source}: {replay.runs[-1]}")
    slower = f" ({replay.lag})" if getattr(replay, "lag", "") else ""
    return Final(name, Ending.UNDECIDED, f"the twin refutes the witness{source} in {len(replay.runs)} runs: the "
                                         f"abstraction allows a behaviour the cell does not show{slower}{tried}")


def exit_code(endings: list[Final]) -> int:
    """0 every property holds, 1 one is violated, :data:`EXIT_UNDECIDED` none violated and one undecided."""
    found = {f.ending for f in endings}
    if Ending.VIOLATED in found:
        return 1
    if Ending.UNDECIDED in found:
        return EXIT_UNDECIDED
    return 0
