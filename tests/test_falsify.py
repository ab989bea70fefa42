"""Falsification: the search space, the guides' meeting distance, the score, and ``cellsim falsify``
as a user meets it (a process, its folder read back, its report in Chromium)."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest
from conftest import ONE_AT_A_TIME, ROOT, WELDING_CELL
from hypothesis import given, settings
from hypothesis import strategies as st

from cellsim.config.sampling import ChoiceSampler, SimplexSampler, UniformSampler, draw_configuration
from cellsim.campaign.space import SearchSpace
from cellsim.logic import parse
from cellsim.logic.robustness import meeting
from cellsim.logic.trace import Signal, Trace

TWO_OPERATORS = ROOT / "scenarios" / "two_operators.yaml"
SAMPLERS = {
    "waits": SimplexSampler("simplex", total=20.0, minimum=0.5),
    "start": UniformSampler("uniform", low=0.0, high=12.0),
    "side": ChoiceSampler("choice", values=["left", "right", "middle"]),
}
POINTS = {"waits": ["w.a", "w.b", "w.c", "w.d"], "start": ["s"], "side": ["x", "y"]}


def _cellsim(*args, timeout=600):
    return subprocess.run([sys.executable, "-m", "cellsim", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT, env={**os.environ, "COLUMNS": "200"})


# --------------------------------------------------------------------------- the space


def test_the_space_has_one_coordinate_per_free_value():
    # the simplex of 4 has 3 free values; uniform 1; choice 2
    assert SearchSpace(SAMPLERS, POINTS).dimension == 6


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-2.0, 3.0), min_size=6, max_size=6))
def test_every_point_is_a_configuration_the_samplers_could_draw(point):
    config = SearchSpace(SAMPLERS, POINTS).decode(point)
    waits = [config[p] for p in POINTS["waits"]]
    assert all(w >= 0.5 for w in waits)
    assert round(sum(waits) * 1e6) == 20_000_000  # exactly on the sampler's 1e-6 grid
    assert all(round(w * 1e6) / 1e6 == w for w in waits)
    assert 0.0 <= config["s"] <= 12.0
    assert {config["x"], config["y"]} <= {"left", "right", "middle"}


def test_the_middle_point_is_the_middle_configuration():
    space = SearchSpace(SAMPLERS, POINTS)
    config = space.decode(space.centre())
    assert [config[p] for p in POINTS["waits"]] == [5.0, 5.0, 5.0, 5.0]
    assert config["s"] == 6.0


def test_a_uniform_point_is_a_configuration_drawn_as_the_campaign_draws_it():
    """Random search's baseline is the campaign's distribution: each marginal's empirical CDF, from
    decoding uniform points and from the campaign's own draws, agree within the two-sample
    Kolmogorov-Smirnov critical value at 0.1 %."""
    space, rng, n = SearchSpace(SAMPLERS, POINTS), np.random.default_rng(5), 3000
    decoded = [space.decode(rng.random(space.dimension)) for _ in range(n)]
    drawn = [draw_configuration(SAMPLERS, POINTS, 11, i) for i in range(n)]
    critical = 1.95 * math.sqrt(2 / n)
    for path in ("w.a", "w.d", "s"):
        a, b = np.sort([c[path] for c in decoded]), np.sort([c[path] for c in drawn])
        grid = np.linspace(min(a[0], b[0]), max(a[-1], b[-1]), 400)
        gap = np.max(np.abs(np.searchsorted(a, grid, side="right") / n - np.searchsorted(b, grid, side="right") / n))
        assert gap < critical, (path, gap)
    for path in ("x",):
        shares = [sum(c[path] == v for c in decoded) / n for v in ("left", "right", "middle")]
        assert all(abs(s - 1 / 3) < 0.04 for s in shares)


def test_an_unknown_configuration_point_is_refused():
    with pytest.raises(ValueError, match="unknown configuration point"):
        SearchSpace({"nowhere": SAMPLERS["start"]}, POINTS)


# --------------------------------------------------------------------------- the guides' distance


def _trace(**signals) -> Trace:
    return Trace({name: Signal([t for t, _ in s], [v for _, v in s]) for name, s in signals.items()}, start=0.0, end=10.0)


def _vocabulary():
    from cellsim.logic import BoolDomain

    return {"a": BoolDomain(), "b": BoolDomain()}


def test_meeting_is_the_gap_between_two_situations_or_minus_their_overlap():
    a, b = parse("a", _vocabulary()), parse("b", _vocabulary())
    apart = _trace(a=[(0, False), (2.0, True), (3.0, False)], b=[(0, False), (4.5, True), (6.0, False)])
    assert meeting(a, b, apart) == pytest.approx(1.5)
    overlapping = _trace(a=[(0, False), (2.0, True), (5.0, False)], b=[(0, False), (4.5, True), (6.0, False)])
    assert meeting(a, b, overlapping) == pytest.approx(-0.5)
    never = _trace(a=[(0, False)], b=[(0, True)])
    assert meeting(a, b, never) == math.inf


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 9.9), st.booleans()), min_size=1, max_size=8),
       st.lists(st.tuples(st.floats(0, 9.9), st.booleans()), min_size=1, max_size=8))
def test_meeting_is_negative_exactly_when_the_two_held_together(xs, ys):
    from cellsim.logic import satisfaction

    trace = _trace(a=sorted({t: v for t, v in [(0.0, False), *xs]}.items()),
                   b=sorted({t: v for t, v in [(0.0, False), *ys]}.items()))
    a, b = parse("a", _vocabulary()), parse("b", _vocabulary())
    together = satisfaction(parse("a and b", _vocabulary()), trace)
    distance = meeting(a, b, trace)
    assert (distance < 0) == (not together.is_empty())
    if distance < 0:
        assert distance == pytest.approx(-together.measure())


# --------------------------------------------------------------------------- the guides in a scenario


def test_a_guide_naming_an_unknown_condition_is_refused_at_its_key(tmp_path):
    from cellsim.config.typed_yaml import ConfigError
    from cellsim.scenario import load_scenario
    from cellsim.validation.check import scenario_safety_case

    bad = tmp_path / "bad.yaml"
    bad.write_text(f"base: {TWO_OPERATORS}\nvalidation:\n  guides:\n    g: {{meet: [HS_e, otab], conditions: [HS:detectd]}}\n")
    with pytest.raises(ConfigError) as e:
        scenario_safety_case(load_scenario(bad))
    assert "validation.guides.g.conditions.0" in str(e.value) and "HS:detected" in str(e.value)


def test_a_guide_must_meet_exactly_two_situations(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(f"base: {TWO_OPERATORS}\nvalidation:\n  guides:\n    g: {{meet: [HS_e]}}\n")
    done = _cellsim("scenario", "check", bad)
    assert done.returncode == 2
    assert "bad.yaml" in done.stderr and "meet" in done.stderr and "exactly two" in done.stderr


# --------------------------------------------------------------------------- the score


def test_the_score_is_the_least_normalised_margin_plus_the_closest_guide():
    from cellsim.campaign.falsify import Scorer
    from cellsim.scenario import load_scenario
    from cellsim.validation.check import scenario_safety_case

    case = scenario_safety_case(load_scenario(TWO_OPERATORS))
    scorer = Scorer(case, ("HS:detected", "Final:Cell"), 30.0)
    assert scorer.guides == ["two people at once"]
    result = {"status": "completed", "margins": {
        "robustness": {"HS:detected": {"space": "inf", "time": 0.24}, "Final:Cell": {"space": "inf", "time": "inf"}},
        "guides": {"two people at once": 3.0}}}
    # 0.24 s of the condition's 0.5 s window; the guide 3 s of a 30 s run
    assert scorer.score(result) == pytest.approx(0.48 + 0.1)
    result["margins"]["guides"]["two people at once"] = "inf"
    assert scorer.score(result) == pytest.approx(0.48 + 1.0)
    assert scorer.score({"status": "failed"}) > 2


# --------------------------------------------------------------------------- the command


@pytest.fixture(scope="module")
def found(tmp_path_factory):
    """CMA-ES on the misuse scenario, seed 3: a violation within its first batch."""
    out = tmp_path_factory.mktemp("falsify") / "misuse"
    done = _cellsim("falsify", TWO_OPERATORS, "--method", "cmaes", "--budget", "30", "--seed", "3", "--jobs", "2",
                    "--out", out)
    return done, out, json.loads((out / "results.json").read_text())


@ONE_AT_A_TIME
def test_falsify_stops_at_a_violation_and_exits_1(found):
    done, out, results = found
    assert done.returncode == 1, done.stderr
    search = results["search"]
    first = search["first_violation"]
    assert first is not None and search["runs_to_first_violation"] == first + 1
    runs = {r["index"]: r for r in results["runs"]}
    assert runs[first]["violations"]
    assert all(not runs[i]["violations"] for i in range(first))  # the first, in run order
    assert f"violation found at run {first}" in done.stdout
    assert len(runs) < 30  # it stopped


def test_a_violation_of_a_condition_not_searched_is_still_a_finding(tmp_path):
    """A search for NoHarm on the fenceless stand-off cell: its runs are checked on every condition, and TrueSSM
    fails in some (docs/harm.md). The search found no violation of its target, but the output names the other
    violations and the blind spots, and the exit is 1 (an audit found 'no violation', exit 0)."""
    out = tmp_path / "search"
    done = _cellsim("falsify", ROOT / "scenarios" / "machine_tending_standoff.yaml", "--condition", "NoHarm",
                    "--budget", "5", "--method", "random", "--duration", "5", "--jobs", "1", "--out", out)
    results = json.loads((out / "results.json").read_text())
    assert results["search"]["first_violation"] is None
    others = sorted({r["index"] for r in results["runs"] if "TrueSSM" in r["violations"]})
    assert others, "the stand-off cell's TrueSSM failure no longer shows in 5 runs of 5 s: pick a longer search"
    assert done.returncode == 1, done.stderr
    assert "no violation of NoHarm in 5 runs" in done.stdout
    assert f"TrueSSM: runs {', '.join(map(str, others))}" in done.stdout
    assert "runs with blind spots" in done.stdout or "blind spot" in done.stdout


@ONE_AT_A_TIME
def test_the_violating_run_is_an_ordinary_run_folder_that_violates_again_when_checked(found):
    _, out, results = found
    run = next(r for r in results["runs"] if r["index"] == results["search"]["first_violation"])
    checked = _cellsim("check", out / run["out"], "--json")
    assert checked.returncode == 1
    verdicts = json.loads(checked.stdout)["verdicts"]
    assert {n for n, v in verdicts.items() if v["status"] == "violated"} == set(run["violations"])
    place = json.loads((out / run["out"] / "result.json").read_text())["search"]
    assert place["method"] == "cmaes" and place["batch"] == 0 and len(place["point"]) == 8
    assert place["score"] == run["search"]["score"] < 0


@ONE_AT_A_TIME
def test_a_search_gives_no_bound_and_its_runs_never_join_a_campaign(found):
    _, out, results = found
    assert set(results["bounds"]) == {"excluded"} and "not drawn at random" in results["bounds"]["excluded"]
    checked = _cellsim("check", out)
    assert checked.returncode == 1
    assert "No violation rate or bound" in checked.stdout and "upper bound" not in checked.stdout
    campaign = _cellsim("campaign", TWO_OPERATORS, "--seed", "3", "--runs", "2", "--out", out)
    assert campaign.returncode == 2
    assert "holds a falsification search" in campaign.stderr and "Traceback" not in campaign.stderr


@ONE_AT_A_TIME
def test_the_search_report_in_a_browser_says_what_was_found_and_why_there_is_no_bound(found, tmp_path):
    import shutil

    from playwright.sync_api import sync_playwright

    _, out, results = found
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    assert chromium, "needs Chromium: apt-get install chromium (the README's test command does)"
    problems: list[str] = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=["--no-sandbox", "--disable-gpu"])
        try:
            page = browser.new_page(viewport={"width": 1300, "height": 900})
            page.on("pageerror", lambda e: problems.append(str(e)))
            page.on("console", lambda m: problems.append(m.text) if m.type in ("error", "warning") else None)
            page.goto((out / "report.html").as_uri())
            first = results["search"]["first_violation"]
            assert page.locator("h1").inner_text().startswith("Falsification search")
            assert f"Violation found at run {first}" in page.locator("#search-result").inner_text()
            top = page.locator("#search-critical tbody tr").first.locator("td")
            assert top.nth(0).inner_text() == str(first)
            assert float(top.nth(2).inner_text()) == pytest.approx(results["search"]["best"]["score"], abs=1e-3)
            assert "not drawn at random" in page.locator("#bound-excluded").inner_text()
            assert page.locator("#bound-overall").count() == 0
            page.screenshot(path=str(tmp_path / "search.png"), full_page=True)
        finally:
            browser.close()
    assert problems == []


def test_the_search_is_a_pure_function_of_its_seed_whatever_the_workers(tmp_path):
    """Two generations of CMA-ES (the second depends on the first's scores) with one worker and
    with two: the same points, configurations and scores, run by run."""
    from cellsim.campaign.falsify import FalsifyPlan, run_falsify

    plan = FalsifyPlan(str(WELDING_CELL), (), 5, 4, "cmaes", duration=6.0, conditions=("HRW:detected", "HS:detected"))
    one = run_falsify(plan, tmp_path / "one", jobs=1, batch=2).results["runs"]
    two = run_falsify(plan, tmp_path / "two", jobs=2, batch=2).results["runs"]
    assert [r["search"] for r in one] == [r["search"] for r in two]
    assert [r["configuration"] for r in one] == [r["configuration"] for r in two]
    assert one[2]["search"]["batch"] == 1 and one[2]["search"]["point"] != one[0]["search"]["point"]


def test_quality_diversity_keeps_the_most_critical_run_of_each_cell(tmp_path):
    from cellsim.campaign.falsify import FalsifyPlan, run_falsify

    plan = FalsifyPlan(str(TWO_OPERATORS), (), 2, 8, "qd", duration=8.0, conditions=("HRW:detected", "HS:detected"))
    results = run_falsify(plan, tmp_path / "qd", jobs=1, batch=4).results
    archive = results["search"]["archive"]
    assert archive
    scores = sorted(r["search"]["score"] for r in results["runs"])
    for cell in archive:  # every elite is one of the runs' scores
        assert any(cell["score"] == pytest.approx(s) for s in scores)
    assert archive[0]["score"] == pytest.approx(scores[0])  # the best run is an elite


@pytest.mark.parametrize("args, message", [
    (["--budget", "0"], "--budget must be in [1, 100000]"),
    (["--condition", "HS:detectd"], "no condition named HS:detectd"),
    (["--method", "annealing"], "invalid choice"),
])
def test_bad_falsify_input_is_one_line_and_exit_2(tmp_path, args, message):
    """Every argument is checked before anything shows or is written: no progress bar before the error."""
    done = _cellsim("falsify", TWO_OPERATORS, "--out", tmp_path / "f", *args)
    assert done.returncode == 2
    assert message in done.stderr and "Traceback" not in done.stderr
    if "invalid choice" not in message:  # (argparse's own usage message is two lines)
        assert done.stderr.count("\n") == 1 and "runs" not in done.stderr.split("cellsim: error:")[0], done.stderr
    assert not (tmp_path / "f").exists()


def test_a_scenario_that_samples_nothing_has_nothing_to_search(tmp_path):
    flat = tmp_path / "flat.yaml"
    flat.write_text(f"base: {WELDING_CELL}\ncampaign: !replace {{runs: 5}}\n")
    done = _cellsim("falsify", flat, "--out", tmp_path / "f")
    assert done.returncode == 2 and "nothing to search" in done.stderr, done.stderr


@pytest.mark.parametrize("scenario, violates", [("palletising_fault.yaml", True), ("palletising_cell.yaml", False)])
def test_the_seeded_fault_violates_separation_only_in_its_zone_and_only_in_the_faulty_model(tmp_path, scenario, violates):
    """The benchmark's seeded fault exists (a press front 0.85 m deep: Separation violated) and is the risk
    model's (the shipped one holds the same run); 0.95 m deep, outside the zone, the faulty model holds too."""
    from cellsim.scenario import load_scenario
    from cellsim.simulation import simulate
    from cellsim.validation.check import check

    for depth, expected in ((0.85, violates), (0.95, False)):
        sf = load_scenario(ROOT / "scenarios" / scenario, [f"operator.waypoints.press_front.position.1={depth}"])
        simulate(sf, tmp_path / f"{depth}", duration=40.0)
        violations = check(tmp_path / f"{depth}").result.violations  # what `cellsim check --json` lists
        assert any("Separation" in str(v) for v in violations) == expected, (scenario, depth, violations)


def test_cmaes_searches_a_space_of_one_configuration_point_and_finds_a_default_condition(tmp_path):
    """The cma library needs two dimensions: one configuration point is searched beside an idle coordinate. The
    standoff cell's zone nearest the bench (y above about -1.86 m) violates TrueSSM, a default condition nobody
    wrote in the scenario, and the search climbs the true margin to it."""
    done = _cellsim("falsify", ROOT / "scenarios" / "machine_tending_standoff.yaml", "--condition", "TrueSSM",
                    "--method", "cmaes", "--budget", "40", "--seed", "1", "--jobs", "2", "--duration", "10",
                    "--out", tmp_path / "f")  # (the zone is reached at about 4.3 s)
    assert done.returncode == 1, done.stderr
    results = json.loads((tmp_path / "f" / "results.json").read_text())
    found = results["search"]["runs_to_first_violation"]
    assert found is not None and found <= 40
    violating = [r for r in results["runs"] if "TrueSSM" in r.get("violations", ())]
    standoff = "operator.waypoints.bench_south.position.1"
    assert violating and all(r["configuration"][standoff] > -1.9 for r in violating)


def test_a_search_replacing_another_gives_it_back_whole_when_it_does_not_finish(tmp_path):
    """--overwrite sets the earlier search aside until the new one has written its results: interrupted half way
    (an audit found the earlier folder deleted as soon as the new search started), the earlier is back byte for
    byte and nothing is left beside it."""
    import cellsim

    standoff = ROOT / "scenarios" / "machine_tending_standoff.yaml"
    out = tmp_path / "search"
    cellsim.falsify(standoff, out, budget=2, method="random", duration=2.0, conditions=["NoHarm"])
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}

    def stop(progress):
        if progress.done >= 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        cellsim.falsify(standoff, out, budget=4, method="random", duration=2.0, conditions=["NoHarm"], seed=5,
                        overwrite=True, progress=stop)
    assert {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["search"]


@ONE_AT_A_TIME
def test_a_search_stopped_at_its_first_violation_keeps_the_same_runs_with_two_workers_as_with_one(tmp_path):
    """An audit found a search keeping the run a second worker had in flight when the first violation came: six runs
    with two workers, five with one. The search is a pure function of its seed, method, batch and budget."""
    tending = ROOT / "scenarios" / "machine_tending.yaml"
    made = {}
    for jobs in (1, 2):
        out = tmp_path / f"jobs{jobs}"
        done = _cellsim("falsify", tending, "--condition", "TrueSSM", "--budget", "6", "--duration", "10", "--jobs",
                        jobs, "--out", out)
        assert done.returncode == 1, done.stderr
        results = json.loads((out / "results.json").read_text())
        first = results["search"]["first_violation"]
        made[jobs] = (first, [(r["index"], r["seed"], r["search"]["score"]) for r in results["runs"]],
                      sorted(p.name for p in (out / "runs").iterdir()))
        assert [index for index, _, _ in made[jobs][1]] == list(range(first + 1))
    assert made[2] == made[1]
