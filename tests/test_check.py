"""Traces from black boxes and the ``cellsim check`` command: verdicts, JSON, exported traces, bad input."""

from __future__ import annotations

import json
import shutil
import sqlite3
from pathlib import Path

import pytest
from conftest import WELDING_CELL, run, welding_cell

from cellsim.cli import main
from cellsim.blackbox import BlackBox
from cellsim.validation.check import check
from cellsim.validation.traces import trace_of_run

ALIASES = {"safmod": "robot.safety_mode", "HS": "safety_controller.HS", "oloc": "operator.location"}


@pytest.fixture(scope="module")
def default_run(tmp_path_factory):
    """The welding cell as shipped: the operator reaches at the bench, walks into the cell and leaves."""
    out = tmp_path_factory.mktemp("check") / "run"
    run(welding_cell(), out).close()
    return out


@pytest.fixture(scope="module")
def operator_stays_in_cell(tmp_path_factory):
    """The operator never leaves the cell: Final:Cell is violated."""
    out = tmp_path_factory.mktemp("check") / "stays"
    run(welding_cell("operator.waypoints.cell.wait=100"), out, duration=25.0).close()
    return out


def test_trace_has_one_piecewise_constant_signal_per_scalar_channel(default_run):
    with BlackBox(default_run / "blackbox.sqlite") as bb:
        rt = trace_of_run(bb, ALIASES)
        channels = bb.channels()
        series = {name: bb.series(name) for name in channels}
    trace = rt.trace
    assert (trace.start, trace.end) == (0.0, 30.0)
    scalar = {n for n, c in channels.items() if c.kind != "vector"}
    assert set(trace.signals) == scalar | set(ALIASES)
    for name in scalar:
        # two messages at one instant (the initial value and the first update's): the later holds
        last = dict(zip(series[name].times.tolist(), series[name].values))
        assert trace.signals[name].times.tolist() == list(last)
        assert trace.signals[name].values == list(last.values())
    # an alias is its channel's signal, and its domain is the channel's
    assert trace.signals["HS"] is trace.signals["safety_controller.HS"]
    assert rt.vocabulary["safmod"] == rt.vocabulary["robot.safety_mode"]
    # the value holds from its message until the next one
    hs = series["safety_controller.HS"]
    t_act = hs.times[hs.values.index("act")]
    assert trace.value_at("HS", t_act) == "act"
    assert trace.value_at("HS", t_act - 1e-9) == "inact"


