"""A self-contained HTML report of a test campaign, readable at thousands of runs.

:func:`render_report` turns a campaign's results dictionary (exactly what is written
to ``OUT/results.json``) and the traces of its runs into one HTML document;
:func:`write_report` writes it atomically.  The page needs nothing but a browser: its
style and its script are inlined, its plots are inline SVG, there are no external
assets.  Links point at files of the campaign folder beside it (a run's black box and
scenario).  It stays readable printed (colours are kept, timelines scale to the page
width and are not split across pages, short pieces keep a visible width).

How it is made:

* the page is the Jinja2 template ``templates/report.html.j2``, rendered with
  autoescaping: every string of the data (formulas contain ``<``, ``>`` and ``&``;
  a scenario's descriptions and values are whatever its author wrote) is text on the
  page, never markup.  This module only gathers what the template shows;
* ``static/report.css`` and ``static/report.js`` are package files inlined into the page
  when it is rendered, so the report is still one file that fetches nothing;
* the data the script needs (each run's compact trace, verdicts, evidence and re-run
  command, the colours of every value) is JSON in a ``<script type="application/json"
  id="report-data">`` block, with ``<``, ``>`` and ``&`` written as ``\\u003c`` etc., so no
  string can end the block;
* **every timeline is drawn by the script** (``static/report.js``), from the run's compact
  trace: the runs shown in full (the first violating run of each violated condition, at
  most :data:`MAX_DRAWN_TIMELINES`) as soon as the page loads, so a printed page shows
  them, and any other run when its row in the runs table is opened.  The geometry of a
  timeline is described there.

The page, top to bottom:

* **header** - scenario, number of runs, seed, duration, creation date, the
  provenance (versions, command line, input hash) and an overall badge;
* **summary** - the totals and the time spent per stage;
* **conditions** - one row per safety condition: formula and description, how many
  runs hold it, violate it or leave it undecided, and the first violating runs;
* **use cases** - how many runs exercised each use case;
* **coverage** - per criterion: a bar, ``covered/total`` and the situations never
  reached; a heat map of runs per situation for each two-variable criterion;
* **configurations** - per sampled configuration value, a histogram of its values
  with each bar split by verdict: which settings lead to violations;
* **runs** - one compact row per run: verdict (coloured), seed, one column per
  configuration value (unit in the header, three significant figures), use cases,
  violated conditions, links to its black box and scenario.  The table sorts by a
  click on a column header and filters by text and verdict; clicking a run opens
  its timeline, explanations and the command that re-runs it;
* **timelines** - a legend of every value and lane, then the first violating run of
  each violated condition, drawn in full: the trace, the condition's macros and atoms
  as extra rows, the window it required shaded.

Colours are deterministic and one per value on the whole page: hazard phases have
fixed colours (:data:`PHASE_COLOURS`), booleans dark (true) or light (false), and every
other value takes an :data:`ENUM_PALETTE` colour by its position in the sorted set of
all values of all variables of the report, so ``idle`` is the same colour in every lane.
"""

from __future__ import annotations

import functools
import itertools
import json
import math
import operator
import os
from statistics import median
from collections.abc import Iterable, Mapping, Sequence
from importlib import resources

import jinja2
import numpy as np
from markupsafe import Markup

from cellsim.atomic import write_text
from cellsim.kind import OUTRUN
from cellsim.numbers import instant, is_number, measure, percent, sig3
from cellsim.validation.verdict import RUN_GROUPS, Verdict

__all__ = [
    "BOOL_COLOURS",
    "DEFAULT_LANES",
    "ENUM_PALETTE",
    "MAX_DRAWN_TIMELINES",
    "PHASE_COLOURS",
    "render_report",
    "write_report",
]

FIRST_VIOLATING_SHOWN = 10  # violating runs linked per condition
MAX_DRAWN_TIMELINES = 20  # timelines drawn on load; every other run's is drawn when its row is opened
HISTOGRAM_BINS = 12

DEFAULT_LANES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("Safety mode", ("safmod",)),
    ("Hazard phases", ("HRW", "HS", "HC")),
    ("Sensors", ("lgtBar", "rngDet")),
    ("Operator", ("oloc", "otab")),
    ("Robot and welder", ("ract", "wact", "rloc")),
)
OTHER_GROUP = "Other variables"

PHASE_COLOURS = {
    "inact": "#bdbdbd",
    "act": "#fb8c00",
    "mit": "#c0ca33",
    "mit1": "#aed581",
    "mit2": "#7cb342",
    "res": "#42a5f5",
    "mis": "#e53935",
}
PHASE_SEQUENCE = ("#fb8c00", "#c0ca33", "#aed581", "#7cb342", "#42a5f5", "#ab47bc", "#8d6e63")
"""Colours of a risk model's own phases in declared order, between its initial (grey) and mishap (red)."""
BOOL_COLOURS = {True: "#37474f", False: "#cfd8dc"}
ENUM_PALETTE = (
    "#8dd3c7", "#ffed6f", "#bebada", "#fdb462", "#80b1d3", "#b3de69", "#fccde5", "#d9d9d9", "#bc80bd",
    "#ccebc5", "#e5c494", "#8da0cb", "#e78ac3", "#a6d854", "#66c2a5", "#fed9a6", "#b3cde3", "#decbe4",
    "#ffffcc", "#e5d8bd",
)
"""ColorBrewer Set3, then Set2 and Pastel1, without red (red means mishap or violation here); the
most distinct first, as values are given the first colour no value sharing a variable with them has."""
VIOLATION_COLOUR = "#d32f2f"
VERDICTS = RUN_GROUPS
"""The groups a run's verdict is shown in (``Verdict.group``), best first."""
VERDICT_COLOURS = dict(zip(RUN_GROUPS, ("#43a047", "#fb8c00", "#d32f2f", "#757575")))
STAGES = ("simulate", "trace", "check", "coverage", "report", "wall")
NAV = (("summary", "Summary"), ("conditions", "Conditions"), ("harm", "Harm"), ("use-cases", "Use cases"), ("coverage", "Coverage"),
       ("configurations", "Configurations"), ("runs", "Runs"), ("timelines", "Timelines"))

Samples = Sequence[Sequence[object]]
Timeline = Mapping[str, Samples]

# --------------------------------------------------------------------------- helpers


