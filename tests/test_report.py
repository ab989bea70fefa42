"""Tests for cellsim.campaign.report: the self-contained HTML campaign report."""

from __future__ import annotations

import copy
import os
from html.parser import HTMLParser

import pytest

from cellsim.campaign.report import (
    PHASE_COLOURS,
    MIN_PIECE_WIDTH,
    PLOT_LEFT,
    PLOT_WIDTH,
    pieces,
    render_report,
    time_to_x,
    write_report,
)

DURATION = 30.0
VOID = {"meta", "br", "hr", "img", "input", "link", "col", "area", "base", "wbr", "source"}

HS_TRACE = [[0.0, "inact"], [4.0, "act"], [4.3, "act"], [4.5, "mit"], [12.0, "res"], [14.0, "inact"]]
HS_PIECES = 5  # the repeated "act" merges

TIMELINE = {
    "safmod": [[0.0, "normal"], [4.5, "pflim"], [14.0, "normal"]],
    "HS": HS_TRACE,
    "HC": [[0.0, "inact"], [12.0, "act"], [12.34, "mis"]],
    "lgtBar": [[0.0, False], [10.0, True], [11.0, False], [31.0, True]],  # the last is outside [0, 30)
    "oloc": [[0.0, None], [2.0, "inCell"], [20.0, "none"]],  # undefined first
    "speed": [[0.0, 0.0], [3.0, 0.25], [9.0, 1.5]],
}

RESULTS = {
    "campaign": {
        "scenario": "scenarios/welding_cell.yaml",
        "scenario_name": "welding_cell",
        "runs": 3,
        "seed": 1,
        "duration": DURATION,
        "created": "2026-11-21T10:00:00Z",
        "conditions": {
            "HS:detected": "G((HS_e and HS == inact) -> (HS_e U[0, 0.5s] HS == act))",
            "HC:not_mis": "G(HC != mis & x < 3)",
        },
        "use_cases": {"U1": "F(otab)", "U2": "F(wact == welding)"},
        "samplers": {"operator_waits": {"kind": "simplex", "total": 20.0, "minimum": 0.0}},
    },
    "runs": [
        {
            "index": 0, "seed": 111, "status": "completed",
            "configuration": {"operator.waypoints.bench.wait": 3.2},
            "verdicts": {"HS:detected": {"holds": True, "violated_at": None},
                         "HC:not_mis": {"holds": True, "violated_at": None}},
            "violations": [], "use_cases": ["U1"], "wall_time": 1.1, "out": "runs/0000",
            "rerun": "cellsim simulate campaigns/c1/runs/0000/scenario.yaml --out rerun0",
        },
        {
            "index": 1, "seed": 222, "status": "completed",
            "configuration": {"operator.waypoints.bench.wait": 7.5},
            "verdicts": {"HS:detected": {"holds": True, "violated_at": None},
                         "HC:not_mis": {"holds": False, "violated_at": 12.34}},
            "violations": ["HC:not_mis"], "use_cases": ["U1", "U2"], "wall_time": 1.3, "out": "runs/0001",
            "rerun": "cellsim simulate campaigns/c1/runs/0001/scenario.yaml --out rerun1",
        },
        {
            "index": 2, "seed": 333, "status": "failed", "error": "solver diverged <at> t=3 & beyond",
            "configuration": {"operator.waypoints.bench.wait": 1.0}, "wall_time": 0.2, "out": "runs/0002",
        },
    ],
    "totals": {
        "runs": 3, "completed": 2, "failed": 1, "violating_runs": 1,
        "violations": {"HS:detected": 0, "HC:not_mis": 1},
        "use_cases": {"U1": 2, "U2": 1},
        "coverage": {
            "overall": 0.75,
            "criteria": {
                "wact x oloc": {"variables": ["wact", "oloc"], "description": "welder against operator",
                                "covered": 5, "total": 6, "fraction": 0.833,
                                "missing": ["wact=off, oloc=inCell"]},
            },
        },
    },
    "timing": {"simulate": 2.6, "trace": 0.1, "check": 0.04, "coverage": 0.03, "report": 0.01, "wall": 2.0},
}


