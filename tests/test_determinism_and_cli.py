"""Determinism, the scenario round trip, the black box's contract and the CLI's handling of bad input."""

from __future__ import annotations

import os

import sqlite3

import pytest

from cellsim.cli import main
from cellsim.config.typed_yaml import to_data
from cellsim.scenario import export_scenario, load_scenario

from conftest import WELDING_CELL, run, welding_cell


def test_same_scenario_and_seed_give_identical_messages(tmp_path):
    a = run(welding_cell(), tmp_path / "a", duration=12.0, seed=3).rows()
    b = run(welding_cell(), tmp_path / "b", duration=12.0, seed=3).rows()
    c = run(welding_cell(), tmp_path / "c", duration=12.0, seed=4).rows()
    assert a == b and len(a) > 100
    assert a != c  # the seed draws the operator's walking speeds


def test_black_box_schema_and_metadata(tmp_path):
    bb = run(welding_cell(), tmp_path / "r", duration=2.0, seed=5)
    columns = [r[1] for r in sqlite3.connect(bb.path).execute("PRAGMA table_info(messages)")]
    assert columns == ["t", "channel", "source", "payload"]
    meta = bb.metadata()
    assert meta["seed"] == 5 and meta["status"] == "completed" and "drake" in meta["versions"]
    assert meta["scenario"]["entities"]["robot"]["kind"] == "robot"
    info = bb.channels()["robot.safety_mode"]
    assert info.kind == "enum" and "pflim" in info.domain and info.source == "robot"
    assert bb.series("robot.safety_mode").values[0] == "normal"


def test_export_round_trip(tmp_path):
    sf = welding_cell("operator.waypoints.cell.wait=4", "range_detector.close_below=0.5")
    out = tmp_path / "elsewhere" / "resolved.yaml"
    out.parent.mkdir()
    assert main(["scenario", "export", str(WELDING_CELL), "--set", "operator.waypoints.cell.wait=4",
                 "--set", "range_detector.close_below=0.5", "--out", str(out)]) == 0
    again = load_scenario(out)
    assert again.scenario.entities["operator"].waypoints["cell"].wait == 4.0
    # equal once file references are read relative to each file
    assert again.resolve_path("entities.robot.model", again.scenario.entities["robot"].model) == \
        sf.resolve_path("entities.robot.model", sf.scenario.entities["robot"].model)
    a, b = to_data(sf.scenario), to_data(again.scenario)
    for d in (a, b):
        d["entities"]["robot"]["model"] = d["behaviours"]["safety_controller"]["risk_model"] = None
    assert a == b


def test_export_beside_the_original_loads_to_an_equal_scenario(tmp_path):
    original = load_scenario(WELDING_CELL)
    copy = WELDING_CELL.parent / f".roundtrip-{tmp_path.name}.yaml"
    try:
        copy.write_text(export_scenario(original))
        assert load_scenario(copy).scenario == original.scenario
    finally:
        copy.unlink()


def test_simulate_writes_black_box_and_resolved_scenario(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["simulate", str(WELDING_CELL), "--duration", "3", "--seed", "7", "--out", str(out)]) == 0
    assert (out / "blackbox.sqlite").is_file() and (out / "scenario.yaml").is_file()
    printed = capsys.readouterr().out
    assert "real-time factor" in printed and "work cycles completed" in printed
    assert "safety conditions" in printed and "all 16 conditions hold" in printed
    assert load_scenario(out / "scenario.yaml").scenario.name == "welding_cell"
    assert main(["simulate", str(WELDING_CELL), "--duration", "3", "--out", str(out)]) == 2  # never overwrites silently