def _fmt(value: object) -> str:
    """A data value as short text: ``true``/``false``/``null``, 6 significant digits."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, (int, str)):
        return str(value)
    return json.dumps(value, sort_keys=True, default=str)


def _shown(value: object) -> object:
    """What ``{{ value }}`` prints (the template environment's ``finalize``): text as it is
    (then escaped), any other data value as :func:`_fmt` writes it (``None`` is ``null``)."""
    return value if isinstance(value, str) else _fmt(value)


def _seconds(t: object) -> str:
    """A duration in seconds with its unit, three significant figures, or a dash."""
    return "\u2014" if not is_number(t) else measure(t, "s")


def _instant(t: object) -> str:
    """A moment of a run (10 ms), or a dash."""
    return "\u2014" if not is_number(t) else instant(float(t))  # type: ignore[arg-type]


def _plural(n: int, noun: str) -> str:
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def _dict(value: object) -> dict:
    return value if isinstance(value, dict) else {}


def _list(value: object) -> list:
    return value if isinstance(value, list) else []


def _run_index(run: Mapping, position: int) -> int:
    index = run.get("index")
    return index if isinstance(index, int) and not isinstance(index, bool) else position


def _is_failed(run: Mapping) -> bool:
    return run.get("status") == Verdict.FAILED.value


def _violated(run: Mapping) -> list[str]:
    """The conditions ``run`` violates: its ``violations``, else its false verdicts."""
    if _is_failed(run):
        return []
    listed = [str(c) for c in _list(run.get("violations"))]
    from_verdicts = [str(c) for c, v in _dict(run.get("verdicts")).items()
                     if _status(_dict(v)) == Verdict.VIOLATED.value]
    return listed + [c for c in from_verdicts if c not in listed]


def _verdict_of(run: Mapping) -> str:
    """The group of a run's verdict (``Verdict.group``): failed, violated, undecided (a condition
    inconclusive or missing data) or holds."""
    known = {v.value for v in Verdict}
    statuses = [status for v in _dict(run.get("verdicts")).values() if (status := _status(_dict(v))) in known]
    if _violated(run):
        statuses.append(Verdict.VIOLATED.value)
    if _list(run.get("undecided")):
        statuses.append(Verdict.INCONCLUSIVE.value)
    return Verdict.of_run(statuses, failed=_is_failed(run)).group


def _status(verdict: Mapping) -> str | None:
    """A verdict's status; results written before statuses existed have only ``holds``."""
    status = verdict.get("status")
    if isinstance(status, str):
        return status
    holds = verdict.get("holds")
    return None if not isinstance(holds, bool) else (Verdict.HOLDS if holds else Verdict.VIOLATED).value


def _overall(coverage: Mapping) -> object:
    """The overall coverage fraction: ``totals.coverage.overall`` is ``{covered, total, fraction}``."""
    overall = coverage.get("overall")
    if isinstance(overall, Mapping):
        fraction, covered, total = overall.get("fraction"), overall.get("covered"), overall.get("total")
        if not is_number(fraction) and is_number(covered) and is_number(total) and total:
            fraction = covered / total
        return fraction
    return overall


def _with_unit(name: str, unit: object) -> str:
    return f"{name} ({unit})" if isinstance(unit, str) and unit else name


def _bar_width(fraction: object) -> str:
    """A coverage bar's filled share, as a CSS percentage."""
    width = 0.0 if not is_number(fraction) else min(max(float(fraction), 0.0), 1.0) * 100  # type: ignore[arg-type]
    return f"{width:.1f}%"


def _num(x: float) -> str:
    """An SVG coordinate."""
    return f"{x:.2f}"


# --------------------------------------------------------------------------- colours


def _kind(values: Iterable[object]) -> str:
    """``phase``, ``bool``, ``numeric`` or ``enum``: how a variable is drawn."""
    defined = [v for v in values if v is not None]
    if defined and all(isinstance(v, bool) for v in defined):
        return "bool"
    if defined and all(is_number(v) for v in defined):
        return "numeric"
    if defined and all(isinstance(v, str) and v in PHASE_COLOURS for v in defined):
        return "phase"
    return "enum"


class _Palette:
    """Kinds and colours of the variables over all the report's traces.

    A variable's kind (see :func:`_kind`) is computed once over every trace, and every
    enumeration value of every variable gets one colour by its place in the sorted set
    of all of them, so that a value has the same colour in every lane of the page.
    """

    def __init__(self, timelines: Iterable[Timeline], phases: Mapping[str, Mapping] | None = None) -> None:
        """``phases``: hazard variable -> its risk model's ``{values, initial, mishap}``."""
        self.phases = dict(phases or {})
        self.hazards = list(self.phases)
        self._phase_colours = {var: _phase_colours(spec) for var, spec in self.phases.items()}
        timelines = list(timelines)
        types: dict[str, set] = {}
        for timeline in timelines:  # first the types: a numeric variable's values are never collected
            for var, samples in timeline.items():
                types.setdefault(var, set()).update(type(s[1]) for s in samples if len(s) >= 2 and s[1] is not None)
        self.variables = list(types)
        """Every variable of every trace."""
        numeric = {var for var, seen in types.items() if seen and seen <= {int, float}}
        values: dict[str, set] = {var: set() for var in types if var not in numeric}
        for timeline in timelines:
            for var, samples in timeline.items():
                if var in values:
                    values[var].update((type(s[1]), s[1]) for s in samples if len(s) >= 2 and s[1] is not None)
        self._kinds = {var: _kind(v for _, v in vals) for var, vals in values.items()}
        self._kinds.update(dict.fromkeys(numeric, "numeric"))
        self.values = {var: sorted({_fmt(v) for _, v in vals}) for var, vals in values.items()}
        """Each non-numeric variable's values as text, sorted: what the legend lists."""
        self._enum = _colour_values([vals for var, vals in self.values.items() if self.kind(var) == "enum"])

    def kind(self, var: str) -> str:
        if var in self.phases:
            return "phase"
        return self._kinds.get(var, "enum")

    def colour(self, var: str, value: object) -> str:
        kind = self.kind(var)
        if var in self._phase_colours:
            return self._phase_colours[var].get(str(value), "#9e9e9e")
        if kind == "phase":
            return PHASE_COLOURS.get(str(value), "#9e9e9e")
        if kind == "bool" or isinstance(value, bool):
            return BOOL_COLOURS[bool(value)]
        return self._enum.get(_fmt(value), ENUM_PALETTE[-1])

    def colours(self) -> dict[str, dict[str, str]]:
        """Variable -> value text -> colour, for every drawn (non-numeric) variable: the script's palette."""
        return {var: {text: self._colour_of_text(var, text) for text in texts} for var, texts in self.values.items()}

    def phase_legend(self) -> list[tuple[list[str], dict[str, str]]]:
        """(hazards, their phases' colours): hazards with the same phases share one entry. Variables
        drawn as phases without a risk model's record (published phase names) get the published colours."""
        entries: list[tuple[list[str], dict[str, str]]] = []
        for var, colours in self._phase_colours.items():
            same = next((e for e in entries if e[1] == colours), None)
            if same:
                same[0].append(var)
            else:
                entries.append(([var], colours))
        others = [v for v in self.variables if v not in self.phases and self.kind(v) == "phase"]
        if others:
            seen = sorted({t for v in others for t in self.values.get(v, [])}, key=list(PHASE_COLOURS).index)
            entries.append((others, {t: PHASE_COLOURS[t] for t in seen}))
        return entries

    def _colour_of_text(self, var: str, text: str) -> str:
        if self.kind(var) == "bool":
            return BOOL_COLOURS[text == "true"]
        return self.colour(var, text)


