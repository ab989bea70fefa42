"""The bound as a user meets it: ``cellsim campaign`` (results.json and ``--until-bound``) and
``cellsim check`` on a campaign folder, run as processes."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import pytest
from conftest import ONE_AT_A_TIME, ROOT, WELDING_CELL

from cellsim.validation.bound import probability, runs_needed, upper_bound

pytestmark = ONE_AT_A_TIME  # a campaign's two workers take both cores
TWO_OPERATORS = ROOT / "scenarios" / "two_operators.yaml"


def _cellsim(*args, timeout=600):
    return subprocess.run([sys.executable, "-m", "cellsim", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT, env={**__import__("os").environ, "COLUMNS": "200"})


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """``--until-bound 0.5`` on the welding cell: five runs, none violating."""
    out = tmp_path_factory.mktemp("bound") / "clean"
    return _cellsim("campaign", WELDING_CELL, "--until-bound", "0.5", "--jobs", "2", "--out", out), out


def test_until_bound_says_how_many_runs_it_takes_then_stops_there(clean):
    done, out = clean
    assert done.returncode == 0, done.stderr
    assert f"takes {runs_needed(0.5)} runs without a violation" in done.stderr
    results = json.loads((out / "results.json").read_text())
    assert results["totals"]["runs"] == runs_needed(0.5) == 5
    assert results["campaign"]["until_bound"] == 0.5
    bounds = results["bounds"]
    assert bounds["overall"] == {"failures": 0, "runs": 5, "rate": 0.0, "upper_bound": upper_bound(0, 5)}
    assert bounds["overall"]["upper_bound"] < 0.5 and "reached" in done.stdout
    assert set(bounds["conditions"]) == set(results["campaign"]["conditions"])
    # the distribution it holds under: the scenario's samplers, in words
    assert "operator_waits" in bounds["sampling"] and "summing to 20" in bounds["sampling"]
    assert "every run 30 s long" in bounds["sampling"]  # what the runs have in common is part of it too
    assert "Clopper-Pearson" in bounds["method"] and "counts as violating it" in bounds["counted"]
    assert "decided as their outcomes came" not in bounds["sampling"]  # none counted against it: 0 of 5 is exact


def test_check_on_a_campaign_folder_gives_each_conditions_rate_and_bound(clean):
    _, out = clean
    done = _cellsim("check", out)
    assert done.returncode == 0, done.stderr
    assert "any condition" in done.stdout and "0 of 5" in done.stdout
    assert probability(upper_bound(0, 5)) in done.stdout and "operator_waits" in done.stdout
    as_json = json.loads(_cellsim("check", out, "--json").stdout)
    stored = json.loads((out / "results.json").read_text())["bounds"]
    assert as_json["bounds"]["overall"] == stored["overall"] and as_json["bounds"]["sampling"] == stored["sampling"]
    assert [r["run"] for r in as_json["runs"]] == ["0000", "0001", "0002", "0003", "0004"]


def test_a_campaign_whose_sampling_is_not_recorded_is_checked_without_a_bound(clean, tmp_path):
    """A bound holds under the distribution the runs were drawn from: with results.json gone (or damaged) that is not
    known, so check gives each condition's violating runs and no bound (an audit found it bounding such runs, the
    distribution 'not recorded: state it yourself')."""
    _, finished = clean
    out = shutil.copytree(finished, tmp_path / "c")
    (out / "results.json").write_text("{")
    done = _cellsim("check", out, "--json")
    assert done.returncode == 0, done.stderr
    shown = json.loads(done.stdout)
    assert "missing or records no sampling distribution" in shown["bounds"]["excluded"]
    assert "overall" not in shown["bounds"] and len(shown["runs"]) == 5


def test_runs_left_undecided_are_shown_beside_the_violating_ones(clean, tmp_path):
    """Without a bound, a run that ended early (interrupted at 5 s of 30) decides nothing: its conditions are
    undecided, the table says which runs, and the check does not pass (exit 1). Before, it read 0 violating and
    exited 1 with nothing saying why."""
    import sqlite3

    _, finished = clean
    out = shutil.copytree(finished, tmp_path / "c")
    (out / "results.json").unlink()
    db = sqlite3.connect(out / "runs" / "0003" / "blackbox.sqlite")
    db.execute("UPDATE metadata SET value = '\"interrupted\"' WHERE key = 'status'")
    db.execute("INSERT OR REPLACE INTO metadata (key, value) VALUES ('recorded_until', '5.0')")
    db.commit()
    db.close()
    done = _cellsim("check", out)
    assert done.returncode == 1, done.stderr
    assert "undecided runs" in done.stdout and "of 5: 0003" in done.stdout


def test_a_run_the_campaign_was_stopped_in_is_left_out_of_the_bound_and_named(clean, tmp_path):
    """Ctrl-C stops a campaign in a run: its folder has no result.json and the campaign redoes it. check counts it
    nowhere (an audit found it counted as violating every condition: 1 of 14, exit 1) and names it."""
    _, finished = clean
    out = shutil.copytree(finished, tmp_path / "c")
    (out / "runs" / "0003" / "result.json").unlink()
    done = _cellsim("check", out)
    assert done.returncode == 0, done.stderr
    assert "0 of 4" in done.stdout and "0 of 5" not in done.stdout
    assert "1 run(s) stopped before they ended" in done.stdout and ": 0003" in done.stdout
    shown = json.loads(_cellsim("check", out, "--json").stdout)
    assert shown["bounds"]["overall"]["runs"] == 4 and shown["bounds"]["excluded_unfinished_runs"] == 1
    assert shown["bounds"]["sampling"].count("of the runs drawn so") == 0


def test_a_run_the_campaign_recorded_as_failed_is_counted_nowhere_by_its_check_either(clean, tmp_path):
    """An audit found check re-judged a run whose result.json says failed (a simulation that crashed part-way, its
    black box kept): counted completed, its conditions undecided, in the bound's runs and failures, where the
    campaign's own bound left it out."""
    _, finished = clean
    out = shutil.copytree(finished, tmp_path / "c")
    result = out / "runs" / "0003" / "result.json"
    recorded = json.loads(result.read_text())
    recorded.update(status="failed", error="RuntimeError: the solver diverged")
    result.write_text(json.dumps(recorded))
    done = _cellsim("check", out, "--json")
    assert done.returncode == 2  # (left out of the figures: the check does not pass)
    shown = json.loads(done.stdout)
    assert shown["bounds"]["overall"]["runs"] == 4 and shown["bounds"]["excluded_failed_runs"] == 1
    (failed,) = [r for r in shown["runs"] if r["status"] == "failed"]
    assert failed["run"] == "0003" and "the campaign recorded it failed: RuntimeError: the solver diverged" in failed["error"]
    assert "0003: the campaign recorded it failed" in done.stderr


