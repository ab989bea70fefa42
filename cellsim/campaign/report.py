"""A self-contained HTML report of a test campaign, readable at thousands of runs.

:func:`render_report` turns a campaign's results dictionary (exactly what is written
to ``OUT/results.json``) and the traces of its runs into one HTML document;
:func:`write_report` writes it atomically.  The page needs nothing but a browser:
CSS and a small script are inline, plots are inline SVG, there are no external
assets.  Links point at files of the campaign folder beside it (a run's black box
and scenario).  It stays readable printed (colours are kept, timelines scale to the
page width and are not split across pages, short pieces keep a visible width).

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
  its timeline, explanations and the command that re-runs it (drawn by the script
  from the run's trace embedded in the page);
* **timelines** - the first violating run of each violated condition, drawn in full
  (as SVG in the page, so it prints): the trace, the condition's macros and atoms
  as extra rows, the window it required shaded, and a legend of every value.

Timeline geometry (SVG user units; the SVG has a ``viewBox`` and scales to the page
width): time ``t`` in ``[0, duration]`` maps to ``x = PLOT_LEFT + PLOT_WIDTH * t /
duration`` (:func:`time_to_x`, clamped), printed with two decimals.  Ticks every 5 s
(labels thinned when crowded).  One lane per variable, grouped under titles (see
:data:`DEFAULT_LANES`).  A trace ``{variable: [[t, value], ...]}`` is cut into constant
pieces by :func:`pieces`.  Each defined piece of an enumerated or boolean variable is a
``<rect class="piece" data-var="...">`` (at least :data:`MIN_PIECE_WIDTH` wide) in a
``<g>`` whose ``<title>`` reads ``var = value from t0 to t1 s``; numeric variables are a
step ``<polyline class="step">`` with a labelled axis in the variable's unit.  Each
violation is a red ``<line class="violation" data-condition="...">`` at its time; each
explained violation adds a group "Why <condition>" whose lanes are the condition's
macros and atoms (true/false pieces, ``data-var`` the macro's name or the atom as
written) and a ``<rect class="window" data-condition="...">`` shading the window the
condition required.

Colours are deterministic and one per value on the whole page: hazard phases have
fixed colours (:data:`PHASE_COLOURS`), booleans dark (true) or light (false), and every
other value takes an :data:`ENUM_PALETTE` colour by its position in the sorted set of
all values of all variables of the report, so ``idle`` is the same colour in every lane.

Every string from the data is escaped (formulas contain ``<``, ``>`` and ``&``; the
embedded data escapes ``<`` so no string can end the script).
"""

from __future__ import annotations

import itertools
import json
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from html import escape

import numpy as np

from cellsim.atomic import write_text
from cellsim.numbers import instant, is_number, measure, percent, sig3

__all__ = [
    "BOOL_COLOURS",
    "DEFAULT_LANES",
    "ENUM_PALETTE",
    "MIN_PIECE_WIDTH",
    "PHASE_COLOURS",
    "PLOT_LEFT",
    "PLOT_WIDTH",
    "SVG_WIDTH",
    "TICK_STEP",
    "pieces",
    "render_timeline",
    "render_report",
    "time_to_x",
    "write_report",
]

# --------------------------------------------------------------------------- layout

SVG_WIDTH = 1000.0
PLOT_LEFT = 170.0  # the lane labels sit left of this
PLOT_RIGHT_MARGIN = 20.0
PLOT_WIDTH = SVG_WIDTH - PLOT_LEFT - PLOT_RIGHT_MARGIN
TICK_STEP = 5.0  # seconds between ticks
MIN_LABEL_SPACING = 36.0  # tick labels closer than this are thinned
LANE_HEIGHT = 20.0
NUMERIC_LANE_HEIGHT = 40.0
LANE_GAP = 4.0
GROUP_HEADER = 18.0
AXIS_HEIGHT = 22.0  # tick labels above the lanes
MARKER_ROW = 13.0  # one row of violation labels
CHAR_WIDTH = 6.4  # approximate width of a character at font-size 11
MIN_PIECE_WIDTH = 1.5  # a piece of a few milliseconds stays visible on screen and on paper
FIRST_VIOLATING_SHOWN = 10  # violating runs linked per condition
MAX_DRAWN_TIMELINES = 20  # full SVG timelines in the page; every other run's is drawn on demand

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
VERDICT_COLOURS = {"violated": "#d32f2f", "undecided": "#fb8c00", "failed": "#757575", "holds": "#43a047"}
VERDICTS = ("holds", "undecided", "violated", "failed")
STAGES = ("simulate", "trace", "check", "coverage", "report", "wall")
HISTOGRAM_BINS = 12

Samples = Sequence[Sequence[object]]
Timeline = Mapping[str, Samples]

# --------------------------------------------------------------------------- helpers


def _e(value: object) -> str:
    """``value`` as escaped text (attribute-safe)."""
    return escape(value if isinstance(value, str) else _fmt(value), quote=True)


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


def _num(x: float) -> str:
    """An SVG coordinate."""
    return f"{x:.2f}"


def _seconds(t: object) -> str:
    """A duration in seconds with its unit, three significant figures, or a dash."""
    return "&mdash;" if not is_number(t) else measure(t, "s")


def _instant(t: object) -> str:
    """A moment of a run (10 ms), or a dash."""
    return "&mdash;" if not is_number(t) else instant(float(t))  # type: ignore[arg-type]


def _dict(value: object) -> dict:
    return value if isinstance(value, dict) else {}


def _list(value: object) -> list:
    return value if isinstance(value, list) else []


def _run_index(run: Mapping, position: int) -> int:
    index = run.get("index")
    return index if isinstance(index, int) and not isinstance(index, bool) else position


def _is_failed(run: Mapping) -> bool:
    return run.get("status") == "failed"


def _violated(run: Mapping) -> list[str]:
    """The conditions ``run`` violates: its ``violations``, else its false verdicts."""
    if _is_failed(run):
        return []
    listed = [str(c) for c in _list(run.get("violations"))]
    from_verdicts = [str(c) for c, v in _dict(run.get("verdicts")).items() if _status(_dict(v)) == "violated"]
    return listed + [c for c in from_verdicts if c not in listed]


def _verdict_of(run: Mapping) -> str:
    """One word for a run: ``failed``, ``violated``, ``undecided`` (a condition inconclusive or missing data) or ``holds``."""
    if _is_failed(run):
        return "failed"
    if _violated(run):
        return "violated"
    verdicts = [_status(_dict(v)) for v in _dict(run.get("verdicts")).values()]
    if _list(run.get("undecided")) or any(v not in ("holds", None) for v in verdicts):
        return "undecided"
    return "holds"


def _status(verdict: Mapping) -> str | None:
    """A verdict's status; results written before statuses existed have only ``holds``."""
    status = verdict.get("status")
    if isinstance(status, str):
        return status
    holds = verdict.get("holds")
    return None if not isinstance(holds, bool) else ("holds" if holds else "violated")


def _plural(n: int, noun: str) -> str:
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def _anchor(index: int) -> str:
    """The run's row in the runs table."""
    return f"run-{index}"


def _timeline_anchor(index: int) -> str:
    """The run's full timeline, for the runs drawn in the page."""
    return f"timeline-{index}"


def _overall(coverage: Mapping) -> object:
    """The overall coverage fraction: ``totals.coverage.overall`` is ``{covered, total, fraction}``."""
    overall = coverage.get("overall")
    if isinstance(overall, Mapping):
        fraction, covered, total = overall.get("fraction"), overall.get("covered"), overall.get("total")
        if not is_number(fraction) and is_number(covered) and is_number(total) and total:
            fraction = covered / total
        return fraction
    return overall


def _fit(label: str) -> str:
    """A lane label cut to the room left of the plot (the whole label is the element's title)."""
    room = int((PLOT_LEFT - 10) / CHAR_WIDTH)
    return label if len(label) <= room else label[: room - 1] + "\u2026"


def _breakable(key: str) -> str:
    """A dotted key, escaped, that may wrap after each dot."""
    return ".<wbr>".join(_e(part) for part in key.split("."))


def _with_unit(name: str, unit: object) -> str:
    return f"{name} ({unit})" if isinstance(unit, str) and unit else name


# --------------------------------------------------------------------------- pieces


def time_to_x(t: float, duration: float) -> float:
    """The SVG ``x`` of time ``t`` on a timeline of ``duration`` seconds (clamped)."""
    if duration <= 0:
        return PLOT_LEFT
    t = min(max(float(t), 0.0), duration)
    return PLOT_LEFT + PLOT_WIDTH * t / duration


