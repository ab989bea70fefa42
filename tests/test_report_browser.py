"""The campaign report opened in a real browser (Debian's Chromium, driven by Playwright).

Every timeline of the page is drawn by its script (cellsim/campaign/static/report.js): the runs
shown in full as the page loads, any other run when its row is opened. So the timelines are
tested here, where they exist: on a real campaign's report (what a person sees: the headline
coverage, the violating run drawn with the window its condition required, any run opening to
its own timeline, the table sorting and filtering, the printed page), and on a hand-made
report whose every piece, tick and label is known in advance. No page may log a script error
or warning, or fetch anything.
"""

from __future__ import annotations

import copy
import json
import re
import shutil
import zlib

import pytest
from conftest import ONE_AT_A_TIME, ROOT
from test_report import DURATION, EVIDENCE, HOSTILE, HS_PIECES, RESULTS, TIMELINE, hostile_results

from cellsim.campaign.report import BOOL_COLOURS, PHASE_COLOURS, render_report
from cellsim.cli import main

pytestmark = ONE_AT_A_TIME  # a campaign's two workers take both cores
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
TWO_OPERATORS = ROOT / "scenarios" / "two_operators.yaml"

# The timeline's geometry, as docs/report.md and report.js state it: time t of a run of
# `duration` seconds is at x = 170 + 810 * t / duration in a drawing 1000 units wide.
PLOT_LEFT, PLOT_WIDTH, MIN_PIECE_WIDTH = 170.0, 810.0, 1.5


def time_to_x(t: float, duration: float = DURATION) -> float:
    return PLOT_LEFT + PLOT_WIDTH * min(max(t, 0.0), duration) / duration


def pieces(samples, duration: float = DURATION) -> list[tuple[float, float, object]]:
    """The constant pieces (t0, t1, value) of a trace over [0, duration): the documented rule, as an oracle."""
    ordered = sorted((float(t), v) for t, v in samples)
    out: list[tuple[float, float, object]] = []
    for i, (t0, value) in enumerate(ordered):
        t1 = min(ordered[i + 1][0] if i + 1 < len(ordered) else duration, duration)
        t0 = max(t0, 0.0)
        if t1 <= t0:
            continue
        if out and out[-1][2] == value and out[-1][1] == t0:
            out[-1] = (out[-1][0], t1, value)
        else:
            out.append((t0, t1, value))
    return out


DRAWING = """svg => ({
  pieces: Array.from(svg.querySelectorAll('rect.piece')).map(r => ({var: r.getAttribute('data-var'),
      x: +r.getAttribute('x'), width: +r.getAttribute('width'), fill: r.getAttribute('fill'),
      tip: r.parentNode.querySelector('title').textContent})),
  lanes: Array.from(svg.querySelectorAll('rect.lane')).map(r => [+r.getAttribute('y'), +r.getAttribute('height')]),
  laneLabels: Array.from(svg.querySelectorAll('text.lane-label')).map(t => [t.lastChild.textContent, t.querySelector('title').textContent]),
  groups: Array.from(svg.querySelectorAll('text.group')).map(t => t.textContent),
  ticks: Array.from(svg.querySelectorAll('line.tick')).map(l => +l.getAttribute('x1')),
  tickLabels: Array.from(svg.querySelectorAll('text.tick-label')).map(t => t.textContent),
  violations: Array.from(svg.querySelectorAll('line.violation')).map(l => [l.getAttribute('data-condition'), +l.getAttribute('x1'),
      +l.getAttribute('x2'), l.parentNode.querySelector('title').textContent]),
  violationLabels: Array.from(svg.querySelectorAll('text.violation-label')).map(t => t.textContent),
  windows: Array.from(svg.querySelectorAll('rect.window')).map(r => ({condition: r.getAttribute('data-condition'),
      x: +r.getAttribute('x'), width: +r.getAttribute('width'), y: +r.getAttribute('y'), height: +r.getAttribute('height'),
      tip: r.parentNode.querySelector('title').textContent})),
  steps: Array.from(svg.querySelectorAll('polyline.step')).map(p => [p.getAttribute('data-var'), p.getAttribute('points').split(' ').length]),
  yLabels: Array.from(svg.querySelectorAll('text.y-label')).map(t => t.textContent),
  yAxes: svg.querySelectorAll('line.y-axis').length,
  viewBox: svg.getAttribute('viewBox').split(' ').map(Number),
  width: svg.getBoundingClientRect().width,
})"""