def test_runs_a_search_chose_bound_nothing_even_when_the_folder_lost_its_plan(clean, tmp_path):
    """A run's own result records that a search chose it: such runs give no bound, whatever the folder's plan says
    (an audit bounded a search's runs once its plan.json was unreadable)."""
    _, finished = clean
    out = shutil.copytree(finished, tmp_path / "c")
    result = out / "runs" / "0001" / "result.json"
    result.write_text(json.dumps({**json.loads(result.read_text()), "search": {"score": 0.5}}))
    (out / "plan.json").write_text("{")
    shown = json.loads(_cellsim("check", out, "--json").stdout)
    assert "chosen by the search" in shown["bounds"]["excluded"] and "overall" not in shown["bounds"]


def test_a_run_whose_scenario_was_damaged_is_left_out_of_the_figures_by_name(clean, tmp_path):
    """One damaged run's scenario does not stop the campaign's check: the others are judged and bounded, and it is
    named as left out (exit 2: evidence never shrinks silently)."""
    _, finished = clean
    out = shutil.copytree(finished, tmp_path / "c")
    (out / "runs" / "0002" / "scenario.yaml").write_text("base: [\n")
    done = _cellsim("check", out, "--json")
    assert done.returncode == 2
    shown = json.loads(done.stdout)
    assert shown["bounds"]["overall"]["runs"] == 4 and "0002" in done.stderr and "could not be checked" in done.stderr


