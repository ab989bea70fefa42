"""``cellsim verify``: build the abstract cell, check it with Storm, and try each witness on the twin.

``abstract_model(sf)`` asks every module's kind for its abstraction (a kind
without one stops it: ``VerifyError``), cuts the floor into places, and joins the
parts into one PRISM program with its properties; ``verify(sf)`` checks them.
"""

from __future__ import annotations

import contextlib
import math
import os
import tempfile
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

from cellsim import registry
from cellsim.verify.cone import cone, within_cone
from cellsim.verify.expressions import VerifyError
from cellsim.verify.floor import build_floor, cut_floor
from cellsim.verify.isolated import ProcessStopped, in_own_process
from cellsim.verify.model import AbstractCell, Property, declare_for_readers
from cellsim.verify.prism import Program
from cellsim.verify.properties import ConditionProperties, Skipped
from cellsim.verify.storm import (DD_MEMORY, EXPLICIT_LIMIT, Checked, ModelStats, build, build_symbolic, check,
                                  to_sparse, valuation_labels)


@dataclass
class AbstractModel:
    cell: AbstractCell
    text: str
    properties: list[Property]
    skipped: list[Skipped]
    labels: dict[str, str]
    """Property name -> the label of its bad states (safety properties)."""
    times: dict[str, float] = field(default_factory=dict)
    header: str = ""
    parts: list = field(default_factory=list)
    """Each module's abstraction (:class:`cellsim.verify.model.ModuleAbstraction`): who can refine what."""
    unasked: list[str] = field(default_factory=list)
    """The properties the cell has that ``only`` did not ask for (:func:`abstract_model`): neither built nor checked."""

    def groups(self) -> list[tuple[list[Property], Program, list[str]]]:
        """The properties by the model they are checked in, its program and the modules it leaves out: the cell with
        no monitor (the mishaps, the invariants, the user's), then the cell with each monitor alone. A monitor only
        its property reads is left out of the others' models, and each model keeps only its labels' cone of
        influence (:mod:`cellsim.verify.cone`): the same behaviours of what the properties read, fewer states."""
        cell = self.cell
        plain = [p for p in self.properties if p.name not in cell.monitors]
        groups = []
        if plain:
            # the properties whose labels have the same cone share one model (a property reading the arms, as the harm
            # conditions do, does not bring them into the mishaps' model); labels of no property's stay with the first
            theirs = {k for p in self.properties if p.name in self.labels for k in self._labels_of(p)}
            spare = {k: v for k, v in cell.labels.items() if k not in theirs}
            by_cone: dict = {}
            for prop in plain:
                if prop.name not in self.labels:  # (a user's own PCTL: with every label no property has)
                    by_cone.setdefault(None, []).append(prop)
                    continue
                mine = {k: cell.labels[k] for k in self._labels_of(prop)}
                by_cone.setdefault(frozenset(cone(cell.program(self.header, [], mine))), []).append(prop)
            for i, props in enumerate(by_cone.values()):
                labels = {k: cell.labels[k] for p in props if p.name in self.labels for k in self._labels_of(p)}
                if i == 0 or None in by_cone and props is by_cone[None]:
                    labels.update(spare)
                groups.append((props, *within_cone(cell.program(self.header, [], labels))))
        responses = [p for p in self.properties if p.name in cell.monitors and p.within is not None]
        if responses:  # short windows, each pending a few periods: one model for them all costs less than one each
            labels = {k: cell.labels[k] for p in responses for k in self._labels_of(p)}
            groups.append((responses, *within_cone(cell.program(self.header, [p.name for p in responses], labels))))
        for prop in self.properties:
            if prop.name in cell.monitors and prop.within is None:
                labels = {k: cell.labels[k] for k in self._labels_of(prop)}
                groups.append(([prop], *within_cone(cell.program(self.header, [prop.name], labels))))
        return groups

    def unmonitored_labels(self) -> dict[str, str]:
        """Every label but those that read a monitor (an obligation's bad and sustained states): the whole cell's
        decision diagrams are built without monitors, and check each obligation on the labels of its parts."""
        reading = {key for prop in self.properties if prop.obligation and prop.name in self.labels
                   for key in (self.labels[prop.name], sustained_label(self.labels[prop.name]))}
        return {key: text for key, text in self.cell.labels.items() if key not in reading}

    def bound(self) -> float:
        """The product of the cell's variables' numbers of values (the monitors left out): no more
        states than this can be reached."""
        variables = self.cell.program(self.header, []).variables().values()
        return math.prod(2 if v.boolean else v.high - v.low + 1 for v in variables)

    def _labels_of(self, prop: Property) -> list[str]:
        return labels_of(prop, self.labels[prop.name])


