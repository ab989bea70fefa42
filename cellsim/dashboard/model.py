"""What the dashboard knows of a cell in operation: the latest of everything, and the trace so far.

``CellModel`` is fed by a feed (``cellsim.dashboard.feeds``: the running twin over
Zenoh, or a recorded black box) and read by the views. It keeps the latest value
of every channel, the trace so far (each channel's changes, for the safety
conditions), the physical samples, the twin's status, the bridge daemon's
diagnostics and an event log. Nothing in it renders; nothing a message holds
can break it: a message for an unknown channel, or with a value outside its
channel's domain, is counted and dropped.

Safety conditions are evaluated online over the trace so far
(:meth:`CellModel.conditions`), with the offline checker's semantics on an
unfinished run (docs/condition-language.md):

* ``holds``: decided, whatever comes next (an eventuality that came true);
* ``holds so far``: no violation yet, and the future could still bring one;
* ``pending``: an obligation is open (a hazard raised and not yet mitigated):
  on the trace so far the condition fails, but the run going on can still
  fulfil it;
* ``violated at T``: a violation nothing can undo, first at T;
* ``no data yet``: a variable it reads has had no message.
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from cellsim.codec import FAILURES
from cellsim.hazards import HazardPhases
from cellsim.link import Fault, failed_link
from cellsim.channels import value_text
from cellsim.numbers import instant, measure

LEVELS = ("OK", "WARN", "ERROR", "STALE")
DIAGNOSTICS_MISSED = 3
"""Diagnostics periods (the status's ``every_s``, else 1 s) with no word from a device after which its last level is
shown STALE: a daemon that died, or a link to it lost, leaves no level standing as if fresh."""
"""Link health, as ROS diagnostics name it (a group shows its worst member)."""
LINK_LEVEL = {"ok": "OK", "recovering": "WARN", "corrupt": "ERROR", "stale": "STALE"}
CONDITIONS_EVERY = 0.5
"""Simulated seconds at least between evaluations of the safety conditions, when a variable they read changed."""
CONDITIONS_AT_LEAST_EVERY = 2.0
"""... and at most between two evaluations (time passing alone can close an obligation: a deadline)."""


def worst(levels) -> str:
    return max(levels, key=LEVELS.index, default="OK")


@dataclass(frozen=True)
class Event:
    sim_time: float
    text: str
    level: str = "OK"


class CellModel:
    """The dashboard's picture of one cell."""

    def __init__(self, description: dict):
        from cellsim.channels import logic_domain
        from cellsim.validation.traces import validator_of

        self.scenario: dict = description.get("scenario") or {}
        self.name: str = self.scenario.get("name", "?")
        self.channels: dict[str, dict] = description.get("channels") or {}
        self.hazards: dict[str, dict] = description.get("hazards") or {}
        self.kinds: dict[str, str] = {
            name: cfg.get("kind", "?")
            for section in ("entities", "behaviours", "services")
            for name, cfg in (self.scenario.get(section) or {}).items()
        }
        self.entities = [name for name in (self.scenario.get("entities") or {})]
        self._domains = {name: logic_domain(c["kind"], c["domain"], c.get("unit")) for name, c in self.channels.items()}
        self._valid = {name: validator_of(d) for name, d in self._domains.items() if d is not None}
        self.values: dict[str, object] = {}
        self.changed_at: dict[str, float] = {}
        self.series: dict[str, tuple[list[float], list]] = {}
        self.sim_time = 0.0
        self.physical: dict[str, dict] = {}
        self.status: dict | None = None
        self.slower: set[str] = set()
        """Entities the twin said it reacts to slower than its scenario assumes."""
        self.diagnostics: dict[str, dict] = {}
        self._heard: dict[str, float] = {}  # device -> when its last diagnostics came (``clock``)
        self.clock = time.monotonic
        """The dashboard's clock (s): how long ago a device's diagnostics came."""
        self.twin = "waiting"
        """waiting (no twin yet), running, gone (its liveliness token went), replay, ended."""
        self.events: deque[Event] = deque(maxlen=500)
        self.event_count = 0
        """Events logged since the start (the deque keeps the newest)."""
        self.dropped = 0
        """Messages that were not what their key carries (counted, never fatal)."""
        self.complete = False
        """Whether the trace is the whole run (a replay that reached its end)."""
        self._case = None
        self._case_error: str | None = None
        self._verdicts: list[tuple[str, str, str, str]] = []
        self.explanations: dict[str, str] = {}
        """Violated condition -> why, in one sentence (as ``cellsim check`` says it)."""
        self._evaluated_at = -math.inf
        self._read: set[str] | None = None
        """The channels the conditions read (None: not compiled yet)."""
        self._read_changed = True

    @classmethod
    def from_blackbox(cls, bb) -> CellModel:
        """A model of the run recorded in ``bb`` (an open BlackBox), before any message."""
        metadata = bb.metadata()
        channels = {
            name: {"source": i.source, "kind": i.kind, "domain": i.domain, "unit": i.unit, "period": i.period,
                   "description": i.description}
            for name, i in bb.channels().items()
        }
        return cls({"scenario": metadata.get("scenario") or {}, "channels": channels, "hazards": metadata.get("hazards") or {}})

    # -- in ----------------------------------------------------------------------------
    def apply_channel(self, name: str, sim_time: float, value) -> None:
        """A channel's value at ``sim_time`` (s, the twin's clock)."""
        meta = self.channels.get(name)
        if (meta is None or not isinstance(sim_time, (int, float)) or not math.isfinite(sim_time)
                or (value is not None and name in self._valid and not self._valid[name](value))):
            self.dropped += 1
            return
        self.sim_time = max(self.sim_time, float(sim_time))
        previous = self.values.get(name, _UNSET)
        self.values[name] = value
        if previous == value and name in self.series:
            return
        self.changed_at[name] = float(sim_time)
        if self._read is None or name in self._read:
            self._read_changed = True
        if name in self._domains and self._domains[name] is not None:
            times, values = self.series.setdefault(name, ([], []))
            if times and sim_time <= times[-1]:
                values[-1] = value
            else:
                times.append(float(sim_time))
                values.append(value)
        self._note_change(name, sim_time, previous, value)

    def apply_physical(self, entity: str, message: dict) -> None:
        """The latest physical sample of an entity (``{"t", "seq", "fields"}`` or a failure)."""
        if entity in self.entities and isinstance(message, dict):
            self.physical[entity] = message
        else:
            self.dropped += 1

    def apply_status(self, status: dict) -> None:
        if isinstance(status, dict) and isinstance(status.get("sim_time"), (int, float)):
            self.status = status
            self.sim_time = max(self.sim_time, float(status["sim_time"]))
            self._note_reaction(status.get("reaction"))
        else:
            self.dropped += 1

    def _note_reaction(self, reaction) -> None:
        """Log each entity the first time the twin says it reacts to its samples slower than assumed."""
        if not isinstance(reaction, dict) or not isinstance(reaction.get("slower"), list):
            return
        assumed = reaction.get("assumed") if isinstance(reaction.get("assumed"), dict) else {}
        for entity in reaction["slower"]:
            if isinstance(entity, str) and entity not in self.slower:
                self.slower.add(entity)
                limit = assumed.get(entity)
                said = f" {limit * 1000:g} ms" if isinstance(limit, (int, float)) else ""
                self.log(f"{entity}: the twin reacts to its samples slower than the{said} the scenario assumes: "
                         "its evidence is optimistic for this cell", "ERROR")

    def reaction_text(self) -> tuple[str, bool]:
        """The twin's slowest reaction (sample -> decision) in its last status, and whether any entity's
        reactions were ever slower than assumed: for the header."""
        reaction = (self.status or {}).get("reaction")
        slowest = reaction.get("slowest") if isinstance(reaction, dict) else None
        values = [v for v in slowest.values() if isinstance(v, (int, float))] if isinstance(slowest, dict) else []
        text = f"  reaction {max(values) * 1000:.0f} ms" if values else ""
        if self.slower:
            text += f" (slower than assumed: {', '.join(sorted(self.slower))})"
        return text, bool(self.slower)

    def apply_diagnostics(self, device: str, status: dict) -> None:
        if not isinstance(status, dict) or status.get("level", "OK") not in LEVELS and device != "bridge":
            self.dropped += 1
            return
        previous = self.diagnostics.get(device, {}).get("level")
        self.diagnostics[device] = status
        self._heard[device] = self.clock()
        level = status.get("level")
        if device != "bridge" and level != previous and previous is not None:
            self.log(f"{device}: link {previous} -> {level} ({status.get('message', '')})", level)

    def diagnostics_level(self, device: str) -> str | None:
        """A device's diagnostics level as shown now: its last, or STALE once ``DIAGNOSTICS_MISSED`` of its periods
        passed with no word (None: never heard)."""
        status = self.diagnostics.get(device)
        if status is None:
            return None
        every = status.get("every_s")
        # (at most the longest period a bridge configuration allows: a status claiming more keeps nothing fresh longer)
        every = min(every, 60.0) if isinstance(every, (int, float)) and math.isfinite(every) and every > 0 else 1.0
        if self.clock() - self._heard.get(device, -math.inf) > DIAGNOSTICS_MISSED * every:
            return "STALE"
        return str(status.get("level"))

    def set_twin(self, state: str) -> None:
        if state != self.twin:
            self.log({"running": "the twin is running", "gone": "the twin is gone", "ended": "the replay ended"}.get(state, state),
                     "OK" if state in ("running", "replay", "ended") else "ERROR")
        self.twin = state

    def log(self, text: str, level: str = "OK") -> None:
        self.events.append(Event(self.sim_time, text, level))
        self.event_count += 1

    def _note_change(self, name: str, t: float, previous, value) -> None:
        module, _, signal = name.partition(".")
        if previous is _UNSET:
            return
        if signal == "twin_mode":
            self.log(f"{module}: twin mode {previous} -> {value}")
        elif name in self.hazards:
            self.log(f"hazard {signal}: {previous} -> {value}", HazardPhases.of(self.hazards[name]).level(value))
        elif signal == "physical_link":
            self.log(f"{module}: physical link {value}", LINK_LEVEL.get(value, "WARN"))

    # -- views -------------------------------------------------------------------------
    def kind(self, module: str):
        """The module's kind (``cellsim.kind.ModuleKind``), or None when it is not installed here."""
        from cellsim import registry

        try:
            return registry.get(self.kinds.get(module, "?"))
        except registry.KindError:
            return None

    def glance_rows(self, panel: str) -> list[tuple[str, str]]:
        """What each module's kind shows in ``panel`` (``ModuleKind.glance``), modules in the scenario's order."""
        rows = []
        for module in self.kinds:
            for line in getattr(self.kind(module), "glance", ()):
                if line.panel != panel:
                    continue
                rows.append((line.label.format(name=module), _glanced(self.values.get(f"{module}.{line.signal}"), line)))
        return rows

    def hazard_rows(self) -> list[tuple[str, str, float, str]]:
        """(hazard, phase, seconds in that phase, level) of each hazard."""
        rows = []
        for channel, phases in self.hazards.items():
            phase = self.values.get(channel, phases.get("initial"))
            since = self.sim_time - self.changed_at.get(channel, 0.0)
            rows.append((channel.rpartition(".")[2], str(phase), max(0.0, since), HazardPhases.of(phases).level(phase)))
        return rows

    def cell_rows(self) -> list[tuple[str, str]]:
        """The cell at a glance: what each kind shows there (safety modes, the process), and what each supervisor
        (a safety controller) demands: its channels other than its hazards."""
        rows = self.glance_rows("cell")
        for module in self.kinds:
            if getattr(self.kind(module), "supervises", False):
                for name, meta in self.channels.items():
                    if meta["source"] == module and name not in self.hazards and self.values.get(name) is not None:
                        rows.append((name.rpartition(".")[2], _text(self.values.get(name))))
        return rows

    def robot_rows(self) -> list[tuple[str, str]]:
        """The arms and the people near them: what each kind shows there."""
        return self.glance_rows("robot")

    def entity_rows(self) -> list[dict]:
        """Per entity: twin mode, link level and sample age, the bridge's diagnostics level, and
        twin-versus-physical values (``diverges`` where they differ)."""
        ages = (self.status or {}).get("sample_age") or {}
        rows = []
        for entity in self.entities:
            mode = self.values.get(f"{entity}.twin_mode")
            link = self.values.get(f"{entity}.physical_link")
            level = "-" if mode in (None, "model") else LINK_LEVEL.get(link, "STALE")
            if self.twin == "gone" and level != "-":
                level = "STALE"  # the link as the twin last saw it: nobody sees it now
            diagnostics = self.diagnostics_level(entity)
            if diagnostics is not None and level != "-":
                level = worst([level, diagnostics])
            twin_text, physical_text, diverges = self._compare(entity)
            rows.append({"entity": entity, "kind": self.kinds.get(entity, "?"), "mode": _text(mode), "level": level,
                         "age": ages.get(entity), "diagnostics": diagnostics, "twin": twin_text, "physical": physical_text,
                         "diverges": diverges})
        return rows

    def _compare(self, entity: str) -> tuple[str, str, bool]:
        """The twin's and the physical twin's values of an entity, and whether they differ."""
        message = self.physical.get(entity)
        fields = message.get("fields") if isinstance(message, dict) else None
        comparison = getattr(self.kind(entity), "comparison", None)
        if comparison is not None:  # a vector channel against several sample fields (a robot's joints)
            text_of = lambda xs: " ".join(f"{x * comparison.scale:.0f}" for x in xs) + f" {comparison.unit}"  # noqa: E731
            twin_values = _finite_numbers(self.values.get(f"{entity}.{comparison.signal}"))
            twin = "-" if twin_values is None else text_of(twin_values)
            if not isinstance(fields, dict):
                return twin, _failure(message), False
            physical_values = _finite_numbers([fields.get(f) for f in comparison.fields])
            if physical_values is None:
                return twin, "malformed", True
            diverges = (twin_values is not None and len(twin_values) == len(physical_values)
                        and float(np.max(np.abs(np.subtract(twin_values, physical_values)))) > comparison.tolerance)
            return twin, text_of(physical_values), diverges
        shown = [f for f in (fields or {}) if f"{entity}.{f}" in self.channels] or \
            [n.partition(".")[2] for n, m in self.channels.items() if m["source"] == entity
             and n.partition(".")[2] not in ("twin_mode", "physical_link")][:2]
        twin = ", ".join(_text(self.values.get(f"{entity}.{f}")) for f in shown[:2]) or "-"
        if not isinstance(fields, dict):
            return twin, _failure(message), False
        physical = ", ".join(_text(fields.get(f)) for f in shown[:2])
        diverges = any(_differs(self.values.get(f"{entity}.{f}"), fields.get(f)) for f in shown[:2])
        return twin, physical, diverges

    # -- safety conditions ---------------------------------------------------------------
    def conditions(self, force: bool = False) -> list[tuple[str, str, str, str]]:
        """(condition, verdict, level, description) over the trace so far; re-evaluated every CONDITIONS_EVERY s.

        The moment a condition becomes violated, the event log says why (its explanation)."""
        since = self.sim_time - self._evaluated_at
        if not force and (since < CONDITIONS_EVERY or (not self._read_changed and since < CONDITIONS_AT_LEAST_EVERY)):
            return self._verdicts
        self._evaluated_at, self._read_changed = self.sim_time, False
        case = self._safety_case()
        if case is None:
            return self._verdicts
        from cellsim.logic.trace import Signal, Trace
        from cellsim.validation.verdict import Verdict

        if self.sim_time <= 0.0:
            return self._verdicts
        signals = {name: Signal(np.asarray(times, dtype=np.float64), list(values)) for name, (times, values) in self.series.items()}
        for name in self._domains:
            signals.setdefault(name, Signal(np.zeros(0), []))
        for variable, channel in case.validation.variables.items():
            signals[variable] = signals.get(channel, Signal(np.zeros(0), []))
        try:
            result = case.check(Trace(signals, 0.0, self.sim_time), complete=self.complete)
        except Exception as e:  # noqa: BLE001 - a trace the checker refuses is shown, never fatal
            self._verdicts = [("(conditions)", f"cannot evaluate: {e}", "ERROR", "")]
            return self._verdicts
        from cellsim.config.validation import description_of

        rows, why = [], {}
        for name, verdict in result.verdicts.items():
            row = None
            if verdict.status is Verdict.VIOLATED:
                at = "" if verdict.violated_at is None else f" at {instant(verdict.violated_at)}"
                row = (f"violated{at}", "ERROR")
                why[name] = verdict.explanation
            elif verdict.status is Verdict.INCONCLUSIVE:
                row = ("holds so far", "OK") if verdict.reading == "holds so far" else ("pending", "WARN")
            elif verdict.status is Verdict.MISSING_DATA:
                row = (f"no data yet ({', '.join(verdict.missing)})", "STALE")
            elif verdict.status is Verdict.HOLDS:
                row = ("holds", "OK")
            if row is not None:
                rows.append((name, *row, description_of(case.validation.conditions[name]) or ""))
        for name, text, level, _ in rows:
            before = next((t for n, t, _, _ in self._verdicts if n == name), None)
            if level == "ERROR" and (before is None or not before.startswith("violated")):
                self.log(f"condition {name} {text}" + (f": {why[name]}" if why.get(name) else ""), "ERROR")
        self._verdicts, self.explanations = rows, {name: text for name, text in why.items() if text}
        return rows

    def _safety_case(self):
        if self._case is not None or self._case_error is not None:
            return self._case
        from cellsim.config.typed_yaml import from_data
        from cellsim.validation.conditions import SafetyCase
        from cellsim.config.validation import Validation
        from cellsim.scenario import Scenario
        from cellsim.validation.defaults import default_conditions, with_defaults
        from cellsim.validation.traces import with_aliases

        data = self.scenario.get("validation") or {}
        try:  # the default conditions it is judged by (NoHarm, NoClamping, TrueSSM), as check judges it
            defaults = default_conditions(from_data(Scenario, self.scenario, "the twin's scenario"))
        except Exception as e:  # noqa: BLE001 - (a kind not installed here): its own conditions still shown
            defaults = {}
            self.log(f"the default conditions cannot be read from the twin's scenario ({e}): its own alone shown",
                     "WARN")
        try:
            validation = with_defaults(from_data(Validation, data, "the twin's scenario"), defaults, self.channels)
            if not validation.conditions:
                self._case_error = "no safety conditions"
                return None
            domains = {n: d for n, d in self._domains.items() if d is not None}
            vocabulary = with_aliases(domains, validation.variables, self.channels)
            self._case = SafetyCase.compile(validation, vocabulary, lambda key: ("the twin's scenario", None, key))
            from cellsim.logic.syntax import variables_of

            read = set().union(*(variables_of(f) for f in self._case.conditions.values()))
            self._read = {validation.variables.get(v, v) for v in read}
        except Exception as e:  # noqa: BLE001 - shown, never fatal
            self._case_error = str(e)
            self._verdicts = [("(conditions)", f"cannot compile: {e}", "ERROR", "")]
        return self._case


_UNSET = object()


def _text(value) -> str:
    return value_text(value, true="yes", false="no")


def _glanced(value, line) -> str:
    """A value as a kind's glance line shows it: a number with its unit (``far`` beyond its ``far``), a count
    as a whole number, anything else as text."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return _text(value)
    if line.far is not None and value > line.far:
        return "far"
    return measure(value, line.unit) if line.unit else f"{value:g}"


def _finite_numbers(values) -> list[float] | None:
    """``values`` if it is a list of finite numbers, else None (a stale robot's joints, NaN, are None)."""
    if not isinstance(values, list) or not values:
        return None
    if not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in values):
        return None
    return [float(x) for x in values]


def _failure(message) -> str:
    """What a failure message says of a physical link: ``link stale (timeout)``, ``link corrupt (crc)``."""
    if isinstance(message, dict) and message.get("failed") in FAILURES:
        fault = Fault(message["failed"])
        return f"link {failed_link(fault).value} ({fault.value})"
    return "-"


def _differs(a, b) -> bool:
    if a is None or b is None:
        return False
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return abs(float(a) - float(b)) > 1e-3 * max(1.0, abs(float(a)))
    return a != b