@pytest.mark.parametrize("flag", [["--robustness"], ["--export-trace", "t.json"]])
def test_a_one_run_option_on_a_campaign_folder_is_one_line_and_exit_2(clean, flag, tmp_path):
    _, out = clean
    done = _cellsim("check", out, *[str(tmp_path / f) if f.endswith(".json") else f for f in flag])
    assert done.returncode == 2 and f"{flag[0]} takes one run" in done.stderr and done.stdout == ""
    assert not (tmp_path / "t.json").exists()


@pytest.mark.parametrize("damage", ["missing", "corrupt"])
def test_check_on_a_campaign_folder_with_an_unreadable_run_never_passes(clean, tmp_path, damage):
    """Evidence never shrinks silently: the figures leave the run out and say so, and the check exits 2
    (as that run checked alone does), naming the run, in one line on stderr."""
    _, out = clean
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    blackbox = copy / "runs" / "0003" / "blackbox.sqlite"
    if damage == "missing":
        blackbox.unlink()
    else:
        blackbox.write_bytes(b"SQLite format 3\x00" + bytes(range(256)) * 8)
    done = _cellsim("check", copy, "--json")
    assert done.returncode == 2, done.stderr
    result = json.loads(done.stdout)
    assert result["bounds"]["excluded_failed_runs"] == 1 and result["bounds"]["overall"]["runs"] == 4
    assert [r["status"] for r in result["runs"]].count("failed") == 1
    errors = [line for line in done.stderr.splitlines() if line.startswith("cellsim: error:")]
    assert len(errors) == 1 and "1 of 5 runs" in errors[0] and "0003" in errors[0]
    table = _cellsim("check", copy)
    assert table.returncode == 2 and "left out, not checkable: 0003" in table.stdout
    alone = _cellsim("check", copy / "runs" / "0003")
    assert alone.returncode == 2


def test_until_bound_stops_at_the_first_violation_and_says_the_violation_is_the_finding(tmp_path):
    out = tmp_path / "misuse"
    done = _cellsim("campaign", TWO_OPERATORS, "--until-bound", "0.01", "--jobs", "1", "--out", out)
    assert done.returncode == 1, done.stderr
    assert f"takes {runs_needed(0.01)} runs" in done.stderr
    results = json.loads((out / "results.json").read_text())
    runs = results["runs"]
    assert runs and runs[-1]["violations"] and not any(r["violations"] for r in runs[:-1])  # one worker: it stopped there
    assert len(runs) < runs_needed(0.01) and results["bounds"]["overall"]["failures"] == 1
    assert "the violation is the finding" in done.stdout
    # its number of runs was decided by their outcomes: the exact bound takes it as fixed, which the statement says
    assert "decided as their outcomes came (--until-bound stops at the first run" in results["bounds"]["sampling"]
    # asked again, it does not run on past the violation
    again = _cellsim("campaign", TWO_OPERATORS, "--until-bound", "0.01", "--jobs", "1", "--out", out)
    assert again.returncode == 1 and len(json.loads((out / "results.json").read_text())["runs"]) == len(runs)
    # extended past the violation with --runs: said too, and the whole history of its sizing is kept
    extended = _cellsim("campaign", TWO_OPERATORS, "--runs", str(len(runs) + 1), "--jobs", "1", "--out", out)
    assert extended.returncode == 1, extended.stderr
    results = json.loads((out / "results.json").read_text())
    assert "the campaign was extended after runs counted against it" in results["bounds"]["sampling"]
    assert [e["until_bound"] for e in results["campaign"]["sizing"]] == [0.01, 0.01, None]


