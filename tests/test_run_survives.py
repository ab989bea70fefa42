"""A run's record survives what happens to its process, and one run owns its folder.

These tests start real ``cellsim simulate`` processes, wait (with a deadline) on
what the black box has committed, and stop every process they start by its PID.
"""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cellsim.cli import main
from cellsim.blackbox import BlackBox
from cellsim.simulation import BLACKBOX

from conftest import WELDING_CELL

DEADLINE = 90.0


def start_simulate(out: Path, *extra: str, duration: float = 120.0) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "cellsim.cli", "simulate", str(WELDING_CELL), "--out", str(out),
         "--duration", str(duration), "--quiet", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )


def recorded_until(blackbox: Path) -> float:
    """What the run has committed so far (0 before its first commit)."""
    if not blackbox.exists():
        return 0.0
    db = sqlite3.connect(f"file:{blackbox}?mode=ro", uri=True, timeout=1.0)
    try:
        row = db.execute("SELECT value FROM metadata WHERE key = 'recorded_until'").fetchone()
    except sqlite3.OperationalError:  # the file exists but its schema is not written yet
        return 0.0
    finally:
        db.close()
    return json.loads(row[0]) if row else 0.0


def wait_for_record(proc: subprocess.Popen, blackbox: Path, seconds: float) -> float:
    """Wait until the run has committed ``seconds`` of simulated time; fail at the deadline."""
    deadline = time.monotonic() + DEADLINE
    while time.monotonic() < deadline:
        reached = recorded_until(blackbox)
        if reached >= seconds:
            return reached
        if proc.poll() is not None:
            pytest.fail(f"simulate ended early ({proc.returncode}): {proc.stderr.read()}")
        time.sleep(0.05)  # polling a file another process writes: no event to wait on
    pytest.fail(f"no {seconds} s of record within {DEADLINE} s")


def stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    for stream in (proc.stdout, proc.stderr):
        stream.close()


