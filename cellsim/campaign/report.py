"""A self-contained HTML report of a test campaign.

:func:`render_report` turns a campaign's results dictionary (exactly what is written
to ``OUT/results.json``) and the reconstructed traces of its violating runs into one
HTML document; :func:`write_report` writes it atomically.  The page needs nothing
but a browser: CSS is inline, plots are inline SVG, there are no scripts, no
external assets and no links out of the page.  It stays readable printed (colours
are kept, timelines scale to the page width and are not split across pages).

The page, top to bottom:

* **header** - scenario, number of runs, seed, duration, creation date and an
  overall badge: ``no violations`` or ``N runs violate M conditions`` (plus
  ``K runs failed`` when some runs did not complete);
* **summary** - the totals (runs, completed, failed, violating, overall coverage)
  and the time spent per stage (``simulate``, ``trace``, ``check``, ``coverage``,
  ``report``, ``wall``);
* **conditions** - one row per safety condition: its formula, how many runs hold
  it, violate it or did not check it (failed runs), and the first violating runs
  as links to their timelines;
* **use cases** - how many runs exercised each use case;
* **coverage** - per criterion: a bar, ``covered/total`` and the situations never
  reached, by name;
* **runs** - every run: index, seed, sampled configuration, use cases, violated
  conditions and status (a failed run shows its error); violating rows are
  highlighted and followed by the command that reruns them;
* **timelines** - one section per violating run, with anchor ``id="run-<index>"``,
  holding an SVG timeline of its trace.

Timeline geometry (all lengths in SVG user units; the SVG has a ``viewBox`` and
scales to the page width): the plot spans ``x`` from :data:`PLOT_LEFT` to
:data:`PLOT_LEFT` + :data:`PLOT_WIDTH`; time ``t`` in ``[0, duration]`` maps to
``x = PLOT_LEFT + PLOT_WIDTH * t / duration`` (:func:`time_to_x`, ``t`` clamped to
the domain), printed with two decimals.  Ticks every 5 s (labels thinned when they
would crowd).  One lane per variable, grouped under titles (see
:data:`DEFAULT_LANES`).  A trace ``{variable: [[t, value], ...]}`` is cut into
constant pieces by :func:`pieces` (a value holds from its ``t`` to the next
sample; repeats merge; the domain is ``[0, duration)``).  Each defined piece of an
enumerated or boolean variable is one ``<rect class="piece" data-var="...">``
inside a ``<g>`` whose ``<title>`` reads ``var = value from t0 to t1 s``, with the
value written inside when the piece is wide enough; ``null`` pieces (undefined)
are left empty.  Numeric variables are drawn as a step ``<polyline>`` with min/max
labels instead.  Each violation of the run is a red ``<line class="violation"
data-condition="...">`` at ``x = time_to_x(violated_at)`` labelled with the
condition's name.

Colours are deterministic: hazard phases have fixed colours (:data:`PHASE_COLOURS`:
``inact`` grey, ``act`` orange, ``mit``/``mit1``/``mit2`` yellow-green, ``res`` blue,
``mis`` red), booleans are dark (true) or light (false), and other enumerations take
:data:`ENUM_PALETTE` colours by the value's position in the sorted set of values the
variable takes over all traces of the report (so a value has one colour on the page).

Every string from the data is escaped (condition formulas contain ``<``, ``>`` and
``&``).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from html import escape

from cellsim.atomic import write_text

__all__ = [
    "BOOL_COLOURS",
    "DEFAULT_LANES",
    "ENUM_PALETTE",
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
PLOT_LEFT = 150.0  # the lane labels sit left of this
PLOT_RIGHT_MARGIN = 20.0
PLOT_WIDTH = SVG_WIDTH - PLOT_LEFT - PLOT_RIGHT_MARGIN
TICK_STEP = 5.0  # seconds between ticks
MIN_LABEL_SPACING = 36.0  # tick labels closer than this are thinned
LANE_HEIGHT = 20.0
NUMERIC_LANE_HEIGHT = 34.0
LANE_GAP = 4.0
GROUP_HEADER = 18.0
AXIS_HEIGHT = 22.0  # tick labels above the lanes
MARKER_ROW = 13.0  # one row of violation labels
CHAR_WIDTH = 6.4  # approximate width of a character at font-size 11
FIRST_VIOLATING_SHOWN = 10  # violating runs linked per condition

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
    "#8dd3c7", "#bebada", "#80b1d3", "#fdb462", "#b3de69", "#fccde5",
    "#d9d9d9", "#bc80bd", "#ccebc5", "#ffed6f",
)  # ColorBrewer Set3 without its red (red means mishap or violation here)
VIOLATION_COLOUR = "#d32f2f"
STAGES = ("simulate", "trace", "check", "coverage", "report", "wall")

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
    return "&mdash;" if not _is_number(t) else f"{float(t):.6g}"  # type: ignore[arg-type]


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


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
    return f"run-{index}"


def _overall(coverage: Mapping) -> object:
    """The overall coverage fraction: ``totals.coverage.overall`` is ``{covered, total, fraction}``."""
    overall = coverage.get("overall")
    if isinstance(overall, Mapping):
        fraction, covered, total = overall.get("fraction"), overall.get("covered"), overall.get("total")
        if not _is_number(fraction) and _is_number(covered) and _is_number(total) and total:
            fraction = covered / total
        return fraction
    return overall


def _fraction_text(fraction: object) -> str:
    return "n/a" if not _is_number(fraction) else f"{100.0 * float(fraction):.1f}%"  # type: ignore[arg-type]


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
        ((float(s[0]), s[1]) for s in samples if len(s) >= 2 and _is_number(s[0])),
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


# --------------------------------------------------------------------------- colours


def _kind(values: Iterable[object]) -> str:
    """``phase``, ``bool``, ``numeric`` or ``enum``: how a variable is drawn."""
    defined = [v for v in values if v is not None]
    if defined and all(isinstance(v, bool) for v in defined):
        return "bool"
    if defined and all(_is_number(v) for v in defined):
        return "numeric"
    if defined and all(isinstance(v, str) and v in PHASE_COLOURS for v in defined):
        return "phase"
    return "enum"


def _sort_key(value: object) -> tuple[str, str]:
    return (type(value).__name__, _fmt(value))


class _Palette:
    """Kinds and colours of the variables over all the report's traces.

    A variable's kind (see :func:`_kind`) and its enumeration order (the sorted set
    of its values) are computed once over every trace, so that a value has the same
    colour in every timeline of the page.
    """

    def __init__(self, timelines: Iterable[Timeline], phases: Mapping[str, Mapping] | None = None) -> None:
        """``phases``: hazard variable -> its risk model's ``{values, initial, mishap}``."""
        self.phases = dict(phases or {})
        self.hazards = list(self.phases)
        self._phase_colours = {var: _phase_colours(spec) for var, spec in self.phases.items()}
        values: dict[str, list] = {}
        for timeline in timelines:
            for var, samples in timeline.items():
                values.setdefault(var, []).extend(s[1] for s in samples if len(s) >= 2)
        self._kinds = {var: _kind(vals) for var, vals in values.items()}
        self._order = {
            var: sorted({_sort_key(v) for v in vals if v is not None}) for var, vals in values.items()
        }

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
        if kind == "bool":
            return BOOL_COLOURS[bool(value)]
        order = self._order.get(var, [])
        key = _sort_key(value)
        i = order.index(key) if key in order else len(order)
        return ENUM_PALETTE[i % len(ENUM_PALETTE)]


