"""Meshcat shows the cell: camera, see-through fences, drawn state live and replayed from a black box."""

from __future__ import annotations

import base64
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from cellsim.scenario import load_scenario
from cellsim.blackbox import BlackBox
from cellsim.simulation import make_simulator, simulate
from cellsim.visual.scene import camera_pose
from cellsim.visual.serve import open_meshcat
from cellsim.diagrams.cell import build_cell

ROOT = Path(__file__).resolve().parents[1]
WELDING = ROOT / "scenarios" / "welding_cell.yaml"
CELLSIM = [sys.executable, "-m", "cellsim"]
BROKEN_AT = 12.2
"""In the default welding run the operator reaches across the table: the curtain is broken and the robot in pflim."""


def visible(meshcat, path: str) -> bool:
    """The ``visible`` property Meshcat holds for ``path`` (msgpack: 0xc3 true, 0xc2 false)."""
    packed = meshcat._GetPackedProperty(path, "visible")
    assert packed, f"no visible property at {path}"
    return packed[-1:] == b"\xc3"


def messages(meshcat) -> list[bytes]:
    """Every command Meshcat would send a new browser (decoded from its static page)."""
    return [base64.b64decode(b) for b in re.findall(r'base64,([A-Za-z0-9+/=]+)"', meshcat.StaticHtml())]


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """A headless welding-cell run through the curtain break (to 13 s)."""
    out = tmp_path_factory.mktemp("meshcat") / "run"
    simulate(load_scenario(WELDING), out, duration=13.0)
    return out


@pytest.fixture
def meshcat():
    m = open_meshcat()
    yield m
    del m


@pytest.mark.parametrize("scenario", ["welding_cell.yaml", "palletising_cell.yaml", "two_operators.yaml"])
def test_the_camera_stands_outside_the_cell_looking_at_its_middle(scenario):
    extent = load_scenario(ROOT / "scenarios" / scenario).scenario.layout.extent()
    lo, hi = np.array(extent[0]), np.array(extent[1])
    camera, target = camera_pose(extent)
    assert not np.all((lo <= camera) & (camera <= hi)), "the camera is inside the fence"
    assert np.all((lo <= target) & (target <= hi))
    assert camera[2] > target[2]  # looking down into the cell


def test_a_headless_cell_has_no_drawing_system():
    cell = build_cell(load_scenario(WELDING), seed=0, duration=1.0, record=False)
    assert cell.cue_visualizer is None and cell.meshcat_visualizer is None


def test_live_meshcat_draws_what_the_channels_say(meshcat, tmp_path):
    sf = load_scenario(WELDING)
    cell = build_cell(sf, seed=0, duration=BROKEN_AT, record=False, meshcat=meshcat)
    simulator = make_simulator(cell)
    simulator.set_target_realtime_rate(0.0)  # (what is drawn, not its pacing: as fast as it goes)
    simulator.Initialize()
    drawer = cell.cue_visualizer.drawer
    beams = next(c for c in drawer.cues if c.name == "light_barrier/beams")
    shell = next(c for c in drawer.cues if c.name == "robot/safety_mode")
    marker = next(c for c in drawer.cues if c.name == "operator/seen")

    # the scene: a camera outside the fence, the fences faded and outlined, the plain beams hidden
    camera = meshcat._GetPackedProperty("/Cameras/default/rotated/<object>", "position")
    assert camera, "no camera position was set"
    fences = [p for p in ("north", "east", "south")]
    for side in fences:
        path = f"/drake/visualizer/fixture/fence_{side}"
        assert meshcat._GetPackedProperty(path, "modulated_opacity"), path
        assert meshcat.HasPath(path + "_outline")
    assert not visible(meshcat, beams.replaces[0])

    simulator.AdvanceTo(5.0)  # the operator at the bench, nobody seen, the robot at full speed
    assert drawer.visible_look(beams.name) == "clear"
    assert visible(meshcat, beams.looks["clear"][0].path) and not visible(meshcat, beams.looks["broken"][0].path)
    assert drawer.visible_look(shell.name) is None  # normal: the arm's own colours
    assert not any(visible(meshcat, p.path) for p in shell.looks["pflim"])
    assert drawer.visible_look(marker.name) is None
    assert not visible(meshcat, marker.looks["seen"][0].path)

    simulator.AdvanceTo(BROKEN_AT)  # reaching across the table
    values = cell.cue_visualizer.values(cell.cue_visualizer.GetMyContextFromRoot(simulator.get_context()))
    assert values["light_barrier.broken"] is True and values["robot.safety_mode"] == "pflim"
    assert visible(meshcat, beams.looks["broken"][0].path) and not visible(meshcat, beams.looks["clear"][0].path)
    assert all(visible(meshcat, p.path) for p in shell.looks["pflim"])
    assert len(shell.looks["pflim"]) >= 6  # a shell on every link of the arm
    assert visible(meshcat, marker.looks["seen"][0].path)


