"""Tests for cellsim.campaign.report: the self-contained HTML campaign report, as written.

What the page holds before any script runs: its sections, escaped text, the script's data
and the places where the script draws timelines. The timelines themselves are drawn by the
page's script and tested in a browser (tests/test_report_browser.py).
"""

from __future__ import annotations

import copy
import json
import os
import re
from html.parser import HTMLParser
from importlib import resources

import pytest

from cellsim.campaign.report import BOOL_COLOURS, PHASE_COLOURS, render_report, write_report

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
        self.raw: dict[str, list[str]] = {}  # script and style contents, by tag

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
        if self.stack and self.stack[-1] in ("script", "style"):
            self.raw.setdefault(self.stack[-1], []).append(data)
        else:
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


def script_data(page: str) -> dict:
    """The JSON the page's script draws from (the ``report-data`` block)."""
    start = page.index('id="report-data">') + len('id="report-data">')
    return json.loads(page[start:page.index("</script>", start)])


def markup(page: str) -> str:
    """The page without its scripts: what is there before any script runs."""
    return page[:page.index('<script type="application/json" id="report-data">')]


def section(page: str, ident: str) -> str:
    """The markup of the section ``ident``, up to its first nested section's end or its own."""
    start = page.index(f'id="{ident}"')
    return page[start:page.index("</section>", start)]


def test_page_parses_and_tags_balance(parsed):
    assert parsed.errors == []
    assert parsed.stack == []
    tags = [t for t, _, _ in parsed.elements]
    for tag in ("html", "head", "body", "main", "table", "svg", "style", "script"):
        assert tag in tags


def test_page_is_self_contained(page, parsed):
    for needle in ("src=", "<link", "url(", "@import", "https://"):
        assert needle not in page
    # the only address is the SVG namespace the script creates elements in; it is never fetched
    assert set(re.findall(r"http://[^\s\"'<>]*", page)) == {"http://www.w3.org/2000/svg"}
    # scripts only inline: the page's data and the code that draws, sorts and filters
    scripts = [a for t, a, _ in parsed.elements if t == "script"]
    assert scripts == [{"type": "application/json", "id": "report-data"}, {}]


def test_the_style_and_the_script_are_the_packages_own_files_inlined(parsed):
    """report.css and report.js are package data, put into the page as they are (no copy in Python)."""
    static = resources.files("cellsim.campaign").joinpath("static")
    assert parsed.raw["style"] == [static.joinpath("report.css").read_text(encoding="utf-8")]
    assert parsed.raw["script"][1] == static.joinpath("report.js").read_text(encoding="utf-8")
    templates = resources.files("cellsim.campaign").joinpath("templates")
    assert templates.joinpath("report.html.j2").is_file()


def test_no_timeline_is_drawn_in_python_the_script_draws_each_in_its_place(page, parsed):
    """One renderer: the page holds no timeline SVG, only the places the script draws the shown runs in."""
    assert "<svg class=\"timeline\"" not in page and 'class="piece"' not in page
    slots = [(a.get("data-draw"), ancestors) for t, a, ancestors in parsed.elements if a.get("data-draw") is not None]
    assert [s for s, _ in slots] == ["1"]
    assert 'data-draw="1"' in section(page, "timeline-1")
    assert "report.js" not in page  # inlined, not linked


def test_header_badge_and_summary(page):
    assert "1 run violates 1 condition" in page
    assert "1 run failed" in page
    assert "welding_cell" in page and "2026-11-21T10:00:00Z" in page
    for stage in ("simulate", "trace", "check", "coverage", "wall"):
        assert f"<th>{stage}</th>" in page
    assert '<th>Coverage</th><td class="num" id="coverage-figure">75.0%</td>' in page


def test_no_violations_badge():
    results = copy.deepcopy(RESULTS)
    results["runs"] = [results["runs"][0]]
    page = render_report(results, {})
    assert "no violations" in page
    assert 'id="timeline-' not in page and "data-draw=" not in markup(page)
    assert "No violating runs" in section(page, "timelines")
    assert parse(page).errors == []