SIZE_ANYWAY = 1e17
"""The decision diagrams' tables are sized by what the model's variables allow: up to this many states,
``SMALL_DD_MEMORY`` (:func:`dd_memory`)."""
SMALL_DD_MEMORY = 128
"""MB for the decision diagrams of a model whose variables allow at most ``SIZE_ANYWAY`` states. The shipped cells
of that size need at most 32 MB (the assembly bench's 1.25 million states; it fills 16 MB), so this is four times
that; a larger cap costs start-up (0.5 s more at 512 MB: the welding cell's whole build 1.1 s against 0.6 s)."""
SEEN_MARGIN = 4
"""How many times the growth a group's monitors showed in an earlier round (its model's states over the whole cell's)
a refined round expects at most, in deciding to build that group state by state; the product of the monitors' ranges
is the bound otherwise (the welding cell's detections: 27 times, where they added 3 %). A wrong guess costs time, never
an answer: the model built is the same either way."""
STATE_BY_STATE = 500_000
"""Every property is checked on the whole cell's decision diagrams (every monitor in it), and only a group with a
violated property is built again, with only its own monitor, for its witness (or whether its response can always
still come): state by state when the whole cell has at most this many reachable states, else as decision diagrams
made sparse. Storm's state-by-state builder evaluates every command's guard in every state (the assembly bench's
1.25 million states took it 100 s, its decision diagrams 2 s); making a model sparse costs more per transition when
the person's pace is modelled (the welding cell's paced group of 76,516 states: 4.6 s state by state, 8.9 s made
sparse) and when its labels are intricate (the machine-tending cell's true margin, 382,299 states: 19 s state by
state, 50 s made sparse; 12 s state by state since a person's moves are a command per direction)."""


REFINED_GROWTH = 10
"""How many times the states of a refinement's round may grow on the largest model checked before it, and its decision
diagrams still start in ``SMALL_DD_MEMORY`` (:func:`dd_memory`): the shipped cells' refinements grow it 1.5 to 3
times (the welding cell's 12,931 states to 19,665, then 38,694)."""
SMALL_DD_STATES = 1_250_000
"""States that fit ``SMALL_DD_MEMORY``'s tables with room to spare (the assembly bench's 1.25 million fill 16 MB)."""


def dd_memory(bound: float, grown_from: int | None = None) -> int:
    """MB for the decision diagrams' tables (:func:`cellsim.verify.storm.build_symbolic`). Sylvan takes its tables
    at start (the cap costs start-up: 0.5 s at 256 MB, 1.8 s at 2048) and stops the process when they are full, so
    the cap follows what the model's variables allow: ``SMALL_DD_MEMORY`` up to ``SIZE_ANYWAY`` states, else
    ``DD_MEMORY``; and, in a refinement's round (``grown_from``: the largest model checked before it), small while
    ``REFINED_GROWTH`` times that fits ``SMALL_DD_STATES`` (a refinement's counters widen the variables' ranges far
    more than the states they reach: the welding cell's pace, 700 times the bound for 1.5 times the states). Tables
    that prove too small are a build again with ``DD_MEMORY`` (:func:`verify`)."""
    if grown_from is not None and grown_from * REFINED_GROWTH <= SMALL_DD_STATES:
        return SMALL_DD_MEMORY
    return SMALL_DD_MEMORY if bound <= SIZE_ANYWAY else DD_MEMORY


OBLIGATION_PARTS = ("oa", "ob", "oc")
"""The suffixes of the labels of an obligation's parts ``a``, ``b``, ``c`` (:attr:`Property.obligation`)."""


def labels_of(prop: Property, label: str) -> list[str]:
    """The labels a property's check reads: its bad states', its sustained violation's, its obligation's parts, its
    response's a and b."""
    return [label, *([sustained_label(label)] if prop.sustained else []),
            *([f"{label}_{key}" for key in OBLIGATION_PARTS] if prop.obligation else []),
            *([f"{label}_a", f"{label}_b", *(f"{label}_end{k}" for k in range(prop.ends))] if prop.response else [])]


def sustained_label(label: str) -> str:
    """The label of a property's sustained violations, beside ``label`` (its bad states)."""
    return f"{label}_sustained"