def _colour_values(variables: Iterable[Sequence[str]]) -> dict[str, str]:
    """One colour per value text, different from every value it shares a variable with.

    Values are taken in sorted order and given the first :data:`ENUM_PALETTE` colour not
    yet used by a value of any of their variables (a greedy colouring), so ``idle`` is one
    colour in every lane, and ``near`` and ``close`` never look alike in theirs.
    """
    variables = [list(v) for v in variables]
    colours: dict[str, str] = {}
    for value in sorted({v for vals in variables for v in vals}):
        taken = {colours[other] for vals in variables if value in vals for other in vals if other in colours}
        free = [c for c in ENUM_PALETTE if c not in taken]
        colours[value] = free[0] if free else ENUM_PALETTE[len(colours) % len(ENUM_PALETTE)]
    return colours


def _phase_colours(spec: Mapping) -> dict[str, str]:
    """A hazard's phases coloured: the published ones as ever, otherwise initial grey, mishap red."""
    values = [str(v) for v in _list(spec.get("values"))]
    if values and all(v in PHASE_COLOURS for v in values):
        return {v: PHASE_COLOURS[v] for v in values}
    colours, others = {}, itertools.cycle(PHASE_SEQUENCE + ENUM_PALETTE)
    for v in values:
        if v == spec.get("initial"):
            colours[v] = PHASE_COLOURS["inact"]
        elif v == spec.get("mishap"):
            colours[v] = PHASE_COLOURS["mis"]
        else:
            colours[v] = next(others)
    return colours


# --------------------------------------------------------------------------- lanes


def _lane_groups(
    variables: Iterable[str], lanes: Sequence[tuple[str, Sequence[str]]] | None, hazards: Sequence[str] = ()
) -> list[tuple[str, list[str]]]:
    """The groups of lanes of the page's timelines, over its ``variables``; empty groups are dropped.

    With the default lanes, the hazards of the cell's risk model (``hazards``) fill
    the hazard-phase group, and variables not named there follow under "Other
    variables"; explicit ``lanes`` are drawn as given.  The script draws, for a run,
    the variables of these groups that its trace has.
    """
    variables = list(variables)
    default = [(title, tuple(hazards) if hazards and title == "Hazard phases" else names) for title, names in DEFAULT_LANES]
    groups = [(title, [v for v in names if v in variables]) for title, names in (lanes or default)]
    if lanes is None:
        named = {v for _, names in default for v in names}
        groups.append((OTHER_GROUP, sorted(v for v in variables if v not in named)))
    return [(title, names) for title, names in groups if names]


# --------------------------------------------------------------------------- what the sections show


def _conditions(results: Mapping) -> list[str]:
    """All condition names: the campaign's order first, then any others seen."""
    names = list(_dict(_dict(results.get("campaign")).get("conditions")))
    extra = list(_dict(_dict(results.get("totals")).get("violations")))
    for run in _list(results.get("runs")):
        extra.extend(_dict(_dict(run).get("verdicts")))
        extra.extend(str(c) for c in _list(_dict(run).get("violations")))
    for name in extra:
        if name not in names:
            names.append(name)
    return names


FINDING_RUNS = {
    "with blind spots": lambda f: f.get("what") == "blind spot",
    "with harm above its limits": lambda f: f.get("what") == "contact" and is_number(f.get("severity"))
    and f["severity"] > 1.0,
    "outrunning a measurement": lambda f: f.get("what") in OUTRUN,
}
"""What runs can show beside the conditions' verdicts, each a badge of the report's header and a line of the
campaign's summary: blind spots, contacts above their limits (a waived NoHarm's too), a measurement outrun between
two looks."""


def finding_runs(runs: Sequence[Mapping]) -> dict[str, list[int]]:
    """The indices of the runs that showed each of :data:`FINDING_RUNS` (only those some run showed)."""
    found = {what: [_run_index(r, i) for i, r in enumerate(runs)
                    if any(keep(_dict(f)) for f in _list(r.get("findings")))] for what, keep in FINDING_RUNS.items()}
    return {what: indices for what, indices in found.items() if indices}


def _violating_runs(runs: Sequence[Mapping]) -> list[tuple[int, Mapping]]:
    return [(_run_index(r, i), r) for i, r in enumerate(runs) if _violated(r)]


def _header(results: Mapping, runs: Sequence[Mapping]) -> dict:
    campaign = _dict(results.get("campaign"))
    record = _dict(results.get("provenance"))
    violating = _violating_runs(runs)
    planned = campaign.get("runs", len(runs))
    done = len(runs)  # (a failed run was made too: its badge says so)
    count = planned if planned == done or not is_number(planned) else f"{done} of {planned} planned"
    meta = [
        ("Scenario", campaign.get("scenario")),
        ("Budget" if results.get("search") else "Runs", count),
        ("Seed", campaign.get("seed")),
        ("Duration", _seconds(campaign["duration"]) if is_number(campaign.get("duration")) else None),
        ("Created", campaign.get("created")),
    ]
    return {
        "meta": [(label, value) for label, value in meta if value is not None],
        "violating_runs": len(violating),
        "violated_conditions": len({c for _, r in violating for c in _violated(r)}),
        "undecided_runs": sum(1 for r in runs if not _is_failed(r) and not _violated(r) and _list(r.get("undecided"))),
        "failed": sum(1 for r in runs if _is_failed(r)),
        "findings": {what: len(indices) for what, indices in finding_runs(runs).items()},
        "versions": ", ".join(f"{k} {v}" for k, v in _dict(record.get("versions")).items()),
        "command": record.get("command"),
        "input_hash": _dict(record.get("inputs")).get("hash"),
    }