def test_the_header_says_what_the_verdicts_do_not():
    """A helper's audit found a campaign whose scanner missed a person in its field in 2 of 3 runs under a green
    'no violations' badge, the blind spots only in a table further down; an undecided run green too; and a campaign
    stopped early headed with the runs it planned. The header now says each."""
    results = copy.deepcopy(RESULTS)
    first = results["runs"][0]
    runs = [dict(first, index=i, findings=found, undecided=undecided) for i, (found, undecided) in enumerate([
        ([{"what": "blind spot", "subject": "scanner", "field": "protective", "start": 1.0, "end": 2.0, "text": "x"}], []),
        ([{"what": "contact", "subject": "harm", "severity": 1.4, "region": "hand", "start": 3.0, "end": None,
           "text": "y"}], []),
        ([{"what": "contact", "subject": "harm", "severity": 0.4, "region": "hand", "start": 3.0, "end": None,
           "text": "z"}], ["HS:detected"]),
    ])]
    results["runs"] = runs
    results["campaign"]["runs"] = 9
    page = render_report(results, {})
    header = page[:page.index("</header>")]
    assert "no violations" not in header and "1 run undecided" in header
    results["runs"] = runs[:1]  # a blind spot alone: no condition violated, and not a green badge
    alone = render_report(results, {})
    assert "no condition violated" in alone[:alone.index("</header>")] and "badge ok" not in alone[:alone.index("</header>")]
    assert "1 run with blind spots" in header and "1 run with harm above its limits" in header  # (0.4: within)
    assert "3 of 9 planned" in header
    assert parse(page).errors == []


def test_a_search_s_use_case_shares_are_not_rates():
    """A falsification search chose its runs: the share of them that exercised a use case is theirs, not a rate
    among the cell's runs (the evidence audit found it read as one)."""
    results = copy.deepcopy(RESULTS)
    results["search"] = {"method": "cmaes", "budget": 3}
    shown = section(render_report(results, {}), "use-cases")
    assert "Share of the search" in shown and "not a rate" in shown
    assert "Share of the search" not in section(render_report(copy.deepcopy(RESULTS), {}), "use-cases")


def test_violating_run_has_timeline_section(parsed, page):
    sections = [a for t, a, _ in parsed.elements if t == "section" and a.get("id", "").startswith("timeline-")]
    assert [s["id"] for s in sections] == ["timeline-1"]
    shown = section(page, "timeline-1")
    assert "<strong>HC:not_mis</strong> violated at 12.34 s" in shown
    assert "Run folder: <code>runs/0001</code>" in shown


def test_first_violating_runs_link_to_their_rows_and_every_run_has_one(parsed, page):
    assert '<a href="#run-1">1</a>' in page
    rows = [a["id"] for t, a, _ in parsed.elements if t == "tr" and a.get("id", "").startswith("run-")]
    assert rows == ["run-0", "run-1", "run-2"]


def test_data_strings_are_escaped(page):
    assert "HS_e U[0, 0.5s] HS == act" in page
    assert "(HS_e and HS == inact) -&gt; (HS_e" in page
    assert "G(HC != mis &amp; x &lt; 3)" in page
    assert "x < 3" not in page and "-> (" not in page


def test_missing_situations_and_coverage(page):
    assert "<li>wact=off, oloc=inCell</li>" in page
    assert "5/6" in page and "83.3%" in page
    assert "Overall: " in section(page, "coverage")


def test_failed_run_error_shown(page):
    assert 'title="solver diverged &lt;at&gt; t=3 &amp; beyond"' in page


def test_runs_table_rows_and_rerun(parsed, page):
    rows = [a.get("class") for t, a, _ in parsed.elements if t == "tr" and a.get("class") is not None]
    assert rows.count("violating") >= 2  # the run row and the condition row
    assert "failed" in rows
    verdicts = [a.get("data-verdict") for t, a, _ in parsed.elements if t == "tr" and a.get("data-verdict")]
    assert verdicts == ["holds", "violated", "failed"]
    assert '<tr id="run-1" data-run="1" data-verdict="violated" class="violating">' in page
    assert "runs/0001/scenario.yaml --out rerun1" in section(page, "timeline-1")
    # a passing run's re-run command waits in the page's data, for when its row is opened
    assert "--out rerun0" not in markup(page) and script_data(page)["runs"]["0"]["rerun"].endswith("--out rerun0")
    assert '<a href="runs/0001/blackbox.sqlite">black box</a>' in page
    assert '<a href="runs/0001/scenario.yaml">scenario</a>' in page