@dataclass
class Verification:
    model: AbstractModel
    stats: ModelStats
    results: list[Checked]
    times: dict[str, float]
    largest: ModelStats | None = None
    """The largest of the models built (the cell with one monitor)."""
    refinable: ModelStats | None = None
    """The largest of the models built for properties a refinement can change (not a liveness condition's
    stronger response, which is checked once: its witness is never run)."""
    replays: dict = field(default_factory=dict)
    """Property name -> its witness replayed in the twin (:func:`cellsim.verify.witness.replay`), when asked for."""
    replayed: bool = False
    """Whether the witnesses were replayed on the twin (a witness nobody tried leaves its property undecided)."""
    refinements: list = field(default_factory=list)
    """The refinements switched on, in order (:class:`cellsim.verify.refine.Refinement`)."""
    costly: bool = False
    """Stopped once the whole cell was built, nothing checked: more states than asked for (``verify``'s
    ``costly_above``)."""
    growth: dict = field(default_factory=dict)
    """Group of properties (their names, sorted) -> how many times the whole cell's states its own model (with its
    monitors) had, where it was built: what a refined round expects of the same group (:data:`SEEN_MARGIN`)."""
    not_refined: str = ""
    """Why the refinement that was next was not tried (the model it makes could be too large), if it was not."""
    earlier: dict = field(default_factory=dict)
    """Property name -> what the twin said, in words, of the witnesses of coarser rounds run at the end and refuted
    (:func:`cellsim.verify.refine.verify_with_twin`): part of what blocks its verdict."""

    def endings(self) -> list:
        """Each property's final verdict (:mod:`cellsim.verify.endings`): holds, violated (a witness the twin
        confirms) or undecided (with what blocks a verdict and what was refined); None for a numeric query."""
        from cellsim.verify.endings import ending_of

        tried = [r.key for r in self.refinements] + ([self.not_refined] if self.not_refined else [])
        return [ending_of(r, self.replays.get(r.prop.name), replayed=self.replayed, symbolic=self.stats.symbolic,
                          refinements=tried, earlier=self.earlier.get(r.prop.name, ())) for r in self.results]

    @property
    def exit_code(self) -> int:
        """0 every property holds, 1 one is violated (confirmed by the twin), 3 none is but one is undecided."""
        from cellsim.verify.endings import exit_code

        return exit_code(self.endings())

    @property
    def holds(self) -> bool:
        """Whether every property holds in the abstraction (a liveness condition under fairness too)."""
        return all(r.holds is not False or r.fair for r in self.results)


def twin_mode_assumptions(configs: dict) -> list[str]:
    """What the abstraction assumes of the entities' physical twins: each entity is modelled by its digital
    behaviour, so one in shadow or twin mode (from the start or later) is assumed to behave as that model,
    over a link that never fails."""
    from cellsim.vocabulary import TwinMode

    linked = {}
    for name, cfg in configs.items():
        twin = getattr(cfg, "twin", None)
        modes = [] if twin is None else [twin.mode, *(c.mode for c in twin.changes)]
        if any(m is not TwinMode.MODEL for m in modes):
            linked[name] = twin
    if not linked:
        return ["every entity is its digital model (no physical twin, so no stale, corrupt or recovering link)"]
    said = []
    for name, twin in linked.items():
        when = f"{twin.mode.value} mode" + "".join(f", {c.mode.value} mode from {c.at:g} s" for c in twin.changes)
        text = (f"{name} follows its physical twin ({when}): it is modelled as its digital model, so the physical "
                "twin is assumed to behave as that model over a link never stale, corrupt or recovering (its "
                "fail-safe readings are not modelled)")
        if any(m is TwinMode.TWIN for m in [twin.mode, *(c.mode for c in twin.changes)]):
            text += "; in twin mode its commands are assumed to reach the physical twin and be obeyed within a period"
        said.append(text)
    return said