class Collector(HTMLParser):
    """Checks that tags balance and collects the elements with their attributes."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.stack: list[str] = []
        self.errors: list[str] = []
        self.elements: list[tuple[str, dict, tuple[str, ...]]] = []  # (tag, attrs, ancestors)
        self.text: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.elements.append((tag, dict(attrs), tuple(self.stack)))
        if tag not in VOID:
            self.stack.append(tag)

    def handle_startendtag(self, tag, attrs):
        self.elements.append((tag, dict(attrs), tuple(self.stack)))

    def handle_endtag(self, tag):
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"</{tag}> closes {self.stack[-1:] or 'nothing'}")
        else:
            self.stack.pop()

    def handle_data(self, data):
        self.text.append(data)


def parse(page: str) -> Collector:
    parser = Collector()
    parser.feed(page)
    parser.close()
    return parser


@pytest.fixture(scope="module")
def page() -> str:
    return render_report(RESULTS, {1: TIMELINE})


@pytest.fixture(scope="module")
def parsed(page) -> Collector:
    return parse(page)


def run_svg_elements(parsed: Collector, index: int) -> list[tuple[str, dict]]:
    """The elements inside the SVG of the section ``timeline-<index>`` (a run drawn in full)."""
    inside, out = False, []
    for tag, attrs, ancestors in parsed.elements:
        if tag == "section" and attrs.get("id") == f"timeline-{index}":
            inside, depth = True, len(ancestors)
            continue
        if inside and len(ancestors) <= depth:
            break
        if inside and "svg" in ancestors:
            out.append((tag, attrs))
    return out


def test_page_parses_and_tags_balance(parsed):
    assert parsed.errors == []
    assert parsed.stack == []
    tags = [t for t, _, _ in parsed.elements]
    for tag in ("html", "head", "body", "main", "table", "svg"):
        assert tag in tags


def test_page_is_self_contained(page):
    for needle in ("http://", "https://", "src=", "<link"):
        assert needle not in page
    # scripts only inline: the page's data and the code that sorts, filters and draws
    assert page.count("<script") == 2 and '<script type="application/json" id="report-data">' in page


def test_header_badge_and_summary(page):
    assert "1 run violates 1 condition" in page
    assert "1 run failed" in page
    assert "welding_cell" in page and "2026-11-21T10:00:00Z" in page
    for stage in ("simulate", "trace", "check", "coverage", "wall"):
        assert f"<th>{stage}</th>" in page


def test_no_violations_badge():
    results = copy.deepcopy(RESULTS)
    results["runs"] = [results["runs"][0]]
    page = render_report(results, {})
    assert "no violations" in page
    assert 'id="timeline-' not in page
    assert parse(page).errors == []


def test_violating_run_has_timeline_section(parsed):
    sections = [a for t, a, _ in parsed.elements if t == "section" and a.get("id", "").startswith("timeline-")]
    assert [s["id"] for s in sections] == ["timeline-1"]
    elements = run_svg_elements(parsed, 1)
    assert elements, "no svg in timeline-1"


def test_first_violating_runs_link_to_their_rows_and_every_run_has_one(parsed, page):
    assert '<a href="#run-1">1</a>' in page
    rows = [a["id"] for t, a, _ in parsed.elements if t == "tr" and a.get("id", "").startswith("run-")]
    assert rows == ["run-0", "run-1", "run-2"]


def test_pieces_cut_merge_and_clip():
    assert pieces(HS_TRACE, DURATION) == [
        (0.0, 4.0, "inact"), (4.0, 4.5, "act"), (4.5, 12.0, "mit"), (12.0, 14.0, "res"), (14.0, 30.0, "inact"),
    ]
    assert pieces(TIMELINE["lgtBar"], DURATION)[-1] == (11.0, 30.0, False)
    assert pieces([[-1.0, "a"], [2.0, "b"]], 10.0) == [(0.0, 2.0, "a"), (2.0, 10.0, "b")]
    assert pieces([], 10.0) == []


@pytest.mark.parametrize("var", ["safmod", "HS", "HC", "lgtBar", "oloc"])
def test_one_rect_per_defined_piece(parsed, var):
    rects = [a for t, a in run_svg_elements(parsed, 1) if t == "rect" and a.get("class") == "piece"
             and a.get("data-var") == var]
    expected = [p for p in pieces(TIMELINE[var], DURATION) if p[2] is not None]
    assert len(rects) == len(expected)
    assert var != "HS" or len(rects) == HS_PIECES
    for rect, (t0, t1, _) in zip(rects, expected, strict=True):
        assert float(rect["x"]) == pytest.approx(time_to_x(t0, DURATION), abs=0.01)
        width = max(time_to_x(t1, DURATION) - time_to_x(t0, DURATION), MIN_PIECE_WIDTH)
        assert float(rect["width"]) == pytest.approx(width, abs=0.02)


def test_piece_colours_and_tooltips(parsed, page):
    hs = [a for t, a in run_svg_elements(parsed, 1) if t == "rect" and a.get("data-var") == "HS"]
    assert [r["fill"] for r in hs] == [PHASE_COLOURS[v] for v in ("inact", "act", "mit", "res", "inact")]
    hc = [a for t, a in run_svg_elements(parsed, 1) if t == "rect" and a.get("data-var") == "HC"]
    assert hc[-1]["fill"] == PHASE_COLOURS["mis"]
    lgt = [a["fill"] for t, a in run_svg_elements(parsed, 1) if t == "rect" and a.get("data-var") == "lgtBar"]
    assert lgt[0] == lgt[2] != lgt[1]
    assert "<title>HS = mit from 4.50 s to 12.00 s</title>" in page


def test_numeric_variable_is_a_step_plot(parsed, page):
    elements = run_svg_elements(parsed, 1)
    assert not [a for t, a in elements if t == "rect" and a.get("data-var") == "speed"]
    lines = [a for t, a in elements if t == "polyline" and a.get("data-var") == "speed"]
    assert len(lines) == 1
    assert len(lines[0]["points"].split()) == 2 * 3
    labels = [a for t, a in elements if t == "text" and a.get("class") == "y-label"]
    assert len(labels) == 2  # an axis: its top and bottom values
    assert ">1.50<" in page and ">0<" in page


def test_violation_marker_at_violation_time(parsed):
    # Axis mapping (module docstring): x = PLOT_LEFT + PLOT_WIDTH * t / duration.
    expected = PLOT_LEFT + PLOT_WIDTH * 12.34 / DURATION
    assert time_to_x(12.34, DURATION) == pytest.approx(expected)
    markers = [a for t, a in run_svg_elements(parsed, 1) if t == "line" and a.get("class") == "violation"]
    assert len(markers) == 1
    assert markers[0]["data-condition"] == "HC:not_mis"
    assert markers[0]["x1"] == markers[0]["x2"] == f"{expected:.2f}"


def test_ticks_every_five_seconds(parsed):
    ticks = [a for t, a in run_svg_elements(parsed, 1) if t == "line" and a.get("class") == "tick"]
    assert [float(a["x1"]) for a in ticks] == pytest.approx(
        [time_to_x(t, DURATION) for t in range(0, 31, 5)], abs=0.01
    )


def test_data_strings_are_escaped(page):
    assert "HS_e U[0, 0.5s] HS == act" in page
    assert "(HS_e and HS == inact) -&gt; (HS_e" in page
    assert "G(HC != mis &amp; x &lt; 3)" in page
    assert "x < 3" not in page and "-> (" not in page


def test_missing_situations_and_coverage(page):
    assert "<li>wact=off, oloc=inCell</li>" in page
    assert "5/6" in page and "83.3%" in page


def test_failed_run_error_shown(page):
    assert "solver diverged &lt;at&gt; t=3 &amp; beyond" in page


def test_runs_table_rows_and_rerun(parsed, page):
    rows = [a.get("class") for t, a, _ in parsed.elements if t == "tr" and a.get("class") is not None]
    assert rows.count("violating") >= 2  # the run row and the condition row
    assert "failed" in rows
    verdicts = [a.get("data-verdict") for t, a, _ in parsed.elements if t == "tr" and a.get("data-verdict")]
    assert verdicts == ["holds", "violated", "failed"]
    timeline = page[page.index('id="timeline-1"'):]
    assert "runs/0001/scenario.yaml --out rerun1" in timeline
    # a passing run's re-run command waits in the page's data, for when its row is opened
    body = page[:page.index('id="report-data"')]
    assert "--out rerun0" not in body and "--out rerun0" in page
    assert '<a href="runs/0001/blackbox.sqlite">black box</a>' in page
    assert '<a href="runs/0001/scenario.yaml">scenario</a>' in page


def test_missing_optional_keys_and_string_keys():
    minimal = {"runs": [{"seed": 5, "status": "completed", "violations": ["c"],
                         "verdicts": {"c": {"holds": False, "violated_at": 1.0}}}]}
    page = render_report(minimal, {"0": {"x": [[0, "a"], [0.5, "b"]]}})
    parsed = parse(page)
    assert parsed.errors == [] and parsed.stack == []
    assert 'id="run-0"' in page and 'id="timeline-0"' in page
    assert len([a for t, a in run_svg_elements(parsed, 0) if t == "rect" and a.get("class") == "piece"]) == 2
    without = render_report(minimal, {})
    assert "No trace available" in without[:without.index('id="report-data"')]


def test_write_report_is_atomic(tmp_path):
    target = tmp_path / "report.html"
    target.write_text("old report")
    write_report(target, RESULTS, {1: TIMELINE})
    assert target.read_text(encoding="utf-8") == render_report(RESULTS, {1: TIMELINE})
    assert os.listdir(tmp_path) == ["report.html"]
    write_report(target, RESULTS, {})
    written = target.read_text(encoding="utf-8")
    assert "No trace available" in written[:written.index('id="report-data"')]
    assert os.listdir(tmp_path) == ["report.html"]


def test_write_report_failure_keeps_old_file(tmp_path, monkeypatch):
    target = tmp_path / "report.html"
    target.write_text("old report")

    def boom(*_args):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError, match="disk full"):
        write_report(target, RESULTS, {1: TIMELINE})
    assert target.read_text() == "old report"
    assert os.listdir(tmp_path) == ["report.html"]


def test_a_cells_own_hazard_phases_get_the_hazard_lanes_and_colours_of_its_risk_model():
    """The palletising cell's phases (idle ... harm), not the welding cell's, from its black box's record."""
    phases = {"PALLET": {"values": ["idle", "detected", "guarded", "clearing", "harm"], "initial": "idle", "mishap": "harm"}}
    timeline = {"PALLET": [[0.0, "idle"], [4.0, "detected"], [4.02, "guarded"], [9.0, "harm"]],
                "curtain": [[0.0, False], [4.0, True]]}
    page = render_report(RESULTS, {1: timeline}, phases=phases)
    parsed = parse(page)
    rects = [a for t, a in run_svg_elements(parsed, 1) if t == "rect" and a.get("data-var") == "PALLET"]
    fills = [a["fill"] for a in sorted(rects, key=lambda a: float(a["x"]))]  # in time (narrow pieces are drawn last)
    assert fills[0] == PHASE_COLOURS["inact"] and fills[-1] == PHASE_COLOURS["mis"]  # initial grey, mishap red
    assert len(set(fills)) == 4  # detected and guarded told apart
    texts = [a for t, a in run_svg_elements(parsed, 1) if t == "text"]
    assert texts  # lane titles are drawn as text; the hazard sits under "Hazard phases"
    assert page.index(">Hazard phases<") < page.index('data-var="PALLET"') < page.index(">Other variables<")
    legend = page[page.index('class="legend"'):page.index("Red lines")]
    assert "guarded" in legend and "harm" in legend and "inact" not in legend