def test_missing_optional_keys_and_string_keys():
    minimal = {"runs": [{"seed": 5, "status": "completed", "violations": ["c"],
                         "verdicts": {"c": {"holds": False, "violated_at": 1.0}}}]}
    page = render_report(minimal, {"0": {"x": [[0, "a"], [0.5, "b"]]}})
    parsed = parse(page)
    assert parsed.errors == [] and parsed.stack == []
    assert 'id="run-0"' in page and 'id="timeline-0"' in page and 'data-draw="0"' in page
    data = script_data(page)
    assert data["runs"]["0"]["trace"] == {"x": [[0, 500], ["a", "b"]]}
    assert data["duration"] == 1.0  # no campaign duration: the last sample's time, at least 1 s
    without = render_report(minimal, {})
    assert "No trace available" in section(without, "timeline-0")
    assert "data-draw=" not in markup(without)


def test_write_report_is_atomic(tmp_path):
    target = tmp_path / "report.html"
    target.write_text("old report")
    write_report(target, RESULTS, {1: TIMELINE})
    assert target.read_text(encoding="utf-8") == render_report(RESULTS, {1: TIMELINE})
    assert os.listdir(tmp_path) == ["report.html"]
    write_report(target, RESULTS, {})
    written = target.read_text(encoding="utf-8")
    assert "No trace available" in section(written, "timeline-1")
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


def test_the_scripts_data_holds_each_runs_compact_trace_verdicts_and_the_pages_colours(page):
    data = script_data(page)
    assert data["duration"] == DURATION
    assert set(data["runs"]) == {"0", "1", "2"}
    run = data["runs"]["1"]
    # times as steps in ms from the previous sample; the repeated "act" is dropped
    assert run["trace"]["HS"] == [[0, 4000, 500, 7500, 2000], ["inact", "act", "mit", "res", "inact"]]
    assert run["trace"]["lgtBar"] == [[0, 10000, 1000, 20000], ["false", "true", "false", "true"]]  # 31 s: clipped when drawn
    assert run["trace"]["oloc"] == [[0, 2000, 18000], [None, "inCell", "none"]]
    steps, values, extremes = run["trace"]["speed"]  # numeric: values and their exact extremes for the axis
    assert steps == [0, 3000, 6000] and values == [0.0, 0.25, 1.5] and extremes == [0.0, 1.5]
    assert run["violations"] == [["HC:not_mis", 12.34, None]]
    assert data["runs"]["0"]["trace"] is None and data["runs"]["2"]["error"] == "solver diverged <at> t=3 & beyond"
    assert data["kinds"] == {"safmod": "enum", "HS": "phase", "HC": "phase", "lgtBar": "bool", "oloc": "enum", "speed": "numeric"}
    assert data["colours"]["HS"] == {v: PHASE_COLOURS[v] for v in ("act", "inact", "mit", "res")}
    assert data["colours"]["lgtBar"] == {"true": BOOL_COLOURS[True], "false": BOOL_COLOURS[False]}
    assert data["groups"] == [["Safety mode", ["safmod"]], ["Hazard phases", ["HS", "HC"]], ["Sensors", ["lgtBar"]],
                              ["Operator", ["oloc"]], ["Other variables", ["speed"]]]


def test_a_trace_out_of_time_order_is_put_in_order_for_the_script():
    page = render_report(RESULTS, {1: {"x": [[5.0, "b"], [0.0, "a"]], "v": [[2.0, 3.0], [0.0, 1.0]]}})
    trace = script_data(page)["runs"]["1"]["trace"]
    assert trace["x"] == [[0, 5000], ["a", "b"]]
    assert trace["v"][:2] == [[0, 2000], [1.0, 3.0]]


def test_the_data_block_cannot_be_ended_by_a_string_of_the_data(page):
    results = copy.deepcopy(RESULTS)
    results["runs"][1]["rerun"] = "x </script><script>alert(1)</script> <!-- & y"
    page = render_report(results, {1: TIMELINE})
    start = page.index('id="report-data">') + len('id="report-data">')
    block = page[start:page.index("</script>", start)]
    assert "<" not in block and ">" not in block and "&" not in block
    assert json.loads(block)["runs"]["1"]["rerun"] == results["runs"][1]["rerun"]