def abstract_model(sf, cell=None, *, timed: bool = False, refinements: frozenset = frozenset(),
                   measured: dict | None = None, only: tuple[str, ...] = ()) -> AbstractModel:
    """The abstract model of the scenario's cell (its diagram built once, without recording); ``measured``: what an
    earlier model of it read on the floor, kept and added to (:func:`cellsim.verify.floor.cut_floor`); ``only``:
    name patterns (shell-style, ``HS:*``) of the properties to model and check, none: every one. A property not
    asked for is not in the model at all (what only it reads is neither measured nor cut); a pattern that names no
    property of the cell is a VerifyError naming the cell's properties."""
    from cellsim.diagrams.cell import build_cell
    from cellsim.validation.check import cell_safety_case

    times = {}
    start = time.perf_counter()
    if cell is None:
        cell = build_cell(sf, seed=sf.scenario.seed, duration=sf.scenario.duration, record=False)
    times["cell"] = time.perf_counter() - start
    scenario = sf.scenario
    configs = {name: cfg for section in registry.SECTIONS for name, cfg in getattr(scenario, section).items()}
    supervisors = [cell.modules[n].period for n, c in configs.items() if registry.kind_of(c).supervises and n in cell.modules]
    period = min(supervisors) if supervisors else min(getattr(s, "period", 1.0) for s in cell.modules.values())
    abstract = AbstractCell(cell, period, timed, refinements)
    for assumption in twin_mode_assumptions(configs):
        abstract.assume(assumption)
    parts = []
    for name, cfg in configs.items():
        kind = registry.kind_of(cfg)
        part = kind.abstraction(abstract, name, cfg)
        if part is None:
            raise VerifyError(f"kind '{kind.name}' (module '{name}') offers no abstraction: verify cannot model it")
        parts.append(part)
    case = cell_safety_case(sf, cell) if scenario.validation.conditions or scenario.validation.verify else None
    asked = _asked(only)
    conditions = (ConditionProperties(abstract, case, case.validation, asked) if case is not None
                  else None)  # with the default ones
    for part in parts:
        part.declare(abstract)
    if conditions is not None:
        vocabulary, macros = _vocabulary(sf, cell)
        conditions.declare(vocabulary)
        conditions.declare_user(vocabulary, macros)
    for part in parts:
        declare_for_readers(part, abstract)
    times["declare"] = time.perf_counter() - start - times["cell"]
    mark = time.perf_counter()
    abstract.places = cut_floor(abstract, measured)
    build_floor(abstract, abstract.places)
    times["floor"] = time.perf_counter() - mark
    mark = time.perf_counter()
    for name, part in zip(configs, parts):
        abstract.building = name  # (its PRISM modules update at its period)
        part.build(abstract)
    abstract.building = None
    abstract.assume(_time_assumption(abstract))
    skipped: list[Skipped] = []
    properties = list(abstract.properties)
    if conditions is not None:
        conditions.build()
        properties = list(abstract.properties)
        skipped = conditions.skipped
        properties += conditions.user_properties(*_vocabulary(sf, cell))
    unasked = [p.name for p in properties if not asked(p.name)] + (conditions.unasked if conditions else [])
    properties = [p for p in properties if asked(p.name)]
    _every_pattern_names_one(only, [p.name for p in properties] + [s.name for s in skipped] + unasked)
    labels = {}
    for i, prop in enumerate(properties):
        if prop.bad:
            labels[prop.name] = f"bad{i}"
            abstract.labels[f"bad{i}"] = prop.bad
            if prop.sustained:
                abstract.labels[sustained_label(f"bad{i}")] = prop.sustained
            if prop.obligation:
                for key, expression in zip(OBLIGATION_PARTS, prop.obligation):
                    abstract.labels[f"bad{i}_{key}"] = expression
            if prop.response:
                abstract.labels[f"bad{i}_a"], abstract.labels[f"bad{i}_b"] = prop.response
                ends = _at_the_end(abstract)
                prop.ends = len(ends)
                for k, where in enumerate(ends):
                    abstract.labels[f"bad{i}_end{k}"] = where
    selection = (f"Only the properties asked for (--only {' '.join(only)}) are in it; not modelled: "
                 f"{', '.join(unasked)}.\n" if unasked else "")
    header = (f"Abstract model of the cell '{scenario.name}', written by cellsim verify.\n{selection}"
              f"One step is one period of {period:g} s. Assumptions:\n" + "\n".join(f"- {a}" for a in abstract.assumptions))
    text = abstract.program(header).text()
    times["model"] = time.perf_counter() - mark
    return AbstractModel(abstract, text, properties, skipped, labels, times, header, parts, unasked)


def _asked(only: tuple[str, ...]):
    """Whether a property's name is one ``only``'s patterns ask for (every name, where there are none)."""
    from fnmatch import fnmatchcase

    return lambda name: not only or any(fnmatchcase(name, pattern) for pattern in only)


def _every_pattern_names_one(only: tuple[str, ...], names: list[str]) -> None:
    """A VerifyError for the first pattern of ``only`` that names none of the cell's properties ``names``."""
    from fnmatch import fnmatchcase

    for pattern in only:
        if not any(fnmatchcase(name, pattern) for name in names):
            raise VerifyError(f"--only {pattern}: no property of this cell is named like it; its properties: "
                              + ", ".join(names))


AT_THE_END_WAYS = 64
"""The most ways the people may stand when a run ends (their unknown ends' places, combined) that a liveness
condition's end is asked about, one by one; beyond, a run is taken to be able to end owing any response."""


def _at_the_end(abstract: AbstractCell) -> list[str]:
    """Each way the people may stand when a run ends, as an expression: every person whose script's end is known at
    its last stop, each of the others at one of its places (it stands somewhere, and stays there); [] when there
    are more than ``AT_THE_END_WAYS`` ways."""
    import itertools

    people = abstract.places.people if abstract.places is not None else []
    known = [f"{p.variable} = {p.end}" for p in people if p.end is not None]
    unknown = [p for p in people if p.end is None]
    if math.prod(len(p.places) for p in unknown) > AT_THE_END_WAYS:
        return []
    ways = itertools.product(*([f"{p.variable} = {place.index}" for place in p.places] for p in unknown))
    return [" & ".join([*known, *way]) or "true" for way in ways]


def _time_assumption(abstract: AbstractCell) -> str:
    """What the model's time is: its step, which modules update less often, the sensors' readings."""
    slower: dict[int, list[str]] = {}
    for name, every in abstract.slower.items():
        slower.setdefault(every, []).append(name)
    when = "; ".join(f"{', '.join(names)} every {k} steps" for k, names in sorted(slower.items()))
    return (f"one step is {abstract.period:g} s (the fastest supervisor's period); each module updates at its own "
            f"period on that grid, from t = 0 as in the twin ({when or 'every module every step'}), reading the "
            "state before the step; a sensor's readings are taken at its period and read a step later at the "
            "earliest; a person who could walk past a grid point in one of its periods is taken at every step")


def _vocabulary(sf, cell):
    from cellsim.channels import channel_domains
    from cellsim.validation.traces import with_aliases

    specs = [spec for spec, _ in cell.channels.values()]
    vocabulary = with_aliases(channel_domains(specs), sf.scenario.validation.variables, cell.channels)
    return vocabulary, sf.scenario.validation.macros