def _summary(results: Mapping, runs: Sequence[Mapping]) -> dict:
    totals = _dict(results.get("totals"))
    coverage = _dict(totals.get("coverage"))
    timing = _dict(results.get("timing"))
    return {
        "figures": [
            ("Runs", totals.get("runs", len(runs))),
            ("Completed", totals.get("completed", sum(1 for r in runs if r.get("status") == "completed"))),
            ("Failed", totals.get("failed", sum(1 for r in runs if _is_failed(r)))),
            ("Violating runs", totals.get("violating_runs", len(_violating_runs(runs)))),
            *_run_figures(runs),
            *_cluster_figures(_dict(results.get("cluster"))),
        ],
        "coverage": percent(_overall(coverage)) if _has_criteria(coverage) else None,
        "timing": [(s, _seconds(timing[s])) for s in [s for s in STAGES if s in timing] + [s for s in timing if s not in STAGES]],
    }


def _run_figures(runs: Sequence[Mapping]) -> list[tuple[str, object]]:
    """Each numeric figure of the runs' summaries (a robot's work cycles) over the completed runs: its value,
    or its range and median; by subject when several modules give it."""
    found: dict[tuple[str, str], list[float]] = {}
    for run in runs:
        if run.get("status") != "completed":
            continue
        for subject, figures in _dict(run.get("figures")).items():
            for key, value in _dict(figures).items():
                if is_number(value):
                    found.setdefault((str(key), str(subject)), []).append(value)
    keys = [key for key, _ in found]
    return [(f"{key.replace('_', ' ').capitalize()} per run{f' ({subject})' if keys.count(key) > 1 else ''}",
             f"{v[0]:g}" if min(v) == max(v) else f"{min(v):g} to {max(v):g}, median {median(v):g}")
            for (key, subject), v in found.items()]


def _cluster_figures(cluster: Mapping) -> list[tuple[str, object]]:
    """The Dask cluster a campaign ran on, and how many of its runs were handed to another worker."""
    if not cluster:
        return []
    return [("Dask scheduler", cluster.get("scheduler")), ("Workers at the end", cluster.get("workers")),
            ("Retried runs", cluster.get("retries"))]


def _condition_rows(results: Mapping, runs: Sequence[Mapping]) -> list[dict]:
    campaign = _dict(results.get("campaign"))
    formulas, descriptions = _dict(campaign.get("conditions")), _dict(campaign.get("descriptions"))
    rows = []
    violated = [set(_violated(run)) for run in runs]  # once per run, not once per run and condition
    for name in _conditions(results):
        holding, violating, undecided, failed = 0, [], 0, 0
        for i, run in enumerate(runs):
            if _is_failed(run):  # never simulated: apart, as the bound leaves it out
                failed += 1
            elif name in violated[i]:
                violating.append(_run_index(run, i))
            elif _status(_dict(_dict(run.get("verdicts")).get(name))) == Verdict.HOLDS.value:
                holding += 1
            else:
                undecided += 1
        rows.append({
            "name": name, "formula": formulas.get(name), "description": descriptions.get(name),
            "holding": holding, "violating": len(violating), "undecided": undecided, "failed": failed,
            "first": violating[:FIRST_VIOLATING_SHOWN], "more": max(0, len(violating) - FIRST_VIOLATING_SHOWN),
        })
    return rows


SEVERITY_BINS = ((None, None, "no contact"), (-math.inf, 0.5, "up to 0.5"), (0.5, 1.0, "0.5 to 1 (within the limit)"),
                 (1.0, 2.0, "1 to 2 (harm)"), (2.0, math.inf, "2 and above (harm)"))
"""The bins of the worst contact severity per run: (above, at most, label); the first, the runs with no contact at
all (a contact at severity 0, parting or standing, is a contact: up to 0.5)."""


def _harm(results: Mapping, runs: Sequence[Mapping]) -> dict:
    """What the runs did to people's bodies: contacts by body region, the worst severity per run, blind spots, and
    the default conditions the scenario waives (with its reasons)."""
    completed = [r for r in runs if not _is_failed(r)]
    regions: dict[str, dict] = {}
    blind: dict[tuple[str, str], dict] = {}
    fast: list[dict] = []  # runs whose measurement was outrun between two looks (a part too fast, a margin falling)
    closest = None
    for run in completed:
        index = _run_index(run, runs.index(run))
        touched = set()
        for f in _list(run.get("findings")):
            f = _dict(f)
            if f.get("what") == "contact":
                row = regions.setdefault(str(f.get("region")), {"contacts": 0, "runs": set(), "harm": 0, "clamping": 0,
                                                               "worst": 0.0, "worst_run": None})
                severity = f.get("severity") if is_number(f.get("severity")) else 0.0
                row["contacts"] += 1
                touched.add(str(f.get("region")))
                row["runs"].add(index)
                row["harm"] += severity > 1.0
                row["clamping"] += f.get("kind") == "quasi_static"
                if severity >= row["worst"]:
                    row["worst"], row["worst_run"] = severity, index
            elif f.get("what") == "blind spot":
                key = (str(f.get("subject")), str(f.get("field")))
                entry = blind.setdefault(key, {"runs": set(), "seconds": 0.0})
                entry["runs"].add(index)
                end = f.get("end") if is_number(f.get("end")) else _dict(results.get("campaign")).get("duration")
                if is_number(end) and is_number(f.get("start")):
                    entry["seconds"] += end - f["start"]
            elif f.get("what") in OUTRUN:
                fast.append({"run": index, "text": str(f.get("text", ""))})
            elif f.get("what") == "closest approach" and is_number(f.get("distance")):
                if closest is None or f["distance"] < closest["distance"]:
                    closest = {**f, "run": index}
    measured = [r for r in completed if is_number(r.get("worst_severity"))]
    worst = [r["worst_severity"] for r in measured]
    touched_worst = [r["worst_severity"] for r in measured if _contacts(r)]
    bins = [{"label": label, "harm": lo is not None and lo >= 1.0,
             "runs": (len(measured) - len(touched_worst)) if lo is None else sum(1 for w in touched_worst if lo < w <= hi)}
            for lo, hi, label in SEVERITY_BINS]
    for b in bins:
        b["width"] = _bar_width(b["runs"] / len(worst)) if worst else "0%"
    return {
        "measured": bool(worst),
        "waived": _dict(_dict(results.get("campaign")).get("waived")),
        "regions": [{"region": name.replace("_", " "), **row, "runs": len(row["runs"]), "worst": sig3(row["worst"])}
                    for name, row in sorted(regions.items(), key=lambda kv: -kv[1]["worst"])],
        "bins": bins,
        "harmed_runs": sum(1 for w in worst if w > 1.0),
        "blind": [{"sensor": s, "field": fld, "runs": len(e["runs"]), "seconds": _seconds(e["seconds"])}
                  for (s, fld), e in sorted(blind.items())],
        "closest": closest,
        "fast": fast,
    }