def pieces(samples: Samples, duration: float) -> list[tuple[float, float, object]]:
    """The constant pieces ``(t0, t1, value)`` of a variable over ``[0, duration)``.

    A sample ``[t, value]`` holds from ``t`` to the next sample (the last one to
    ``duration``); samples are sorted by time, samples at or after ``duration`` are
    dropped, pieces are clipped to ``[0, duration)``, and consecutive pieces with the
    same value (and type) merge.  ``None`` pieces (undefined stretches) are kept.
    """
    ordered = sorted(
        ((float(s[0]), s[1]) for s in samples if len(s) >= 2 and is_number(s[0])),
        key=lambda s: s[0],
    )
    result: list[tuple[float, float, object]] = []
    for i, (t0, value) in enumerate(ordered):
        t1 = ordered[i + 1][0] if i + 1 < len(ordered) else duration
        t0, t1 = max(t0, 0.0), min(t1, duration)
        if t1 <= t0:
            continue
        last = result[-1] if result else None
        if last and last[2] == value and type(last[2]) is type(value) and last[1] == t0:
            result[-1] = (last[0], t1, value)
        else:
            result.append((t0, t1, value))
    return result


def _held_samples(intervals: Iterable[Sequence[float]]) -> list[list]:
    """Intervals where something held, as a boolean trace ``[[t, true|false], ...]`` from 0."""
    samples: list[list] = [[0.0, False]]
    for interval in intervals:
        if len(interval) == 2 and is_number(interval[0]) and is_number(interval[1]):
            samples += [[float(interval[0]), True], [float(interval[1]), False]]
    return samples


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


def _text_colour(fill: str) -> str:
    """Black or white, whichever reads better on ``fill`` (``#rrggbb``)."""
    r, g, b = (int(fill[i : i + 2], 16) for i in (1, 3, 5))
    return "#000" if 0.299 * r + 0.587 * g + 0.114 * b > 140 else "#fff"


# --------------------------------------------------------------------------- timeline SVG


def _lane_groups(
    timeline: Timeline, lanes: Sequence[tuple[str, Sequence[str]]] | None, hazards: Sequence[str] = ()
) -> list[tuple[str, list[str]]]:
    """The groups of lanes to draw: variables absent from the trace are skipped.

    With the default lanes, the hazards of the cell's risk model (``hazards``) fill
    the hazard-phase group, and variables of the trace not named there follow under
    "Other variables"; explicit ``lanes`` are drawn as given.
    """
    default = [(title, tuple(hazards) if hazards and title == "Hazard phases" else names) for title, names in DEFAULT_LANES]
    groups = [(title, [v for v in names if v in timeline]) for title, names in (lanes or default)]
    if lanes is None:
        named = {v for _, names in default for v in names}
        others = sorted(v for v in timeline if v not in named)
        groups.append((OTHER_GROUP, others))
    return [(title, names) for title, names in groups if names]


def _axis(duration: float, top: float, bottom: float) -> list[str]:
    """Tick lines every :data:`TICK_STEP` seconds, labels thinned when crowded."""
    out = []
    if duration <= 0:
        return out
    per_tick = PLOT_WIDTH * TICK_STEP / duration
    every = max(1, math.ceil(MIN_LABEL_SPACING / per_tick)) if per_tick > 0 else 1
    n = int(math.floor(duration / TICK_STEP + 1e-9))
    for k in range(n + 1):
        t = k * TICK_STEP
        x = _num(time_to_x(t, duration))
        out.append(f'<line class="tick" x1="{x}" x2="{x}" y1="{_num(top - 4)}" y2="{_num(bottom)}"/>')
        if k % every == 0:
            out.append(f'<text class="tick-label" x="{x}" y="{_num(top - 7)}">{t:g} s</text>')
    return out


def _piece_rects(var: str, var_pieces, colour, duration: float, top: float) -> list[str]:
    """One ``rect.piece`` per defined piece, at least :data:`MIN_PIECE_WIDTH` wide; ``colour(value)``.

    Pieces that had to be widened are drawn last, over their neighbours: otherwise the next
    piece would cover all but their true width again."""
    out = []
    narrow = lambda piece: time_to_x(piece[1], duration) - time_to_x(piece[0], duration) < MIN_PIECE_WIDTH  # noqa: E731
    for t0, t1, value in sorted(var_pieces, key=narrow):  # stable: in time order within each kind
        if value is None:
            continue
        x0, x1 = time_to_x(t0, duration), time_to_x(t1, duration)
        width = max(x1 - x0, MIN_PIECE_WIDTH)
        fill = colour(value)
        text = _fmt(value)
        tip = f"{var} = {text} from {instant(t0)} to {instant(t1)}"
        parts = [
            f"<g><title>{_e(tip)}</title>",
            f'<rect class="piece" data-var="{_e(var)}" x="{_num(x0)}" y="{_num(top)}" '
            f'width="{_num(width)}" height="{_num(LANE_HEIGHT)}" fill="{fill}"/>',
        ]
        if x1 - x0 >= len(text) * CHAR_WIDTH + 6:
            parts.append(
                f'<text class="piece-label" x="{_num((x0 + x1) / 2)}" y="{_num(top + LANE_HEIGHT / 2 + 4)}" '
                f'fill="{_text_colour(fill)}">{_e(text)}</text>'
            )
        parts.append("</g>")
        out.append("".join(parts))
    return out


def _step_plot(var: str, var_pieces, duration: float, top: float, unit: str = "") -> list[str]:
    """A step polyline (one per defined stretch) scaled to the lane, with a labelled axis in ``unit``."""
    defined = [v for _, _, v in var_pieces if is_number(v) and math.isfinite(v)]
    if not defined:
        return []
    lo, hi = min(defined), max(defined)
    inner_top, inner_h = top + 4, NUMERIC_LANE_HEIGHT - 8

    def y(v: float) -> float:
        return inner_top + inner_h / 2 if hi == lo else inner_top + inner_h * (hi - v) / (hi - lo)

    suffix = f" {unit}" if unit else ""
    tip = _e(f"{var}: min {sig3(lo)}{suffix}, max {sig3(hi)}{suffix}")
    out, points = [], []

    def flush() -> None:
        if points:
            out.append(f'<polyline class="step" data-var="{_e(var)}" points="{" ".join(points)}"><title>{tip}</title></polyline>')
            points.clear()

    for t0, t1, v in var_pieces:
        if not (is_number(v) and math.isfinite(v)):
            flush()
            continue
        yy = _num(y(v))
        points.extend((f"{_num(time_to_x(t0, duration))},{yy}", f"{_num(time_to_x(t1, duration))},{yy}"))
    flush()
    ticks = [hi] if hi == lo else [hi, lo]
    axis = [f'<line class="y-axis" x1="{_num(PLOT_LEFT)}" x2="{_num(PLOT_LEFT)}" y1="{_num(inner_top)}" y2="{_num(inner_top + inner_h)}"/>']
    for v in ticks:
        yy = y(v)
        axis.append(f'<line class="y-tick" x1="{_num(PLOT_LEFT - 3)}" x2="{_num(PLOT_LEFT + PLOT_WIDTH)}" y1="{_num(yy)}" y2="{_num(yy)}"/>')
        axis.append(f'<text class="y-label" x="{_num(PLOT_LEFT + 3)}" y="{_num(yy + (9 if v == hi else -2))}">{_e(sig3(v) + suffix)}</text>')
    return axis + out


def _marker_rows(markers: list[tuple[float, str]]) -> list[tuple[float, str, int, bool]]:
    """Places violation labels on rows so they do not overlap: ``(x, name, row, anchor_end)``."""
    rows_end: list[float] = []
    placed = []
    for x, name in sorted(markers):
        width = len(name) * CHAR_WIDTH + 6
        anchor_end = x + width > SVG_WIDTH
        span = (x - width, x) if anchor_end else (x, x + width)
        for row, end in enumerate(rows_end):
            if span[0] > end:
                rows_end[row] = span[1]
                break
        else:
            row = len(rows_end)
            rows_end.append(span[1])
        placed.append((x, name, row, anchor_end))
    return placed


def _markers(violations: list[tuple[str, float]], duration: float, label_top: float, bottom: float) -> list[str]:
    out = []
    xs = [(time_to_x(t, duration), name) for name, t in violations]
    by_name = dict(violations)
    for x, name, row, anchor_end in _marker_rows(xs):
        label_y = label_top + (row + 1) * MARKER_ROW - 3
        tx, anchor = (x - 3, "end") if anchor_end else (x + 3, "start")
        tip = f"{name} violated at {instant(by_name[name])}"
        out.append(
            f'<g><title>{_e(tip)}</title>'
            f'<line class="violation" data-condition="{_e(name)}" x1="{_num(x)}" x2="{_num(x)}" '
            f'y1="{_num(label_y - 9)}" y2="{_num(bottom)}" stroke="{VIOLATION_COLOUR}"/>'
            f'<text class="violation-label" x="{_num(tx)}" y="{_num(label_y)}" text-anchor="{anchor}">{_e(name)}</text></g>'
        )
    return out