@pytest.fixture(scope="module")
def browser():
    assert CHROMIUM, "the report's browser test needs Chromium: apt-get install chromium (the README's test command does)"
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(
            executable_path=CHROMIUM,
            args=["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                  "--disable-sync", "--no-first-run"],
        )
        try:
            yield browser
        finally:
            browser.close()


class Opened:
    """A report opened in a new tab, with what went wrong in it: script errors, console errors and
    warnings, requests for anything but the file itself, dialogs (an injected alert())."""

    def __init__(self, browser, path, fragment: str = "", **options) -> None:
        self.page = browser.new_page(viewport={"width": 1300, "height": 900}, **options)
        self.problems: list[str] = []
        page = self.page
        page.on("console", lambda m: self.problems.append(f"console {m.type}: {m.text}") if m.type in ("error", "warning") else None)
        page.on("pageerror", lambda e: self.problems.append(f"script error: {e}"))
        page.on("request", lambda r: self.problems.append(f"request: {r.url}") if r.url.split("#")[0] != path.as_uri() else None)
        page.on("dialog", lambda d: (self.problems.append(f"dialog: {d.message}"), d.dismiss()))
        page.goto(path.as_uri() + fragment)

    def close(self, screenshot=None) -> None:
        if screenshot:
            self.page.screenshot(path=str(screenshot), full_page=True)  # for a person looking into a failure
        self.page.close()
        assert self.problems == []  # no script error, no warning, nothing fetched from anywhere, no dialog


# --------------------------------------------------------------------------- a real campaign's report


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """Four runs of the two-operator misuse scenario: some violate HS:detected (seed 0)."""
    out = tmp_path_factory.mktemp("browser") / "misuse"
    assert main(["campaign", str(TWO_OPERATORS), "--runs", "4", "--jobs", "2", "--seed", "0", "--out", str(out), "--quiet"]) == 1
    return out, json.loads((out / "results.json").read_text())


@pytest.fixture
def page(browser, campaign):
    out, _ = campaign
    opened = Opened(browser, out / "report.html")
    yield opened.page
    opened.close(screenshot=out / "report.png")


def test_the_headline_coverage_is_the_campaigns_figure(page, campaign):
    _, results = campaign
    overall = results["totals"]["coverage"]["overall"]
    shown = page.locator("#coverage-figure").inner_text()
    assert shown != "n/a" and shown.endswith("%")
    assert float(shown.rstrip("%")) == pytest.approx(100 * overall["covered"] / overall["total"], abs=0.05)


def test_each_conditions_rate_and_bound_are_shown_with_the_distribution_they_hold_under(page, campaign):
    from cellsim.validation.bound import probability

    _, results = campaign
    bounds = results["bounds"]
    for name, figures in bounds["conditions"].items():
        row = page.locator("#conditions tbody tr").filter(has=page.locator("strong", has_text=re.compile(f"^{re.escape(name)}$")))
        assert row.locator("td.bound").inner_text() == probability(figures["upper_bound"]), name
    overall = page.locator("#bound-overall")
    assert overall.is_visible() and overall.locator("td.bound").inner_text() == probability(bounds["overall"]["upper_bound"])
    assert bounds["overall"]["failures"] >= 1 and str(bounds["overall"]["failures"]) in overall.inner_text()
    statement = page.locator("#bound-statement")
    assert statement.is_visible()
    assert "Clopper-Pearson" in statement.inner_text() and "operator_waits" in statement.inner_text()


def test_a_violating_runs_timeline_is_drawn_on_load_with_its_required_window(page, campaign):
    _, results = campaign
    violating = [r for r in results["runs"] if r["violations"]]
    assert violating
    run = violating[0]
    condition = run["violations"][0]
    svg = page.locator(f"#timeline-{run['index']} svg.timeline")  # no click: the script drew it as the page loaded
    box = svg.bounding_box()
    assert box and box["width"] > 800 and box["height"] > 300  # drawn at the page's width, not collapsed
    assert svg.locator("rect.piece").count() > 50
    window = svg.locator(f'rect.window[data-condition="{condition}"]')
    assert window.count() == 1 and window.bounding_box()["width"] > 0
    assert svg.locator(f'line.violation[data-condition="{condition}"]').count() == 1
    assert f"Why {condition}" in svg.text_content()
    explanation = run["verdicts"][condition]["explanation"]
    assert explanation in page.locator(f"#timeline-{run['index']}").inner_text()
    assert page.locator(".timeline-slot p").count() == 0  # every placeholder replaced by its drawing


def test_the_runs_drawn_on_load_and_a_run_opened_by_a_click_are_drawn_by_the_same_code(page, campaign):
    """One renderer: the timeline drawn on load and the one drawn under the run's row when it is
    opened are the same drawing, and it shows the run's trace as recorded: its pieces in their
    colours, the ticks, the violation's line, the required window and the numeric lane's axis."""
    out, results = campaign
    run = next(r for r in results["runs"] if r["violations"])
    shown = page.locator(f"#timeline-{run['index']} svg.timeline")
    page.locator(f"tr#run-{run['index']} a.open").click()
    opened = page.locator("tr.details svg.timeline")
    opened.wait_for()
    assert opened.evaluate("svg => svg.outerHTML") == shown.evaluate("svg => svg.outerHTML")

    duration = results["campaign"]["duration"]
    drawn = shown.evaluate(DRAWING)
    trace = json.loads((out / run["out"] / "trace.json").read_text())
    expected = [p for p in pieces(trace["HS"], duration) if p[2] is not None]
    hs = sorted((p for p in drawn["pieces"] if p["var"] == "HS"), key=lambda p: p["x"])
    assert [p["fill"] for p in hs] == [PHASE_COLOURS[v] for _, _, v in expected]
    for p, (t0, t1, value) in zip(hs, expected, strict=True):
        assert p["x"] == pytest.approx(time_to_x(t0, duration), abs=0.02)  # times kept to the millisecond
        assert p["tip"] == f"HS = {value} from {t0:.2f} s to {t1:.2f} s"
    lgt = [p["fill"] for p in drawn["pieces"] if p["var"] == "lgtBar"]
    assert lgt and set(lgt) <= set(BOOL_COLOURS.values())
    assert drawn["ticks"] == pytest.approx([time_to_x(t, duration) for t in range(0, int(duration) + 1, 5)], abs=0.01)
    assert drawn["tickLabels"][0] == "0 s" and drawn["tickLabels"][-1] == f"{duration:g} s"
    condition = run["violations"][0]
    verdict = run["verdicts"][condition]
    name, x1, x2, tip = next(v for v in drawn["violations"] if v[0] == condition)
    assert x1 == x2 == pytest.approx(time_to_x(verdict["violated_at"], duration), abs=0.01)
    assert tip == f"{condition} violated at {verdict['violated_at']:.2f} s" and condition in drawn["violationLabels"]
    lo, hi = verdict["evidence"]["window"]
    (window,) = [w for w in drawn["windows"] if w["condition"] == condition]
    assert window["x"] == pytest.approx(time_to_x(lo, duration), abs=0.01)
    assert window["width"] == pytest.approx(max(time_to_x(hi, duration) - time_to_x(lo, duration), 2 * MIN_PIECE_WIDTH), abs=0.01)
    assert f"Why {condition}" in drawn["groups"]
    assert [label for label, _ in drawn["laneLabels"]].count("sep (m)") == 1  # the numeric lane: its unit, its axis
    assert drawn["steps"] and drawn["steps"][0][0] == "sep" and drawn["yAxes"] == 1
    assert len(drawn["yLabels"]) == 2 and all(label.endswith(" m") for label in drawn["yLabels"])


def test_any_run_opens_to_its_own_timeline(page, campaign):
    out, results = campaign
    holding = next(r for r in results["runs"] if not r["violations"])
    row = page.locator(f"tr#run-{holding['index']}")
    row.locator("a.open").click()
    details = page.locator("tr.details")
    details.locator("svg.timeline").wait_for()
    assert details.locator("rect.piece").count() > 50
    assert details.locator('rect.piece[data-var="safmod"]').count() >= 1
    assert f"runs/{results['campaign']['scenario_name']}" not in details.inner_text()  # re-run outside the campaign
    beside = out.parent / f"misuse-run{holding['index']:04d}"
    assert f"--out {beside}" in details.inner_text()  # beside the campaign folder, never inside it
    row.locator("a.open").click()  # a second click closes it
    assert page.locator("tr.details").count() == 0


def test_a_link_to_a_run_opens_it(browser, campaign):
    out, results = campaign
    index = results["runs"][-1]["index"]
    opened = Opened(browser, out / "report.html", fragment=f"#run-{index}")  # report.html#run-3 opens run 3
    opened.page.locator(f"tr#run-{index} + tr.details svg.timeline").wait_for()
    opened.close()


def test_the_runs_table_sorts_and_filters(page, campaign):
    _, results = campaign
    indices = [r["index"] for r in results["runs"]]
    rows = page.locator("#runs-table tbody tr")
    header = page.locator("#runs-table thead th", has_text="Run")
    header.click()  # ascending
    header.click()  # descending
    assert [int(rows.nth(i).get_attribute("data-run")) for i in range(rows.count())] == sorted(indices, reverse=True)
    page.select_option("#verdict-filter", "violated")
    visible = [r for r in range(rows.count()) if rows.nth(r).is_visible()]
    violating = [r for r in results["runs"] if r["violations"]]
    assert len(visible) == len(violating)
    assert page.locator("#run-count").inner_text() == f"{len(violating)} of {len(indices)} runs"
    page.select_option("#verdict-filter", "")
    page.fill("#run-filter", "no run has this text")
    assert not any(rows.nth(r).is_visible() for r in range(rows.count()))


def _pdf_rectangles(pdf: bytes) -> int:
    """Filled rectangles (``re`` operators) in a PDF's content streams: Chromium keeps SVG rects as vectors."""
    count = 0
    for stream in re.finditer(rb"stream\r?\n(.*?)\r?\nendstream", pdf, re.S):
        try:
            count += len(re.findall(rb" re\b", zlib.decompress(stream.group(1))))
        except zlib.error:
            continue  # an image or a font
    return count


ONLY_TIMELINES = "body * { visibility: hidden !important; } svg.timeline, svg.timeline * { visibility: visible !important; }"
"""Printed with this, a page paints its timelines and nothing else: the PDF's rectangles are theirs alone,
whatever the rest of the page's layout and pagination."""


def test_the_printed_page_shows_the_timelines_drawn_on_load(browser, campaign, tmp_path):
    """Printed (a PDF) with no click, the runs shown in full are there: the PDF of the page holds
    their pieces, which the same page printed without its script does not."""
    out, _ = campaign
    report = tmp_path / "report.html"  # the report, printing its timelines alone
    report.write_text((out / "report.html").read_text().replace("</head>", f"<style>{ONLY_TIMELINES}</style></head>", 1))
    printed = Opened(browser, report)
    printed.page.emulate_media(media="print")
    svgs = printed.page.locator("section.run svg.timeline")
    assert svgs.count() >= 1 and all(svgs.nth(i).bounding_box()["height"] > 300 for i in range(svgs.count()))
    drawn = printed.page.evaluate("document.querySelectorAll('section.run rect.piece, section.run rect.lane').length")
    with_script = printed.page.pdf(format="A4", print_background=True)
    printed.close()
    bare = Opened(browser, report, java_script_enabled=False)
    assert bare.page.locator("svg.timeline").count() == 0
    without_script = bare.page.pdf(format="A4", print_background=True)
    bare.close()
    assert with_script.startswith(b"%PDF")
    assert _pdf_rectangles(without_script) == 0
    assert _pdf_rectangles(with_script) >= drawn > 100


# --------------------------------------------------------------------------- a hand-made report, every piece known


def _explained() -> dict:
    results = copy.deepcopy(RESULTS)
    results["runs"][1]["verdicts"]["HC:not_mis"].update(evidence=EVIDENCE, explanation="HC = mis")
    results["campaign"]["units"] = {"speed": "m/s"}
    return results


@pytest.fixture(scope="module")
def handmade(browser, tmp_path_factory):
    """The test_report fixture, with its violation explained and its numeric lane's unit: drawn on load."""
    path = tmp_path_factory.mktemp("handmade") / "report.html"
    path.write_text(render_report(_explained(), {1: TIMELINE}), encoding="utf-8")
    opened = Opened(browser, path)
    yield opened.page.locator("#timeline-1 svg.timeline").evaluate(DRAWING)
    opened.close()


def draw(browser, tmp_path, results, timelines, **options) -> dict:
    """The timeline of run 1 of a report of ``results``, as drawn on load."""
    path = tmp_path / "report.html"
    path.write_text(render_report(results, timelines, **options), encoding="utf-8")
    opened = Opened(browser, path)
    drawing = opened.page.locator("#timeline-1 svg.timeline").evaluate(DRAWING)
    opened.close()
    return drawing


@pytest.mark.parametrize("var", ["safmod", "HS", "HC", "lgtBar", "oloc"])
def test_one_rect_per_defined_piece(handmade, var):
    rects = sorted((p for p in handmade["pieces"] if p["var"] == var), key=lambda p: p["x"])
    expected = [p for p in pieces(TIMELINE[var]) if p[2] is not None]
    assert len(rects) == len(expected)
    assert var != "HS" or len(rects) == HS_PIECES  # the repeated "act" merges
    for rect, (t0, t1, _) in zip(rects, expected, strict=True):
        assert rect["x"] == pytest.approx(time_to_x(t0), abs=0.01)
        assert rect["width"] == pytest.approx(max(time_to_x(t1) - time_to_x(t0), MIN_PIECE_WIDTH), abs=0.02)


def test_piece_colours_and_tooltips(handmade):
    hs = [p for p in handmade["pieces"] if p["var"] == "HS"]
    assert [p["fill"] for p in hs] == [PHASE_COLOURS[v] for v in ("inact", "act", "mit", "res", "inact")]
    assert [p for p in handmade["pieces"] if p["var"] == "HC"][-1]["fill"] == PHASE_COLOURS["mis"]
    lgt = [p["fill"] for p in handmade["pieces"] if p["var"] == "lgtBar"]
    assert lgt == [BOOL_COLOURS[False], BOOL_COLOURS[True], BOOL_COLOURS[False]]  # 31 s is after the run: dropped
    assert "HS = mit from 4.50 s to 12.00 s" in [p["tip"] for p in hs]


def test_numeric_variable_is_a_step_plot_with_its_unit_on_the_label_and_the_axis(handmade):
    assert not [p for p in handmade["pieces"] if p["var"] == "speed"]
    assert handmade["steps"] == [["speed", 2 * 3]]
    assert handmade["yLabels"] == ["1.50 m/s", "0 m/s"] and handmade["yAxes"] == 1
    assert ["speed (m/s)", "speed (m/s)"] in handmade["laneLabels"]
    assert [h for _, h in handmade["lanes"]].count(40) == 1  # the step plot's lane is taller


def test_violation_marker_at_violation_time(handmade):
    expected = PLOT_LEFT + PLOT_WIDTH * 12.34 / DURATION
    assert handmade["violations"] == [["HC:not_mis", pytest.approx(expected, abs=0.005), pytest.approx(expected, abs=0.005),
                                       "HC:not_mis violated at 12.34 s"]]
    assert handmade["violationLabels"] == ["HC:not_mis"]


def test_ticks_every_five_seconds(handmade):
    assert handmade["ticks"] == pytest.approx([time_to_x(t) for t in range(0, 31, 5)], abs=0.01)
    assert handmade["tickLabels"] == [f"{t} s" for t in range(0, 31, 5)]
    assert handmade["viewBox"][:3] == [0, 0, 1000]


def test_groups_of_lanes_in_order_then_why(handmade):
    assert handmade["groups"] == ["Safety mode", "Hazard phases", "Sensors", "Operator", "Other variables", "Why HC:not_mis"]


def test_a_violations_macros_and_atoms_are_rows_and_its_required_window_is_shaded(handmade):
    for row, intervals in EVIDENCE["rows"].items():
        truths = [p for p in handmade["pieces"] if p["var"] == row and p["fill"] == BOOL_COLOURS[True]]
        assert [p["x"] for p in truths] == pytest.approx([time_to_x(lo) for lo, _ in intervals], abs=0.01)
    (window,) = handmade["windows"]
    assert window["condition"] == "HC:not_mis"
    assert window["x"] == pytest.approx(time_to_x(12.34), abs=0.01)
    assert window["width"] == pytest.approx(time_to_x(12.84) - time_to_x(12.34), abs=0.01)
    # the window spans the lanes, from the first lane's top to the last one's bottom
    top, (last_y, last_h) = handmade["lanes"][0][0], handmade["lanes"][-1]
    assert window["y"] == pytest.approx(top) and window["y"] + window["height"] == pytest.approx(last_y + last_h)
    assert window["tip"] == "HC:not_mis: required between 12.34 s and 12.84 s"


def test_a_value_has_one_colour_in_every_lane(browser, tmp_path):
    timeline = {"ract": [[0.0, "idle"], [5.0, "welding"]], "wact": [[0.0, "welding"], [3.0, "idle"]]}
    drawn = draw(browser, tmp_path, RESULTS, {1: timeline})
    ract = [p["fill"] for p in drawn["pieces"] if p["var"] == "ract"]
    wact = [p["fill"] for p in drawn["pieces"] if p["var"] == "wact"]
    assert ract == wact[::-1] and ract[0] != ract[1]  # idle and welding: the same colours in both lanes


def test_a_piece_of_a_few_milliseconds_keeps_a_visible_width_over_its_neighbour(browser, tmp_path):
    drawn = draw(browser, tmp_path, RESULTS, {1: {"HS": [[0.0, "inact"], [4.0, "act"], [4.002, "mit"]]}})
    rects = [p for p in drawn["pieces"] if p["var"] == "HS"]
    assert rects[-1]["width"] == pytest.approx(MIN_PIECE_WIDTH)  # drawn last: mit does not cover it
    assert rects[-1]["fill"] == PHASE_COLOURS["act"]
    assert [r["fill"] for r in rects[:2]] == [PHASE_COLOURS["inact"], PHASE_COLOURS["mit"]]


def test_a_cells_own_hazard_phases_are_drawn_in_its_risk_models_colours(browser, tmp_path):
    phases = {"PALLET": {"values": ["idle", "detected", "guarded", "clearing", "harm"], "initial": "idle", "mishap": "harm"}}
    timeline = {"PALLET": [[0.0, "idle"], [4.0, "detected"], [4.02, "guarded"], [9.0, "harm"]],
                "curtain": [[0.0, False], [4.0, True]]}
    drawn = draw(browser, tmp_path, RESULTS, {1: timeline}, phases=phases)
    fills = [p["fill"] for p in sorted((p for p in drawn["pieces"] if p["var"] == "PALLET"), key=lambda p: p["x"])]
    assert fills[0] == PHASE_COLOURS["inact"] and fills[-1] == PHASE_COLOURS["mis"]  # initial grey, mishap red
    assert len(set(fills)) == 4  # detected and guarded told apart
    assert drawn["groups"] == ["Hazard phases", "Other variables"]


def test_a_long_lane_name_is_cut_to_the_room_left_of_the_plot_and_whole_in_its_tooltip(browser, tmp_path):
    name = "a_variable_with_a_very_long_name_indeed"
    drawn = draw(browser, tmp_path, RESULTS, {1: {name: [[0.0, "on"]]}})
    ((shown, whole),) = drawn["laneLabels"]
    assert whole == name and shown == name[:24] + "\u2026"


# --------------------------------------------------------------------------- hostile strings


def test_hostile_strings_in_the_scenario_are_text_on_the_page_not_markup(browser, tmp_path):
    """Descriptions, names, values, errors and re-run commands that hold </script>, <script>alert(1)
    and <b>: the page shows them as written, runs no injected script and logs no error."""
    results, timelines = hostile_results()
    path = tmp_path / "report.html"
    path.write_text(render_report(results, timelines), encoding="utf-8")
    opened = Opened(browser, path)
    page = opened.page
    assert page.evaluate("document.querySelectorAll('b').length") == 0
    assert page.evaluate("document.scripts.length") == 2
    assert page.locator("h1").inner_text() == "Test campaign: cell " + HOSTILE
    conditions = page.locator("#conditions").inner_text()
    assert "desc " + HOSTILE in conditions and "G(x " + HOSTILE + ")" in conditions
    assert "missing " + HOSTILE in page.locator("#coverage").inner_text()
    shown = page.locator("#timeline-1")
    assert "why " + HOSTILE in shown.inner_text() and "rerun " + HOSTILE in shown.inner_text()
    drawn = shown.locator("svg.timeline").evaluate(DRAWING)  # drawn on load, the data's strings as text
    lanes = [whole for _, whole in drawn["laneLabels"]]
    assert "atom " + HOSTILE in lanes and "lane" + HOSTILE in lanes
    assert f"oloc = value {HOSTILE} from 0.00 s to 20.00 s" in [p["tip"] for p in drawn["pieces"]]
    opens = {0: "value " + HOSTILE, 1: "why " + HOSTILE, 2: "error " + HOSTILE}  # configuration, explanation, error
    for index, text in opens.items():
        page.locator(f"tr#run-{index} a.open").click()
        details = page.locator(f"tr#run-{index} + tr.details")
        details.wait_for()
        assert text in page.locator(f"tr#run-{index}").inner_text() + details.inner_text()
    assert page.evaluate("document.querySelectorAll('b').length") == 0
    page.locator("#run-filter").fill("</script>")  # filtering reads the rows' text, not their markup
    assert page.locator("#run-count").inner_text() == "1 of 3 runs"  # run 0's configuration value
    opened.close()


# --------------------------------------------------------------------------- harm, in a real campaign's report


@pytest.fixture(scope="module")
def tending(tmp_path_factory):
    """Four runs of the fenceless machine-tending cell: blind spots in every run, TrueSSM violated in some."""
    out = tmp_path_factory.mktemp("browser") / "tending"
    code = main(["campaign", str(ROOT / "scenarios" / "machine_tending.yaml"), "--runs", "4", "--jobs", "2", "--seed", "0",
                 "--out", str(out), "--quiet"])
    return out, code, json.loads((out / "results.json").read_text())


def test_the_harm_section_shows_contacts_severities_and_blind_spots(browser, tending):
    out, code, results = tending
    opened = Opened(browser, out / "report.html", "#harm")
    page = opened.page
    section = page.locator("#harm")
    assert section.is_visible() and page.locator("nav a[href='#harm']").count() == 1
    assert "No run harmed a person" in section.locator("#harm-statement").inner_text()
    rows = section.locator("#harm-severity tbody tr")
    counts = {rows.nth(i).locator("th").inner_text(): int(rows.nth(i).locator("td").first.inner_text())
              for i in range(rows.count())}
    untouched = sum(not any(f["what"] == "contact" for f in r["findings"]) for r in results["runs"])
    assert sum(counts.values()) == 4 and counts["no contact"] == untouched
    blind = section.locator("#blind-spots tbody tr")
    shown = {(blind.nth(i).locator("td").nth(0).inner_text(), blind.nth(i).locator("td").nth(1).inner_text())
             for i in range(blind.count())}
    recorded = {(f["subject"], f["field"]) for r in results["runs"] for f in r["findings"] if f["what"] == "blind spot"}
    assert shown == recorded and ("scanner", "protective") in shown
    conditions = page.locator("#conditions").inner_text()
    assert "TrueSSM" in conditions and "NoHarm" in conditions and "NoClamping" in conditions
    opened.close(screenshot=out / "harm.png")


@pytest.fixture(scope="module")
def touching(tmp_path_factory):
    """Three runs of the machine-tending cell with the person's reach put into the arm's pick point (the arm touches
    their hand, then their forearm), NoClamping waived with a reason."""
    folder = tmp_path_factory.mktemp("touching")
    scenario = folder / "touching.yaml"
    scenario.write_text(f"base: {ROOT / 'scenarios' / 'machine_tending.yaml'}\n"
                        "validation:\n  waive:\n    NoClamping: REASON the bench is padded\n")
    out = folder / "campaign"
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "cellsim", "campaign", str(scenario), "--runs", "3", "--jobs", "2",
                           "--duration", "8", "--out", str(out), "--set",
                           "operator.waypoints.bench_south.reach=[-0.75,-0.25,1.05]"],
                          capture_output=True, text=True, timeout=600)
    checked = subprocess.run([sys.executable, "-m", "cellsim", "check", str(out)], capture_output=True, text=True,
                             timeout=600)
    return out, done, checked, json.loads((out / "results.json").read_text())