def _phase_colours(spec: Mapping) -> dict[str, str]:
    """A hazard's phases coloured: the published ones as ever, otherwise initial grey, mishap red."""
    values = [str(v) for v in _list(spec.get("values"))]
    if values and all(v in PHASE_COLOURS for v in values):
        return {v: PHASE_COLOURS[v] for v in values}
    colours, others = {}, iter(PHASE_SEQUENCE * 4)
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


def _piece_rects(var: str, var_pieces, palette: _Palette, duration: float, top: float) -> list[str]:
    out = []
    for t0, t1, value in var_pieces:
        if value is None:
            continue
        x0, x1 = time_to_x(t0, duration), time_to_x(t1, duration)
        fill = palette.colour(var, value)
        text = _fmt(value)
        tip = f"{var} = {text} from {t0:.6g} to {t1:.6g} s"
        parts = [
            f"<g><title>{_e(tip)}</title>",
            f'<rect class="piece" data-var="{_e(var)}" x="{_num(x0)}" y="{_num(top)}" '
            f'width="{_num(x1 - x0)}" height="{_num(LANE_HEIGHT)}" fill="{fill}"/>',
        ]
        if x1 - x0 >= len(text) * CHAR_WIDTH + 6:
            parts.append(
                f'<text class="piece-label" x="{_num((x0 + x1) / 2)}" y="{_num(top + LANE_HEIGHT / 2 + 4)}" '
                f'fill="{_text_colour(fill)}">{_e(text)}</text>'
            )
        parts.append("</g>")
        out.append("".join(parts))
    return out