def test_simulate_with_meshcat_records_the_same_run(meshcat, tmp_path, run, monkeypatch):
    """Drawing adds nothing to the black box: a run with Meshcat is the run without it. (Its pacing to real time,
    a setting of the simulator outside the diagram, is left out: the drawing systems are what is compared.)"""
    from cellsim.diagrams.cell import CellDiagram

    monkeypatch.setattr(CellDiagram, "realtime_rate", property(lambda self: 0.0))
    out = tmp_path / "with_meshcat"
    simulate(load_scenario(WELDING), out, duration=13.0, meshcat=meshcat)
    with BlackBox(out / "blackbox.sqlite") as a, BlackBox(run / "blackbox.sqlite") as b:
        assert a.rows() == b.rows()


def test_replay_records_an_animation_of_the_black_box(meshcat, run):
    from cellsim.visual.replay import replay

    played = replay(run, meshcat, at=0.0)
    assert played.end == 13.0 and played.frames == 131
    sent = messages(meshcat)
    animation = b"".join(m for m in sent if b"set_animation" in m)
    assert animation, "no animation was published"
    # the arm moves, and the beams go red and clear again, in the animation's tracks
    assert b"/drake/visualizer/robot/ur10/wrist_1_link" in animation
    assert b"/cellsim/light_barrier/beams/broken/0" in animation
    assert b"/robot/ur10/forearm_link/safety_mode_pflim/0" in animation
    with BlackBox(run / "blackbox.sqlite") as bb:
        broken = bb.series("light_barrier.broken")
        assert any(broken.values) and not broken.values[-1]
    drawer = played.cell.cue_visualizer.drawer
    assert drawer.visible_look("light_barrier/beams") == "clear"  # as recorded at the end


def test_replay_at_a_moment_starts_the_recording_there(meshcat, run):
    from cellsim.visual.replay import replay

    played = replay(run, meshcat, at=BROKEN_AT)
    assert played.frames == 9  # 12.2, 12.3 ... 13.0
    assert played.cell.cue_visualizer.drawer.visible_look("light_barrier/beams") == "clear"


def _cli(*args, **kw):
    return subprocess.run([*CELLSIM, *args], capture_output=True, text=True, cwd=ROOT, timeout=120, **kw)


@pytest.mark.parametrize(
    "args, says",
    [
        (["replay", "{missing}", "--meshcat"], "no such run folder"),
        (["replay", "{run}", "--meshcat", "--at", "99"], "--at 99: expected a time from 0 to 13 s"),
        (["replay", "{run}", "--meshcat", "--at", "-1"], "--at -1"),
        (["replay", "{run}", "--meshcat", "--speed", "0"], "--speed 0"),
        (["replay", "{run}"], "replay needs --meshcat"),
        (["replay", "{empty}", "--meshcat"], "not a run folder"),
        (["simulate", str(WELDING), "--meshcat", "--meshcat-wait", "-1", "--out", "{fresh}"], "--meshcat-wait -1"),
    ],
)
def test_bad_replay_input_is_one_line_and_exit_2(args, says, run, tmp_path):
    """Every argument is checked before Meshcat starts: Drake says nothing of a Meshcat server (it used to
    start one, listening, before --at 99 was refused)."""
    (tmp_path / "empty").mkdir()
    names = dict(run=run, missing=tmp_path / "nowhere", empty=tmp_path / "empty", fresh=tmp_path / "fresh")
    result = _cli(*[a.format(**names) for a in args])
    assert result.returncode == 2, result.stderr
    assert "Meshcat" not in result.stderr and "INFO:drake" not in result.stderr, result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("cellsim: error: ") and says in lines[0], result.stderr
    assert not (tmp_path / "fresh").exists()


def _lines_of(stream) -> queue.Queue:
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(line) for line in stream], daemon=True).start()
    return lines