def test_each_contact_and_each_runs_closest_approach_are_shown_and_harm_is_red(browser, touching):
    """An audit found a contact moving from the hand to the forearm folded into one (the forearm in no table), a run
    whose only contact was at severity 0 counted under "no contact", no run's own contacts or closest approach in
    the report, harm drawn in the green of 'holds', and a waived condition's reason missing from the campaign's and
    its check's output."""
    from cellsim.numbers import sig3

    out, done, checked, results = touching
    runs = results["runs"]
    contacts = [(r["index"], f) for r in runs for f in r["findings"] if f["what"] == "contact"]
    assert {f["region"] for _, f in contacts} >= {"hand", "forearm"}, contacts
    # each contact is one region, one person, one part: consecutive ones differ in one of them
    for run in runs:
        mine = [f for f in run["findings"] if f["what"] == "contact"]
        for a, b in zip(mine, mine[1:]):
            assert a["end"] is not None and a["end"] <= b["start"]
            if a["end"] == b["start"]:
                assert (a["region"], a["person"], a["part"]) != (b["region"], b["person"], b["part"])
    opened = Opened(browser, out / "report.html", "#harm")
    page = opened.page
    regions = page.locator("#harm-regions tbody tr")
    shown = {regions.nth(i).locator("td").first.inner_text() for i in range(regions.count())}
    assert shown == {f["region"].replace("_", " ") for _, f in contacts}
    rows = page.locator("#harm-severity tbody tr")
    counts = {rows.nth(i).locator("th").inner_text(): int(rows.nth(i).locator("td").first.inner_text())
              for i in range(rows.count())}
    assert counts["no contact"] == sum(not any(f["what"] == "contact" for f in r["findings"]) for r in runs)
    harm_bar = page.locator("#harm-severity tr:has(th:text('1 to 2 (harm)')) .bar span")
    within_bar = page.locator("#harm-severity tr:has(th:text('up to 0.5')) .bar span")
    assert harm_bar.evaluate("e => getComputedStyle(e).backgroundColor") == "rgb(229, 57, 53)"
    assert within_bar.evaluate("e => getComputedStyle(e).backgroundColor") == "rgb(67, 160, 71)"
    # each run's own closest approach and contacts, in the runs table
    header = page.locator("#runs-table thead th")
    column = [header.nth(i).inner_text().strip() for i in range(header.count())].index("Harm")
    for run in runs:
        cell = page.locator(f"#runs-table tr[data-run='{run['index']}'] td").nth(column).inner_text()
        mine = [f for f in run["findings"] if f["what"] == "contact"]
        if mine:
            worst = max(f["severity"] for f in mine)
            assert f"{len(mine)} contact" in cell and f"worst severity {worst:.3g}" in cell, cell
            # an audit found only the worst named: each one is listed, opened from the cell
            details = page.locator(f"#runs-table tr[data-run='{run['index']}'] details.contacts")
            details.locator("summary").click()
            listed = details.locator("li")
            assert listed.count() == len(mine)
            for i, f in enumerate(mine):
                item = listed.nth(i).inner_text()
                assert item.startswith(f"{sig3(f['start'])} s: ") and f["part"] in item, item
                assert f"severity {sig3(f['severity'])}" in item, item
        assert "closest" in cell or "touched" in cell, cell
        assert not cell.startswith("touched,"), cell
        closest = next(f for f in run["findings"] if f["what"] == "closest approach")
        if closest.get("region"):  # whose region it was, where one was within the cut-off
            assert f"{closest['person']}'s {closest['region'].replace('_', ' ')}" in cell, cell
    assert any(f["what"] == "closest approach" and f.get("person") == "operator" for r in runs for f in r["findings"])
    assert "NoClamping (REASON the bench is padded)" in page.locator("#waived").inner_text()
    opened.close(screenshot=out / "harm.png")
    assert "waived" in done.stdout and "NoClamping: REASON the bench is padded" in done.stdout, done.stdout
    assert "waived: NoClamping (REASON the bench is padded)" in checked.stdout, checked.stdout