def _windows(evidence: Mapping[str, Mapping], duration: float, top: float, bottom: float) -> list[str]:
    """A shaded ``rect.window`` per explained violation: where the condition required something."""
    out = []
    for name, ev in evidence.items():
        window = _list(ev.get("window"))
        if len(window) != 2 or not all(is_number(w) for w in window):
            continue
        x0, x1 = time_to_x(window[0], duration), time_to_x(window[1], duration)
        tip = f"{name}: required between {instant(window[0])} and {instant(window[1])}"
        out.append(
            f'<g><title>{_e(tip)}</title><rect class="window" data-condition="{_e(name)}" x="{_num(x0)}" '
            f'y="{_num(top)}" width="{_num(max(x1 - x0, 2 * MIN_PIECE_WIDTH))}" height="{_num(bottom - top)}"/></g>'
        )
    return out


def _run_violation_times(run: Mapping) -> list[tuple[str, float]]:
    """``(condition, violated_at)`` for each violated condition with a finite time."""
    verdicts = _dict(run.get("verdicts"))
    out = []
    for name in _violated(run):
        t = _dict(verdicts.get(name)).get("violated_at")
        if is_number(t) and math.isfinite(t):
            out.append((name, float(t)))
    return out


def _run_evidence(run: Mapping) -> dict[str, dict]:
    """Violated condition -> its evidence (``{at, window, rows}``), for the conditions that carry one."""
    verdicts = _dict(run.get("verdicts"))
    return {name: ev for name in _violated(run) if (ev := _dict(_dict(verdicts.get(name)).get("evidence")))}


def render_timeline(
    timeline: Timeline,
    duration: float,
    violations: Sequence[tuple[str, float]] = (),
    lanes: Sequence[tuple[str, Sequence[str]]] | None = None,
    palette: _Palette | None = None,
    evidence: Mapping[str, Mapping] | None = None,
    units: Mapping[str, str] | None = None,
) -> str:
    """One run's trace as an inline SVG (see the module docstring for the geometry).

    ``evidence`` maps a violated condition to its ``{window, rows}``
    (:meth:`cellsim.validation.explain.Explainer.evidence`): its rows are drawn under
    "Why <condition>" and its window shaded; ``units`` gives numeric variables their unit.
    """
    palette = palette or _Palette([timeline])
    units = units or {}
    groups = [(title, [(v, timeline[v]) for v in names]) for title, names in _lane_groups(timeline, lanes, palette.hazards)]
    for name, ev in (evidence or {}).items():
        rows = [(row, _held_samples(_list(intervals))) for row, intervals in _dict(ev.get("rows")).items()]
        if rows:
            groups.append((f"Why {name}", rows))
    placed = _marker_rows([(time_to_x(t, duration), name) for name, t in violations])
    n_rows = 1 + max((row for _, _, row, _ in placed), default=-1)
    label_top = 2.0
    axis_top = label_top + n_rows * MARKER_ROW + AXIS_HEIGHT
    body: list[str] = []
    y = axis_top
    for title, lanes_of_group in groups:
        body.append(f'<text class="group" x="4" y="{_num(y + 12)}">{_e(title)}</text>')
        y += GROUP_HEADER
        explaining = title.startswith("Why ")
        for var, samples in lanes_of_group:
            numeric = not explaining and palette.kind(var) == "numeric"
            h = NUMERIC_LANE_HEIGHT if numeric else LANE_HEIGHT
            var_pieces = pieces(samples, duration)
            label = var if explaining or not numeric else _with_unit(var, units.get(var))
            body.append(
                f'<text class="lane-label" x="{_num(PLOT_LEFT - 6)}" y="{_num(y + h / 2 + 4)}">'
                f"<title>{_e(label)}</title>{_e(_fit(label))}</text>"
            )
            body.append(
                f'<rect class="lane" x="{_num(PLOT_LEFT)}" y="{_num(y)}" width="{_num(PLOT_WIDTH)}" height="{_num(h)}"/>'
            )
            if numeric:
                body.extend(_step_plot(var, var_pieces, duration, y, units.get(var, "")))
            else:
                colour = (lambda v: BOOL_COLOURS[bool(v)]) if explaining else (lambda v, var=var: palette.colour(var, v))
                body.extend(_piece_rects(var, var_pieces, colour, duration, y))
            y += h + LANE_GAP
    height = y + 4
    parts = [
        f'<svg class="timeline" viewBox="0 0 {_num(SVG_WIDTH)} {_num(height)}" '
        f'width="100%" role="img" aria-label="timeline">',
        *_axis(duration, axis_top, y - LANE_GAP),
        *_windows(evidence or {}, duration, axis_top + GROUP_HEADER, y - LANE_GAP),
        *body,
        *_markers(list(violations), duration, label_top, y - LANE_GAP),
        "</svg>",
    ]
    return "\n".join(parts)


# --------------------------------------------------------------------------- HTML sections

CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; margin: 1.5em auto;
       max-width: 1200px; padding: 0 1em; color: #212121; line-height: 1.4;
       -webkit-print-color-adjust: exact; print-color-adjust: exact; }