def test_sigkill_keeps_the_record_up_to_the_last_second(tmp_path, capsys):
    out = tmp_path / "killed"
    proc = start_simulate(out)
    try:
        wait_for_record(proc, out / BLACKBOX, 5.0)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        stop(proc)
    assert proc.returncode == -signal.SIGKILL
    with BlackBox(out / BLACKBOX) as bb:
        meta = bb.metadata()
        kept = meta["recorded_until"]
        times = [m.t for m in bb.messages("robot.tool_speed")]
    assert meta["status"] == "running"  # it never got to close
    assert kept >= 5.0
    # everything up to the last commit is there: telemetry every 0.1 s
    assert times[-1] >= kept - 0.2 and len(times) >= 45
    # the killed run is checked up to its record, its G conditions inconclusive
    assert main(["check", str(out), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert report["complete"] is False
    assert {v["status"] for v in report["verdicts"].values()} <= {"inconclusive", "violated"}
    assert report["verdicts"]["HC:not_mis"] == {
        "holds": False, "status": "inconclusive", "violated_at": None, "reading": "holds so far"}


@pytest.mark.parametrize("reader_open", [False, True])
def test_sigterm_closes_the_black_box_as_ctrl_c_does(tmp_path, reader_open):
    """A batch scheduler stops a job with SIGTERM: the run ends as after Ctrl-C, its black box closed with
    status interrupted and its record complete to the moment it stopped, exit 130; also while someone has
    the running record open (the file then stays in SQLite's WAL mode, complete)."""
    out = tmp_path / "terminated"
    proc = start_simulate(out)
    reader = None
    try:
        wait_for_record(proc, out / BLACKBOX, 2.0)
        if reader_open:
            reader = sqlite3.connect(f"file:{out / BLACKBOX}?mode=ro", uri=True)
            reader.execute("SELECT COUNT(*) FROM messages").fetchone()
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=60)
        err = proc.stderr.read()
    finally:
        stop(proc)
        if reader is not None:
            reader.close()
    assert proc.returncode == 130 and err.strip().splitlines()[-1] == "cellsim: interrupted", err
    with BlackBox(out / BLACKBOX) as bb:
        meta = bb.metadata()
    assert meta["status"] == "interrupted" and meta["recorded_until"] >= 2.0


@pytest.mark.parametrize("overwrite", [False, True])
def test_a_second_simulate_into_a_folder_being_written_is_refused(tmp_path, overwrite):
    out = tmp_path / "shared"
    first = start_simulate(out)
    try:
        wait_for_record(first, out / BLACKBOX, 1.0)
        before = (out / "scenario.yaml").read_bytes()
        second = subprocess.run(
            [sys.executable, "-m", "cellsim.cli", "simulate", str(WELDING_CELL), "--out", str(out),
             "--duration", "2", "--seed", "9"] + (["--overwrite"] if overwrite else []),
            capture_output=True, text=True, timeout=120,
        )
        assert second.returncode == 2
        assert second.stderr.strip().count("\n") == 0 and "Traceback" not in second.stderr
        assert "being written by another cellsim process" in second.stderr
        # the first run's files are untouched and it goes on recording
        assert (out / "scenario.yaml").read_bytes() == before
        reached = recorded_until(out / BLACKBOX)
        wait_for_record(first, out / BLACKBOX, reached + 1.0)
    finally:
        stop(first)
    with BlackBox(out / BLACKBOX) as bb:
        assert bb.metadata()["seed"] != 9


@pytest.mark.parametrize("out", [".", ""])
def test_the_current_folder_is_refused(tmp_path, out, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    mine = tmp_path / "scenario.yaml"
    mine.write_text("my own notes\n")
    assert main(["simulate", str(WELDING_CELL), "--out", out, "--duration", "1", "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert "current folder" in err and len(err.strip().splitlines()) == 1
    assert mine.read_text() == "my own notes\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scenario.yaml"]


def test_a_folder_of_other_files_is_refused(tmp_path, capsys):
    out = tmp_path / "notes"
    out.mkdir()
    (out / "todo.txt").write_text("x")
    assert main(["simulate", str(WELDING_CELL), "--out", str(out), "--duration", "1"]) == 2
    assert "holds no run" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["todo.txt"]


def with_condition(tmp_path: Path, name: str, formula: str) -> Path:
    """The welding cell with one more safety condition (a scenario with the welding cell as base)."""
    path = tmp_path / "with_condition.yaml"
    path.write_text(f"base: {WELDING_CELL}\nvalidation:\n  conditions:\n    {json.dumps(name)}: {json.dumps(formula)}\n")
    return path


def test_simulate_exits_1_when_a_condition_is_violated(tmp_path, capsys):
    """simulate and check agree: a violated condition is a safety finding for both."""
    scenario = with_condition(tmp_path, "Never:welds", "G(not wact == welding)")
    out = tmp_path / "run"
    assert main(["simulate", str(scenario), "--out", str(out), "--quiet"]) == 1
    assert capsys.readouterr().out == ""  # --quiet
    assert main(["check", str(out), "--json"]) == 1
    assert json.loads(capsys.readouterr().out)["violations"] == ["Never:welds"]


def test_a_bad_condition_is_refused_before_anything_is_written_even_quiet(tmp_path, capsys):
    scenario = with_condition(tmp_path, "Typo", "G(not wact == weldin)")
    out = tmp_path / "run"
    assert main(["simulate", str(scenario), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "validation.conditions.Typo" in err and "weldin" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_a_mishap_in_a_risk_models_own_phases_is_a_finding(tmp_path, capsys):
    """simulate exits 1 on a mishap whatever the risk model calls its phases."""
    model = tmp_path / "own_phases.yaml"
    model.write_text(
        "name: own\nphases: {values: [clear, warned, hurt], initial: clear, mishap: hurt}\n"
        "monitored:\n  lgtBar: {type: bool}\n"
        "controlled:\n  notif: {values: [ok, leaveArea], default: ok}\n"
        "hazards:\n  X:\n    transitions:\n      - {phase: clear, to: warned}\n      - {phase: warned, to: hurt, after: 0.5}\n"
    )
    scenario = tmp_path / "own.yaml"
    scenario.write_text(
        f"base: {WELDING_CELL}\nbehaviours:\n  safety_controller:\n    risk_model: {model}\n"
        "    monitors: !replace {lgtBar: light_barrier.broken}\n"
        "    commands: !replace {notif: [operator.notification]}\n"
        "validation: !replace {}\n"
    )
    assert main(["simulate", str(scenario), "--out", str(tmp_path / "run"), "--duration", "2"]) == 1
    printed = capsys.readouterr().out
    assert "hazard X" in printed and "raised 1, handled 0, MISHAPS 1" in " ".join(printed.split())


@pytest.mark.parametrize("restart", [False, True])
def test_a_second_campaign_into_a_folder_being_written_is_refused(tmp_path, restart):
    out = tmp_path / "campaign"
    first = subprocess.Popen(
        [sys.executable, "-m", "cellsim.cli", "campaign", str(WELDING_CELL), "--runs", "40", "--jobs", "1",
         "--out", str(out), "--duration", "5", "--quiet"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        deadline = time.monotonic() + DEADLINE
        while not list(out.glob("runs/*/result.json")):  # a run finished: the campaign holds its folder
            assert time.monotonic() < deadline and first.poll() is None, "the first campaign never finished a run"
            time.sleep(0.05)  # polling files another process writes: no event to wait on
        second = subprocess.run(
            [sys.executable, "-m", "cellsim.cli", "campaign", str(WELDING_CELL), "--runs", "2", "--out", str(out),
             "--duration", "5", "--quiet"] + (["--restart"] if restart else []),
            capture_output=True, text=True, timeout=120,
        )
        assert second.returncode == 2
        assert "being written by another cellsim campaign" in second.stderr and "Traceback" not in second.stderr
        assert list(out.glob("runs/*/result.json"))  # the first campaign's runs are still there
        assert first.poll() is None  # and it goes on
    finally:
        stop(first)


def test_a_kill_at_any_moment_loses_at_most_one_simulated_second(tmp_path, monkeypatch):
    """The record on disk lags the simulation by at most a second: at every commit, read back by another
    connection, everything the finished record holds before then is already there, and commits come at
    most one simulated second apart (a SIGKILL between two commits loses what came since the first)."""
    from cellsim.blackbox import BlackBoxWriter
    from cellsim.simulation import simulate

    from conftest import welding_cell

    seen: list[tuple[float, int]] = []  # (recorded_until, messages on disk up to it) at each commit
    commit = BlackBoxWriter.commit

    def spy(self, recorded_until: float) -> None:
        commit(self, recorded_until)
        db = sqlite3.connect(f"file:{self.path}?mode=ro", uri=True)
        try:
            seen.append((recorded_until, db.execute("SELECT COUNT(*) FROM messages WHERE t < ?",
                                                    (recorded_until - 1e-9,)).fetchone()[0]))
        finally:
            db.close()

    monkeypatch.setattr(BlackBoxWriter, "commit", spy)
    simulate(welding_cell(), tmp_path / "run", seed=3, duration=6.5)
    times = [0.0] + [t for t, _ in seen]
    assert max(b - a for a, b in zip(times, times[1:])) <= 1.0 + 1e-9, times
    assert times[-1] == pytest.approx(6.5)
    with BlackBox(tmp_path / "run" / BLACKBOX) as bb:
        final = [m.t for channel in bb.channels() for m in bb.messages(channel)]
    # what a kill just after this commit would have kept: all of it before then (the samples of the commit's
    # own instant are taken by the next step, as recorded_until says: the record is complete before it)
    for until, on_disk in seen:
        assert on_disk == sum(1 for t in final if t < until - 1e-9), until


@pytest.mark.parametrize("stop_with", [KeyboardInterrupt, RuntimeError])
def test_an_overwriting_run_that_does_not_finish_leaves_the_old_run_whole(tmp_path, stop_with):
    """--overwrite writes the new run beside the old one and swaps them only once it is written: interrupted or
    failed half way, the old run's files are as they were and nothing of the new one is left behind."""
    from cellsim.scenario import load_scenario
    from cellsim.simulation import simulate

    out = tmp_path / "run"
    assert main(["simulate", str(WELDING_CELL), "--out", str(out), "--duration", "1", "--seed", "3", "--quiet"]) == 0
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}

    def stop(done, total):
        if done >= 1.0:
            raise stop_with("stopped half way")

    with pytest.raises(stop_with):
        simulate(load_scenario(WELDING_CELL), out, seed=9, duration=3.0, overwrite=True, on_progress=stop)
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    # finished, it takes the old run's place, and only then
    summary = simulate(load_scenario(WELDING_CELL), out, seed=9, duration=1.0, overwrite=True)
    assert summary.out_dir == out and summary.status == "completed"
    with BlackBox(out / BLACKBOX) as bb:
        assert bb.metadata()["seed"] == 9
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_an_overwrite_through_a_linked_out_keeps_the_link_and_the_users_files(tmp_path):
    """--out a symbolic link to the run's folder: the run is replaced in the folder it names, the link stays (the
    first version swapped the link itself away and every later overwrite failed at its end); files beside the run
    that no run wrote (an export, notes) stay with it."""
    target = tmp_path / "run-1"
    link = tmp_path / "latest"
    assert main(["simulate", str(WELDING_CELL), "--out", str(target), "--duration", "0.5", "--quiet"]) == 0
    link.symlink_to(target)
    (target / "notes.txt").write_text("mine")
    for seed in (4, 5):
        assert main(["simulate", str(WELDING_CELL), "--out", str(link), "--duration", "0.5", "--seed", str(seed),
                     "--overwrite", "--quiet"]) == 0
        assert link.is_symlink() and (target / "notes.txt").read_text() == "mine"
        with BlackBox(target / BLACKBOX) as bb:
            assert bb.metadata()["seed"] == seed
    assert sorted(p.name for p in tmp_path.iterdir()) == ["latest", "run-1"]