EVIDENCE = {"at": 12.34, "window": [12.34, 12.84],
            "rows": {"HC_e": [[12.0, 20.0]], "rngDet == close": [[11.5, 20.0]], "HC == act": [[12.0, 12.34]]}}


def _explained_results() -> dict:
    results = copy.deepcopy(RESULTS)
    results["runs"][1]["verdicts"]["HC:not_mis"]["evidence"] = EVIDENCE
    results["runs"][1]["verdicts"]["HC:not_mis"]["explanation"] = "HC = mis"
    return results


def test_a_violations_macros_and_atoms_are_rows_and_its_required_window_is_shaded():
    page = render_report(_explained_results(), {1: TIMELINE})
    parsed = parse(page)
    elements = run_svg_elements(parsed, 1)
    assert ">Why HC:not_mis<" in page
    for row, intervals in EVIDENCE["rows"].items():
        rects = [a for t, a in elements if t == "rect" and a.get("data-var") == row]
        truths = [a for a in rects if a["fill"] == "#37474f"]  # true: the boolean colour, as everywhere
        assert [float(a["x"]) for a in truths] == pytest.approx([time_to_x(lo, DURATION) for lo, _ in intervals], abs=0.01)
    window = [a for t, a in elements if t == "rect" and a.get("class") == "window"]
    assert len(window) == 1 and window[0]["data-condition"] == "HC:not_mis"
    assert float(window[0]["x"]) == pytest.approx(time_to_x(12.34, DURATION), abs=0.01)
    assert float(window[0]["width"]) == pytest.approx(time_to_x(12.84, DURATION) - time_to_x(12.34, DURATION), abs=0.01)
    # the window spans the lanes, from the first lane's top to the last one's bottom
    lanes = [a for t, a in elements if t == "rect" and a.get("class") == "lane"]
    assert float(window[0]["y"]) == pytest.approx(float(lanes[0]["y"]))
    assert "HC:not_mis: required between 12.34 s and 12.84 s" in page