def properties_text(model: AbstractModel) -> str:
    """The properties file: one PCTL property per line, named as ``verify`` prints them with each character Storm
    does not take in a name (``:``) written ``_``, the printed name in the comment above it."""
    lines = [f"// not asked for (--only), not modelled: {', '.join(model.unasked)}"] if model.unasked else []
    for prop in model.properties:
        text = f'Pmax=? [ F "{model.labels[prop.name]}" ]' if prop.bad else prop.pctl
        lines.append(f"// {prop.name}: {prop.description}")
        lines.append(f'"{_safe(prop.name)}": {text};')
    return "\n".join(lines) + "\n"


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c == "_" else "_" for c in name)


def verify(sf, *, export: Path | None = None, timed: bool = False, refinements: frozenset = frozenset(),
           on_stage=None, checked_before: dict | None = None, model: AbstractModel | None = None,
           enough=None, grown_from: int | None = None, measured: dict | None = None,
           growth_seen: dict | None = None, costly_above: float | None = None,
           only: tuple[str, ...] = ()) -> Verification:
    """Build and check the abstract model; ``export``: also write it there (and its .props beside it);
    ``refinements``: the modules' refinements to switch on (:class:`cellsim.verify.model.AbstractCell`);
    ``checked_before``: property name -> its result from an earlier round, taken as it is (a refinement round's
    liveness conditions, checked once for good): not checked again, but in the results, in their place;
    ``model``: the abstract model of ``sf`` with these refinements, already built (a refinement's, built to judge its
    size: :func:`cellsim.verify.refine.verify_with_twin`), which this call then owns;
    ``enough(model, checked)``: whether a witness just built settles the round (a module's refinement takes it up):
    once one does, the properties whose witnesses are still to be built (not a liveness condition's, whose answer
    under fairness is kept for good) are left violated without one, ``deferred``; ``grown_from``: the states of the
    largest model an earlier round checked (a refinement's round), which sizes the decision diagrams' tables
    (:func:`dd_memory`); ``measured``: as :func:`abstract_model` says; ``growth_seen``: an earlier round's
    ``Verification.growth``, which decides how a group's own model is built (:data:`SEEN_MARGIN`); ``costly_above``:
    stop once the whole cell is built if it has more states than this, nothing checked (``Verification.costly``: a
    refinement sized by building its round, :func:`cellsim.verify.refine.verify_with_twin`); the model keeps its
    properties, to be checked by a later call (whose ``checked_before`` holds at least these); ``only``: the
    properties asked for, as :func:`abstract_model` says."""
    leave_out = frozenset(checked_before or ())
    say = on_stage or (lambda text: None)
    say("building the abstract model")
    if model is None or model.cell.refinements != frozenset(refinements) or model.cell.timed != timed:
        model = abstract_model(sf, timed=timed, refinements=refinements, measured=measured, only=only)
    if export is not None and model.properties:  # every property (this round's model), before any is left out
        write_export(model, export)
    taken: list = []  # what leaving them out took from the model (put back where it keeps every property)
    for prop in [p for p in model.properties if p.name in leave_out]:  # its monitor and labels go with it
        monitor = model.cell.monitors.pop(prop.name, None)
        label = model.labels.pop(prop.name, None)
        cell_labels = {key: model.cell.labels.pop(key) for key in (labels_of(prop, label) if label else ())
                       if key in model.cell.labels}
        taken.append((prop.name, monitor, label, cell_labels))
    every = list(model.properties)
    model.properties = [p for p in model.properties if p.name not in leave_out]
    if not model.properties:
        raise VerifyError("nothing to verify: no safety controller's hazards and no validation condition of a "
                          "checkable shape" + "".join(f"; not checked: {s.name}: {s.reason}" for s in model.skipped))
    times = dict(model.times)
    # (where Storm cannot have a process of its own, tables it outgrows would end this one: no small start there)
    memory = dd_memory(model.bound(), grown_from if hasattr(os, "fork") else None)
    # the scratch folder is this process's: a Storm process stopped (Ctrl-C kills it) leaves nothing behind
    with tempfile.TemporaryDirectory(prefix="cellsim-verify-") as scratch:
        try:
            storm = in_own_process(lambda tell: _storm(model, memory, tell, enough, Path(scratch), growth_seen,
                                                                costly_above), say)
        except ProcessStopped as stopped:
            if memory >= DD_MEMORY:
                raise VerifyError(_stopped(stopped, memory)) from None
            say(f"Storm stopped ({stopped.how}): its decision diagrams may have outgrown {memory} MB; "
                f"building again with {DD_MEMORY} MB")
            try:
                storm = in_own_process(
                    lambda tell: _storm(model, DD_MEMORY, tell, enough, Path(scratch), growth_seen, costly_above),
                    say)
            except ProcessStopped as again:
                raise VerifyError(_stopped(again, DD_MEMORY)) from None
    results, storm_times, stats, largest, refinable, growth = storm
    times.update(storm_times)
    # the model is kept whole, for a later call (a refinement sized by building it, an export) to leave out what it will
    for name, monitor, label, cell_labels in taken:
        if monitor is not None:
            model.cell.monitors[name] = monitor
        if label is not None:
            model.labels[name] = label
        model.cell.labels.update(cell_labels)
    if results is None:  # stopped at the whole cell: too large to check now (``costly_above``)
        model.properties = every
        return Verification(model, stats, [], times, stats, costly=True)
    results.update(checked_before or {})
    model.properties = [p for p in every if p.name in results]
    ordered = [results[p.name] for p in model.properties]
    if any(r.fair for r in ordered):
        model.cell.assume(FAIRNESS)
    return Verification(model, stats, ordered, times, largest, refinable=refinable, growth=growth)


