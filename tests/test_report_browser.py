"""A real campaign's report.html, opened in a real browser (Debian's Chromium, driven by Playwright).

What a person sees: the headline coverage is the campaign's figure, the violating run's
timeline is drawn with the window its condition required, any run opens to its own
timeline, the runs table sorts and filters, and the page logs no script error.
"""

from __future__ import annotations

import json
import shutil

import pytest
from conftest import ROOT

from cellsim.cli import main

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
TWO_OPERATORS = ROOT / "scenarios" / "two_operators.yaml"


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """Four runs of the two-operator misuse scenario: some violate HS:detected (seed 0)."""
    out = tmp_path_factory.mktemp("browser") / "misuse"
    assert main(["campaign", str(TWO_OPERATORS), "--runs", "4", "--jobs", "2", "--seed", "0", "--out", str(out), "--quiet"]) == 1
    return out, json.loads((out / "results.json").read_text())


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


@pytest.fixture
def page(browser, campaign):
    out, _ = campaign
    page = browser.new_page(viewport={"width": 1300, "height": 900})
    problems: list[str] = []
    page.on("console", lambda m: problems.append(f"console {m.type}: {m.text}") if m.type in ("error", "warning") else None)
    page.on("pageerror", lambda e: problems.append(f"script error: {e}"))
    page.on("request", lambda r: problems.append(f"request: {r.url}") if not r.url.startswith("file://") else None)
    page.goto((out / "report.html").as_uri())
    yield page
    page.screenshot(path=str(out / "report.png"), full_page=True)  # for a person looking into a failure
    page.close()
    assert problems == []  # no script error, no warning, nothing fetched from anywhere


def test_the_headline_coverage_is_the_campaigns_figure(page, campaign):
    _, results = campaign
    overall = results["totals"]["coverage"]["overall"]
    shown = page.locator("#coverage-figure").inner_text()
    assert shown != "n/a" and shown.endswith("%")
    assert float(shown.rstrip("%")) == pytest.approx(100 * overall["covered"] / overall["total"], abs=0.05)


def test_a_violating_runs_timeline_is_drawn_with_its_required_window(page, campaign):
    _, results = campaign
    violating = [r for r in results["runs"] if r["violations"]]
    assert violating
    run = violating[0]
    condition = run["violations"][0]
    svg = page.locator(f"#timeline-{run['index']} svg.timeline")
    box = svg.bounding_box()
    assert box and box["width"] > 800 and box["height"] > 300  # drawn at the page's width, not collapsed
    assert svg.locator("rect.piece").count() > 50
    window = svg.locator(f'rect.window[data-condition="{condition}"]')
    assert window.count() == 1 and window.bounding_box()["width"] > 0
    assert svg.locator(f'line.violation[data-condition="{condition}"]').count() == 1
    assert f"Why {condition}" in svg.text_content()
    explanation = run["verdicts"][condition]["explanation"]
    assert explanation in page.locator(f"#timeline-{run['index']}").inner_text()


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


def test_a_timeline_opened_from_the_table_draws_what_the_printed_one_does(page, campaign):
    """The script draws a run from its embedded trace; the page draws violating runs in full for print.
    Both must show the same pieces, at the same places, in the same colours."""
    _, results = campaign
    run = next(r for r in results["runs"] if r["violations"])
    pieces = """svg => Array.from(svg.querySelectorAll('rect.piece')).map(r =>
        [r.getAttribute('data-var'), +r.getAttribute('x'), +r.getAttribute('width'), r.getAttribute('fill')])"""
    printed = page.locator(f"#timeline-{run['index']} svg.timeline").evaluate(pieces)
    page.locator(f"tr#run-{run['index']} a.open").click()
    opened = page.locator("tr.details svg.timeline")
    opened.wait_for()
    drawn = opened.evaluate(pieces)
    assert [(v, fill) for v, _, _, fill in drawn] == [(v, fill) for v, _, _, fill in printed]
    for (_, x, w, _), (_, x0, w0, _) in zip(drawn, printed):
        assert x == pytest.approx(x0, abs=0.05) and w == pytest.approx(w0, abs=0.05)  # times kept to the millisecond
    printed_svg = page.locator(f"#timeline-{run['index']} svg.timeline")
    same = """svg => [Array.from(svg.querySelectorAll('line.tick, line.violation')).map(l => [l.getAttribute('class'),
        +l.getAttribute('x1'), +l.getAttribute('y1'), +l.getAttribute('y2')]),
        Array.from(svg.querySelectorAll('text.y-label, text.tick-label, text.violation-label')).map(t => t.textContent),
        svg.querySelectorAll('polyline.step').length, svg.getAttribute('viewBox').split(' ').map(Number)]"""
    lines, texts, polylines, view = opened.evaluate(same)
    lines0, texts0, polylines0, view0 = printed_svg.evaluate(same)
    assert texts == texts0 and polylines == polylines0 and view == view0  # axes, units, labels, the same height
    assert [c for c, *_ in lines] == [c for c, *_ in lines0]
    assert [v for _, *xs in lines for v in xs] == pytest.approx([v for _, *xs in lines0 for v in xs], abs=0.05)
    window = "svg => Array.from(svg.querySelectorAll('rect.window')).flatMap(r => [+r.getAttribute('x'), +r.getAttribute('width')])"
    shaded = page.locator(f"#timeline-{run['index']} svg.timeline").evaluate(window)
    assert len(shaded) == 2 and opened.evaluate(window) == pytest.approx(shaded, abs=0.05)