def test_a_value_has_one_colour_in_every_lane_and_the_legend_lists_it():
    timeline = {"ract": [[0.0, "idle"], [5.0, "welding"]], "wact": [[0.0, "welding"], [3.0, "idle"]]}
    page = render_report(RESULTS, {1: timeline})
    elements = run_svg_elements(parse(page), 1)
    fills = {(a["data-var"], i): a["fill"] for i, (t, a) in enumerate(e for e in elements if e[0] == "rect" and e[1].get("data-var"))}
    ract, wact = [f for (v, _), f in fills.items() if v == "ract"], [f for (v, _), f in fills.items() if v == "wact"]
    assert ract == wact[::-1] and ract[0] != ract[1]  # idle and welding: the same colours in both lanes
    legend = page[page.index('class="legend"'):page.index("Red lines")]
    assert f'background: {ract[0]}"></span>idle' in legend and f'background: {ract[1]}"></span>welding' in legend


def test_numeric_lanes_name_their_unit_on_the_label_and_the_axis():
    results = copy.deepcopy(RESULTS)
    results["campaign"]["units"] = {"speed": "m/s"}  # as a campaign records them, from its black boxes
    page = render_report(results, {1: TIMELINE})
    assert ">speed (m/s)<" in page and ">1.50 m/s<" in page and ">0 m/s<" in page