def _storm(model: AbstractModel, memory: int, say, enough=None, scratch: Path | None = None,
           growth_seen: dict | None = None, costly_above: float | None = None):
    """Build and check ``model`` with Storm (Sylvan's tables capped at ``memory`` MB); returns (property name ->
    Checked, the Storm stages' seconds, the stats of the model the size was judged on, of the largest model built,
    of the largest one with a liveness condition, each group's growth seen: ``Verification.growth``; no results
    (None) where the whole cell has more states than ``costly_above``). ``enough``, ``growth_seen`` and
    ``costly_above``: as :func:`verify` says; ``scratch``: a folder for the
    programs Storm reads (its caller's, who removes it; else one of its own). Run in a process of its own
    (:func:`verify`)."""
    results, stats, largest, refinable = {}, None, None, None
    seen: dict = {}  # each group built: its states over the whole cell's (``Verification.growth``)
    settled = False  # a witness was taken up (``enough``): the other witnesses wait for the refined model
    times = {"storm_parse": 0.0, "storm_build": 0.0, "storm_check": 0.0}
    still = tuple(person.variable for person in model.cell.places.people)

    def checked(program, built, props, valuations=None, dropped=(), monitored=True):
        mark = time.perf_counter()
        for prop in props:
            say(f"Storm: checking {prop.name}")
            results[prop.name] = check(program, built, prop, model.labels.get(prop.name), still, valuations, monitored)
            if dropped:
                results[prop.name] = replace(results[prop.name], left_out=tuple(dropped))
        times["storm_check"] += time.perf_counter() - mark

    def count(group_stats):
        times["storm_parse"] += group_stats.parse_seconds
        times["storm_build"] += group_stats.build_seconds

    with (contextlib.nullcontext(str(scratch)) if scratch is not None
          else tempfile.TemporaryDirectory(prefix="cellsim-verify-")) as scratch:
        # the whole cell as decision diagrams, without monitors (each obligation checked as a nested formula): its
        # size decides how it is checked
        whole = Path(scratch) / "model.prism"
        # every module, even one no property observes: a state where one cannot step is refused here (the groups'
        # models, each on its cone, rely on that)
        # (where some update is probabilistic the nested formula would count every path from a state where a violation
        # is possible, more than the monitor's paths: the monitors are then in the whole cell, as they once always were)
        nested = not _probabilistic(model.cell.program(model.header, [], {}))
        program_now = (model.cell.program(model.header, [], model.unmonitored_labels()) if nested
                       else model.cell.program(model.header))
        whole.write_text(program_now.text())
        say("Storm: building the state space as decision diagrams")
        program, symbolic, whole_stats = build_symbolic(whole, memory)
        count(whole_stats)
        say(f"Storm: {whole_stats.states:,} states, {whole_stats.transitions:,} transitions, as decision diagrams")
        if costly_above is not None and whole_stats.states > costly_above:
            return None, times, whole_stats, whole_stats, None, seen
        checked(program, symbolic, model.properties, monitored=not nested)
        del symbolic
        # only a group with a violated property is built again, with its own monitors: for its witness, or whether
        # its response can always still come (a liveness condition's answer under fairness came from the decision
        # diagrams: nothing to build)
        pending = []
        for i, (props, group, dropped) in enumerate(model.groups()):
            again = [p for p in props if p.bad and results[p.name].holds is False and results[p.name].fair is None]
            if again:
                pending.append((i, props, group, dropped, again))
        stats = largest = whole_stats
        engines = set()  # how the groups were built: "state", "sparse", "held"
        for i, props, group, dropped, again in pending:
            if settled and all(p.within is None for p in again):
                for prop in again:
                    results[prop.name] = replace(results[prop.name], deferred=True)
                continue
            path = Path(scratch) / f"model{i}.prism"
            # state by state when it is small: surely so where the whole cell times what the group's monitors add
            # (their ages' values) is; else its size is found as decision diagrams first, and the model made
            # sparse from them (or, small after all, built state by state; too large, sought with people held)
            growth = _monitors_growth(group, model.cell.monitors) if nested else 1
            key = tuple(sorted(p.name for p in props))
            if key in (growth_seen or {}):
                growth = min(growth, SEEN_MARGIN * growth_seen[key])
            by_state = (whole_stats.states * growth <= STATE_BY_STATE
                        and whole_stats.transitions * growth <= EXPLICIT_LIMIT)
            if not by_state:
                path.write_text(group.text() + valuation_labels(group.variables()))
                say(f"Storm: the state space for {', '.join(p.name for p in again)}, as decision diagrams"
                    + _leaving_out(dropped))
                program, symbolic, group_stats = build_symbolic(path, memory)
                count(group_stats)
                if group_stats.states <= STATE_BY_STATE and group_stats.transitions <= EXPLICIT_LIMIT:
                    del symbolic
                    by_state = True
            if by_state:
                path.write_text(group.text())
                say(f"Storm: the state space for {', '.join(p.name for p in again)}, state by state"
                    + _leaving_out(dropped))
                program, built, group_stats = build(path)
                count(group_stats)
                valuations = None
                engines.add("state")
            else:
                if group_stats.states > largest.states:
                    largest = group_stats
                if group_stats.transitions > EXPLICIT_LIMIT:
                    del symbolic
                    say(f"Storm: {group_stats.transitions:,} transitions: too many to make sparse")
                    engines.add("held")
                    witnessed = [p for p in again if p.within is None]
                    if witnessed:
                        _witness_held(model, group, dropped, witnessed, results, memory, Path(scratch), say, count)
                    continue
                mark = time.perf_counter()
                built, valuations = to_sparse(symbolic, group.variables())
                times["storm_build"] += time.perf_counter() - mark
                del symbolic
                engines.add("sparse")
            if any(p.within is None for p in props) and (refinable is None or group_stats.states > refinable.states):
                refinable = group_stats
            if group_stats.states > largest.states:  # (a group carries its monitors, which the whole cell did not)
                largest = group_stats
            seen[key] = group_stats.states / max(whole_stats.states, 1)
            checked(program, built, again, valuations, dropped)
            settled = settled or enough is not None and any(
                p.within is None and results[p.name].witness is not None and enough(model, results[p.name])
                for p in again)
        # (symbolic: some witness came from the decision diagrams alone, with people held, or none)
        stats = replace(whole_stats, symbolic="held" in engines, made_sparse="sparse" in engines,
                        by_state="state" in engines)
    return results, times, stats, largest, refinable, seen