def _step_plot(var: str, var_pieces, duration: float, top: float) -> list[str]:
    """A step polyline (one per defined stretch) scaled to the lane, with min/max labels."""
    defined = [v for _, _, v in var_pieces if _is_number(v) and math.isfinite(v)]
    if not defined:
        return []
    lo, hi = min(defined), max(defined)
    inner_top, inner_h = top + 3, NUMERIC_LANE_HEIGHT - 6

    def y(v: float) -> float:
        return inner_top + inner_h / 2 if hi == lo else inner_top + inner_h * (hi - v) / (hi - lo)

    tip = _e(f"{var}: min {_fmt(lo)}, max {_fmt(hi)}")
    out, points = [], []

    def flush() -> None:
        if points:
            out.append(f'<polyline class="step" data-var="{_e(var)}" points="{" ".join(points)}"><title>{tip}</title></polyline>')
            points.clear()

    for t0, t1, v in var_pieces:
        if not (_is_number(v) and math.isfinite(v)):
            flush()
            continue
        yy = _num(y(v))
        points.extend((f"{_num(time_to_x(t0, duration))},{yy}", f"{_num(time_to_x(t1, duration))},{yy}"))
    flush()
    out.append(f'<text class="minmax" x="{_num(PLOT_LEFT + 3)}" y="{_num(top + 10)}">max {_e(_fmt(hi))}</text>')
    out.append(
        f'<text class="minmax" x="{_num(PLOT_LEFT + 3)}" y="{_num(top + NUMERIC_LANE_HEIGHT - 3)}">min {_e(_fmt(lo))}</text>'
    )
    return out


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
        tip = f"{name} violated at {by_name[name]:.6g} s"
        out.append(
            f'<g><title>{_e(tip)}</title>'
            f'<line class="violation" data-condition="{_e(name)}" x1="{_num(x)}" x2="{_num(x)}" '
            f'y1="{_num(label_y - 9)}" y2="{_num(bottom)}" stroke="{VIOLATION_COLOUR}"/>'
            f'<text class="violation-label" x="{_num(tx)}" y="{_num(label_y)}" text-anchor="{anchor}">{_e(name)}</text></g>'
        )
    return out


def _run_violation_times(run: Mapping) -> list[tuple[str, float]]:
    """``(condition, violated_at)`` for each violated condition with a finite time."""
    verdicts = _dict(run.get("verdicts"))
    out = []
    for name in _violated(run):
        t = _dict(verdicts.get(name)).get("violated_at")
        if _is_number(t) and math.isfinite(t):
            out.append((name, float(t)))
    return out