def _bounds(results: Mapping) -> dict | None:
    """The campaign's violation rates and their upper bounds (results' ``bounds``), for people; None for
    results written before cellsim stated them."""
    from cellsim.validation.bound import probability

    bounds = _dict(results.get("bounds"))
    if not bounds or not isinstance(bounds.get("overall"), Mapping):
        return None

    def row(figures):
        figures = _dict(figures)
        return {"failures": figures.get("failures"), "runs": figures.get("runs"),
                "rate": probability(figures.get("rate")), "upper": probability(figures.get("upper_bound"))}

    return {
        "confidence": percent(bounds.get("confidence")),
        "method": bounds.get("method"), "counted": bounds.get("counted"), "sampling": bounds.get("sampling"),
        "overall": row(bounds["overall"]),
        "conditions": {str(name): row(f) for name, f in _dict(bounds.get("conditions")).items()},
    }


SEARCH_ROWS = 10
"""The most critical runs a falsification report lists."""


def _search(results: Mapping, runs: Sequence[Mapping]) -> dict | None:
    """A falsification search's record (results' ``search``) for people; None for a campaign."""
    search = _dict(results.get("search"))
    if not search:
        return None

    def score(run: Mapping) -> float:
        value = _dict(run.get("search")).get("score")
        return value if is_number(value) else math.inf

    ranked = sorted((r for r in runs if is_number(_dict(r.get("search")).get("score"))), key=score)[:SEARCH_ROWS]
    return {
        "method": search.get("method"), "batch": search.get("batch"), "budget": search.get("budget"),
        "conditions": ", ".join(map(str, _list(search.get("conditions")))),
        "guides": ", ".join(map(str, _list(search.get("guides")))) or "none",
        "first": search.get("first_violation"), "runs_to_first": search.get("runs_to_first_violation"),
        "runs": search.get("runs", len(runs)), "not_a_sample": search.get("not_a_sample"),
        "critical": [{"index": r.get("index"), "batch": _dict(r.get("search")).get("batch"),
                      "score": f"{score(r):.3f}", "violations": ", ".join(_violated(r)) or "-"} for r in ranked],
        "archive": [{"use_cases": ", ".join(map(str, _list(c.get("use_cases")))) or "none",
                     "situation": c.get("situation"), "score": f"{c['score']:.3f}" if is_number(c.get("score")) else "-"}
                    for c in (_dict(c) for c in _list(search.get("archive")))],
    }


def _use_case_rows(results: Mapping, runs: Sequence[Mapping]) -> list[dict]:
    campaign = _dict(results.get("campaign"))
    formulas, descriptions = _dict(campaign.get("use_cases")), _dict(campaign.get("descriptions"))
    counts = dict(_dict(_dict(results.get("totals")).get("use_cases")))
    if not counts:
        for run in runs:
            for u in _list(run.get("use_cases")):
                counts[str(u)] = counts.get(str(u), 0) + 1
    rows = []
    for name in list(formulas) + [u for u in counts if u not in formulas]:
        n = counts.get(name, 0)
        rows.append({"name": name, "formula": formulas.get(name), "description": descriptions.get(name), "runs": n,
                     "share": percent(n / len(runs)) if runs and is_number(n) else "n/a"})
    return rows


def _heatmap(name: str, c: Mapping) -> dict | None:
    """Runs per situation of a two-variable criterion: rows the first variable's values, columns the second's."""
    axes, counts, variables = _list(c.get("axes")), _list(c.get("runs")), _list(c.get("variables"))
    if len(axes) != 2 or len(variables) != 2 or len(counts) != len(_list(axes[0])) * len(_list(axes[1])):
        return None
    rows_of, cols_of = [_fmt(v) for v in axes[0]], [_fmt(v) for v in axes[1]]
    top = max([n for n in counts if is_number(n)] + [1])
    rows = []
    for i, r in enumerate(rows_of):
        cells = []
        for j, col in enumerate(cols_of):
            n = counts[i * len(cols_of) + j]
            shade = 0.15 + 0.75 * n / top if is_number(n) and n else 0.0
            cells.append({"runs": n, "tip": f"{variables[0]}={r}, {variables[1]}={col}: {_plural(n, 'run')}",
                          "shade": f"{shade:.2f}", "ink": "#fff" if shade > 0.6 else "#1b5e20"})
        rows.append((r, cells))
    return {"name": name, "variables": variables, "columns": cols_of, "rows": rows}


def _has_criteria(coverage: Mapping) -> bool:
    """Whether there is an overall coverage to show: some situation to cover (no criteria is not 100 %)."""
    total = _dict(coverage.get("overall")).get("total")
    return "overall" in coverage and not (is_number(total) and total == 0)


def _coverage(results: Mapping) -> dict:
    coverage = _dict(_dict(results.get("totals")).get("coverage"))
    criteria = []
    for name, c in _dict(coverage.get("criteria")).items():
        c = _dict(c)
        covered, total, fraction = c.get("covered"), c.get("total"), c.get("fraction")
        if not is_number(fraction) and is_number(covered) and is_number(total) and total:
            fraction = covered / total
        criteria.append({
            "name": name, "description": c.get("description"), "variables": _list(c.get("variables")),
            "bar": _bar_width(fraction), "covered": covered if covered is not None else "?",
            "total": total if total is not None else "?", "percent": percent(fraction),
            "missing": _list(c.get("missing")), "heatmap": _heatmap(name, c),
        })
    overall = _overall(coverage)
    return {"has_overall": _has_criteria(coverage), "bar": _bar_width(overall), "percent": percent(overall),
            "criteria": criteria, "heatmaps": [c["heatmap"] for c in criteria if c["heatmap"]]}


def _config_keys(runs: Sequence[Mapping]) -> list[str]:
    return list(dict.fromkeys(k for run in runs for k in _dict(run.get("configuration"))))