def test_a_cells_own_hazard_phases_get_the_hazard_lanes_and_colours_of_its_risk_model():
    """The palletising cell's phases (idle ... harm), not the welding cell's, from its black box's record."""
    phases = {"PALLET": {"values": ["idle", "detected", "guarded", "clearing", "harm"], "initial": "idle", "mishap": "harm"}}
    timeline = {"PALLET": [[0.0, "idle"], [4.0, "detected"], [4.02, "guarded"], [9.0, "harm"]],
                "curtain": [[0.0, False], [4.0, True]]}
    page = render_report(RESULTS, {1: timeline}, phases=phases)
    data = script_data(page)
    colours = data["colours"]["PALLET"]
    assert colours["idle"] == PHASE_COLOURS["inact"] and colours["harm"] == PHASE_COLOURS["mis"]  # initial grey, mishap red
    assert len({colours[v] for v in ("idle", "detected", "guarded", "harm")}) == 4  # detected and guarded told apart
    assert data["groups"] == [["Hazard phases", ["PALLET"]], ["Other variables", ["curtain"]]]
    legend = page[page.index('class="legend"'):page.index("Red lines")]
    assert "guarded" in legend and "harm" in legend and "inact" not in legend
    assert '<code data-var="PALLET">PALLET</code>' in legend and '<code data-var="curtain">curtain</code>' in legend


def test_a_value_has_one_colour_for_the_whole_page_and_the_legend_lists_every_lane_and_value():
    timeline = {"ract": [[0.0, "idle"], [5.0, "welding"]], "wact": [[0.0, "welding"], [3.0, "idle"]],
                "speed": [[0.0, 1.0]]}
    page = render_report(RESULTS, {1: timeline})
    colours = script_data(page)["colours"]
    assert colours["ract"] == colours["wact"] and colours["ract"]["idle"] != colours["ract"]["welding"]
    legend = page[page.index('class="legend"'):page.index("Red lines")]
    for var in ("ract", "wact"):
        row = legend[legend.index(f'<code data-var="{var}">'):]
        row = row[:row.index("</div>")]
        assert f'background: {colours[var]["idle"]}"></span>idle' in row
        assert f'background: {colours[var]["welding"]}"></span>welding' in row
    assert '<strong>Step plots</strong> (<code data-var="speed">speed</code>)' in legend


def test_numeric_lanes_take_their_unit_from_the_campaign():
    results = copy.deepcopy(RESULTS)
    results["campaign"]["units"] = {"speed": "m/s"}  # as a campaign records them, from its black boxes
    assert script_data(render_report(results, {1: TIMELINE}))["units"] == {"speed": "m/s"}


def test_a_violations_evidence_goes_to_the_script():
    results = copy.deepcopy(RESULTS)
    results["runs"][1]["verdicts"]["HC:not_mis"]["evidence"] = EVIDENCE
    results["runs"][1]["verdicts"]["HC:not_mis"]["explanation"] = "HC = mis"
    page = render_report(results, {1: TIMELINE})
    assert script_data(page)["runs"]["1"]["evidence"] == {"HC:not_mis": EVIDENCE}
    assert "<strong>HC:not_mis</strong> violated at 12.34 s: HC = mis" in section(page, "timeline-1")


EVIDENCE = {"at": 12.34, "window": [12.34, 12.84],
            "rows": {"HC_e": [[12.0, 20.0]], "rngDet == close": [[11.5, 20.0]], "HC == act": [[12.0, 12.34]]}}


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


# --------------------------------------------------------------------------- hostile strings

HOSTILE = "</script><script>alert(1)</script><b>bold</b> & \"quoted\" 'single' <!--"


def hostile_results() -> tuple[dict, dict]:
    """A campaign whose every author-written string is markup: names, descriptions, values, errors."""
    results = copy.deepcopy(RESULTS)
    campaign = results["campaign"]
    campaign["scenario_name"] = "cell " + HOSTILE
    campaign["descriptions"] = {"HC:not_mis": "desc " + HOSTILE, "U1": "use " + HOSTILE}
    campaign["conditions"]["HC:not_mis"] = "G(x " + HOSTILE + ")"
    campaign["created"] = HOSTILE
    results["provenance"] = {"versions": {"cellsim": HOSTILE}, "command": "cmd " + HOSTILE, "inputs": {"hash": HOSTILE}}
    results["runs"][0]["configuration"]["mode" + HOSTILE] = "value " + HOSTILE
    results["runs"][0]["out"] = "runs/" + HOSTILE
    violating = results["runs"][1]
    violating["verdicts"]["HC:not_mis"].update(explanation="why " + HOSTILE, evidence={
        "at": 12.34, "window": [12.34, 12.84], "rows": {"atom " + HOSTILE: [[12.0, 13.0]]}})
    violating["rerun"] = "rerun " + HOSTILE
    results["runs"][2]["error"] = "error " + HOSTILE
    results["totals"]["coverage"]["criteria"]["wact x oloc"]["missing"] = ["missing " + HOSTILE]
    timeline = {**TIMELINE, "oloc": [[0.0, "value " + HOSTILE], [20.0, "none"]], "lane" + HOSTILE: [[0.0, "on"]]}
    return results, {1: timeline, 0: TIMELINE}