BAD = {
    "malformed YAML": ("name: welding_cell\n", "name: [welding_cell\n", "malformed YAML"),
    "unknown key": ("    braking_time: 0.5\n", "    braking_tme: 0.5\n", "unknown key 'braking_tme'"),
    "unknown entity kind": ("    kind: machine\n", "    kind: machin\n", "unknown kind 'machin'"),
    "bad twin mode": ("    unsupported_request: ignore\n    twin: {mode: model}\n",
                      "    unsupported_request: ignore\n    twin: {mode: shadw}\n", "'shadw' is not one of: model, shadow, twin"),
    "wrong value type": ("    near_below: 2.0\n", "    near_below: two\n", "expected a number"),
    "missing model file": ("    model: models/ur10.urdf\n", "    model: models/ur5.urdf\n", "file not found: models/ur5.urdf"),
    "collaborative mode above normal": ("    speed_limits: {normal: 1.0, hguid: 0.25, ssmon: 0.5, pflim: 0.25}\n",
                                        "    speed_limits: {normal: 1.0, hguid: 0.25, ssmon: 1.5, pflim: 0.25}\n",
                                        "speed_limits.ssmon: 1.5 m/s is above normal"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_scenario_files_one_line_exit_2_nothing_written(case, tmp_path, capsys):
    old, new, problem = BAD[case]
    text = WELDING_CELL.read_text()
    assert old in text
    # beside the original, so models resolve; named by the process too (two test workers' tmp_paths share names)
    bad = WELDING_CELL.parent / f".bad-{os.getpid()}-{tmp_path.name}.yaml"
    try:
        bad.write_text(text.replace(old, new, 1))
        out = tmp_path / "out"
        assert main(["simulate", str(bad), "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and problem in err and str(bad) in err
        changed = text.replace(old, new, 1).splitlines()
        line = next(i for i, l in enumerate(changed, 1) if l == new.splitlines()[-1])
        if case == "malformed YAML":  # reported where the parser gives up, a line or so later
            assert any(f":{n}:" in err for n in range(line, line + 3))
        else:
            assert f":{line}:" in err
        assert not out.exists()
    finally:
        bad.unlink()


@pytest.mark.parametrize(
    "assignment, problem",
    [("operator.waypoints.cell.wiat=4", "no such configuration point"), ("operator.waypoints.cell.wait=abc", "expected a number"),
     ("robot.twin.mode=shadw", "is not one of"), ("nonsense", "expected dotted.path=value")],
)
def test_bad_overrides_one_line_exit_2_nothing_written(assignment, problem, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["simulate", str(WELDING_CELL), "--set", assignment, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and problem in err and "--set" in err
    assert not out.exists()


def test_usage_errors_exit_2(capsys):
    with pytest.raises(SystemExit) as e:
        main(["simulate"])
    assert e.value.code == 2
    assert main([]) == 2


def test_meshcat_serves_the_cell_while_simulating_and_closes_on_exit(tmp_path):
    """--meshcat serves the cell on localhost while the run goes at real time; the server ends with it.

    Run in a child process: a pydrake diagram holding Python systems is never
    freed within a process, and with it the Meshcat server it draws on.
    """
    import re
    import socket
    import subprocess
    import sys
    import urllib.request

    command = [sys.executable, "-m", "cellsim.cli", "simulate", str(WELDING_CELL), "--meshcat",
               "--duration", "1.5", "--out", str(tmp_path / "shown")]
    child = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        address = None
        for line in child.stderr:  # the address is printed before the run starts
            address = re.search(r"(http://localhost:(\d+))", line)
            if address:
                break
        assert address, "no Meshcat address printed"
        with urllib.request.urlopen(address.group(1), timeout=5) as page:
            assert page.status == 200 and b"meshcat" in page.read().lower()
        out, _ = child.communicate(timeout=60)
    finally:
        child.kill()
        child.wait()
    assert child.returncode == 0 and "real-time factor" in out
    with pytest.raises(OSError), socket.create_connection(("localhost", int(address.group(2))), timeout=1.0):
        pass


def test_each_channel_has_one_message_at_t0_the_value_after_the_first_update(tmp_path):
    """The initial sample, replaced at once by the publishers' first update, held for no time."""
    bb = run(welding_cell(), tmp_path / "r", duration=1.0, seed=1)
    at_zero: dict[str, list] = {}
    for m in bb.messages():
        if m.t == 0.0:
            at_zero.setdefault(m.channel, []).append(m.value)
    assert at_zero and all(len(values) == 1 for values in at_zero.values()), at_zero
    assert at_zero["robot.activity"] == ["exchWrkp"]  # not idle, then exchWrkp
    assert set(at_zero) == set(bb.channels())  # every channel starts at 0


def test_a_run_shorter_than_one_period_keeps_what_the_first_update_wrote(tmp_path):
    """No sample follows the one at t = 0, yet the publishers' updates at 0 happened: they are kept, once."""
    bb = run(welding_cell(), tmp_path / "r", duration=0.01, seed=1)
    at_zero: dict[str, list] = {}
    for m in bb.messages():
        if m.t == 0.0:
            at_zero.setdefault(m.channel, []).append(m.value)
    assert at_zero["robot.activity"] == ["exchWrkp"] and at_zero["robot.safety_mode"] == ["normal"]
    assert set(at_zero) == set(bb.channels()) and all(len(v) == 1 for v in at_zero.values()), at_zero


def test_version_is_the_package_version():
    import subprocess
    import sys
    from importlib.metadata import version

    done = subprocess.run([sys.executable, "-m", "cellsim.cli", "--version"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stdout.strip() == f"cellsim {version('cellsim')}"


# Digests of the messages rows of both shipped scenarios (30 s, seed 3), recorded before
# the modular-cells refactors (registry, vocabulary in data, inheritance): the welding
# cell's words moved from Python into its scenario files, and its evidence did not change.
# Since then people walk round fixtures (the welding cell's operator used to walk through
# the operator bench and the south fence): with straight walks (avoid_fixtures false) the
# rows are still those recorded before; WALKING_ROUND are the rows as shipped now.
# A change that alters the simulation must update these, saying why in its commit.
# Updated when every channel came to be recorded at its publisher's rate (issue 33's recorder tests):
# the range detector's distance and the operator's position, sampled every 0.1 s before (every_sample),
# are recorded at each update where they change; the simulation itself is unchanged.
# Digests of the messages rows of both shipped scenarios (30 s, seed 3): REFERENCE_ROWS with people walking
# straight lines (avoid_fixtures false), WALKING_ROUND as shipped (round the fixtures). A change that alters
# the simulation must update these, saying why in its commit.
# Updated for issue 35 (harm measured): people have bodies of named regions (a scanner or range detector at
# leg height sees the legs, no longer a capsule standing for the whole body), the harm service's channels are
# recorded, the robot's joints and tool speed at every update of its controller (every 0.1 s before), and a
# person's posture (how they turn and reach), so that a replay shows the reach a contact happened in.
# Then the light curtain's and the range detector's blind-spot channels (`unseen`): one message each at t = 0,
# none after (nobody is hidden from them in these runs); the simulation itself is unchanged.
# Then the harm service's looks: one plant step after each person's update and each multiple of far_period (not
# at it), so its separation readings fall a step later, and its `unwatched_part_speed` channel (the robot parts'
# speed at each look ending an interval watched only at looks). Every row but the harm service's is as before
# (3,834 / 3,863 / 4,081 / 4,109 rows, digests unchanged); the simulation itself is unchanged.
# Then people turn at their turn_rate (half a turn a second) instead of in one update (a turn had swung a hand
# half a metre in 40 ms, through what the harm service could see): a turn's posture is recorded over the updates
# it takes (the welding cell's operator.posture 33 -> 99 messages), and what sees or judges the body sees it a
# little later or sooner (light barrier, range detector, the safety controller's answers, the harm service's
# nearest region and separation).
# Then the harm service's nearest_person channel (whose region is nearest): its messages are added, every other
# row is as before. Then its region_jump channel: one message (0 at t = 0), every other row as before.
REFERENCE_ROWS = {
    "welding_cell": (4086, "1552f33d337c0addf3cd4eb292c0a051b901eb0392d005c1922d57fecb442ba8"),
    "two_operators": (4319, "951022d297231bbeb3d6585c79e16d621707e739b685c6a1d1b058ad9c6a148c"),
}
WALKING_ROUND = {
    "welding_cell": (4143, "002e9126ffd04f22a8f54a9e990b2e9422d32d814286f06684c20027a856b92b"),
    "two_operators": (4391, "944241a50d3554acfa5a7b8b7bbc5e936675a39e17799f6ece9f12984d3b05d1"),
}


def _digest(tmp_path, name: str, straight: bool) -> tuple[int, str]:
    import hashlib
    import json

    from conftest import ROOT

    sf = load_scenario(ROOT / "scenarios" / f"{name}.yaml")
    for cfg in sf.scenario.modules_of_kind("operator").values():
        cfg.avoid_fixtures = not straight
    rows = run(sf, tmp_path / "run", duration=30.0, seed=3).rows()
    return len(rows), hashlib.sha256(json.dumps(rows).encode()).hexdigest()


@pytest.mark.parametrize("name", list(REFERENCE_ROWS))
def test_the_shipped_scenarios_give_the_reference_black_box_row_for_row(tmp_path, name):
    assert _digest(tmp_path / "straight", name, straight=True) == REFERENCE_ROWS[name]
    assert _digest(tmp_path / "round", name, straight=False) == WALKING_ROUND[name]


def test_every_argument_of_every_command_says_what_it_is_for():
    import argparse

    from cellsim.cli import build_parser

    silent, no_exit_codes = [], []

    def walk(parser, path):
        if "130 interrupted" not in parser.format_help():
            no_exit_codes.append(" ".join(path))
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, [*path, name])
            elif not action.help or action.help == argparse.SUPPRESS:
                silent.append(" ".join([*path, *(action.option_strings or [action.dest])]))

    walk(build_parser(), ["cellsim"])
    assert silent == []
    assert no_exit_codes == []  # every command's --help ends with the exit codes, 130 included


def test_check_on_a_campaign_folder_points_at_its_runs(tmp_path, capsys):
    from cellsim.cli import main

    (tmp_path / "c" / "runs" / "0000").mkdir(parents=True)
    (tmp_path / "c" / "runs" / "0000" / "blackbox.sqlite").write_bytes(b"")
    assert main(["check", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    # runs without a plan: said so, and no report that is not there is named
    assert "holds runs but no campaign.json" in err and str(tmp_path / "c" / "runs" / "0000") in err
    assert "report" not in err