def test_check_holds_on_the_default_run_and_says_which_use_cases(default_run, capsys):
    assert main(["check", str(default_run), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["holds"] is True
    assert len(report["verdicts"]) == 16  # the cell's 14 and the default NoHarm, NoClamping
    assert all(v == {"holds": True, "status": "holds", "violated_at": None} for v in report["verdicts"].values())
    assert report["use_cases"] == ["U1", "U2"]  # reaches across the table, walks to the welder
    assert ["ssmon"] in report["coverage"]["safmod"]  # HS was mitigated by speed and separation monitoring


def test_check_exits_1_and_names_the_violated_condition(operator_stays_in_cell, capsys):
    assert main(["check", str(operator_stays_in_cell), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert report["holds"] is False
    assert set(report["violations"]) == {"Final:Cell", "HS:handled", "HC:handled"}
    assert report["verdicts"]["Final:Cell"] == {
        "holds": False, "status": "violated", "violated_at": 0.0,
        "explanation": "oloc went none -> inCell; G oloc == none never held from 0.00 s to the end of the run",
        # what a timeline draws: the whole run was the window; the operator was out only until 14.4 s
        "evidence": {"at": 0.0, "window": [0.0, 25.0], "rows": {"oloc == none": [[0.0, 14.4]]}}}
    # HS (and HC) are mitigated when the operator comes near, never handled: the first
    # violation is the instant the mitigation starts
    with BlackBox(operator_stays_in_cell / "blackbox.sqlite") as bb:
        hs = bb.series("safety_controller.HS")
    assert report["verdicts"]["HS:handled"]["violated_at"] == hs.times[hs.values.index("mit")]
    assert report["verdicts"]["Final:Tbl"]["holds"] is True


def test_check_prints_a_verdict_table(operator_stays_in_cell, capsys):
    assert main(["check", str(operator_stays_in_cell)]) == 1
    out = capsys.readouterr().out
    assert "Final:Cell" in out and "VIOLATED" in out and "F G(oloc == none)" in out


def test_export_trace_round_trips(default_run, tmp_path, capsys):
    target = tmp_path / "trace.json"
    assert main(["check", str(default_run), "--export-trace", str(target)]) == 0
    exported = json.loads(target.read_text())
    checked = check(default_run)
    for name, signal in checked.trace.trace.signals.items():
        assert exported[name] == [[t, v] for t, v in zip(signal.times.tolist(), signal.values)]
    assert exported["safmod"][0] == [0.0, "normal"]
    assert not list(tmp_path.glob("*.tmp"))


def test_check_a_black_box_file_against_another_scenario(default_run, tmp_path, capsys):
    """A recording with no scenario beside it (as made beside the real cell) is checked with --scenario."""
    lone = tmp_path / "recording.sqlite"
    shutil.copy(default_run / "blackbox.sqlite", lone)
    assert main(["check", str(lone), "--json"]) == 2
    assert "--scenario" in capsys.readouterr().err
    assert main(["check", str(lone), "--scenario", str(WELDING_CELL), "--json"]) == 0


def _cut(default_run, tmp_path, at: float, recorded_until: bool) -> Path:
    """A copy of the default run as if it had stopped at ``at`` s."""
    partial = tmp_path / "partial"
    shutil.copytree(default_run, partial)
    with sqlite3.connect(partial / "blackbox.sqlite") as db:
        db.execute("DELETE FROM messages WHERE t >= ?", (at,))
        db.execute("UPDATE metadata SET value = '\"interrupted\"' WHERE key = 'status'")
        if recorded_until:
            db.execute("UPDATE metadata SET value = ? WHERE key = 'recorded_until'", (json.dumps(at),))
        else:
            db.execute("DELETE FROM metadata WHERE key = 'recorded_until'")
    return partial


def test_an_interrupted_run_ends_where_its_record_was_committed(default_run, tmp_path):
    checked = check(_cut(default_run, tmp_path, 12.0, recorded_until=True))
    assert checked.trace.trace.end == 12.0
    assert not checked.trace.complete


def test_a_recording_whose_last_message_is_a_mishap_violates_not_mis(default_run, tmp_path):
    """Without recorded_until (a recording from the real cell), the last value holds for its period."""
    partial = _cut(default_run, tmp_path, 12.0, recorded_until=False)
    with sqlite3.connect(partial / "blackbox.sqlite") as db:
        db.execute("INSERT INTO messages VALUES (12.5, 'safety_controller.HC', 'safety_controller', '{\"value\": \"mis\"}')")
    checked = check(partial)
    with BlackBox(partial / "blackbox.sqlite") as bb:
        period = bb.channels()["safety_controller.HC"].period
    assert checked.trace.trace.end == pytest.approx(12.5 + period)
    verdict = checked.result.verdicts["HC:not_mis"]
    assert verdict.status == "violated" and verdict.violated_at == 12.5  # seen: conclusive


def test_an_incomplete_run_marks_verdicts_the_cut_could_change_inconclusive(default_run, tmp_path, capsys):
    partial = _cut(default_run, tmp_path, 12.0, recorded_until=True)
    assert main(["check", str(partial), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    statuses = {name: v["status"] for name, v in report["verdicts"].items()}
    # nothing was violated in the first 12 s, but G conditions have only held so far
    assert set(statuses.values()) == {"inconclusive"}
    assert report["verdicts"]["HS:not_mis"]["reading"] == "holds so far"
    assert report["holds"] is False and report["violations"] == []


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    return err


def test_bad_runs_exit_2_with_one_line(tmp_path, capsys):
    assert main(["check", str(tmp_path / "nowhere")]) == 2
    assert "no such run folder" in _one_error_line(capsys)
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["check", str(empty)]) == 2
    assert "not a run folder" in _one_error_line(capsys)
    junk = tmp_path / "junk.sqlite"
    junk.write_text("not a database")
    assert main(["check", str(junk), "--scenario", str(WELDING_CELL)]) == 2
    assert "junk.sqlite" in _one_error_line(capsys)


def _scenario_with_validation(tmp_path, validation_text: str):
    """A copy of the welding cell whose validation file is ``validation_text``."""
    folder = tmp_path / "scenario"
    shutil.copytree(WELDING_CELL.parent, folder)
    (folder / "welding_cell_validation.yaml").write_text(validation_text)
    return folder / "welding_cell.yaml"


@pytest.mark.parametrize(
    "edit, expected",
    [
        (("HS == act))", "HS == akt))"), "welding_cell_validation.yaml:52: conditions.HS:detected.formula: column 52 of the formula: 'akt' is not a value of HS"),
        (("HC_e: permissive", "HC_e: permisive"), "welding_cell_validation.yaml:39: macros.HC_e: column 1 of the formula"),
        (("sep: ground_truth.separation", "sep: ground_truth.distance"), "welding_cell_validation.yaml:28: variables.sep: there is no channel 'ground_truth.distance'"),
        (("variables: [rloc, rngDet]", "variables: [rloc, rngdet]"), "coverage"),
    ],
)
def test_bad_conditions_are_found_before_anything_runs(default_run, tmp_path, capsys, edit, expected):
    text = (WELDING_CELL.parent / "welding_cell_validation.yaml").read_text()
    assert edit[0] in text
    scenario = _scenario_with_validation(tmp_path, text.replace(edit[0], edit[1]))
    assert main(["scenario", "check", str(scenario)]) == 2
    assert expected in _one_error_line(capsys)
    assert main(["check", str(default_run), "--scenario", str(scenario)]) == 2
    assert expected in _one_error_line(capsys)


def test_a_scenario_extends_the_validation_file_it_names(tmp_path, capsys):
    """two_operators adds its visitor to the welding cell's conditions; errors point at the right file."""
    from cellsim.scenario import load_scenario

    two = WELDING_CELL.parent / "two_operators.yaml"
    validation = load_scenario(two).scenario.validation
    base = welding_cell().scenario.validation
    assert set(validation.conditions) == set(base.conditions) | {"Final:Visitor"}
    assert validation.variables["vloc"] == "visitor.location" and validation.variables["safmod"] == "robot.safety_mode"
    assert validation.use_cases["MU"] != base.use_cases["MU"] and "visitor_unseen" in validation.use_cases["MU"]

    folder = tmp_path / "scenario"
    shutil.copytree(WELDING_CELL.parent, folder)
    text = (folder / "two_operators.yaml").read_text()
    line = text.splitlines().index('    "Final:Visitor": F G(vloc == none)') + 1
    (folder / "two_operators.yaml").write_text(text.replace("F G(vloc == none)", "F G(vloc == nowhere)"))
    assert main(["scenario", "check", str(folder / "two_operators.yaml")]) == 2
    err = capsys.readouterr().err
    assert f"two_operators.yaml:{line}: validation.conditions.Final:Visitor: column" in err


def test_a_corrupt_message_is_one_error_line_naming_channel_and_time(default_run, tmp_path, capsys):
    damaged = tmp_path / "damaged"
    shutil.copytree(default_run, damaged)
    with sqlite3.connect(damaged / "blackbox.sqlite") as db:
        t = db.execute("SELECT t FROM messages WHERE channel = 'robot.safety_mode' ORDER BY rowid LIMIT 1 OFFSET 1").fetchone()[0]
        db.execute("UPDATE messages SET payload = '{not json' WHERE channel = 'robot.safety_mode' AND t = ?", (t,))
    assert main(["check", str(damaged)]) == 2
    err = _one_error_line(capsys)
    assert "robot.safety_mode" in err and f"t = {t}" in err


def test_unwritable_output_paths_are_one_error_line(default_run, tmp_path, capsys):
    missing = tmp_path / "no" / "such" / "folder"
    assert main(["check", str(default_run), "--export-trace", str(missing / "t.json")]) == 2
    assert "no such folder to write into" in _one_error_line(capsys)
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    assert main(["campaign", str(WELDING_CELL), "--runs", "1", "--out", str(blocker / "c"), "--quiet"]) == 2
    assert str(blocker) in _one_error_line(capsys)
    assert not missing.exists() and blocker.read_text() == ""


def test_a_hazard_never_recorded_is_missing_data_not_holds(default_run, tmp_path, capsys, monkeypatch):
    """HS never recorded: its four conditions cannot hold vacuously."""
    copy = tmp_path / "no_hs"
    shutil.copytree(default_run, copy)
    with sqlite3.connect(copy / "blackbox.sqlite") as db:
        db.execute("DELETE FROM messages WHERE channel = 'safety_controller.HS'")
    assert main(["check", str(copy), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    for condition in ("HS:detected", "HS:mitigated", "HS:handled", "HS:not_mis"):
        assert report["verdicts"][condition]["status"] == "missing data"
        assert report["verdicts"][condition]["missing"] == ["HS"]
    assert report["verdicts"]["HC:not_mis"]["status"] == "holds"
    assert report["undecided"] == ["HS:detected", "HS:mitigated", "HS:handled", "HS:not_mis"]
    monkeypatch.setenv("COLUMNS", "160")
    assert main(["check", str(copy)]) == 1
    assert capsys.readouterr().out.count("missing data: HS never recorded") == 4


CORRUPTIONS = {
    "metadata not JSON": ("UPDATE metadata SET value = '{oops' WHERE key = 'status'", "metadata 'status' is not JSON"),
    "domain not JSON": ("UPDATE channels SET domain = '[idle' WHERE name = 'robot.activity'", "its domain is not JSON"),
    "unknown kind": ("UPDATE channels SET kind = 'colour' WHERE name = 'robot.activity'", "unknown kind 'colour'"),
    "enum domain not names": ("UPDATE channels SET domain = '[1, 2]' WHERE name = 'robot.activity'", "non-empty list of names"),
    "period not a number": ("UPDATE channels SET period = 'fast' WHERE name = 'robot.activity'", "not a positive number"),
    "value out of domain": (
        "UPDATE messages SET payload = '{\"value\": \"dancing\"}' WHERE rowid = "
        "(SELECT min(rowid) FROM messages WHERE channel = 'robot.activity')", "outside its domain"),
    "bool not a bool": (
        "UPDATE messages SET payload = '{\"value\": 3}' WHERE rowid = "
        "(SELECT min(rowid) FROM messages WHERE channel = 'light_barrier.broken')", "outside its domain"),
    "time not a number": (
        "UPDATE messages SET t = 'soon' WHERE rowid = (SELECT max(rowid) FROM messages WHERE channel = 'robot.activity')",
        "time stamp 'soon'"),
    "payload not a message": (
        "UPDATE messages SET payload = '[1]' WHERE rowid = (SELECT max(rowid) FROM messages WHERE channel = 'robot.activity')",
        "is not a cellsim message"),
    "no messages": ("DELETE FROM messages", "holds no messages"),
    # vector channels are no trace variables, but a run's record all the same
    "vector not a vector": (
        "UPDATE messages SET payload = '{\"value\": \"not a vector\"}' WHERE rowid = "
        "(SELECT max(rowid) FROM messages WHERE channel = 'robot.joint_positions')", "is not a vector of numbers"),
    "vector of text": (
        "UPDATE messages SET payload = '{\"value\": [1, \"x\", 3, 4, 5, 6]}' WHERE rowid = "
        "(SELECT min(rowid) FROM messages WHERE channel = 'robot.joint_positions')", "is not a vector of numbers"),
    "vector cut short": (
        "UPDATE messages SET payload = '{\"value\": [1, 2]}' WHERE rowid = "
        "(SELECT max(rowid) FROM messages WHERE channel = 'robot.joint_positions')", "vectors of different lengths"),
}


@pytest.mark.parametrize("corruption", list(CORRUPTIONS))
def test_a_corrupt_black_box_is_one_line_and_exit_2(default_run, tmp_path, capsys, corruption):
    sql, expected = CORRUPTIONS[corruption]
    copy = tmp_path / "corrupt"
    shutil.copytree(default_run, copy)
    with sqlite3.connect(copy / "blackbox.sqlite") as db:
        db.execute(sql)
    assert main(["check", str(copy)]) == 2
    err = _one_error_line(capsys)
    assert "corrupt black box" in err and expected in err, err


def test_a_conditions_description_is_shown_by_check_and_in_its_json(default_run, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "250")  # a wide terminal: the table's cells are not wrapped
    described = "A person the scanner sees near the working cell is detected within 0.5 s."
    assert main(["check", str(default_run), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["descriptions"]["HS:detected"] == described
    assert main(["check", str(default_run)]) == 0
    assert described in capsys.readouterr().out


def test_check_shows_what_each_exercised_use_case_means(default_run, capsys):
    assert main(["check", str(default_run)]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "U1: The operator walks to the welder while the cell works" in out
    assert "U2: The operator reaches across the workbench while the cell works." in out
    assert main(["check", str(default_run), "--json"]) == 0
    descriptions = json.loads(capsys.readouterr().out)["descriptions"]
    assert descriptions["U2"] == "The operator reaches across the workbench while the cell works."
    assert descriptions["HS:detected"].startswith("A person the scanner sees")  # conditions' and use cases' alike


def test_check_says_the_runs_verdict_in_the_one_vocabulary(default_run, capsys):
    """check (the one evidence path) and check --json carry the run's verdict as the Verdict enum says it."""
    from cellsim.cli import main
    from cellsim.validation.verdict import Verdict

    checked = check(default_run)
    assert checked.verdict is Verdict.HOLDS and all(v.status in Verdict for v in checked.result.verdicts.values())
    assert main(["check", str(default_run), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["verdict"] == "holds"