@pytest.mark.parametrize("args, message", [
    (["--until-bound", "0"], "must be a probability in (0, 1)"),
    (["--until-bound", "1.5"], "must be a probability in (0, 1)"),
    (["--until-bound", "0.1", "--runs", "3"], "not both"),
    (["--until-bound", "1e-6"], "needs 2,995,731 runs"),
])
def test_a_bad_until_bound_is_one_line_and_exit_2(tmp_path, args, message):
    done = _cellsim("campaign", WELDING_CELL, *args, "--out", tmp_path / "c")
    assert done.returncode == 2 and message in done.stderr and not (tmp_path / "c").exists()


def test_until_bound_keeps_the_same_runs_with_two_workers_as_with_one(tmp_path):
    """An audit found --until-bound counting a second run with two workers: the run in flight when run 0 violated
    was kept (1 of 1 with one worker, 2 of 2 with two). The campaign is the runs up to the first violation, as one
    worker makes it; one in flight past it is left out, its folder removed."""
    tending = ROOT / "scenarios" / "machine_tending.yaml"
    made = {}
    for jobs in (1, 2):
        out = tmp_path / f"jobs{jobs}"
        done = _cellsim("campaign", tending, "--until-bound", "0.5", "--duration", "10", "--seed", "3", "--jobs", jobs,
                        "--out", out)
        assert done.returncode == 1, done.stderr
        results = json.loads((out / "results.json").read_text())
        made[jobs] = ([r["index"] for r in results["runs"]], results["bounds"]["overall"]["failures"],
                      sorted(p.name for p in (out / "runs").iterdir()))
    assert made[2] == made[1] == ([0], 1, ["0000"])


def test_check_of_an_extension_stopped_before_its_results_says_the_bound_is_approximate(tmp_path):
    """An audit found check taking its statement from the results.json the extension had not yet written again: the
    campaign extended after runs counted against it, and stopped, was bounded as exact. The statement of how the
    number of runs was decided now comes from campaign.json's sizing, for the runs check counts."""
    import os
    import signal
    import time

    tending = ROOT / "scenarios" / "machine_tending.yaml"
    out = tmp_path / "c"
    first = _cellsim("campaign", tending, "--runs", "1", "--duration", "10", "--seed", "3", "--jobs", "1", "--out", out)
    assert first.returncode == 1, first.stderr  # runs count against the bound (TrueSSM, in this cell)
    assert "approximate" not in json.loads((out / "results.json").read_text())["bounds"]["sampling"]
    # 40: far more than can finish before Ctrl-C lands (CI once saw six end first, exit 1)
    child = subprocess.Popen([sys.executable, "-m", "cellsim", "campaign", str(tending), "--runs", "40", "--duration", "10",
                              "--seed", "3", "--jobs", "1", "--out", str(out), "--quiet"],
                             stdin=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=ROOT, start_new_session=True)
    try:
        deadline = time.monotonic() + 120.0
        while not (out / "runs" / "0001" / "result.json").exists():  # the extension's first run, on disk
            assert child.poll() is None, child.stderr.read()
            assert time.monotonic() < deadline, "the extension finished no run in 120 s"
            time.sleep(0.05)
        child.send_signal(signal.SIGINT)
        _, err = child.communicate(timeout=60)
    finally:
        if child.poll() is None:
            os.killpg(child.pid, signal.SIGKILL)
        child.wait()
    assert child.returncode == 130, err
    shown = json.loads(_cellsim("check", out, "--json").stdout)
    counted = shown["bounds"]["overall"]["runs"]
    assert counted >= 2 and len(json.loads((out / "results.json").read_text())["runs"]) == 1  # results.json: stale
    assert "the campaign was extended after runs counted against it" in shown["bounds"]["sampling"]
    assert "approximate" in shown["bounds"]["sampling"]