def test_a_piece_of_a_few_milliseconds_keeps_a_visible_width_over_its_neighbour():
    page = render_report(RESULTS, {1: {"HS": [[0.0, "inact"], [4.0, "act"], [4.002, "mit"]]}})
    rects = [a for t, a in run_svg_elements(parse(page), 1) if t == "rect" and a.get("data-var") == "HS"]
    assert float(rects[-1]["width"]) == pytest.approx(MIN_PIECE_WIDTH)  # drawn last: mit does not cover it
    assert rects[-1]["fill"] == PHASE_COLOURS["act"] and [r["fill"] for r in rects[:2]] == [
        PHASE_COLOURS["inact"], PHASE_COLOURS["mit"]]


def test_two_variable_criteria_get_a_heat_map_of_runs_per_situation():
    results = copy.deepcopy(RESULTS)
    criterion = results["totals"]["coverage"]["criteria"]["wact x oloc"]
    criterion.update(axes=[["idle", "welding", "off"], ["none", "inCell"]], runs=[2, 1, 0, 3, 1, 0])
    page = render_report(results, {1: TIMELINE})
    heat = page[page.index('<table class="heatmap" data-criterion="wact x oloc">'):]
    heat = heat[:heat.index("</table>")]
    cells = parse(heat)
    values = [a.get("title") for t, a, _ in cells.elements if t == "td"]
    assert values == [f"wact={w}, oloc={o}: {n} run{'s' if n != 1 else ''}"
                      for (w, o), n in zip([(w, o) for w in ("idle", "welding", "off") for o in ("none", "inCell")], [2, 1, 0, 3, 1, 0])]
    assert heat.count('class="never"') == 2  # never reached: marked, not merely pale


def test_configuration_values_against_verdicts_split_each_bin_by_verdict():
    results = copy.deepcopy(RESULTS)
    results["campaign"]["configuration_units"] = {"operator.waypoints.bench.wait": "s"}
    page = render_report(results, {1: TIMELINE})
    figure = page[page.index('<figure class="histogram" data-key="operator.waypoints.bench.wait">'):]
    figure = figure[:figure.index("</figure>")]
    assert "<code>wait (s)</code>" in figure and "1 violating run" in figure
    bins = [a["class"] for t, a, _ in parse(figure).elements if t == "rect"]
    assert sorted(bins) == ["bin failed", "bin holds", "bin violated"]  # 1.0 failed, 3.2 held, 7.5 violated
    # the runs table's column: the same value, its unit, three significant figures, sortable by its exact value
    assert '<code>wait (s)</code></th>' in page and '<td class="num">3.20</td>' in page


def test_the_provenance_header_shows_versions_command_and_input_hash():
    results = copy.deepcopy(RESULTS)
    results["provenance"] = {"versions": {"cellsim": "0.1.0", "drake": "1.51.1"}, "command": "cellsim campaign x.yaml --runs 3",
                             "inputs": {"hash": "ab" * 32}}
    header = render_report(results, {})
    header = header[:header.index("</header>")]
    assert "cellsim 0.1.0, drake 1.51.1" in header and "<code>cellsim campaign x.yaml --runs 3</code>" in header
    assert f'<code title="{"ab" * 32}">{"ab" * 8}</code>' in header