def _probabilistic(program: Program) -> bool:
    """Whether some update of ``program`` is taken with a probability other than 1 (no shipped kind's is: the model's
    choices are the people's, the robots' pace and the processes', all nondeterministic)."""
    return any(len(command.updates) > 1 or command.updates[0][0] not in ("1", "1.0")
               for module in program.modules for command in module.commands)


def _monitors_growth(group: Program, monitors: dict) -> int:
    """How many times the monitors in ``group`` can multiply the states of the cell without them: the product of
    their variables' numbers of values."""
    names = {module.name for module in monitors.values()}
    return math.prod(v.high - v.low + 1 for m in group.modules if m.name in names for v in m.variables)


def _leaving_out(modules: list[str]) -> str:
    """How a stage's message names the modules outside its properties' cone of influence."""
    return f" (leaving out {', '.join(modules)}: no property there can observe them)" if modules else ""


def held(program: Program, people: list) -> Program:
    """``program`` with ``people`` (``PersonPlaces``) held where they start: each floor module keeps only the commands
    that leave its person's place as it is, and the place is no longer a variable but the start place's number
    wherever it is read, nor, for a paced person, where they came from (Storm folds a variable nothing changes into a
    constant, and would then not know it when the model is made sparse). Every path of it is a path of ``program`` (only choices of where to walk are taken away),
    so a witness found in it is one of ``program``, each held person at its start (:func:`with_held`)."""
    import re
    from dataclasses import replace as copy

    from cellsim.verify.floor import ENTERED_AT_START

    floors = {f"{p.role.module}_floor": p.variable for p in people}
    starts = {p.variable: str(p.start) for p in people}
    # a paced person held where they start never came from elsewhere: where they came from is a constant too
    variables = {v.name for m in program.modules for v in m.variables}
    starts.update({f"{p.variable}_from": str(ENTERED_AT_START) for p in people if f"{p.variable}_from" in variables})
    pattern = re.compile(r"\b(" + "|".join(map(re.escape, starts)) + r")\b") if starts else None

    def fixed(expr: str) -> str:
        return pattern.sub(lambda m: starts[m.group(1)], expr) if pattern else expr

    def command(c):
        return copy(c, guard=fixed(c.guard), updates=tuple((fixed(p), {k: fixed(v) for k, v in u.items()})
                                                         for p, u in c.updates))

    def module(m):
        var = floors.get(m.name)
        kept = [c for c in m.commands if var is None or not any(var in u for _, u in c.updates)]
        return copy(m, variables=[v for v in m.variables if v.name not in starts], commands=[command(c) for c in kept])

    return copy(program, modules=[module(m) for m in program.modules],
                formulas={k: fixed(v) for k, v in program.formulas.items()},
                labels={k: fixed(v) for k, v in program.labels.items()})