def render_timeline(
    timeline: Timeline,
    duration: float,
    violations: Sequence[tuple[str, float]] = (),
    lanes: Sequence[tuple[str, Sequence[str]]] | None = None,
    palette: _Palette | None = None,
) -> str:
    """One run's trace as an inline SVG (see the module docstring for the geometry)."""
    palette = palette or _Palette([timeline])
    groups = _lane_groups(timeline, lanes, palette.hazards)
    placed = _marker_rows([(time_to_x(t, duration), name) for name, t in violations])
    n_rows = 1 + max((row for _, _, row, _ in placed), default=-1)
    label_top = 2.0
    axis_top = label_top + n_rows * MARKER_ROW + AXIS_HEIGHT
    body: list[str] = []
    y = axis_top
    for title, names in groups:
        body.append(f'<text class="group" x="4" y="{_num(y + 12)}">{_e(title)}</text>')
        y += GROUP_HEADER
        for var in names:
            numeric = palette.kind(var) == "numeric"
            h = NUMERIC_LANE_HEIGHT if numeric else LANE_HEIGHT
            var_pieces = pieces(timeline[var], duration)
            body.append(f'<text class="lane-label" x="{_num(PLOT_LEFT - 6)}" y="{_num(y + h / 2 + 4)}">{_e(var)}</text>')
            body.append(
                f'<rect class="lane" x="{_num(PLOT_LEFT)}" y="{_num(y)}" width="{_num(PLOT_WIDTH)}" height="{_num(h)}"/>'
            )
            if numeric:
                body.extend(_step_plot(var, var_pieces, duration, y))
            else:
                body.extend(_piece_rects(var, var_pieces, palette, duration, y))
            y += h + LANE_GAP
    height = y + 4
    parts = [
        f'<svg class="timeline" viewBox="0 0 {_num(SVG_WIDTH)} {_num(height)}" '
        f'width="100%" role="img" aria-label="timeline">',
        *_axis(duration, axis_top, y - LANE_GAP),
        *body,
        *_markers(list(violations), duration, label_top, y - LANE_GAP),
        "</svg>",
    ]
    return "\n".join(parts)


# --------------------------------------------------------------------------- HTML sections

CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; margin: 1.5em auto;
       max-width: 1100px; padding: 0 1em; color: #212121; line-height: 1.4;
       -webkit-print-color-adjust: exact; print-color-adjust: exact; }
