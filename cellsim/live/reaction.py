"""The live twin's own reaction time, measured, against the reaction its scenario's evidence assumes.

A simulated run, ``verify``'s model and the SSM formula all rest on how fast the cell reacts:
in simulation a change an entity senses is decided on by the controller within the controller's
period after the entity's update; an SSM monitor's ``reaction_time`` (T_r) is written into every
protective distance it computes. Beside the real cell the path is longer: the sample travels to the
twin, waits to be taken, waits for the controller's update, and the twin may lag the wall clock. A
twin whose reaction is slower than its evidence assumes makes that evidence optimistic, so it
measures itself and says so.

**What is measured**, for each physical sample that changed its entity's fields (the oldest change
in each drain of its source): from the sample's stamp at its source (the sender's wall clock when it
was taken) to the end of the first update of the cell's fastest controller after the entity took it in,
when the commands that update decides go out (the command publishers look one plant step after it). A
slower module that also reads the entity (a process controller) decides later; that is not counted. A controller whose
own logic takes more updates to act (the risk model: detect, then mitigate) takes them in simulation
too: they are part of the evidence, not of the twin's delay. Only entities in shadow or twin mode are measured (in model mode their
samples drive nothing). Not seen by the twin: the physical sensor's response before its sample was
stamped, and the bus and robot controller after the command left (``scripts/bench_bridge.py``
measures the bridge's part). Stamps and the twin's clock are compared as wall clocks: on two machines
they must be synchronised (PTP or NTP), as the link rule's freshness already requires.

**What is assumed**, per entity (:func:`assumed_reactions`): the smallest ``reaction_time`` a module of
the scenario states (an SSM monitor's T_r), else the entity's own period plus the period of the
cell's fastest deciding module (the longest a change takes in simulation to be sensed and decided on).
"""

from __future__ import annotations

import sys
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
from pydrake.systems.framework import LeafSystem

from cellsim.vocabulary import TwinMode

KEPT = 2000
"""Reactions kept per entity for the figures (the newest); the counts cover the whole run."""


@dataclass(frozen=True)
class Assumed:
    """The reaction (s) a scenario's evidence assumes of one entity's samples, and why."""

    seconds: float
    why: str


def deciding_period(scenario) -> float | None:
    """The period (s) of the cell's fastest deciding module (a behaviour: its controllers and monitors),
    or None when it has none."""
    periods = [getattr(cfg, "period", None) for cfg in scenario.behaviours.values()]
    periods = [p for p in periods if isinstance(p, (int, float)) and p > 0]
    return min(periods) if periods else None


def assumed_reactions(scenario, entities: dict) -> dict[str, Assumed]:
    """Per entity (name -> its system, with ``period``): the reaction its scenario's evidence assumes."""
    stated = [(cfg.reaction_time, name) for name, cfg in scenario.behaviours.items()
              if isinstance(getattr(cfg, "reaction_time", None), (int, float))]
    deciding = deciding_period(scenario)
    assumed = {}
    for name, entity in entities.items():
        if stated:
            seconds, module = min(stated)
            assumed[name] = Assumed(seconds, f"{module}'s reaction_time")
        elif deciding is not None:
            assumed[name] = Assumed(entity.period + deciding,
                                    f"its period {entity.period * 1000:g} ms + the controller's {deciding * 1000:g} ms")
    return assumed