def test_replay_serves_the_page_until_terminated(run):
    process = subprocess.Popen(
        [*CELLSIM, "replay", str(run), "--meshcat", "--at", "10"],
        cwd=ROOT, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        lines, url, deadline = _lines_of(process.stdout), None, time.monotonic() + 60
        while url is None:
            line = lines.get(timeout=max(0.1, deadline - time.monotonic()))
            found = re.search(r"Meshcat: (http://localhost:\d+)", line)
            url = found and found.group(1)
        with urllib.request.urlopen(url, timeout=10) as page:
            assert "MeshCat" in page.read().decode()
        assert process.poll() is None  # still serving
    finally:
        os.kill(process.pid, signal.SIGTERM)
        code = process.wait(timeout=30)
    assert code == 130, process.stderr.read()


def test_simulate_with_meshcat_waits_for_a_browser_then_simulates_anyway(tmp_path):
    result = _cli(
        "simulate", str(WELDING), "--meshcat", "--meshcat-wait", "0.5", "--duration", "0.5",
        "--out", str(tmp_path / "run"),
    )
    assert result.returncode == 0, result.stderr
    assert "waiting up to 0.5 s for a browser" in result.stderr
    assert "no browser connected within 0.5 s; simulating anyway" in result.stderr
    assert (tmp_path / "run" / "blackbox.sqlite").is_file()


def test_simulate_with_meshcat_starts_once_a_real_browser_opens_it(tmp_path):
    """A browser (Chromium, driven by Playwright) opens the printed URL: the wait ends there, long
    before its 120 s, and the run completes."""
    import shutil

    from playwright.sync_api import sync_playwright

    chromium = shutil.which("chromium")
    assert chromium, "this test needs Chromium: apt-get install chromium (the README's test command does)"
    process = subprocess.Popen(
        [*CELLSIM, "simulate", str(WELDING), "--meshcat", "--meshcat-wait", "120", "--duration", "1",
         "--out", str(tmp_path / "run")],
        cwd=ROOT, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        lines, said, deadline = _lines_of(process.stderr), [], time.monotonic() + 60
        while not any("waiting up to 120 s for a browser" in line for line in said):
            said.append(lines.get(timeout=max(0.1, deadline - time.monotonic())))
        url = next(re.search(r"http://\S+", line).group(0) for line in said if "Meshcat: http" in line)
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=chromium, args=["--no-sandbox", "--disable-gpu",
                                        "--disable-background-networking", "--disable-component-update"])
            try:
                browser.new_page().goto(url)
                assert process.wait(timeout=60) == 0  # the browser ended the wait: the run went on and completed
            finally:
                browser.close()
        while not lines.empty():
            said.append(lines.get())
        assert not any("no browser connected" in line for line in said), said
        assert (tmp_path / "run" / "blackbox.sqlite").is_file()
    finally:
        if process.poll() is None:
            process.kill()
        process.wait(timeout=30)


def test_each_monitored_arm_has_a_floor_disc_coloured_by_what_its_monitor_allows(meshcat):
    """The assembly bench: free at full speed while nobody is near, limited (amber) once the operator
    walks in; the looks for a stop and a violated margin chosen from the channels as well."""
    from conftest import ROOT

    cell = build_cell(load_scenario(ROOT / "scenarios" / "assembly_bench.yaml"), seed=0, duration=6.0, record=False,
                      meshcat=meshcat)
    simulator = make_simulator(cell)
    simulator.set_target_realtime_rate(0.0)  # (what is drawn, not its pacing)
    simulator.Initialize()
    drawer = cell.cue_visualizer.drawer
    disc = next(c for c in drawer.cues if c.name == "loader_ssm/ssm")
    assert {c.name for c in drawer.cues} >= {"loader_ssm/ssm", "assembler_ssm/ssm"}
    simulator.AdvanceTo(1.0)
    assert drawer.visible_look(disc.name) == "free" and visible(meshcat, disc.looks["free"][0].path)
    simulator.AdvanceTo(5.0)  # the operator on the way to the bench: the limit below the 1 m/s ssmon cap
    assert drawer.visible_look(disc.name) == "limited"
    assert visible(meshcat, disc.looks["limited"][0].path) and not visible(meshcat, disc.looks["free"][0].path)
    monitor = cell.modules["loader_ssm"]
    assert monitor.look({"loader_ssm.margin": 0.1, "loader_ssm.speed_limit": 0.0}) == "stopped"
    assert monitor.look({"loader_ssm.margin": -0.01, "loader_ssm.speed_limit": 0.3}) == "too_fast"
    assert monitor.look({}) is None


@pytest.mark.parametrize("args", [["--at", "99"], ["--at", "-1"], ["--speed", "0"]])
def test_a_refused_replay_never_starts_meshcat(run, monkeypatch, capsys, args):
    """The run's end and the speed are checked before the Meshcat server opens (it used to open first)."""
    from cellsim.cli import main

    opened = []
    monkeypatch.setattr("cellsim.visual.serve.open_meshcat", lambda *a, **k: opened.append(a) or pytest.fail("opened"))
    assert main(["replay", str(run), "--meshcat", *args]) == 2
    assert opened == [] and capsys.readouterr().err.startswith("cellsim: error: ")