h1 { margin-bottom: 0.2em; }
h2 { border-bottom: 2px solid #e0e0e0; padding-bottom: 0.2em; margin-top: 1.6em; }
dl.meta { display: grid; grid-template-columns: max-content auto; gap: 0.1em 1em; }
dl.meta dt { font-weight: 600; }
dl.meta dd { margin: 0; }
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
tr.rerun td { background: #fff5f5; font-size: 0.9em; }
.error { color: #b71c1c; }
.bar { display: inline-block; width: 160px; height: 0.8em; background: #eeeeee;
       border: 1px solid #bdbdbd; vertical-align: middle; }
.bar span { display: block; height: 100%; background: #43a047; }
ul.missing { margin: 0.2em 0; padding-left: 1.2em; }
.muted { color: #757575; }
.legend span.swatch { display: inline-block; width: 0.9em; height: 0.9em; border: 1px solid #9e9e9e;
                      vertical-align: middle; margin: 0 0.25em 0 0.8em; }
section.run { margin-top: 1.2em; }
svg.timeline { max-width: 1000px; display: block; margin: 0.5em 0; }
svg.timeline text { font-size: 11px; font-family: system-ui, sans-serif; }
svg.timeline .tick { stroke: #e0e0e0; stroke-width: 1; }
svg.timeline .tick-label { fill: #616161; text-anchor: middle; }
svg.timeline .group { font-weight: 600; fill: #424242; }
svg.timeline .lane { fill: none; stroke: #e0e0e0; }
svg.timeline .lane-label { text-anchor: end; fill: #212121; }
svg.timeline .piece { stroke: #ffffff; stroke-width: 0.5; }
svg.timeline .piece-label { text-anchor: middle; pointer-events: none; }
svg.timeline .step { fill: none; stroke: #1565c0; stroke-width: 1.5; }
svg.timeline .minmax { fill: #757575; font-size: 9px; }
svg.timeline .violation { stroke: #d32f2f; stroke-width: 1.5; }
svg.timeline .violation-label { fill: #d32f2f; font-weight: 600; }
nav a { margin-right: 1em; }
@media print {
  body { max-width: none; margin: 0; }
  nav { display: none; }
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
    meta = [
        ("Scenario", campaign.get("scenario")),
        ("Runs", campaign.get("runs", len(runs))),
        ("Seed", campaign.get("seed")),
        ("Duration", f"{_fmt(campaign['duration'])} s" if _is_number(campaign.get("duration")) else None),
        ("Created", campaign.get("created")),
    ]
    rows = "".join(f"<dt>{k}</dt><dd>{_e(v)}</dd>" for k, v in meta if v is not None)
    nav = "".join(
        f'<a href="#{a}">{t}</a>'
        for a, t in (("summary", "Summary"), ("conditions", "Conditions"), ("use-cases", "Use cases"),
                     ("coverage", "Coverage"), ("runs", "Runs"), ("timelines", "Timelines"))
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
        rows += f'<tr><th>Coverage</th><td class="num">{_fraction_text(_overall(coverage))}</td></tr>'
    timing = _dict(results.get("timing"))
    stages = [s for s in STAGES if s in timing] + [s for s in timing if s not in STAGES]
    timing_rows = "".join(
        f'<tr><th>{_e(s)}</th><td class="num">{_seconds(timing[s])}</td></tr>' for s in stages
    )
    timing_table = (
        '<table class="timing"><caption>Time per stage (s; stages are summed over workers, '
        '"wall" is elapsed)</caption>'
        f"<tbody>{timing_rows}</tbody></table>"
        if stages
        else '<p class="muted">No timing recorded.</p>'
    )
    return (
        '<section id="summary"><h2>Summary</h2>\n'
        f'<table class="totals"><tbody>{rows}</tbody></table>\n{timing_table}</section>'
    )


def _condition_rows(results: Mapping, runs: Sequence[Mapping]) -> str:
    formulas = _dict(_dict(results.get("campaign")).get("conditions"))
    rows = []
    for name in _conditions(results):
        holding, violating, unchecked = 0, [], 0
        for i, run in enumerate(runs):
            verdict = _dict(_dict(run.get("verdicts")).get(name))
            if name in _violated(run):
                violating.append(_run_index(run, i))
            elif _status(verdict) == "holds":
                holding += 1
            else:
                unchecked += 1
        links = ", ".join(f'<a href="#{_anchor(i)}">{i}</a>' for i in violating[:FIRST_VIOLATING_SHOWN])
        if len(violating) > FIRST_VIOLATING_SHOWN:
            links += f' <span class="muted">and {len(violating) - FIRST_VIOLATING_SHOWN} more</span>'
        formula = formulas.get(name)
        formula_html = f'<code class="formula">{_e(formula)}</code>' if formula is not None else ""
        description = _dict(_dict(results.get("campaign")).get("descriptions")).get(name)
        if isinstance(description, str) and description:
            formula_html += f'<br><span class="muted">{_e(description)}</span>'
        cls = ' class="violating"' if violating else ""
        rows.append(
            f"<tr{cls}><td><strong>{_e(name)}</strong></td><td>{formula_html}</td>"
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
    formulas = _dict(_dict(results.get("campaign")).get("use_cases"))
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
        share = _fraction_text(n / total) if total and _is_number(n) else "n/a"
        formula = formulas.get(name)
        formula_html = f'<code class="formula">{_e(formula)}</code>' if formula is not None else ""
        cls = ' class="failed"' if n == 0 else ""
        rows.append(
            f"<tr{cls}><td><strong>{_e(name)}</strong></td><td>{formula_html}</td>"
            f'<td class="num">{_e(n)}</td><td class="num">{share}</td></tr>'
        )
    return (
        '<section id="use-cases"><h2>Use cases</h2>\n<table><thead><tr><th>Use case</th><th>Formula</th>'
        '<th class="num">Runs</th><th class="num">Share</th></tr></thead>\n<tbody>\n'
        + "\n".join(rows)
        + "\n</tbody></table></section>"
    )


def _bar(fraction: object) -> str:
    width = 0.0 if not _is_number(fraction) else min(max(float(fraction), 0.0), 1.0) * 100  # type: ignore[arg-type]
    return f'<span class="bar"><span style="width: {width:.1f}%"></span></span>'


def _coverage_section(results: Mapping) -> str:
    coverage = _dict(_dict(results.get("totals")).get("coverage"))
    criteria = _dict(coverage.get("criteria"))
    head = '<section id="coverage"><h2>Coverage</h2>\n'
    if "overall" in coverage:
        head += f"<p>Overall: {_bar(_overall(coverage))} {_fraction_text(_overall(coverage))}</p>\n"
    if not criteria:
        return head + '<p class="muted">No coverage criteria.</p></section>'
    rows = []
    for name, c in criteria.items():
        c = _dict(c)
        covered, total = c.get("covered"), c.get("total")
        fraction = c.get("fraction")
        if not _is_number(fraction) and _is_number(covered) and _is_number(total) and total:
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
            f'<td class="num">{_fraction_text(fraction)}</td><td>{missing_html}</td></tr>'
        )
    return (
        head
        + "<table><thead><tr><th>Criterion</th><th>Variables</th><th>Covered</th>"
        '<th class="num">Situations</th><th class="num">Fraction</th><th>Missing situations</th></tr></thead>\n<tbody>\n'
        + "\n".join(rows)
        + "\n</tbody></table></section>"
    )


def _config_keys(runs: Sequence[Mapping]) -> list[str]:
    keys: list[str] = []
    for run in runs:
        for k in _dict(run.get("configuration")):
            if k not in keys:
                keys.append(k)
    return keys


MAX_CONFIG_COLUMNS = 6  # more sampled values are listed in one cell


def _config_cells(run: Mapping, keys: Sequence[str]) -> str:
    config = _dict(run.get("configuration"))
    if len(keys) <= MAX_CONFIG_COLUMNS:
        return "".join(f'<td class="num">{_e(config[k]) if k in config else ""}</td>' for k in keys)
    items = "<br>".join(f"<code>{_e(k)}</code> = {_e(v)}" for k, v in config.items())
    return f"<td>{items}</td>"


def _status_cell(run: Mapping) -> str:
    status = _e(run.get("status", "unknown"))
    if _is_failed(run):
        error = run.get("error")
        detail = f'<pre class="error">{_e(error)}</pre>' if error is not None else ""
        return f'<td><span class="error">{status}</span>{detail}</td>'
    return f"<td>{status}</td>"


def _runs_section(runs: Sequence[Mapping]) -> str:
    if not runs:
        return '<section id="runs"><h2>Runs</h2><p class="muted">No runs.</p></section>'
    keys = _config_keys(runs)
    if len(keys) <= MAX_CONFIG_COLUMNS:
        config_head = "".join(f'<th class="num"><code>{_e(k)}</code></th>' for k in keys)
    else:
        config_head = "<th>Configuration</th>"
    n_cols = 6 + (len(keys) if len(keys) <= MAX_CONFIG_COLUMNS else 1)
    rows = []
    for i, run in enumerate(runs):
        index = _run_index(run, i)
        violated = _violated(run)
        cls = ' class="violating"' if violated else ' class="failed"' if _is_failed(run) else ""
        index_html = f'<a href="#{_anchor(index)}">{index}</a>' if violated else str(index)
        violated_html = ", ".join(f'<a href="#{_anchor(index)}">{_e(c)}</a>' for c in violated)
        use_cases = ", ".join(_e(u) for u in _list(run.get("use_cases")))
        rows.append(
            f'<tr{cls}><td class="num">{index_html}</td><td class="num">{_e(run.get("seed", ""))}</td>'
            f"{_config_cells(run, keys)}<td>{use_cases}</td><td>{violated_html}</td>{_status_cell(run)}"
            f'<td class="num">{_seconds(run.get("wall_time"))}</td></tr>'
        )
        if violated and run.get("rerun"):
            rows.append(
                f'<tr class="rerun"><td colspan="{n_cols}">Rerun: <code>{_e(run["rerun"])}</code></td></tr>'
            )
    return (
        '<section id="runs"><h2>Runs</h2>\n<table><thead><tr><th class="num">Run</th><th class="num">Seed</th>'
        f"{config_head}<th>Use cases</th><th>Violated</th><th>Status</th>"
        '<th class="num">Wall (s)</th></tr></thead>\n<tbody>\n'
        + "\n".join(rows)
        + "\n</tbody></table></section>"
    )


def _legend(palette: "_Palette") -> str:
    phases = next(iter(palette._phase_colours.values()), PHASE_COLOURS)
    items = list(phases.items()) + [("true", BOOL_COLOURS[True]), ("false", BOOL_COLOURS[False])]
    swatches = "".join(f'<span class="swatch" style="background: {c}"></span>{_e(n)}' for n, c in items)
    return (
        f'<p class="legend">Hazard phases and booleans:{swatches}. '
        f'<span style="color: {VIOLATION_COLOUR}">Red lines</span> mark violations; '
        "hover a piece for its value and times.</p>"
    )


def _timeline_key(timelines: Mapping, index: int) -> Timeline | None:
    found = timelines.get(index)
    if found is None:
        found = timelines.get(str(index))
    return found if isinstance(found, Mapping) else None


def _run_timeline_section(
    run: Mapping, index: int, timeline: Timeline | None, duration: float,
    lanes: Sequence[tuple[str, Sequence[str]]] | None, palette: _Palette,
) -> str:
    formulas = _dict(run.get("verdicts"))
    items = []
    for name in _violated(run):
        verdict = _dict(formulas.get(name))
        why = verdict.get("explanation")
        why = f": {_e(why)}" if isinstance(why, str) and why else ""
        items.append(f"<li><strong>{_e(name)}</strong> violated at {_seconds(verdict.get('violated_at'))} s{why}</li>")
    rerun = f'<p>Rerun: <code>{_e(run["rerun"])}</code></p>' if run.get("rerun") else ""
    out = f'<p class="muted">Output folder: <code>{_e(run["out"])}</code></p>' if run.get("out") else ""
    if timeline:
        plot = render_timeline(timeline, duration, _run_violation_times(run), lanes, palette)
    else:
        plot = '<p class="muted">No trace available for this run.</p>'
    return (
        f'<section class="run" id="{_anchor(index)}"><h3>Run {index} '
        f'<span class="muted">(seed {_e(run.get("seed", "?"))})</span></h3>\n'
        f"<ul>{''.join(items)}</ul>\n{rerun}{out}\n{plot}\n</section>"
    )


def _duration(results: Mapping, timelines: Iterable[Timeline]) -> float:
    """The campaign's duration, else the last sample time of any trace (at least 1 s)."""
    d = _dict(results.get("campaign")).get("duration")
    if _is_number(d) and math.isfinite(d) and d > 0:
        return float(d)
    last = [float(s[0]) for tl in timelines for samples in tl.values() for s in samples if s and _is_number(s[0])]
    return max([1.0, *last])


def _timelines_section(
    results: Mapping, runs: Sequence[Mapping], timelines: Mapping,
    lanes: Sequence[tuple[str, Sequence[str]]] | None, phases: Mapping | None = None,
) -> str:
    violating = _violating_runs(runs)
    if not violating:
        return '<section id="timelines"><h2>Timelines</h2><p class="muted">No violating runs.</p></section>'
    traces = {index: _timeline_key(timelines, index) for index, _ in violating}
    present = [t for t in traces.values() if t]
    palette = _Palette(present, phases)
    duration = _duration(results, present)
    sections = [
        _run_timeline_section(run, index, traces[index], duration, lanes, palette) for index, run in violating
    ]
    return '<section id="timelines"><h2>Timelines of violating runs</h2>\n' + _legend(palette) + "\n" + "\n".join(sections) + "</section>"


# --------------------------------------------------------------------------- API


def render_report(
    results: Mapping,
    timelines: Mapping[int, Timeline] | None,
    lanes: Sequence[tuple[str, Sequence[str]]] | None = None,
    phases: Mapping[str, Mapping] | None = None,
) -> str:
    """The whole HTML report of a campaign.

    ``results`` is the campaign's results dictionary (``OUT/results.json``);
    ``timelines`` maps a violating run's index (int, or its decimal string as read
    back from JSON) to its trace ``{variable: [[t, value], ...]}``; ``lanes`` groups
    the timeline lanes as ``[(group title, [variable, ...]), ...]`` (default:
    :data:`DEFAULT_LANES`, then the trace's other variables); ``phases`` gives each hazard
    variable its risk model's ``{values, initial, mishap}`` (its lanes, colours and legend).
    """
    runs = [r for r in _list(results.get("runs")) if isinstance(r, Mapping)]
    campaign = _dict(results.get("campaign"))
    title = f"Test campaign: {campaign.get('scenario_name') or campaign.get('scenario') or 'campaign'}"
    body = "\n".join(
        (
            _header(results, runs),
            "<main>",
            _summary(results, runs),
            _conditions_section(results, runs),
            _use_cases_section(results, runs),
            _coverage_section(results),
            _runs_section(runs),
            _timelines_section(results, runs, timelines or {}, lanes, phases),
            "</main>",
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