def test_hostile_strings_are_text_on_the_page_not_markup():
    results, timelines = hostile_results()
    page = render_report(results, timelines)
    parsed = parse(page)
    assert parsed.errors == [] and parsed.stack == []
    tags = [t for t, _, _ in parsed.elements]
    assert "b" not in tags and tags.count("script") == 2  # no element made of the data
    assert page.count("</script>") == 2 and "alert(1)</script>" not in page
    text = "".join(parsed.text)
    for shown in ("cell " + HOSTILE, "desc " + HOSTILE, "G(x " + HOSTILE + ")", "missing " + HOSTILE, "why " + HOSTILE,
                  "rerun " + HOSTILE, "lane" + HOSTILE, "value " + HOSTILE):
        assert shown in text, shown  # read back as the very text written
    attributes = [v for _, a, _ in parsed.elements for v in a.values()]
    assert "error " + HOSTILE in attributes and HOSTILE in attributes  # the error's tooltip, the input hash's
    data = script_data(page)
    assert data["runs"]["1"]["rerun"] == "rerun " + HOSTILE
    assert data["runs"]["1"]["trace"]["oloc"][1][0] == "value " + HOSTILE


def test_a_failed_run_is_counted_apart_in_the_conditions_table_as_the_bound_leaves_it_out():
    """An audit found a failed run in the Undecided column while the rate and bound left it out: one row read
    Holding 2, Undecided 4 (of which 3 never ran), bound over 2. Failed runs now have their own column."""
    conditions = section(render_report(RESULTS, {1: TIMELINE}), "conditions")
    assert '<th class="num" title="the run could not be simulated: left out of the rate and the bound">Failed</th>' in conditions
    rows = [[re.sub(r"<[^>]+>", "", cell).strip() for cell in re.findall(r"<td[^>]*>(.*?)</td>", row, re.S)]
            for row in re.findall(r"<tr[^>]*>(.*?)</tr>", conditions, re.S)]
    for name in RESULTS["campaign"]["conditions"]:
        (cells,) = [r for r in rows if r and r[0] == name]
        holding, violating, undecided, failed = map(int, cells[2:6])
        assert failed == 1 and holding + violating + undecided == 2  # the failed run once, in its own column


def test_a_campaign_with_no_coverage_criteria_shows_none_not_100_percent():
    results = copy.deepcopy(RESULTS)
    results["totals"]["coverage"] = {"overall": {"covered": 0, "total": 0, "fraction": 1.0}, "criteria": {}}
    page = render_report(results, {})
    assert 'id="coverage-figure"' not in page and "100.0%" not in section(page, "coverage")
    assert "No coverage criteria." in section(page, "coverage")


def test_a_runs_closest_approach_reads_as_what_it_was():
    """An audit found nobody within the cut-off shown as "closest 0.500 m at 0 s" (the cut-off, at the channel's
    first sample), a stray comma after "touched", and neither a near miss's speed nor a touch's severity."""
    from cellsim.campaign.report import _harm_cell

    def cell(closest):
        return _harm_cell({"findings": [{"what": "closest approach", "start": 4.882, **closest}]})["text"]

    assert cell({"distance": 0.5, "robot": "robot"}) == "closest: nobody within 0.500 m"
    assert cell({"distance": 0.124, "region": "hand", "person": "operator", "tool_speed": 0.35}) == (
        "closest 0.124 m, operator's hand at 4.88 s, tool at 0.350 m/s")
    assert cell({"distance": -0.0484, "region": "hand", "person": "operator", "speed": 0.3, "severity": 0.321}) == (
        "touched operator's hand at 4.88 s, 0.0484 m deep, 0.300 m/s, severity 0.321")