def _short_key(key: str, keys: Sequence[str]) -> str:
    """The shortest dotted tail of ``key`` no other key ends with (``bench.wait`` for ``operator.waypoints.bench.wait``)."""
    parts = key.split(".")
    for n in range(1, len(parts) + 1):
        tail = ".".join(parts[-n:])
        if not any(k != key and (k == tail or k.endswith("." + tail)) for k in keys):
            return tail
    return key


def _histogram(key: str, label: str, runs: Sequence[Mapping], verdicts: Sequence[str]) -> dict | None:
    """Values of one configuration key in bins, each bar stacked by the runs' ``verdicts``: an SVG's geometry."""
    points = [(_dict(r.get("configuration")).get(key), verdict) for r, verdict in zip(runs, verdicts)]
    numeric = [(float(v), verdict) for v, verdict in points if is_number(v) and math.isfinite(v)]
    if numeric and len(numeric) == len([p for p in points if p[0] is not None]):
        lo, hi = min(v for v, _ in numeric), max(v for v, _ in numeric)
        n_bins = 1 if hi == lo else HISTOGRAM_BINS
        width = (hi - lo) / n_bins if hi > lo else 1.0
        labels = [sig3(lo + width * (i + 0.5)) for i in range(n_bins)] if hi > lo else [sig3(lo)]
        counts = [dict.fromkeys(VERDICTS, 0) for _ in range(n_bins)]
        for v, verdict in numeric:
            counts[min(int((v - lo) / width), n_bins - 1) if hi > lo else 0][verdict] += 1
        ends = (sig3(lo), sig3(hi))
    else:
        values = sorted({_fmt(v) for v, _ in points if v is not None})
        labels, counts = values, [dict.fromkeys(VERDICTS, 0) for _ in values]
        for v, verdict in points:
            if v is not None:
                counts[values.index(_fmt(v))][verdict] += 1
        ends = (values[0], values[-1]) if values else ("", "")
    if not counts:
        return None
    w, h, left, bottom = 340.0, 120.0, 28.0, 18.0
    plot_w, plot_h = w - left - 6, h - bottom - 6
    top = max(sum(c.values()) for c in counts) or 1
    bar_w = plot_w / len(counts)
    bars = []
    for i, c in enumerate(counts):
        y = h - bottom
        for verdict in VERDICTS:
            if not (n := c[verdict]):
                continue
            bh = plot_h * n / top
            y -= bh
            bars.append({"verdict": verdict, "x": _num(left + i * bar_w + 0.5), "y": _num(y), "width": _num(max(bar_w - 1, 1)),
                         "height": _num(bh), "fill": VERDICT_COLOURS[verdict],
                         "tip": f"{label} ~ {labels[i]}: {_plural(n, 'run')} {verdict}"})
    return {
        "key": key, "label": label, "violated": sum(c["violated"] for c in counts), "bars": bars,
        "width": _num(w), "height": _num(h), "left": _num(left), "right": _num(w - 6), "base": _num(h - bottom),
        "ends": ends, "top": top, "top_y": _num(h - bottom - plot_h + 8), "label_x": _num(left - 3), "ends_y": _num(h - 5),
    }


def _configurations(results: Mapping, runs: Sequence[Mapping]) -> dict:
    keys = _config_keys(runs)
    units = _dict(_dict(results.get("campaign")).get("configuration_units"))
    verdicts = [_verdict_of(r) for r in runs]
    plots = [_histogram(k, _with_unit(_short_key(k, keys), units.get(k)), runs, verdicts) for k in keys]
    return {"sampled": keys, "histograms": [p for p in plots if p]}


def _contacts(run: Mapping) -> list[dict]:
    """A run's contacts with anybody (its ``contact`` findings)."""
    return [_dict(f) for f in _list(run.get("findings")) if _dict(f).get("what") == "contact"]


def _harm_cell(run: Mapping) -> dict:
    """What the runs table says of a run's harm: its closest approach (distance, whose region, time, and the speed
    and severity of a touch or the tool's speed at a near miss), its contacts (how many, the worst's severity and
    region) and each contact in words (``contacts``); ``worst``: that severity, for sorting (-1: no contact)."""
    found = [_dict(f) for f in _list(run.get("findings"))]
    closest = next((f for f in found if f.get("what") == "closest approach" and is_number(f.get("distance"))), None)
    contacts = _contacts(run)
    parts = []
    if closest is not None:
        parts.append(_closest_text(closest))
    worst = max((c for c in contacts if is_number(c.get("severity"))), key=lambda c: c["severity"], default=None)
    if worst is not None:
        parts.append(f"{len(contacts)} contact{'s' if len(contacts) != 1 else ''}, worst severity {sig3(worst['severity'])}"
                     f" ({str(worst.get('region', '')).replace('_', ' ')}, {sig3(worst.get('speed'))} m/s)")
    return {"text": "; ".join(parts), "worst": worst["severity"] if worst is not None else -1.0,
            "harm": worst is not None and worst["severity"] > 1.0, "contacts": [_contact_text(c) for c in contacts]}


def _closest_text(closest: Mapping) -> str:
    """A run's closest approach in the runs table: nobody within the cut-off, a near miss, or a touch."""
    region = str(closest.get("region") or "none")
    if region == "none":  # nobody came within the harm service's cut-off: its value, not a person's distance
        return f"closest: nobody within {sig3(closest['distance'])} m"
    when = f" at {sig3(closest['start'])} s" if is_number(closest.get("start")) else ""
    whose = f"{closest['person']}'s " if closest.get("person") else ""
    where = f"{whose}{region.replace('_', ' ')}"
    if closest["distance"] <= 0:
        how = (f", {sig3(closest['speed'])} m/s, severity {sig3(closest['severity'])}"
               if is_number(closest.get("speed")) and is_number(closest.get("severity")) else "")
        return f"touched {where}{when}, {sig3(-closest['distance'])} m deep{how}"
    tool = f", tool at {sig3(closest['tool_speed'])} m/s" if is_number(closest.get("tool_speed")) else ""
    return f"closest {sig3(closest['distance'])} m, {where}{when}{tool}"


def _contact_text(contact: Mapping) -> str:
    """One contact in words: when, whose region, by which part, its kind, speed and severity."""
    whose = f"{contact['person']}'s " if contact.get("person") else ""
    when = f"{sig3(contact['start'])} s" if is_number(contact.get("start")) else "?"
    kind = str(contact.get("kind") or "").replace("_", "-")
    return (f"{when}: {whose}{str(contact.get('region', '')).replace('_', ' ')} by {contact.get('part', '?')}, {kind}, "
            f"{sig3(contact.get('speed'))} m/s, severity {sig3(contact.get('severity'))}")