h1 { margin-bottom: 0.2em; }
h2 { border-bottom: 2px solid #e0e0e0; padding-bottom: 0.2em; margin-top: 1.6em; }
dl.meta { display: grid; grid-template-columns: max-content auto; gap: 0.1em 1em; }
dl.meta dt { font-weight: 600; }
dl.meta dd { margin: 0; word-break: break-all; }
.badge { display: inline-block; padding: 0.25em 0.7em; border-radius: 1em; font-weight: 600;
         margin-right: 0.5em; border: 1px solid transparent; }
.badge.ok { background: #e8f5e9; color: #1b5e20; border-color: #66bb6a; }
.badge.bad { background: #ffebee; color: #b71c1c; border-color: #e57373; }
.badge.warn { background: #fff8e1; color: #e65100; border-color: #ffb74d; }
table { border-collapse: collapse; margin: 0.5em 0; font-size: 0.92em; }
th, td { border: 1px solid #e0e0e0; padding: 0.25em 0.5em; text-align: left; vertical-align: top; }
th { background: #f5f5f5; }
td.num, th.num { text-align: right; font-variant-numeric: tabular-nums; }
code, pre { font-family: ui-monospace, "SFMono-Regular", Menlo, Consolas, monospace; font-size: 0.9em; }
pre { white-space: pre-wrap; word-break: break-all; margin: 0; }
code.formula { white-space: pre-wrap; word-break: break-word; }
tr.violating td { background: #ffebee; }
tr.failed td { background: #fff8e1; }
.error { color: #b71c1c; }
.bar { display: inline-block; width: 160px; height: 0.8em; background: #eeeeee;
       border: 1px solid #bdbdbd; vertical-align: middle; }
.bar span { display: block; height: 100%; background: #43a047; }
ul.missing { margin: 0.2em 0; padding-left: 1.2em; }
.muted { color: #757575; }
.legend { line-height: 1.9; }
.legend span.swatch { display: inline-block; width: 0.9em; height: 0.9em; border: 1px solid #9e9e9e;
                      vertical-align: middle; margin: 0 0.25em 0 0.8em; }
.verdict { font-weight: 600; }
.verdict.holds { color: #1b5e20; } .verdict.violated { color: #b71c1c; }
.verdict.undecided { color: #e65100; } .verdict.failed { color: #616161; }
table.runs { font-size: 0.85em; }
table.runs td, table.runs th { padding: 0.15em 0.4em; white-space: nowrap; }
table.runs th { white-space: normal; vertical-align: bottom; max-width: 9em; }
table.timing caption { white-space: nowrap; text-align: left; }
table.runs th[data-sort] { cursor: pointer; user-select: none; }
table.runs th[data-sort]::after { content: " \\2195"; color: #bdbdbd; }
table.runs th.sorted-asc::after { content: " \\25B2"; color: #424242; }
table.runs th.sorted-desc::after { content: " \\25BC"; color: #424242; }
table.runs a.open { font-weight: 600; }
tr.details > td { background: #fafafa; white-space: normal; }
.filters { margin: 0.5em 0; }
.filters input, .filters select { font: inherit; padding: 0.15em 0.4em; }
table.heatmap td { text-align: center; min-width: 3.2em; font-variant-numeric: tabular-nums; }
table.heatmap td.never { background: #ffebee; color: #b71c1c; }
.plots { display: flex; flex-wrap: wrap; gap: 0.5em 1.5em; }
figure.histogram { margin: 0; }
figure.histogram figcaption { font-size: 0.85em; }
svg.histogram { width: 340px; height: auto; }
svg.histogram text { font-size: 10px; font-family: system-ui, sans-serif; fill: #424242; }
svg.histogram .axis { stroke: #9e9e9e; }
section.run { margin-top: 1.2em; break-inside: avoid; }
svg.timeline { max-width: 1100px; display: block; margin: 0.5em 0; }
svg.timeline text { font-size: 11px; font-family: system-ui, sans-serif; }
svg.timeline .tick { stroke: #e0e0e0; stroke-width: 1; }
svg.timeline .tick-label { fill: #616161; text-anchor: middle; }
svg.timeline .group { font-weight: 600; fill: #424242; }
svg.timeline .lane { fill: none; stroke: #e0e0e0; }
svg.timeline .lane-label { text-anchor: end; fill: #212121; }
svg.timeline .piece { shape-rendering: crispEdges; }
svg.timeline .piece-label { text-anchor: middle; pointer-events: none; }
svg.timeline .step { fill: none; stroke: #1565c0; stroke-width: 1.5; }
svg.timeline .y-axis { stroke: #9e9e9e; }
svg.timeline .y-tick { stroke: #eeeeee; stroke-dasharray: 2 3; }
svg.timeline .y-label { fill: #616161; font-size: 9px; }
svg.timeline .window { fill: #ffe082; fill-opacity: 0.45; stroke: #ff8f00; stroke-dasharray: 4 2; }
svg.timeline .violation { stroke: #d32f2f; stroke-width: 1.5; }
svg.timeline .violation-label { fill: #d32f2f; font-weight: 600; }
nav a { margin-right: 1em; }
@media print {
  body { max-width: none; margin: 0; }
  nav, .filters { display: none; }
  section.run, table tr { break-inside: avoid; }
  svg.timeline { max-width: 100%; }
}
"""


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


def _violating_runs(runs: Sequence[Mapping]) -> list[tuple[int, Mapping]]:
    return [(_run_index(r, i), r) for i, r in enumerate(runs) if _violated(r)]


def _provenance_rows(results: Mapping) -> list[tuple[str, str | None]]:
    """Versions, command line and input hash of the campaign (``results["provenance"]``), as HTML."""
    record = _dict(results.get("provenance"))
    versions = ", ".join(f"{k} {v}" for k, v in _dict(record.get("versions")).items())
    digest = _dict(record.get("inputs")).get("hash")
    return [
        ("Versions", _e(versions) if versions else None),
        ("Command", f"<code>{_e(record['command'])}</code>" if record.get("command") else None),
        ("Input hash", f'<code title="{_e(digest)}">{_e(str(digest)[:16])}</code>' if digest else None),
    ]


def _header(results: Mapping, runs: Sequence[Mapping]) -> str:
    campaign = _dict(results.get("campaign"))
    name = campaign.get("scenario_name") or campaign.get("scenario") or "campaign"
    violating = _violating_runs(runs)
    conditions = {c for _, r in violating for c in _violated(r)}
    failed = sum(1 for r in runs if _is_failed(r))
    if violating:
        verb = "violate" if len(violating) != 1 else "violates"
        badge = (
            f'<span class="badge bad">{_plural(len(violating), "run")} {verb} '
            f'{_plural(len(conditions), "condition")}</span>'
        )
    else:
        badge = '<span class="badge ok">no violations</span>'
    if failed:
        badge += f'<span class="badge warn">{_plural(failed, "run")} failed</span>'
    text = lambda key: _e(campaign[key]) if campaign.get(key) is not None else None  # noqa: E731
    meta = [
        ("Scenario", text("scenario")),
        ("Runs", _e(campaign.get("runs", len(runs)))),
        ("Seed", text("seed")),
        ("Duration", _seconds(campaign["duration"]) if is_number(campaign.get("duration")) else None),
        ("Created", text("created")),
        *_provenance_rows(results),
    ]
    rows = "".join(f"<dt>{k}</dt><dd>{v}</dd>" for k, v in meta if v is not None)
    nav = "".join(
        f'<a href="#{a}">{t}</a>'
        for a, t in (("summary", "Summary"), ("conditions", "Conditions"), ("use-cases", "Use cases"),
                     ("coverage", "Coverage"), ("configurations", "Configurations"), ("runs", "Runs"),
                     ("timelines", "Timelines"))
    )
    return (
        f"<header><h1>Test campaign: {_e(name)}</h1>\n<p>{badge}</p>\n"
        f'<dl class="meta">{rows}</dl>\n<nav>{nav}</nav></header>'
    )


def _summary(results: Mapping, runs: Sequence[Mapping]) -> str:
    totals = _dict(results.get("totals"))
    coverage = _dict(totals.get("coverage"))
    figures = [
        ("Runs", totals.get("runs", len(runs))),
        ("Completed", totals.get("completed", sum(1 for r in runs if r.get("status") == "completed"))),
        ("Failed", totals.get("failed", sum(1 for r in runs if _is_failed(r)))),
        ("Violating runs", totals.get("violating_runs", len(_violating_runs(runs)))),
    ]
    rows = "".join(f'<tr><th>{k}</th><td class="num">{_e(v)}</td></tr>' for k, v in figures)
    if "overall" in coverage:
        rows += f'<tr><th>Coverage</th><td class="num" id="coverage-figure">{percent(_overall(coverage))}</td></tr>'
    timing = _dict(results.get("timing"))
    stages = [s for s in STAGES if s in timing] + [s for s in timing if s not in STAGES]
    timing_rows = "".join(
        f'<tr><th>{_e(s)}</th><td class="num">{_seconds(timing[s])}</td></tr>' for s in stages
    )
    timing_table = (
        '<table class="timing"><caption>Time per stage (stages are summed over workers, '
        '"wall" is elapsed)</caption>'
        f"<tbody>{timing_rows}</tbody></table>"
        if stages
        else '<p class="muted">No timing recorded.</p>'
    )
    return (
        '<section id="summary"><h2>Summary</h2>\n'
        f'<table class="totals"><tbody>{rows}</tbody></table>\n{timing_table}</section>'
    )


def _formula_cell(formula: object, description: object) -> str:
    html = f'<code class="formula">{_e(formula)}</code>' if formula is not None else ""
    if isinstance(description, str) and description:
        html += f'<br><span class="muted">{_e(description)}</span>'
    return html


def _condition_rows(results: Mapping, runs: Sequence[Mapping]) -> str:
    campaign = _dict(results.get("campaign"))
    formulas, descriptions = _dict(campaign.get("conditions")), _dict(campaign.get("descriptions"))
    rows = []
    violated = [set(_violated(run)) for run in runs]  # once per run, not once per run and condition
    for name in _conditions(results):
        holding, violating, unchecked = 0, [], 0
        for i, run in enumerate(runs):
            verdict = _dict(_dict(run.get("verdicts")).get(name))
            if name in violated[i]:
                violating.append(_run_index(run, i))
            elif _status(verdict) == "holds":
                holding += 1
            else:
                unchecked += 1
        links = ", ".join(f'<a href="#{_anchor(i)}">{i}</a>' for i in violating[:FIRST_VIOLATING_SHOWN])
        if len(violating) > FIRST_VIOLATING_SHOWN:
            links += f' <span class="muted">and {len(violating) - FIRST_VIOLATING_SHOWN} more</span>'
        cls = ' class="violating"' if violating else ""
        rows.append(
            f"<tr{cls}><td><strong>{_e(name)}</strong></td><td>{_formula_cell(formulas.get(name), descriptions.get(name))}</td>"
            f'<td class="num">{holding}</td><td class="num">{len(violating)}</td>'
            f'<td class="num">{unchecked}</td><td>{links}</td></tr>'
        )
    return "\n".join(rows)


def _conditions_section(results: Mapping, runs: Sequence[Mapping]) -> str:
    rows = _condition_rows(results, runs)
    if not rows:
        return '<section id="conditions"><h2>Conditions</h2><p class="muted">No conditions checked.</p></section>'
    return (
        '<section id="conditions"><h2>Conditions</h2>\n<table><thead><tr><th>Condition</th><th>Formula</th>'
        '<th class="num">Holding</th><th class="num">Violating</th><th class="num" title="inconclusive, missing data, or the run failed">Undecided</th>'
        f"<th>First violating runs</th></tr></thead>\n<tbody>\n{rows}\n</tbody></table></section>"
    )


def _use_cases_section(results: Mapping, runs: Sequence[Mapping]) -> str:
    campaign = _dict(results.get("campaign"))
    formulas, descriptions = _dict(campaign.get("use_cases")), _dict(campaign.get("descriptions"))
    counts = dict(_dict(_dict(results.get("totals")).get("use_cases")))
    if not counts:
        for run in runs:
            for u in _list(run.get("use_cases")):
                counts[str(u)] = counts.get(str(u), 0) + 1
    names = list(formulas) + [u for u in counts if u not in formulas]
    if not names:
        return '<section id="use-cases"><h2>Use cases</h2><p class="muted">No use cases defined.</p></section>'
    total = len(runs)
    rows = []
    for name in names:
        n = counts.get(name, 0)
        share = percent(n / total) if total and is_number(n) else "n/a"
        cls = ' class="failed"' if n == 0 else ""
        rows.append(
            f"<tr{cls}><td><strong>{_e(name)}</strong></td><td>{_formula_cell(formulas.get(name), descriptions.get(name))}</td>"
            f'<td class="num">{_e(n)}</td><td class="num">{share}</td></tr>'
        )
    return (
        '<section id="use-cases"><h2>Use cases</h2>\n<table><thead><tr><th>Use case</th><th>Formula</th>'
        '<th class="num">Runs</th><th class="num">Share</th></tr></thead>\n<tbody>\n'
        + "\n".join(rows)
        + "\n</tbody></table></section>"
    )


def _bar(fraction: object) -> str:
    width = 0.0 if not is_number(fraction) else min(max(float(fraction), 0.0), 1.0) * 100  # type: ignore[arg-type]
    return f'<span class="bar"><span style="width: {width:.1f}%"></span></span>'


def _heatmap(name: str, c: Mapping) -> str:
    """Runs per situation of a two-variable criterion: rows the first variable's values, columns the second's."""
    axes, counts, variables = _list(c.get("axes")), _list(c.get("runs")), _list(c.get("variables"))
    if len(axes) != 2 or len(variables) != 2 or len(counts) != len(_list(axes[0])) * len(_list(axes[1])):
        return ""
    rows_of, cols_of = [str(v) for v in axes[0]], [str(v) for v in axes[1]]
    top = max([n for n in counts if is_number(n)] + [1])
    head = "".join(f"<th>{_e(v)}</th>" for v in cols_of)
    body = []
    for i, r in enumerate(rows_of):
        cells = []
        for j, col in enumerate(cols_of):
            n = counts[i * len(cols_of) + j]
            tip = f"{variables[0]}={r}, {variables[1]}={col}: {_plural(n, 'run')}"
            if not n:
                cells.append(f'<td class="never" title="{_e(tip)}">0</td>')
                continue
            shade = 0.15 + 0.75 * n / top
            colour = "#fff" if shade > 0.6 else "#1b5e20"
            cells.append(f'<td title="{_e(tip)}" style="background: rgba(67,160,71,{shade:.2f}); color: {colour}">{n}</td>')
        body.append(f"<tr><th>{_e(r)}</th>{''.join(cells)}</tr>")
    return (
        f'<figure class="heatmap-figure"><figcaption><strong>{_e(name)}</strong>: runs in each situation '
        f'(rows {_e(variables[0])}, columns {_e(variables[1])}; red: never reached)</figcaption>'
        f'<table class="heatmap" data-criterion="{_e(name)}"><thead><tr><th></th>{head}</tr></thead>'
        f"<tbody>{''.join(body)}</tbody></table></figure>"
    )


def _coverage_section(results: Mapping) -> str:
    coverage = _dict(_dict(results.get("totals")).get("coverage"))
    criteria = _dict(coverage.get("criteria"))
    head = '<section id="coverage"><h2>Coverage</h2>\n'
    if "overall" in coverage:
        head += f"<p>Overall: {_bar(_overall(coverage))} {percent(_overall(coverage))}</p>\n"
    if not criteria:
        return head + '<p class="muted">No coverage criteria.</p></section>'
    rows, maps = [], []
    for name, c in criteria.items():
        c = _dict(c)
        covered, total = c.get("covered"), c.get("total")
        fraction = c.get("fraction")
        if not is_number(fraction) and is_number(covered) and is_number(total) and total:
            fraction = covered / total
        variables = ", ".join(_e(v) for v in _list(c.get("variables")))
        missing = _list(c.get("missing"))
        missing_html = (
            '<ul class="missing">' + "".join(f"<li>{_e(m)}</li>" for m in missing) + "</ul>"
            if missing
            else '<span class="muted">none</span>'
        )
        desc = f'<div class="muted">{_e(c["description"])}</div>' if c.get("description") else ""
        rows.append(
            f"<tr><td><strong>{_e(name)}</strong>{desc}</td><td>{variables}</td>"
            f"<td>{_bar(fraction)}</td>"
            f'<td class="num">{_e(covered if covered is not None else "?")}/{_e(total if total is not None else "?")}</td>'
            f'<td class="num">{percent(fraction)}</td><td>{missing_html}</td></tr>'
        )
        maps.append(_heatmap(name, c))
    maps_html = "".join(m for m in maps if m)
    return (
        head
        + "<table><thead><tr><th>Criterion</th><th>Variables</th><th>Covered</th>"
        '<th class="num">Situations</th><th class="num">Fraction</th><th>Missing situations</th></tr></thead>\n<tbody>\n'
        + "\n".join(rows)
        + "\n</tbody></table>\n"
        + (f'<h3>Situations by runs</h3><div class="plots">{maps_html}</div>' if maps_html else "")
        + "</section>"
    )


# --------------------------------------------------------------------------- configurations


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


def _histogram(key: str, label: str, runs: Sequence[Mapping], verdicts: Sequence[str]) -> str:
    """Values of one configuration key in bins, each bar stacked by the runs' ``verdicts`` (an SVG figure)."""
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
        return ""
    w, h, left, bottom = 340.0, 120.0, 28.0, 18.0
    plot_w, plot_h = w - left - 6, h - bottom - 6
    top = max(sum(c.values()) for c in counts) or 1
    bar_w = plot_w / len(counts)
    bars = []
    for i, c in enumerate(counts):
        y = h - bottom
        for verdict in VERDICTS:
            n = c[verdict]
            if not n:
                continue
            bh = plot_h * n / top
            y -= bh
            tip = f"{label} ~ {labels[i]}: {_plural(n, 'run')} {verdict}"
            bars.append(
                f'<rect class="bin {verdict}" x="{_num(left + i * bar_w + 0.5)}" y="{_num(y)}" width="{_num(max(bar_w - 1, 1))}" '
                f'height="{_num(bh)}" fill="{VERDICT_COLOURS[verdict]}"><title>{_e(tip)}</title></rect>'
            )
    violated = sum(c["violated"] for c in counts)
    axis = (
        f'<line class="axis" x1="{_num(left)}" x2="{_num(w - 6)}" y1="{_num(h - bottom)}" y2="{_num(h - bottom)}"/>'
        f'<text x="{_num(left)}" y="{_num(h - 5)}">{_e(ends[0])}</text>'
        f'<text x="{_num(w - 6)}" y="{_num(h - 5)}" text-anchor="end">{_e(ends[1])}</text>'
        f'<text x="{_num(left - 3)}" y="{_num(h - bottom - plot_h + 8)}" text-anchor="end">{top}</text>'
        f'<text x="{_num(left - 3)}" y="{_num(h - bottom)}" text-anchor="end">0</text>'
    )
    return (
        f'<figure class="histogram" data-key="{_e(key)}"><figcaption><code>{_e(label)}</code>'
        f' <span class="muted">{_plural(violated, "violating run")}</span></figcaption>'
        f'<svg class="histogram" viewBox="0 0 {_num(w)} {_num(h)}" role="img" aria-label="{_e(label)} against verdicts">'
        f"{axis}{''.join(bars)}</svg></figure>"
    )


def _configurations_section(results: Mapping, runs: Sequence[Mapping]) -> str:
    keys = _config_keys(runs)
    if not keys:
        return '<section id="configurations"><h2>Configurations</h2><p class="muted">No sampled configuration.</p></section>'
    units = _dict(_dict(results.get("campaign")).get("configuration_units"))
    legend = "".join(
        f'<span class="swatch" style="background: {VERDICT_COLOURS[v]}"></span>{v}' for v in VERDICTS
    )
    verdicts = [_verdict_of(r) for r in runs]
    plots = "".join(_histogram(k, _with_unit(_short_key(k, keys), units.get(k)), runs, verdicts) for k in keys)
    return (
        '<section id="configurations"><h2>Configurations against verdicts</h2>\n'
        f'<p class="legend">Each sampled value in bins; bars split by the runs\' verdicts:{legend}.</p>'
        f'<div class="plots">{plots}</div></section>'
    )


# --------------------------------------------------------------------------- runs table


def _status_cell(run: Mapping) -> str:
    verdict = _verdict_of(run)
    title = ""
    if _is_failed(run) and run.get("error") is not None:
        title = f' title="{_e(run["error"])}"'
    return f'<td class="verdict {verdict}" data-value="{verdict}"{title}>{verdict}</td>'


def _file_links(run: Mapping) -> str:
    out = run.get("out")
    if not isinstance(out, str) or not out:
        return "<td></td>"
    folder = escape(out.rstrip("/"), quote=True)
    return f'<td><a href="{folder}/blackbox.sqlite">black box</a> <a href="{folder}/scenario.yaml">scenario</a></td>'


def _runs_section(results: Mapping, runs: Sequence[Mapping]) -> str:
    if not runs:
        return '<section id="runs"><h2>Runs</h2><p class="muted">No runs.</p></section>'
    keys = _config_keys(runs)
    units = _dict(_dict(results.get("campaign")).get("configuration_units"))
    numeric = {k: all(is_number(_dict(r.get("configuration")).get(k, 0)) for r in runs) for k in keys}
    config_head = "".join(
        f'<th class="num" data-sort="{"num" if numeric[k] else "text"}" title="{_e(k)}">'
        f"<code>{_breakable(_with_unit(_short_key(k, keys), units.get(k)))}</code></th>"
        for k in keys
    )
    rows = []
    for i, run in enumerate(runs):
        index = _run_index(run, i)
        violated = _violated(run)
        verdict = _verdict_of(run)
        cls = ' class="violating"' if verdict == "violated" else ' class="failed"' if verdict == "failed" else ""
        config = _dict(run.get("configuration"))
        cells = "".join(
            f'<td class="num">{_e(sig3(config[k]))}</td>' if k in config else '<td class="num"></td>'
            for k in keys
        )
        use_cases = ", ".join(_e(u) for u in _list(run.get("use_cases")))
        rows.append(
            f'<tr id="{_anchor(index)}" data-run="{index}" data-verdict="{verdict}"{cls}>'
            f'<td class="num" data-value="{index}"><a class="open" href="#{_anchor(index)}">{index}</a></td>'
            f'{_status_cell(run)}<td class="num" data-value="{_e(run.get("seed", ""))}">{_e(run.get("seed", ""))}</td>'
            f"{cells}<td>{use_cases}</td><td>{', '.join(_e(c) for c in violated)}</td>"
            f'<td class="num" data-value="{_e(run.get("wall_time", ""))}">{_seconds(run.get("wall_time"))}</td>{_file_links(run)}</tr>'
        )
    options = "".join(f'<option value="{v}">{v}</option>' for v in VERDICTS)
    return (
        '<section id="runs"><h2>Runs</h2>\n'
        '<p class="filters"><label>Filter <input type="search" id="run-filter" placeholder="text in a row, e.g. HS:detected"></label> '
        f'<label>Verdict <select id="verdict-filter"><option value="">all</option>{options}</select></label> '
        f'<span id="run-count" class="muted">{_plural(len(runs), "run")}</span> '
        '<span class="muted">Click a column to sort, a run to open its timeline.</span></p>\n'
        '<table class="runs" id="runs-table"><thead><tr><th class="num" data-sort="num">Run</th>'
        '<th data-sort="text">Verdict</th><th class="num" data-sort="num">Seed</th>'
        f'{config_head}<th data-sort="text">Use cases</th><th data-sort="text">Violated</th>'
        '<th class="num" data-sort="num">Wall</th><th>Files</th></tr></thead>\n<tbody>\n'
        + "\n".join(rows)
        + "\n</tbody></table></section>"
    )


# --------------------------------------------------------------------------- timelines


def _legend(palette: _Palette) -> str:
    """Every value drawn on the page with its colour: phases, booleans, then each variable's values."""
    rows = [(", ".join(hazards), list(colours.items())) for hazards, colours in palette.phase_legend()]
    rows.append(("Booleans", [("true", BOOL_COLOURS[True]), ("false", BOOL_COLOURS[False])]))
    for var, texts in palette.values.items():
        if palette.kind(var) == "enum":
            rows.append((var, [(t, palette.colour(var, t)) for t in texts]))
    items = "".join(
        f"<div><strong>{_e(title)}</strong>"
        + "".join(f'<span class="swatch" style="background: {c}"></span>{_e(n)}' for n, c in entries)
        + "</div>"
        for title, entries in rows
    )
    return (
        f'<div class="legend">{items}<div><span style="color: {VIOLATION_COLOUR}">Red lines</span> mark violations; '
        '<span style="background: #ffe08299; border: 1px dashed #ff8f00">&nbsp;shaded&nbsp;</span> the window a violated '
        "condition required; rows under &ldquo;Why&rdquo; show where each of its macros and atoms held (dark: true). "
        "Hover a piece for its value and times.</div></div>"
    )


def _timeline_key(timelines: Mapping, index: int) -> Timeline | None:
    found = timelines.get(index)
    if found is None:
        found = timelines.get(str(index))
    return found if isinstance(found, Mapping) else None


def _explanations(run: Mapping) -> str:
    verdicts = _dict(run.get("verdicts"))
    items = []
    for name in _violated(run):
        verdict = _dict(verdicts.get(name))
        why = verdict.get("explanation")
        why = f": {_e(why)}" if isinstance(why, str) and why else ""
        items.append(f"<li><strong>{_e(name)}</strong> violated at {_instant(verdict.get('violated_at'))}{why}</li>")
    return f"<ul>{''.join(items)}</ul>"


def _run_timeline_section(
    run: Mapping, index: int, timeline: Timeline | None, duration: float,
    lanes: Sequence[tuple[str, Sequence[str]]] | None, palette: _Palette, units: Mapping[str, str],
) -> str:
    rerun = f'<p>Re-run: <code>{_e(run["rerun"])}</code></p>' if run.get("rerun") else ""
    out = f'<p class="muted">Run folder: <code>{_e(run["out"])}</code></p>' if run.get("out") else ""
    if timeline:
        plot = render_timeline(timeline, duration, _run_violation_times(run), lanes, palette, _run_evidence(run), units)
    else:
        plot = '<p class="muted">No trace available for this run.</p>'
    return (
        f'<section class="run" id="{_timeline_anchor(index)}"><h3>Run <a href="#{_anchor(index)}">{index}</a> '
        f'<span class="muted">(seed {_e(run.get("seed", "?"))})</span></h3>\n'
        f"{_explanations(run)}\n{rerun}{out}\n{plot}\n</section>"
    )


def _duration(results: Mapping, timelines: Iterable[Timeline]) -> float:
    """The campaign's duration, else the last sample time of any trace (at least 1 s)."""
    d = _dict(results.get("campaign")).get("duration")
    if is_number(d) and math.isfinite(d) and d > 0:
        return float(d)
    last = [float(s[0]) for tl in timelines for samples in tl.values() for s in samples if s and is_number(s[0])]
    return max([1.0, *last])


def _drawn(runs: Sequence[Mapping]) -> list[tuple[int, Mapping]]:
    """The violating runs drawn in full: the first of each violated condition, at most
    :data:`MAX_DRAWN_TIMELINES` (a drawn timeline is some 35 kB; every run's opens on demand)."""
    violating = _violating_runs(runs)
    first = {}
    for index, run in violating:
        for name in _violated(run):
            first.setdefault(name, (index, run))
    chosen = list({index: (index, run) for index, run in first.values()}.values())
    return sorted(chosen[:MAX_DRAWN_TIMELINES], key=lambda item: item[0])


def _timelines_section(
    runs: Sequence[Mapping], traces: Mapping, duration: float,
    lanes: Sequence[tuple[str, Sequence[str]]] | None, palette: _Palette, units: Mapping[str, str],
) -> str:
    violating = _violating_runs(runs)
    if not violating:
        return (
            '<section id="timelines"><h2>Timelines</h2><p class="muted">No violating runs. '
            "Open any run in the table to see its timeline.</p>" + _legend(palette) + "</section>"
        )
    drawn = _drawn(runs)
    more = len(violating) - len(drawn)
    note = (
        f'<p class="muted">{_plural(len(drawn), "violating run")} drawn here (the first of each violated condition); '
        f"open any other run in the table to draw its timeline ({more} more violating).</p>"
        if more else ""
    )
    sections = [
        _run_timeline_section(run, index, _timeline_key(traces, index), duration, lanes, palette, units)
        for index, run in drawn
    ]
    return (
        '<section id="timelines"><h2>Timelines of violating runs</h2>\n' + note + _legend(palette) + "\n"
        + "\n".join(sections) + "</section>"
    )


# --------------------------------------------------------------------------- the script and its data


def _compact(timeline: Timeline, palette: _Palette) -> dict[str, list]:
    """A trace for the script: ``{var: [time steps (ms), values]}``; repeated values dropped.

    Each time is the step from the previous sample's (the first from 0), in whole
    milliseconds: a 0.1-s series costs four characters a sample instead of six. A
    numeric series is ``[steps, values, [lowest, highest]]``: its values rounded to the
    decimals that give its largest value four significant figures (a step plot 32 units
    tall shows no more), its exact extremes for the axis; it is held in numpy (300
    samples a run, 1000 runs: a Python loop per sample was half the report's time).
    """
    out = {}
    for var, samples in timeline.items():
        rows = [s for s in samples if len(s) >= 2 and is_number(s[0])]
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
                 lanes: Sequence[tuple[str, Sequence[str]]] | None, palette: _Palette, units: Mapping[str, str]) -> str:
    """The data the script draws timelines from, as JSON safe inside ``<script>``."""
    per_run = {}
    for i, run in enumerate(runs):
        index = _run_index(run, i)
        trace = _timeline_key(traces, index)
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
        "groups": _lane_groups(dict.fromkeys(palette.variables), lanes, palette.hazards),
        "kinds": {var: palette.kind(var) for var in palette.variables},
        "colours": palette.colours(),
        "units": dict(units),
        "runs": per_run,
        "geometry": {"svgWidth": SVG_WIDTH, "plotLeft": PLOT_LEFT, "plotWidth": PLOT_WIDTH, "lane": LANE_HEIGHT,
                     "numericLane": NUMERIC_LANE_HEIGHT, "gap": LANE_GAP, "group": GROUP_HEADER, "tick": TICK_STEP,
                     "minPiece": MIN_PIECE_WIDTH, "labelRoom": int((PLOT_LEFT - 10) / CHAR_WIDTH),
                     "charWidth": CHAR_WIDTH, "markerRow": MARKER_ROW, "axisHeight": AXIS_HEIGHT,
                     "minLabelSpacing": MIN_LABEL_SPACING},
        "boolColours": {"true": BOOL_COLOURS[True], "false": BOOL_COLOURS[False]},
    }
    text = json.dumps(data, separators=(",", ":"), allow_nan=False, default=str)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


SCRIPT = r"""
(function () {
  "use strict";
  var table = document.getElementById("runs-table");
  if (!table) return;
  var data = null;
  function load() {
    if (!data) data = JSON.parse(document.getElementById("report-data").textContent);
    return data;
  }
  var body = table.tBodies[0];
  var rows = Array.prototype.slice.call(body.rows);
  var count = document.getElementById("run-count");
  function cellValue(row, col, kind) {
    var cell = row.cells[col];
    var v = cell.getAttribute("data-value");
    if (v === null) v = cell.textContent;
    if (kind === "num") { var n = parseFloat(v); return isNaN(n) ? -Infinity : n; }
    return v.toLowerCase();
  }
  Array.prototype.forEach.call(table.tHead.rows[0].cells, function (th, col) {
    var kind = th.getAttribute("data-sort");
    if (!kind) return;
    th.addEventListener("click", function () {
      var asc = !th.classList.contains("sorted-asc");
      Array.prototype.forEach.call(table.tHead.rows[0].cells, function (h) { h.classList.remove("sorted-asc", "sorted-desc"); });
      th.classList.add(asc ? "sorted-asc" : "sorted-desc");
      closeAll();
      rows.sort(function (a, b) {
        var x = cellValue(a, col, kind), y = cellValue(b, col, kind);
        return (x < y ? -1 : x > y ? 1 : 0) * (asc ? 1 : -1);
      });
      rows.forEach(function (r) { body.appendChild(r); });
    });
  });
  var text = document.getElementById("run-filter"), verdict = document.getElementById("verdict-filter");
  function filter() {
    var q = text.value.trim().toLowerCase(), want = verdict.value, shown = 0;
    closeAll();
    rows.forEach(function (r) {
      var ok = (!want || r.getAttribute("data-verdict") === want) && (!q || r.textContent.toLowerCase().indexOf(q) >= 0);
      r.hidden = !ok;
      if (ok) shown++;
    });
    count.textContent = shown + " of " + rows.length + " runs";
  }
  text.addEventListener("input", filter);
  verdict.addEventListener("change", filter);
  function closeAll() {
    Array.prototype.slice.call(body.querySelectorAll("tr.details")).forEach(function (d) { d.remove(); });
  }
  function esc(s) { return String(s).replace(/[&<>"]/g, function (c) { return {"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;"}[c]; }); }
  function instant(t) { return t.toFixed(2) + " s"; }  // as cellsim.numbers: a moment of a run, 10 ms
  function sig3(x) {  // as cellsim.numbers.sig3: the exponent is the rounded value's; two-digit exponents
    if (typeof x !== "number" || !isFinite(x)) return String(x);
    if (x === 0) return "0";
    var e = x.toExponential(2).split("e"), exponent = parseInt(e[1], 10);
    if (exponent >= -3 && exponent < 5) return x.toFixed(Math.max(0, 2 - exponent));
    var digits = String(Math.abs(exponent));
    return e[0] + "e" + (exponent < 0 ? "-" : "+") + (digits.length < 2 ? "0" + digits : digits);
  }
  function textColour(fill) {  // as the page's own _text_colour: black or white, whichever reads better
    var r = parseInt(fill.slice(1, 3), 16), gr = parseInt(fill.slice(3, 5), 16), bl = parseInt(fill.slice(5, 7), 16);
    return 0.299 * r + 0.587 * gr + 0.114 * bl > 140 ? "#000" : "#fff";
  }
  function pieces(steps, values, duration) {
    var out = [], times = [], t = 0;
    steps.forEach(function (step) { t += step; times.push(t); });
    for (var i = 0; i < times.length; i++) {
      var t0 = Math.max(times[i] / 1000, 0), t1 = Math.min(i + 1 < times.length ? times[i + 1] / 1000 : duration, duration);
      if (t1 > t0) out.push([t0, t1, values[i]]);
    }
    return out;
  }
  function heldTrace(intervals) {  // as a compact trace: steps in ms from the previous sample
    var t = [0], v = ["false"], last = 0;
    intervals.forEach(function (iv) {
      t.push(Math.round(iv[0] * 1000) - last, Math.round((iv[1] - iv[0]) * 1000));
      last = Math.round(iv[0] * 1000) + Math.round((iv[1] - iv[0]) * 1000);
      v.push("true", "false");
    });
    return [t, v];
  }
  function markerRows(marks) {  // as _marker_rows: labels on rows so that none overlaps another
    var ends = [], g = load().geometry;
    return marks.slice().sort(function (a, b) { return a[0] - b[0]; }).map(function (m) {
      var width = m[1].length * g.charWidth + 6, atEnd = m[0] + width > g.svgWidth;
      var from = atEnd ? m[0] - width : m[0], to = atEnd ? m[0] : m[0] + width, row = 0;
      while (row < ends.length && !(from > ends[row])) row++;
      ends[row] = to;
      return [m[0], m[1], row, atEnd];
    });
  }
  function timeline(run) {  // as render_timeline: the same layout, from the run's compact trace
    var d = load(), g = d.geometry, dur = d.duration, parts = [];
    function X(t) { return g.plotLeft + g.plotWidth * Math.min(Math.max(t, 0), dur) / dur; }
    var marks = markerRows(run.violations.filter(function (v) { return typeof v[1] === "number"; })
      .map(function (v) { return [X(v[1]), v[0]]; }));
    var rows = marks.reduce(function (n, m) { return Math.max(n, m[2] + 1); }, 0);
    var labelTop = 2, axisTop = labelTop + rows * g.markerRow + g.axisHeight, y = axisTop;
    var groups = d.groups.map(function (grp) {
      return [grp[0], grp[1].filter(function (v) { return run.trace[v]; }).map(function (v) { return [v, run.trace[v], false]; })];
    });
    Object.keys(run.evidence).forEach(function (name) {
      var rows = run.evidence[name].rows || {};
      groups.push(["Why " + name, Object.keys(rows).map(function (r) { return [r, heldTrace(rows[r]), true]; })]);
    });
    groups.forEach(function (grp) {
      if (!grp[1].length) return;
      parts.push('<text class="group" x="4" y="' + (y + 12) + '">' + esc(grp[0]) + "</text>");
      y += g.group;
      grp[1].forEach(function (lane) {
        var v = lane[0], numeric = !lane[2] && d.kinds[v] === "numeric", h = numeric ? g.numericLane : g.lane;
        var unit = d.units[v], label = numeric && unit ? v + " (" + unit + ")" : v;
        var fitted = label.length <= g.labelRoom ? label : label.slice(0, g.labelRoom - 1) + "\u2026";
        parts.push('<text class="lane-label" x="' + (g.plotLeft - 6) + '" y="' + (y + h / 2 + 4) + '"><title>' + esc(label) + "</title>" + esc(fitted) + "</text>");
        parts.push('<rect class="lane" x="' + g.plotLeft + '" y="' + y + '" width="' + g.plotWidth + '" height="' + h + '"/>');
        var ps = pieces(lane[1][0], lane[1][1], dur);
        if (numeric && lane[1][2]) {  // the exact extremes scale the lane and label its axis
          var lo = lane[1][2][0], hi = lane[1][2][1], u = unit ? " " + unit : "", pts = [];
          var Y = function (x) { return hi === lo ? y + 4 + (h - 8) / 2 : y + 4 + (h - 8) * (hi - x) / (hi - lo); };
          var flush = function () {
            if (pts.length) parts.push('<polyline class="step" data-var="' + esc(v) + '" points="' + pts.join(" ") + '"/>');
            pts = [];
          };
          ps.forEach(function (p) {
            if (typeof p[2] !== "number") { flush(); return; }  // an undefined stretch breaks the line
            pts.push(X(p[0]).toFixed(2) + "," + Y(p[2]).toFixed(2), X(p[1]).toFixed(2) + "," + Y(p[2]).toFixed(2));
          });
          flush();
          parts.push('<text class="y-label" x="' + (g.plotLeft + 3) + '" y="' + (Y(hi) + 9).toFixed(2) + '">' + esc(sig3(hi) + u) + "</text>");
          if (hi !== lo) parts.push('<text class="y-label" x="' + (g.plotLeft + 3) + '" y="' + (Y(lo) - 2).toFixed(2) + '">' + esc(sig3(lo) + u) + "</text>");
        } else if (!numeric) {  // widened pieces last, over their neighbours, as _piece_rects does
          var narrow = function (p) { return X(p[1]) - X(p[0]) < g.minPiece; };
          ps.filter(function (p) { return !narrow(p); }).concat(ps.filter(narrow)).forEach(function (p) {
            if (p[2] === null) return;
            var fill = lane[2] ? d.boolColours[p[2]] : ((d.colours[v] || {})[p[2]] || "#9e9e9e");
            var x0 = X(p[0]), w = Math.max(X(p[1]) - x0, g.minPiece);
            var text = String(p[2]), label = "";
            if (X(p[1]) - x0 >= text.length * g.charWidth + 6) {
              label = '<text class="piece-label" x="' + ((x0 + X(p[1])) / 2).toFixed(2) + '" y="' + (y + h / 2 + 4) + '" fill="' + textColour(fill) + '">' + esc(text) + "</text>";
            }
            parts.push('<g><title>' + esc(v + " = " + text + " from " + instant(p[0]) + " to " + instant(p[1])) + '</title><rect class="piece" data-var="' + esc(v) +
              '" x="' + x0.toFixed(2) + '" y="' + y + '" width="' + w.toFixed(2) + '" height="' + h + '" fill="' + fill + '"/>' + label + "</g>");
          });
        }
        y += h + g.gap;
      });
    });
    var bottom = y - g.gap, under = [], over = [];
    var perTick = g.plotWidth * g.tick / dur, every = Math.max(1, Math.ceil(g.minLabelSpacing / perTick));
    for (var k = 0; k * g.tick <= dur + 1e-9; k++) {  // as _axis: labels thinned when they would crowd
      var tx = X(k * g.tick).toFixed(2);
      under.push('<line class="tick" x1="' + tx + '" x2="' + tx + '" y1="' + (axisTop - 4) + '" y2="' + bottom + '"/>');
      if (k % every === 0) under.push('<text class="tick-label" x="' + tx + '" y="' + (axisTop - 7) + '">' + (k * g.tick) + " s</text>");
    }
    Object.keys(run.evidence).forEach(function (name) {
      var w = run.evidence[name].window, top = axisTop + g.group;
      if (w) under.push('<g><title>' + esc(name + ": required between " + instant(w[0]) + " and " + instant(w[1])) +
        '</title><rect class="window" data-condition="' + esc(name) + '" x="' + X(w[0]).toFixed(2) + '" y="' + top + '" width="' +
        Math.max(X(w[1]) - X(w[0]), 2 * g.minPiece).toFixed(2) + '" height="' + (bottom - top) + '"/></g>');
    });
    marks.forEach(function (m) {
      var labelY = labelTop + (m[2] + 1) * g.markerRow - 3, tx = m[3] ? m[0] - 3 : m[0] + 3;
      over.push('<line class="violation" data-condition="' + esc(m[1]) + '" x1="' + m[0].toFixed(2) + '" x2="' + m[0].toFixed(2) +
        '" y1="' + (labelY - 9) + '" y2="' + bottom + '"/>');
      over.push('<text class="violation-label" x="' + tx.toFixed(2) + '" y="' + labelY + '" text-anchor="' + (m[3] ? "end" : "start") + '">' + esc(m[1]) + "</text>");
    });
    return '<svg class="timeline" viewBox="0 0 ' + g.svgWidth + " " + (y + 4) + '" width="100%" role="img" aria-label="timeline">' +
      under.join("") + parts.join("") + over.join("") + "</svg>";
  }
  function open(row) {
    var next = row.nextElementSibling;
    if (next && next.classList.contains("details")) { next.remove(); return; }
    var d = load(), index = row.getAttribute("data-run"), run = d.runs[index], html = [];
    run.violations.forEach(function (v) {
      html.push("<li><strong>" + esc(v[0]) + "</strong> violated at " + (typeof v[1] === "number" ? instant(v[1]) : "?") + (v[2] ? ": " + esc(v[2]) : "") + "</li>");
    });
    var out = "";
    if (html.length) out += "<ul>" + html.join("") + "</ul>";
    if (run.error) out += '<pre class="error">' + esc(run.error) + "</pre>";
    if (run.rerun) out += "<p>Re-run: <code>" + esc(run.rerun) + "</code></p>";
    out += run.trace ? timeline(run) : '<p class="muted">No trace available for this run.</p>';
    var tr = document.createElement("tr");
    tr.className = "details";
    tr.innerHTML = '<td colspan="' + row.cells.length + '">' + out + "</td>";
    row.parentNode.insertBefore(tr, row.nextSibling);
  }
  body.addEventListener("click", function (ev) {
    var link = ev.target.closest("a.open");
    if (!link) return;
    ev.preventDefault();
    open(link.closest("tr"));
  });
  function openFromHash() {
    var row = location.hash && document.getElementById(location.hash.slice(1));
    if (row && row.parentNode === body && !(row.nextElementSibling && row.nextElementSibling.classList.contains("details"))) {
      row.hidden = false;
      open(row);
      row.scrollIntoView();
    }
  }
  window.addEventListener("hashchange", openFromHash);
  openFromHash();
})();
"""


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
    then the trace's other variables); ``phases`` gives each hazard variable its risk
    model's ``{values, initial, mishap}`` (its lanes, colours and legend). Numeric lanes
    take their unit from ``results["campaign"]["units"]`` (variable -> unit).
    """
    runs = [r for r in _list(results.get("runs")) if isinstance(r, Mapping)]
    campaign = _dict(results.get("campaign"))
    traces = timelines or {}
    units = _dict(campaign.get("units"))
    present = [t for t in (_timeline_key(traces, _run_index(r, i)) for i, r in enumerate(runs)) if t]
    palette = _Palette(present, phases)
    duration = _duration(results, present)
    title = f"Test campaign: {campaign.get('scenario_name') or campaign.get('scenario') or 'campaign'}"
    body = "\n".join(
        (
            _header(results, runs),
            "<main>",
            _summary(results, runs),
            _conditions_section(results, runs),
            _use_cases_section(results, runs),
            _coverage_section(results),
            _configurations_section(results, runs),
            _runs_section(results, runs),
            _timelines_section(runs, traces, duration, lanes, palette, units),
            "</main>",
            f'<script type="application/json" id="report-data">{_script_data(runs, traces, duration, lanes, palette, units)}</script>',
            f"<script>{SCRIPT}</script>",
        )
    )
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
        f"<title>{_e(title)}</title>\n<style>{CSS}</style>\n</head>\n<body>\n{body}\n</body>\n</html>\n"
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
