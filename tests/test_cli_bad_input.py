"""Bad input and careless outputs never lose data: what a review of the commands found, each held here.

Every case runs the command as the user does (``cellsim.cli.main``, or a process where the pipe matters) and reads
the result back with the standard library: the exit code, one line on stderr naming what is at fault, and the
files on disk.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import sqlite3
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from cellsim.atomic import write_text
from cellsim.cli import main

from conftest import ROOT, WELDING_CELL


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "welding"
    assert main(["simulate", str(WELDING_CELL), "--out", str(out), "--duration", "1", "--quiet"]) == 0
    return out


def damaged(run: Path, tmp_path: Path, sql: str) -> Path:
    """A copy of the run whose black box ``sql`` changed."""
    copy = tmp_path / "damaged"
    shutil.copytree(run, copy)
    db = sqlite3.connect(copy / "blackbox.sqlite")
    db.executescript(sql)
    db.commit()
    db.close()
    return copy


def export_refused(run: Path, tmp_path: Path, capsys, sql: str, problem: str) -> Path:
    """A copy of the run damaged by ``sql``, which export refuses as a corrupt black box saying ``problem``, writing
    nothing."""
    bad = damaged(run, tmp_path, sql)
    mcap = tmp_path / "out.mcap"
    assert main(["export", str(bad), "--mcap", str(mcap)]) == 2
    err = one_error(capsys)
    assert problem in err and "corrupt black box" in err
    assert not mcap.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["damaged"]
    return bad


def files_of(folder: Path) -> dict:
    return {p.relative_to(folder): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def one_error(capsys) -> str:
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    return err


@pytest.mark.parametrize("command", [
    ["export", "{run}", "--mcap", "{run}/blackbox.sqlite"],
    ["check", "{run}", "--export-trace", "{run}/blackbox.sqlite"],
    ["check", "{run}", "--export-trace", "{run}/scenario.yaml"],
    ["scenario", "export", "{scenario}", "--out", "{scenario}"],
])
def test_an_output_that_names_an_input_is_refused_and_the_input_kept(run, tmp_path, capsys, command):
    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    scenario = tmp_path / "scenario.yaml"
    shutil.copy(WELDING_CELL, scenario)
    shutil.copy(WELDING_CELL.parent / "welding_cell_risk_model.yaml", tmp_path)
    shutil.copy(WELDING_CELL.parent / "welding_cell_validation.yaml", tmp_path)
    shutil.copytree(WELDING_CELL.parent / "models", tmp_path / "models")
    before = files_of(tmp_path)
    argv = [part.format(run=copy, scenario=scenario) for part in command]
    assert main(argv) == 2
    assert "is made from; name another file" in one_error(capsys)
    assert files_of(tmp_path) == before


@pytest.mark.parametrize("sql, problem", [
    ("UPDATE messages SET t = -5 WHERE rowid = 3", "time stamp -5"),
    ("UPDATE messages SET t = 1e300 WHERE rowid = 3", "time stamp 1e+300"),
    ("UPDATE messages SET t = 'abc' WHERE rowid = 3", "time stamp 'abc'"),
    ("""UPDATE messages SET payload = '{"value": "flying"}' WHERE channel = 'robot.safety_mode'""",
     "has value 'flying', outside its domain"),
    ("""UPDATE messages SET payload = '{"value": NaN}' WHERE channel = 'robot.tool_speed'""", "has value nan"),
    ("DELETE FROM messages", "it holds no messages"),
    ("DELETE FROM channels WHERE name = 'robot.tool_speed'", "its channels table does not list"),
])
def test_export_refuses_a_corrupt_black_box_as_check_does_and_writes_nothing(run, tmp_path, capsys, sql, problem):
    bad = export_refused(run, tmp_path, capsys, sql, problem)
    assert main(["check", str(bad)]) == 2
    assert problem in one_error(capsys)


@pytest.mark.parametrize("sql, problem", [
    # (the audit's: SetPositions failed in Drake, exit 1, or an IndexError traceback)
    ("""UPDATE messages SET payload = json_remove(payload, '$.value[5]') WHERE channel = 'robot.joint_positions'""",
     "'robot.joint_positions' at t = 0.0 holds 5 numbers where the scenario's cell has 6"),
    ("""UPDATE messages SET payload = '{"value": [1.0]}' WHERE channel = 'operator.position'""",
     "'operator.position' at t = 0.0 holds 1 number where the scenario's cell has 2"),
    ("""UPDATE metadata SET value = '"abc"' WHERE key = 'seed'""", "its metadata's seed is \"abc\""),
    ("""UPDATE metadata SET value = 'null' WHERE key = 'seed'""", "its metadata's seed is null"),
])
def test_export_and_replay_refuse_a_record_the_rebuilt_cell_cannot_pose(run, tmp_path, capsys, sql, problem):
    from cellsim.visual.replay import ReplayError, replay
    from cellsim.visual.serve import open_meshcat

    bad = export_refused(run, tmp_path, capsys, sql, problem)
    meshcat = open_meshcat()  # (on localhost; closed with it)
    try:
        with pytest.raises(ReplayError, match=re.escape(problem)):
            replay(bad, meshcat)
    finally:
        del meshcat


def test_export_refuses_a_pipe_or_device_as_its_mcap_file(run, tmp_path, capsys):
    """The audit's case: MCAP's writer seeks back to index what it wrote. Into /dev/stdout sent to a file, the summary
    line overwrote the file's start (exit 0, an MCAP no reader opens); into a pipe it failed with 'Illegal seek'
    naming no file."""
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    for target in (fifo, Path("/dev/stdout")):
        assert main(["export", str(run), "--mcap", str(target)]) == 2
        assert f"{target} is no regular file" in one_error(capsys)


def test_a_run_checked_against_another_cells_scenario_says_so(run, capsys):
    assert main(["check", str(run), "--scenario", str(ROOT / "scenarios" / "palletising_cell.yaml")]) == 2
    assert f"the run {run / 'blackbox.sqlite'} has none: was it made from another scenario?" in one_error(capsys)


def test_a_written_file_goes_through_a_link_and_into_a_pipe(tmp_path):
    """A symbolic link keeps pointing where it did (its file replaced); a FIFO is written into, not replaced."""
    target = tmp_path / "target.json"
    target.write_text("old")
    link = tmp_path / "link.json"
    link.symlink_to(target)
    write_text(link, "new")
    assert link.is_symlink() and target.read_text() == "new"

    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_text()))
    reader.start()
    write_text(fifo, "through the pipe")
    reader.join(timeout=30)
    assert got == ["through the pipe"] and fifo.is_fifo()


def test_a_write_error_names_the_users_path_not_a_temporary_file(tmp_path, run, capsys):
    (tmp_path / "afile").write_text("")
    assert main(["check", str(run), "--export-trace", str(tmp_path / "afile" / "x.json")]) == 2
    err = one_error(capsys)
    assert "is a file, not a folder" in err and str(tmp_path / "afile") in err and ".tmp" not in err
    assert main(["export", str(run), "--mcap", str(tmp_path / "nodir" / "x.mcap")]) == 2
    err = one_error(capsys)
    assert "no such folder" in err and "partial" not in err and ".tmp" not in err


@pytest.mark.parametrize("buffered", [False, True], ids=["line by line", "buffered to the end"])
def test_a_reader_that_stops_early_leaves_the_verdict_as_the_exit_code(run, buffered):
    """``cellsim check RUN | head -1``: the pipe closes early; the command still exits with its verdict (0: every
    condition holds), not 1 (a finding), 2 (an error) or 120 (Python failing to flush at exit). Unbuffered, the
    reader leaves after the first line; buffered (as outside this sandbox), before anything is flushed."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    if not buffered:
        env["PYTHONUNBUFFERED"] = "1"
    proc = subprocess.Popen([sys.executable, "-m", "cellsim.cli", "check", str(run), "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    try:
        first = b"{" if buffered else proc.stdout.readline()
        proc.stdout.close()  # the reader leaves
        err = proc.stderr.read()
        proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert first.strip() == b"{"
    assert proc.returncode == 0 and b"Traceback" not in err and b"Broken pipe" not in err, err


def test_a_misspelt_replace_tag_is_refused_at_its_line(tmp_path, capsys):
    child = tmp_path / "child.yaml"
    child.write_text(f"base: {WELDING_CELL}\nconfiguration_points: !replac\n  {{}}\n")
    assert main(["scenario", "check", str(child)]) == 2
    assert f"{child}:2: configuration_points: unknown tag '!replac' (did you mean '!replace'?)" in one_error(capsys)


def test_a_scenario_name_never_puts_the_default_run_folder_outside_runs(tmp_path, monkeypatch, capsys):
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    assert main(["simulate", str(WELDING_CELL), "--set", "name=../../escaped", "--duration", "0.2", "--quiet"]) == 2
    assert "name: '../../escaped': a scenario's name is its cell's name in the live twin's keys" in one_error(capsys)
    assert main(["simulate", str(WELDING_CELL), "--set", "name=.. cell", "--duration", "0.2", "--quiet"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["work"]
    (made,) = (work / "runs").iterdir()
    assert made.name.startswith("_cell-")


@pytest.mark.parametrize("name", ["x*", '"*"', "a/b", '"$*"', '"  "'])  # (as --set reads YAML)
def test_a_scenario_name_that_is_no_zenoh_key_is_one_error_before_anything_starts(name, capsys):
    """The audit's: 'x*' ended the live twin in a zenoh.ZError traceback; '*' ran a twin reading every cell's samples."""
    assert main(["scenario", "check", str(WELDING_CELL), "--set", f"name={name}"]) == 2
    assert "a scenario's name is its cell's name in the live twin's keys" in one_error(capsys)


def test_a_broken_robot_model_is_blamed_on_the_model_and_an_override_on_set(tmp_path, capsys):
    cell = tmp_path / "cell"
    shutil.copytree(ROOT / "scenarios", cell)
    (cell / "models" / "ur10.urdf").write_text('<robot name="x"><link name="a"/>\n')
    assert main(["scenario", "check", str(cell / "palletising_cell.yaml")]) == 2
    assert "entities.robot.model: not a robot model Drake can read" in one_error(capsys)
    assert main(["scenario", "check", str(WELDING_CELL), "--set", "robot.tool_frame=tcpp"]) == 2
    assert one_error(capsys).startswith("cellsim: error: --set: entities.robot.tool_frame: ")


def test_check_json_output_is_json(run, capsys):
    assert main(["check", str(run), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["holds"] is True


def test_a_replay_refuses_a_corrupt_record_before_anything_is_opened(run, tmp_path):
    """What replay checks, it checks before Meshcat starts: a value outside its domain too."""
    from cellsim.visual.replay import ReplayError, check_replay

    bad = damaged(run, tmp_path, """UPDATE messages SET payload = '{"value": "flying"}'
                                    WHERE channel = 'robot.safety_mode'""")
    with pytest.raises(ReplayError, match="has value 'flying', outside its domain"):
        check_replay(bad)
    assert check_replay(run)[2] == pytest.approx(1.0)


def test_a_scenario_with_an_absolute_base_and_a_replace_tag_campaigns(tmp_path, capsys):
    """The campaign's snapshot points the scenario's absolute base: at its copy; it read the file with a YAML
    loader that refuses !replace, so such a scenario (valid, simulate runs it) could not be campaigned."""
    child = tmp_path / "child.yaml"
    child.write_text(f"base: {WELDING_CELL}\ncampaign:\n  samplers: !replace\n"
                     "    operator_waits: {kind: simplex, total: 10.0}\n")
    out = tmp_path / "c"
    assert main(["campaign", str(child), "--runs", "1", "--duration", "1", "--out", str(out), "--quiet"]) in (0, 1)
    copy = next(p for p in (out / "inputs").rglob("child.yaml"))
    base = copy.read_text().splitlines()[0]
    assert base.startswith("base: ") and not base.startswith(f"base: {WELDING_CELL}")
    assert (copy.parent / json.loads(base.removeprefix("base: "))).resolve().is_file()


def test_a_stray_argument_is_refused_with_the_commands_own_usage(run, capsys):
    with pytest.raises(SystemExit) as stopped:
        main(["scenario", "check", str(WELDING_CELL), "extra"])
    assert stopped.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: cellsim scenario check") and "unrecognized arguments: extra" in err


def test_an_earlier_export_beside_the_run_is_the_users_to_replace(run, tmp_path, capsys):
    """Only the run's own files are protected: an MCAP exported into the run folder before may be exported again."""
    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    for _ in range(2):
        assert main(["export", str(copy), "--mcap", str(copy / "run.mcap")]) == 0
    assert main(["check", str(copy), "--export-trace", str(copy / "trace.json")]) == 0
    assert main(["check", str(copy), "--export-trace", str(copy / "trace.json")]) == 0


def test_a_stray_argument_to_a_keys_action_gets_that_actions_usage(tmp_path, capsys):
    with pytest.raises(SystemExit) as stopped:
        main(["keys", "show", str(tmp_path), "--bogus"])
    assert stopped.value.code == 2 and capsys.readouterr().err.startswith("usage: cellsim keys show")


@pytest.mark.parametrize("timeout", ["nan", "inf", "0", "-1"])
def test_twin_mode_refuses_a_timeout_it_cannot_wait_as_one_line(timeout, capsys):
    """The audit's: nan and inf ended in a ValueError and an OverflowError traceback (exit 1) building Zenoh's config."""
    assert main(["twin-mode", "robot", "shadow", "--insecure", "--timeout", timeout]) == 2
    assert f"--timeout {float(timeout):g}: expected more than 0 and at most 3600 seconds" in one_error(capsys)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_command_waiting_for_the_twin_stops_at_once_on_ctrl_c_or_sigterm(sig, tmp_path):
    """An audit found a client waiting for the twin (Zenoh connecting, up to --timeout) ignored SIGTERM and Ctrl-C
    until the wait ended (17.5 s of 20; with --timeout 1e20, never): the native call held off Python's handlers."""
    import time

    from live_processes import free_port

    log = (tmp_path / "twin-mode.log").open("w")
    # (a fresh session: Ctrl-C reaches the child as a terminal's would, not ignored as a background job's)
    proc = subprocess.Popen([sys.executable, "-m", "cellsim", "twin-mode", "robot", "shadow", "--insecure", "--connect",
                             f"tcp/127.0.0.1:{free_port()}", "--timeout", "60"], cwd=ROOT, stdout=log, stderr=log,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while "--insecure" not in (tmp_path / "twin-mode.log").read_text():  # (its warning: it waits for the twin now)
            assert proc.poll() is None and time.monotonic() < deadline
            threading.Event().wait(0.05)
        threading.Event().wait(0.5)  # (inside the connecting call)
        proc.send_signal(sig)
        assert proc.wait(timeout=10) == 130
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        log.close()
    assert "cellsim: interrupted" in (tmp_path / "twin-mode.log").read_text()