def _runs_table(results: Mapping, runs: Sequence[Mapping]) -> dict:
    """The runs table: its configuration columns and one row per run, ready to print."""
    keys = _config_keys(runs)
    units = _dict(_dict(results.get("campaign")).get("configuration_units"))
    columns = [{
        "key": k,
        "sort": "num" if all(is_number(_dict(r.get("configuration")).get(k, 0)) for r in runs) else "text",
        "label": _with_unit(_short_key(k, keys), units.get(k)).split("."),  # may wrap after each dot
    } for k in keys]
    rows = []
    for i, run in enumerate(runs):
        config = _dict(run.get("configuration"))
        out = run.get("out")
        rows.append({
            "index": _run_index(run, i),
            "verdict": _verdict_of(run),
            "error": run.get("error") if _is_failed(run) else None,
            "seed": run.get("seed", ""),
            "config": [sig3(config[k]) if k in config else "" for k in keys],
            "use_cases": ", ".join(_fmt(u) for u in _list(run.get("use_cases"))),
            "violated": ", ".join(_violated(run)),
            "harm": _harm_cell(run),
            "wall": run.get("wall_time", ""),
            "wall_text": _seconds(run.get("wall_time")),
            "folder": out.rstrip("/") if isinstance(out, str) and out else None,
        })
    return {"columns": columns, "rows": rows}


def _legend(palette: _Palette) -> list[dict]:
    """Every lane and every value drawn on the page with its colour: phases (by hazard), booleans,
    each enumeration's values, then the step plots.  Each lane's variable is named (``data-var``)."""
    rows = [{"variables": hazards, "title": None, "entries": list(colours.items())} for hazards, colours in palette.phase_legend()]
    booleans = [v for v in palette.variables if palette.kind(v) == "bool"]
    rows.append({"variables": booleans, "title": "Booleans",
                 "entries": [("true", BOOL_COLOURS[True]), ("false", BOOL_COLOURS[False])]})
    for var, texts in palette.values.items():
        if palette.kind(var) == "enum":
            rows.append({"variables": [var], "title": None, "entries": [(t, palette.colour(var, t)) for t in texts]})
    numeric = [v for v in palette.variables if palette.kind(v) == "numeric"]
    if numeric:
        rows.append({"variables": numeric, "title": "Step plots", "entries": []})
    return rows


def _timeline_of(timelines: Mapping, index: int) -> Timeline | None:
    found = timelines.get(index)
    if found is None:
        found = timelines.get(str(index))
    return found if isinstance(found, Mapping) else None


def _drawn(runs: Sequence[Mapping]) -> list[tuple[int, Mapping]]:
    """The violating runs drawn in full: the first of each violated condition, at most
    :data:`MAX_DRAWN_TIMELINES` (the page's load time grows with each); every run opens on demand."""
    first = {}
    for index, run in _violating_runs(runs):
        for name in _violated(run):
            first.setdefault(name, (index, run))
    chosen = list({index: (index, run) for index, run in first.values()}.values())
    return sorted(chosen[:MAX_DRAWN_TIMELINES], key=lambda item: item[0])


def _timelines(runs: Sequence[Mapping], traces: Mapping, palette: _Palette) -> dict:
    drawn = []
    for index, run in _drawn(runs):
        verdicts = _dict(run.get("verdicts"))
        explanations = []
        for name in _violated(run):
            verdict = _dict(verdicts.get(name))
            why = verdict.get("explanation")
            explanations.append((name, _instant(verdict.get("violated_at")), why if isinstance(why, str) and why else None))
        drawn.append({"index": index, "seed": run.get("seed", "?"), "explanations": explanations, "rerun": run.get("rerun"),
                      "folder": run.get("out"), "has_trace": bool(_timeline_of(traces, index))})
    violating = len(_violating_runs(runs))
    return {"violating": violating, "drawn": drawn, "more": violating - len(drawn), "legend": _legend(palette),
            "violation_colour": VIOLATION_COLOUR}


# --------------------------------------------------------------------------- the script's data


_time = operator.itemgetter(0)


def _compact(timeline: Timeline, palette: _Palette) -> dict[str, list]:
    """A trace for the script: ``{var: [time steps (ms), values]}``; repeated values dropped.

    Each time is the step from the previous sample's (the first from 0), in whole
    milliseconds: a 0.1-s series costs four characters a sample instead of six (samples
    are put in time order first, as the script reads steps forward). A
    numeric series is ``[steps, values, [lowest, highest]]``: its values rounded to the
    decimals that give its largest value four significant figures (a step plot 32 units
    tall shows no more), its exact extremes for the axis; it is held in numpy (300
    samples a run, 1000 runs: a Python loop per sample was half the report's time).
    """
    out = {}
    for var, samples in timeline.items():
        rows = [s for s in samples if len(s) >= 2 and is_number(s[0])]
        if any(map(operator.gt, map(_time, rows), map(_time, rows[1:]))):  # in time order already, as written
            rows.sort(key=_time)
        if palette.kind(var) == "numeric":
            out[var] = _compact_numbers(rows)
            continue
        times, values, last, previous = [], [], object(), 0
        for t, v in ((s[0], s[1]) for s in rows):
            v = None if v is None else _fmt(v)
            if v == last:
                continue
            now = round(float(t) * 1000)
            times.append(now - previous)
            values.append(v)
            last, previous = v, now
        out[var] = [times, values]
    return out


def _compact_numbers(rows: Sequence[Sequence[object]]) -> list:
    """A numeric series, compacted (see :func:`_compact`); undefined values (null, NaN) stay null."""
    if not rows:
        return [[], [], None]
    ms = np.round(np.array([float(r[0]) for r in rows]) * 1000).astype(np.int64)
    raw = [r[1] for r in rows]
    values = np.array([float(v) if is_number(v) else np.nan for v in raw])
    finite = np.isfinite(values)
    extremes = [float(values[finite].min()), float(values[finite].max())] if finite.any() else None
    top = float(np.max(np.abs(values[finite]))) if finite.any() else 0.0
    decimals = max(0, 3 - math.floor(math.log10(top))) if top > 0 else 0
    values = np.round(values, decimals)
    same = np.r_[False, (values[1:] == values[:-1]) | (~finite[1:] & ~finite[:-1])]
    keep = ~same
    steps = np.diff(np.r_[0, ms[keep]])
    kept = [None if not np.isfinite(v) else v for v in values[keep].tolist()]
    return [steps.tolist(), kept, extremes]