class ReactionWatch(LeafSystem):
    """Measures the twin's reaction to each changed sample (see the module docstring) at every look of the
    command publishers, and keeps the figures; warns once per entity whose reaction exceeds what is assumed.

    Ports:
      <entity> (input), per watched entity: its ``twin_mode`` channel (a TwinMode code).
    """

    def __init__(self, sources: dict, assumed: dict[str, Assumed], every: float, time_step: float,
                 process: str = "twin", look: float | None = None):
        """``sources``: entity name -> its ``ZenohSampleSource``; ``every``: the fastest deciding module's
        period (s): its updates are the decisions, each looked at one plant step later; ``look``: when within
        that period the command publishers look (s; default one step)."""
        super().__init__()
        self.set_name("reaction_watch")
        self.sources = {name: s for name, s in sources.items() if name in assumed}
        self.assumed, self.step, self.process = assumed, time_step, process
        self.reactions = {name: deque(maxlen=KEPT) for name in self.sources}
        self.counts = {name: 0 for name in self.sources}
        self.exceeded = {name: 0 for name in self.sources}
        self.first_exceeded: dict[str, float] = {}  # entity -> simulated time of its first reaction slower than assumed
        self.recent: list[tuple[str, float]] = []  # since the last status
        self._modes = {name: self.DeclareVectorInputPort(name, 1) for name in self.sources}
        self.DeclarePeriodicPublishEvent(every, time_step if look is None else look, self._look)

    def _look(self, context) -> None:
        decided = context.get_time() - self.step  # the updates whose commands go out now
        now = time.time()
        for name, source in self.sources.items():
            stamps = source.decided_by(decided)
            if not stamps or self._modes[name].Eval(context)[0] == TwinMode.MODEL.code:
                continue
            for stamp in stamps:
                self.note(name, now - stamp, context.get_time())

    def note(self, name: str, reaction: float, t: float) -> None:
        """One reaction (s) of entity ``name``'s sample, measured at simulated time ``t``."""
        self.reactions[name].append(reaction)
        self.recent.append((name, reaction))
        self.counts[name] += 1
        assumed = self.assumed[name]
        if reaction > assumed.seconds:
            self.exceeded[name] += 1
            if self.exceeded[name] == 1:
                self.first_exceeded[name] = round(t, 4)
                print(f"cellsim {self.process}: {name}: sample -> decision {reaction * 1000:.0f} ms at t = {t:.1f} s, "
                      f"slower than the {assumed.seconds * 1000:g} ms the scenario assumes ({assumed.why}): its "
                      "evidence is optimistic for this cell", file=sys.stderr)

    def figures(self) -> dict:
        """Per entity: reactions counted, p50, p99 and max (s) of the newest, how many exceeded the assumed
        reaction, and that reaction: for the black box's metadata."""
        return {name: {"count": self.counts[name], **_spread(self.reactions[name]),
                       "exceeded": self.exceeded[name], "first_exceeded_at": self.first_exceeded.get(name),
                       "assumed": self.assumed[name].seconds, "assumed_why": self.assumed[name].why}
                for name in self.sources}

    def status(self) -> dict:
        """What the status message says: the slowest reaction since the last status per entity that reacted,
        and the entities whose reactions exceeded the assumed reaction since the start."""
        recent: dict[str, float] = {}
        for name, reaction in self.recent:
            recent[name] = max(reaction, recent.get(name, 0.0))
        self.recent = []
        return {"slowest": {n: round(r, 4) for n, r in recent.items()},
                "assumed": {n: a.seconds for n, a in self.assumed.items() if n in self.sources},
                "slower": sorted(n for n, count in self.exceeded.items() if count)}


def _spread(values) -> dict:
    if not values:
        return {"p50": None, "p99": None, "max": None}
    array = np.fromiter(values, float)
    return {"p50": float(np.percentile(array, 50)), "p99": float(np.percentile(array, 99)), "max": float(array.max())}


def reaction_findings(metadata: dict) -> list:
    """A live run's findings from its black box's metadata: each entity whose samples the twin decided on slower
    than its scenario assumes (``Finding`` ``slow reaction``, from its first such reaction to the end)."""
    from cellsim.kind import Finding

    figures = (metadata.get("live") or {}).get("reaction_s") if isinstance(metadata, dict) else None
    found = []
    for name, f in (figures or {}).items():
        if not isinstance(f, dict) or not f.get("exceeded"):
            continue
        slowest = f"{f['max'] * 1000:.0f} ms" if isinstance(f.get("max"), (int, float)) else "?"
        text = (f"{name}: {f['exceeded']} of {f.get('count', '?')} changed samples decided on slower than the "
                f"{f.get('assumed', 0) * 1000:g} ms the scenario assumes ({f.get('assumed_why', '')}), the slowest "
                f"{slowest}: the evidence gathered offline is optimistic for this cell")
        start = f.get("first_exceeded_at")
        found.append(Finding(name, "slow reaction", float(start) if isinstance(start, (int, float)) else 0.0, None,
                             text, {k: f.get(k) for k in ("count", "exceeded", "p50", "p99", "max", "assumed")}))
    return found