def test_a_measurement_outrun_between_looks_is_named_per_run_in_the_harm_section(browser, tmp_path):
    """Two runs of the machine-tending cell with its monitor assuming the true margin falls at 1 m/s at most: each
    run's 'fast fall' finding is listed with its own text and a link to its run, the count reads as English."""
    out = tmp_path / "outrun"
    main(["campaign", str(ROOT / "scenarios" / "machine_tending.yaml"), "--runs", "2", "--jobs", "2", "--seed", "0",
          "--out", str(out), "--quiet", "--set", "ssm.max_margin_fall=1"])
    results = json.loads((out / "results.json").read_text())
    found = [(r["index"], f["text"]) for r in results["runs"] for f in r["findings"] if f["what"] == "fast fall"]
    assert found, "no run found the fall faster than assumed"
    opened = Opened(browser, out / "report.html", "#harm")
    block = opened.page.locator("#fast-parts")
    assert block.is_visible()
    text = block.inner_text()
    plural = "s" if len(found) != 1 else ""
    assert text.startswith(f"In {len(found)} finding{plural} the twin's measurement") and '""' not in text
    items = block.locator("li")
    assert items.count() == len(found)
    for k, (index, finding) in enumerate(found):
        assert f"Run {index}: {finding}" == items.nth(k).inner_text()
        assert items.nth(k).locator(f"a[href='#run-{index}']").count() == 1
    opened.close(screenshot=out / "outrun.png")
