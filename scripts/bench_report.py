#!/usr/bin/env python3
"""Benchmark: the campaign report at 1 000 runs, written and opened in a browser.

Runs a real campaign of --real runs of the two-operator misuse scenario (some violate a
condition), then makes a campaign folder of --runs runs from those results and traces
(run i is real run i mod --real, renumbered, its numeric samples shifted by i * 1e-7 so
that no two runs share a value, as in a real campaign), and times the campaign's own last step on
it (``cellsim.campaign.runner.finish``: coverage merged over every run, each run's trace
read, report.html rendered and written, results.json written). Then opens the report in
Chromium (Playwright; Debian's chromium) and times the page's load (which includes the
script drawing the timelines shown in full), opening one run's timeline and sorting the
runs table.

Targets (issue 13): the report of a 1 000-run campaign generated in under 2 s, its HTML
under 5 MB, and loaded in a browser in under a second.

    .venv/bin/python scripts/bench_report.py [--runs 1000] [--real 20] [--jobs 2]
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cellsim.campaign.runner import (  # noqa: E402
    RESULT, RESULTS, TRACE, CampaignPlan, finish, run_campaign, run_dir,
)
from cellsim.scenario import load_scenario  # noqa: E402
from cellsim.validation.check import scenario_safety_case  # noqa: E402
from cellsim.simulation import BLACKBOX  # noqa: E402

SCENARIO = ROOT / "scenarios" / "two_operators.yaml"


def grow(real: Path, out: Path, runs: int) -> list[dict]:
    """A campaign folder of ``runs`` runs made of the real campaign's results and traces."""
    results = json.loads((real / RESULTS).read_text())["runs"]
    grown = []
    for i in range(runs):
        source = results[i % len(results)]
        folder = run_dir(out, i)
        folder.mkdir(parents=True)
        trace = json.loads((real / source["out"] / TRACE).read_text())
        for samples in trace.values():  # every copy's numbers its own, as a real campaign's are
            for sample in samples:
                if isinstance(sample[1], float):
                    sample[1] += i * 1e-7
        (folder / TRACE).write_text(json.dumps(trace))
        if i == 0:  # the report reads the channels' units and the hazards' phases from one black box
            shutil.copy(real / source["out"] / BLACKBOX, folder / BLACKBOX)
        result = {**source, "index": i, "out": str(folder.relative_to(out))}
        (folder / RESULT).write_text(json.dumps(result))
        grown.append(result)
    return grown


def browse(report: Path, runs: int) -> str:
    """Load, open-a-run (one in the middle of the ``runs``) and sort times of the report in Chromium."""
    chromium = shutil.which("chromium")
    if not chromium:
        return "browser: chromium not found (apt-get install chromium): load time not measured"
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=["--no-sandbox", "--disable-gpu",
                                    "--disable-background-networking", "--disable-component-update", "--disable-sync"])
        page = browser.new_page(viewport={"width": 1300, "height": 900})
        errors = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        loads = []
        for _ in range(3):
            t0 = time.perf_counter()
            page.goto(report.as_uri(), wait_until="load")
            loads.append(time.perf_counter() - t0)
        rows = page.locator("#runs-table tbody tr").count()
        drawn = page.locator("section.run svg.timeline").count()  # by the script, as the page loaded
        t0 = time.perf_counter()
        middle = min(500, runs // 2)  # a run in the middle of the table
        page.locator(f"tr#run-{middle} a.open").click()
        page.locator("tr.details svg.timeline").wait_for()
        opened = time.perf_counter() - t0
        t0 = time.perf_counter()
        page.locator("#runs-table thead th", has_text="Seed").click()
        page.wait_for_function("document.querySelector('#runs-table thead th.sorted-asc') !== null")
        sorted_in = time.perf_counter() - t0
        browser.close()
    return (f"browser: load {min(loads):.3f} s (best of 3; target < 1 s), {rows} rows, {drawn} timelines drawn on load; "
            f"open run {middle}'s timeline "
            f"{opened * 1e3:.0f} ms; sort by seed {sorted_in * 1e3:.0f} ms; script errors {len(errors)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=1000, help="runs in the report (default 1000)")
    parser.add_argument("--real", type=int, default=20, help="real runs simulated to make them from (default 20)")
    parser.add_argument("--jobs", type=int, default=2, help="workers for the real runs (default 2)")
    parser.add_argument("--seed", type=int, default=1, help="campaign seed of the real runs (default 1)")
    args = parser.parse_args()
    if args.runs < 1 or args.real < 1:
        print("error: --runs and --real must be at least 1", file=sys.stderr)
        sys.exit(2)

    with tempfile.TemporaryDirectory() as tmp:
        plan = CampaignPlan(str(SCENARIO), (), args.seed, args.real)
        started = time.perf_counter()
        run_campaign(plan, Path(tmp) / "real", jobs=args.jobs)
        print(f"{args.real} real runs of {SCENARIO.name}: {time.perf_counter() - started:.1f} s")

        out = Path(tmp) / "grown"
        runs = grow(Path(tmp) / "real", out, args.runs)
        sf = load_scenario(SCENARIO)
        big = CampaignPlan(str(SCENARIO), (), args.seed, args.runs)
        case = scenario_safety_case(sf)
        t0 = time.perf_counter()
        outcome = finish(big, out, sf, case, runs, 0, t0)
        total = time.perf_counter() - t0
        size = outcome.report_path.stat().st_size
        violating = sum(1 for r in runs if r.get("violations"))
        print(f"report of {args.runs} runs ({violating} violating): written in {total:.2f} s "
              f"(of which report {outcome.timing['report']:.2f} s, coverage {outcome.timing['coverage']:.2f} s; "
              f"target < 2 s); report.html {size / 1e6:.2f} MB (target < 5 MB)")
        print(browse(outcome.report_path, args.runs))


if __name__ == "__main__":
    main()