def with_held(witness: list[dict], people: list) -> list[dict]:
    """A witness of a model with ``people`` held (:func:`held`), each state given their places back (their starts)."""
    return [{**state, **{p.variable: p.start for p in people}} for state in witness]


def _holdings(people: list) -> list[list]:
    """The sets of people to hold, in the order to try them: all but one (each in turn, as the scenario lists them),
    then all (the cell's own choices only); none for a cell of one person but that last."""
    if len(people) < 2:
        return [list(people)] if people else []
    return [[q for q in people if q is not p] for p in people] + [list(people)]


def _witness_held(model: AbstractModel, group: Program, dropped: list[str], props: list, results: dict, memory: int,
                  scratch: Path, say, count) -> None:
    """Witnesses of ``props`` from the group's model (its cone, ``dropped`` the modules it leaves out), found too large
    to make sparse, with some people held at their start (:func:`held`): the first such model small enough to make
    sparse in which a property is still violated gives its witness (its value stays the whole cell's). Only the
    people the model has are held."""
    present = group.variables()
    people = [p for p in (model.cell.places.people if model.cell.places is not None else []) if p.variable in present]
    wanted = list(props)
    for i, holding in enumerate(_holdings(people)):
        if not wanted:
            return
        sub = held(group, holding)
        who = ", ".join(p.role.module for p in holding)
        path = scratch / f"held{i}.prism"
        path.write_text(sub.text() + valuation_labels(sub.variables()))
        say(f"Storm: the state space for {', '.join(p.name for p in wanted)}, with {who} held at the start"
            + _leaving_out(dropped))
        program, symbolic, sub_stats = build_symbolic(path, memory)
        count(sub_stats)
        if sub_stats.transitions > EXPLICIT_LIMIT:
            continue
        found = {}
        for prop in wanted:
            label = model.labels.get(prop.name)
            if check(program, symbolic, prop, label, ()).holds is False:
                found[prop.name] = prop
        if not found:
            continue
        built, valuations = to_sparse(symbolic, sub.variables())
        still = tuple(person.variable for person in people)
        for prop in found.values():
            mine = check(program, built, prop, model.labels.get(prop.name), still, valuations)
            if mine.witness is not None:
                results[prop.name] = replace(results[prop.name], witness=with_held(mine.witness, holding),
                                             witness_from=f"the model with {who} held at the start",
                                             left_out=tuple(dropped))
                wanted.remove(prop)


def _stopped(stopped: ProcessStopped, memory: int) -> str:
    return (f"Storm stopped ({stopped.how}) while building or checking the abstract model: its decision diagrams "
            f"outgrew their {memory} MB, or Storm failed (what it printed is above); --export writes the model, to "
            "try it in Storm or PRISM")


FAIRNESS = ("a liveness condition whose response may take longer than its window is judged under fairness: "
            "whatever the abstraction lets the people, the robots' pace and the processes do again and again, they "
            "eventually do (a person free to leave does leave, a dwell that can end ends), and the cell can do it too "
            "(the way to the response is found in the abstraction, which allows more than the cell; no witness of it "
            "is run on the twin)")


def export_paths(path: Path, sf=None) -> tuple[Path, Path]:
    """(the PRISM program's file, its properties' beside it with ``.props``), refused (VerifyError) where the two
    would be one file, or (``sf``: the verified scenario) one of them is a file the scenario uses."""
    from cellsim.atomic import OverwritesInput, refuse_inputs

    path = Path(path)
    props = path.with_suffix(".props")
    if props == path:
        raise VerifyError(f"--export {path}: name the model's file (say {path.with_suffix('.prism')}); its "
                          "properties are written beside it, with .props")
    if sf is not None and not sf.built_in_code:
        try:
            for target in (path, props):
                refuse_inputs(target, sf.inputs(), "the exported model")
        except OverwritesInput as e:
            raise VerifyError(str(e)) from None
    for target in (path, props):  # (said before anything is built, not once it is)
        if target.is_dir():
            raise VerifyError(f"--export {path}: {target} is a folder; name a file to write")
    for folder in path.parents:  # (a file on the way)
        if folder.exists():
            if not folder.is_dir():
                raise VerifyError(f"--export {path}: {folder} is a file, not a folder to write into")
            break
    return path, props


def write_export(model: AbstractModel, path: Path) -> tuple[Path, Path]:
    """``path`` (the PRISM program) and ``path`` with ``.props`` (its properties): each written whole or not at all,
    both into temporaries first, then put in place one after the other (the program first)."""
    from cellsim.atomic import replacing

    path, props = export_paths(path, model.cell.sf)
    # both written into temporaries first: an error in either leaves the two files as they were
    with replacing(props, make_folder=True) as properties, replacing(path, make_folder=True) as program:
        program.write(model.text)
        properties.write(properties_text(model))
    return path, props