def _script_data(runs: Sequence[Mapping], traces: Mapping, duration: float,
                 lanes: Sequence[tuple[str, Sequence[str]]] | None, palette: _Palette, units: Mapping[str, str]) -> Markup:
    """The data the script draws timelines from, as JSON safe inside ``<script>``: ``<``, ``>``
    and ``&`` are written ``\\u003c``, ``\\u003e`` and ``\\u0026`` (the same string to JSON), so
    no string of the data can close the block or open a comment in it."""
    per_run = {}
    for i, run in enumerate(runs):
        index = _run_index(run, i)
        trace = _timeline_of(traces, index)
        verdicts = _dict(run.get("verdicts"))
        per_run[index] = {
            "trace": _compact(trace, palette) if trace else None,
            "violations": [[name, _dict(verdicts.get(name)).get("violated_at"), _dict(verdicts.get(name)).get("explanation")]
                           for name in _violated(run)],
            "evidence": _run_evidence(run),
            "rerun": run.get("rerun"),
            "error": run.get("error"),
        }
    data = {
        "duration": duration,
        "groups": _lane_groups(palette.variables, lanes, palette.hazards),
        "kinds": {var: palette.kind(var) for var in palette.variables},
        "colours": palette.colours(),
        "units": {var: unit for var, unit in units.items() if isinstance(unit, str)},
        "boolColours": {"true": BOOL_COLOURS[True], "false": BOOL_COLOURS[False]},
        "runs": per_run,
    }
    text = json.dumps(data, separators=(",", ":"), allow_nan=False, default=str)
    return Markup(text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026"))


def _run_evidence(run: Mapping) -> dict[str, dict]:
    """Violated condition -> its evidence (``{at, window, rows}``), for the conditions that carry one."""
    verdicts = _dict(run.get("verdicts"))
    return {name: ev for name in _violated(run) if (ev := _dict(_dict(verdicts.get(name)).get("evidence")))}


def _duration(results: Mapping, timelines: Iterable[Timeline]) -> float:
    """The campaign's duration, else the last sample time of any trace (at least 1 s)."""
    d = _dict(results.get("campaign")).get("duration")
    if is_number(d) and math.isfinite(d) and d > 0:
        return float(d)
    last = [float(s[0]) for tl in timelines for samples in tl.values() for s in samples if s and is_number(s[0])]
    return max([1.0, *last])


# --------------------------------------------------------------------------- the template


@functools.cache
def _environment() -> jinja2.Environment:
    """The report's templates (package data of :mod:`cellsim.campaign`), autoescaped."""
    env = jinja2.Environment(
        loader=jinja2.PackageLoader("cellsim.campaign", "templates"),
        autoescape=jinja2.select_autoescape(enabled_extensions=("html.j2",), default_for_string=True, default=True),
        undefined=jinja2.StrictUndefined,  # a misspelt name fails the report, not a blank cell
        finalize=_shown,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
    )
    env.filters.update(plural=_plural)
    return env


@functools.cache
def _assets() -> tuple[Markup, Markup]:
    """The page's style and script (``static/report.css``, ``static/report.js``), to inline.

    They are our own files, inlined as they are; each is checked not to hold what would end
    its element early (``</style``, ``</script``) or open a comment in the script."""
    static = resources.files("cellsim.campaign").joinpath("static")
    css = static.joinpath("report.css").read_text(encoding="utf-8")
    js = static.joinpath("report.js").read_text(encoding="utf-8")
    if "</style" in css.lower():
        raise ValueError("static/report.css must not contain '</style'")
    if "</script" in js.lower() or "<!--" in js:
        raise ValueError("static/report.js must not contain '</script' or '<!--'")
    return Markup(css), Markup(js)


# --------------------------------------------------------------------------- API


def render_report(
    results: Mapping,
    timelines: Mapping[int, Timeline] | None,
    lanes: Sequence[tuple[str, Sequence[str]]] | None = None,
    phases: Mapping[str, Mapping] | None = None,
) -> str:
    """The whole HTML report of a campaign.

    ``results`` is the campaign's results dictionary (``OUT/results.json``);
    ``timelines`` maps a run's index (int, or its decimal string as read back from
    JSON) to its trace ``{variable: [[t, value], ...]}``; ``lanes`` groups the timeline
    lanes as ``[(group title, [variable, ...]), ...]`` (default: :data:`DEFAULT_LANES`,
    then the traces' other variables); ``phases`` gives each hazard variable its risk
    model's ``{values, initial, mishap}`` (its lanes, colours and legend). Numeric lanes
    take their unit from ``results["campaign"]["units"]`` (variable -> unit).
    """
    runs = [r for r in _list(results.get("runs")) if isinstance(r, Mapping)]
    campaign = _dict(results.get("campaign"))
    traces = timelines or {}
    present = [t for t in (_timeline_of(traces, _run_index(r, i)) for i, r in enumerate(runs)) if t]
    palette = _Palette(present, phases)
    css, script = _assets()
    return _environment().get_template("report.html.j2").render(
        name=campaign.get("scenario_name") or campaign.get("scenario") or "campaign",
        nav=((("search", "Search"),) + NAV) if results.get("search") else NAV,
        search=_search(results, runs),
        excluded=_dict(results.get("bounds")).get("excluded"),
        header=_header(results, runs),
        summary=_summary(results, runs),
        conditions=_condition_rows(results, runs),
        harm=_harm(results, runs),
        bounds=_bounds(results),
        use_cases=_use_case_rows(results, runs),
        coverage=_coverage(results),
        configurations=_configurations(results, runs),
        verdicts=VERDICTS,
        verdict_colours=VERDICT_COLOURS,
        runs=_runs_table(results, runs),
        timelines=_timelines(runs, traces, palette),
        data=_script_data(runs, traces, _duration(results, present), lanes, palette, _dict(campaign.get("units"))),
        css=css,
        script=script,
    )


def write_report(
    path: str | os.PathLike,
    results: Mapping,
    timelines: Mapping[int, Timeline] | None,
    lanes: Sequence[tuple[str, Sequence[str]]] | None = None,
    phases: Mapping[str, Mapping] | None = None,
) -> None:
    """Renders the report and writes it to ``path`` atomically.

    Readers see the old report or the new one, never a partial one, and no
    temporary file is left behind, even on error (:func:`cellsim.atomic.write_text`).
    """
    write_text(path, render_report(results, timelines, lanes, phases), make_folder=True)
