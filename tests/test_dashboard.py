"""The terminal dashboard, driven as a user drives it: in a terminal (tmux) and with Textual's pilot."""

from __future__ import annotations

import asyncio
import json
import re
import signal
import subprocess
import sys

import pytest

from cellsim.blackbox import BlackBox

from live_processes import ROOT, ChannelWatch, TmuxScreen, free_port, observer, processes, wait_alive

WELDING_CELL = str(ROOT / "scenarios" / "welding_cell.yaml")
TWO_OPERATORS = str(ROOT / "scenarios" / "two_operators.yaml")
# a run of the misuse scenario the campaign found violating HRW:detected (its first run with --seed 0)
VIOLATING = ["--set", "operator.waypoints.bench_entrance.wait=5.985453", "--set", "operator.waypoints.bench.wait=8.975532",
             "--set", "operator.waypoints.cell_entrance.wait=0.174359", "--set", "operator.waypoints.cell.wait=0.019977",
             "--set", "operator.waypoints.exit.wait=4.844679", "--set", "visitor.waypoints.cell.position.0=0.7167867122832157",
             "--set", "visitor.start_delay=7.279629309206158", "--set", "visitor.waypoints.cell_entrance.wait=1.009817",
             "--set", "visitor.waypoints.cell.wait=2.401289", "--set", "visitor.waypoints.exit.wait=4.588894",
             "--seed", "1384040912"]
def _entity(screen: str, name: str) -> list[str]:
    """The entity table's row of ``name``: [name, mode, link level, ...]."""
    for line in screen.splitlines():
        words = line.split()
        if len(words) > 2 and words[0] == name and words[1] in ("model", "shadow", "twin"):
            return words
    return []


SHOWN_TIME = re.compile(r"t =\s+([0-9.]+) s")


def _simulate(out, scenario: str, *args: str) -> None:
    proc = subprocess.run([sys.executable, "-m", "cellsim", "simulate", scenario, "--out", str(out), "--quiet", *args],
                          capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode in (0, 1), proc.stderr


@pytest.fixture(scope="module")
def welding_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("dashboard") / "weld"
    _simulate(out, WELDING_CELL)
    return out


def test_sigterm_ends_the_dashboard_at_once_as_an_interrupt(welding_run):
    """kill (SIGTERM) ends the dashboard as Ctrl-C ends a command: at once, exit 130 (a review saw it lost while the
    screen started, the screen left up)."""
    import os
    import signal

    screen = TmuxScreen(["dashboard", "--replay", str(welding_run), "--start", "16"])
    try:
        screen.wait_for(lambda s: _row(s, "HS"), 30, "the hazards panel")
        os.kill(screen.pid, signal.SIGTERM)
        assert screen.exit_status(5.0) == 130
    finally:
        screen.stop()


def _row(screen: str, first: str) -> list[str]:
    """The words of a table row that starts with the word ``first`` (panels stand side by side:
    the row is the rest of the line from that word on)."""
    for line in screen.splitlines():
        words = line.split()
        if first in words:
            return words[words.index(first):]
    return []


def test_a_replay_shows_each_hazard_in_its_recorded_phase_at_the_time_it_shows(welding_run):
    with BlackBox(welding_run / "blackbox.sqlite") as bb:
        hs = bb.series("safety_controller.HS")
    raised = next(t for t, v in zip(hs.times, hs.values) if v != "inact" and t > 1.0)
    screen = TmuxScreen(["dashboard", "--replay", str(welding_run), "--start", f"{raised - 1.0:.2f}"])
    try:
        seen = []

        def note(text: str) -> bool:
            shown, row = SHOWN_TIME.search(text), _row(text, "HS")
            if shown and len(row) >= 2:
                seen.append((float(shown.group(1)), row[1]))
            return bool(seen) and seen[-1][0] >= raised + 1.0

        screen.wait_for(note, 30, "the replay passing HS being raised")
        for t, phase in seen:  # what the screen says at the time it shows (to its 0.01 s) is what was recorded then
            assert phase in {hs.value_at(t + d) for d in (-0.006, -0.003, 0.0, 0.003, 0.005)}, (t, phase)
        first_raised = next(t for t, phase in seen if phase != "inact")
        assert raised <= first_raised <= raised + 0.6  # shown within a refresh (0.25 s) and a look at the screen
        assert "hazard HS: inact -> act" in screen.text()  # the event log
    finally:
        screen.stop()
    assert not screen.running()


def test_a_replayed_violating_misuse_run_shows_the_condition_violated_when_the_check_does(tmp_path):
    run = tmp_path / "misuse"
    _simulate(run, TWO_OPERATORS, *VIOLATING)
    proc = subprocess.run([sys.executable, "-m", "cellsim", "check", str(run), "--json"], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)
    violated_at = json.loads(proc.stdout)["verdicts"]["HRW:detected"]["violated_at"]
    screen = TmuxScreen(["dashboard", "--replay", str(run), "--start", f"{violated_at - 1.5:.2f}", "--speed", "2"])
    try:
        before = screen.wait_for(lambda s: _row(s, "HRW:detected")[1:3] == ["holds", "so"], 30, "HRW:detected holding so far")
        assert float(SHOWN_TIME.search(before).group(1)) < violated_at
        shown = screen.wait_for(lambda s: _row(s, "HRW:detected")[1:2] == ["violated"], 30, "HRW:detected violated")
        assert _row(shown, "HRW:detected")[1:5] == ["violated", "at", f"{violated_at:.2f}", "s"]
        log = screen.text()
        assert f"condition HRW:detected violated at {violated_at:.2f} s: HRW_e true from {violated_at:.2f} s" in log  # and why
        screen.keys("c")  # every condition in full: what it means, and why it is violated
        full = screen.wait_for(lambda s: "Safety conditions over the trace so far" in s, 10, "the conditions in full")
        assert "A person reaching across the shared table while the robot works there is detected" in " ".join(full.split())
        assert f"why: HRW_e true from {violated_at:.2f} s" in full
        screen.keys("c")
        screen.wait_for(lambda s: "Safety conditions over the trace so far" not in s, 10, "the conditions closed")
    finally:
        screen.stop()


def test_on_a_small_terminal_without_colour_the_cell_and_its_hazards_still_show(welding_run):
    screen = TmuxScreen(["dashboard", "--replay", str(welding_run), "--start", "16"], width=80, height=24,
                        env={"NO_COLOR": "1"})
    try:
        text = screen.wait_for(lambda s: _row(s, "HS") and _entity(s, "robot"), 30, "the cell and hazard panels")
        assert _row(text, "HS")[1] in ("mit", "act") and _row(text, "HS")[-1] == "WARN"  # a level in words, not colour
        assert "cycles completed" in text and "safety mode" in text
    finally:
        screen.stop()


def test_the_dashboard_follows_the_live_twin_sees_a_link_go_stale_and_switches_a_twin_mode(tmp_path):
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    modes = [arg for e in ("robot", "welder", "light_barrier", "range_detector", "operator") for arg in ("--set", f"{e}.twin.mode=shadow")]
    with processes() as start:
        # an engineer's dashboard (an observer's may not switch modes), before the twin: it says it waits
        screen = TmuxScreen(["dashboard", "--connect", endpoint, "--role", "engineer"])
        try:
            screen.wait_for(lambda s: "no twin running" in s, 30, "saying no twin runs")
            twin = start(["live", WELDING_CELL, "--out", str(tmp_path / "twin"), "--listen", endpoint, "--quiet", *modes],
                         tmp_path / "twin.log")
            emulator = start(["emulate", WELDING_CELL, "--out", str(tmp_path / "emulator"), "--connect", endpoint, "--quiet"],
                             tmp_path / "emulator.log")
            screen.wait_for(lambda s: _entity(s, "robot")[1:3] == ["shadow", "OK"], 90, "the robot's link OK")
            # the moving robot's samples change: the twin measures its reaction to them, shown in the header
            screen.wait_for(lambda s: re.search(r"reaction \d+ ms", s), 10, "the twin's reaction time")
            with observer(port) as session:
                mode = ChannelWatch(session, "cellsim/welding_cell/twin/light_barrier/twin_mode")
                wait_alive(session, "cellsim/welding_cell/alive/twin")
                screen.keys("m")  # switch a twin mode: the entity, the mode, then confirm
                screen.wait_for(lambda s: "Switch which entity" in s, 10, "the entity choice")
                screen.keys("3")  # 1 robot, 2 welder, 3 light_barrier
                screen.wait_for(lambda s: "light_barrier: which mode?" in s, 10, "the mode choice")
                screen.keys("Enter")  # the first: model
                screen.wait_for(lambda s: "Switch light_barrier to model mode?" in s, 10, "the confirmation")
                screen.keys("y")
                mode.wait_for("model", 10)  # the twin took it
                mode.close()
            screen.wait_for(lambda s: "light_barrier -> model: accepted" in s, 10, "the twin's answer")
            screen.wait_for(lambda s: _entity(s, "light_barrier")[1:2] == ["model"], 10, "the entity shown in model mode")
            emulator.stop(signal.SIGKILL)  # the physical cell goes: the shadowed robot's link goes stale
            screen.wait_for(lambda s: _entity(s, "robot")[1:3] == ["shadow", "STALE"], 10, "the robot's link STALE")
            twin.stop()  # the twin goes: shown as gone
            screen.wait_for(lambda s: "TWIN GONE" in s, 20, "the twin shown gone")
        finally:
            screen.stop()


def test_a_twin_mode_switch_asks_for_confirmation_and_no_cancels(welding_run):
    from cellsim.dashboard.app import Dashboard
    from cellsim.dashboard.feeds import ReplayFeed

    class Feed(ReplayFeed):
        requests: list = []

        def request_mode(self, entity: str, mode: str) -> dict:
            self.requests.append((entity, mode))
            return {"accepted": True, "reason": "taken"}

    async def drive() -> list:
        feed = Feed(welding_run, speed=1.0, start=5.0)
        app = Dashboard(feed)
        async with app.run_test(size=(120, 40)) as pilot:
            for answer in ("n", "y"):
                await pilot.press("m")
                await pilot.press("down", "enter")  # welder
                await pilot.press("down", "down", "enter")  # twin
                await pilot.pause()
                assert "Switch welder to twin mode?" in str(app.screen.query_one("Static").render())
                await pilot.press(answer)
                await app.workers.wait_for_complete()
                await pilot.pause()
        return feed.requests

    assert asyncio.run(drive()) == [("welder", "twin")]  # only the confirmed one was asked


def test_an_observers_dashboard_says_it_may_not_switch_modes_and_asks_nothing(welding_run):
    from textual.widgets import RichLog

    from cellsim.dashboard.app import Dashboard
    from cellsim.dashboard.feeds import ReplayFeed

    class Feed(ReplayFeed):
        may_switch = False  # as LiveFeed is with an observer's certificate
        requests: list = []

        def request_mode(self, entity: str, mode: str) -> dict:
            self.requests.append((entity, mode))
            return {"accepted": False, "reason": "no answer"}

    async def drive() -> tuple[list, str]:
        feed = Feed(welding_run, speed=1.0, start=5.0)
        app = Dashboard(feed)
        async with app.run_test(size=(120, 40)) as pilot:
            await pilot.pause()
            await pilot.press("m")
            await pilot.pause()
            events = "\n".join(str(line.text) for line in app.query_one("#events", RichLog).lines)
            no_choice = not any("Switch which entity" in str(w.render()) for w in app.screen.query("Static"))
        return feed.requests, events, no_choice

    requests, events, no_choice = asyncio.run(drive())
    assert requests == [] and no_choice
    assert "an observer may not switch twin modes: start the dashboard with --role engineer" in events


def test_malformed_messages_are_counted_never_fatal(welding_run):
    from cellsim.dashboard.feeds import LiveFeed
    from cellsim.dashboard.model import CellModel

    with BlackBox(welding_run / "blackbox.sqlite") as bb:
        model = CellModel.from_blackbox(bb)
    feed = LiveFeed(session=object(), cell="welding_cell")
    feed.model = model
    for key, payload in [
        ("cellsim/welding_cell/twin/robot/safety_mode", b"{not json"),
        ("cellsim/welding_cell/twin/robot/safety_mode", b'{"sim_time": 1.0, "value": "flying"}'),  # not a safety mode
        ("cellsim/welding_cell/twin/nobody/x", b'{"sim_time": 1.0, "value": 3}'),
        ("cellsim/welding_cell/twin/robot/safety_mode", b'{"sim_time": "soon", "value": "normal"}'),
        ("cellsim/welding_cell/status/twin", b"[1, 2]"),
        ("cellsim/welding_cell/diagnostics/light_barrier", b'{"level": "PURPLE"}'),
        ("cellsim/welding_cell/physical/robot", b"\xff\xfe"),
        ("cellsim/welding_cell/twin/robot/safety_mode", b'{"sim_time": 2.0, "value": "ssmon"}'),
        # a stale robot: its joints unknown (NaN, null in JSON), its physical link failed
        ("cellsim/welding_cell/twin/robot/joint_positions", b'{"sim_time": 2.5, "value": [null, null, null, null, null, null]}'),
        ("cellsim/welding_cell/physical/robot", b'{"t": 1.0, "seq": 3, "failed": "timeout"}'),
    ]:
        feed._inbox.append((key, payload))
    feed.drain()
    # (the malformed physical sample was followed by a newer one: only the newest is decoded)
    assert model.dropped == 6 and model.values["robot.safety_mode"] == "ssmon"
    robot = next(row for row in model.entity_rows() if row["entity"] == "robot")
    assert (robot["twin"], robot["physical"]) == ("-", "link stale (timeout)")
    assert model.hazard_rows() and model.conditions(force=True)


def test_the_bridge_daemons_diagnostics_set_an_entitys_link_level_and_are_logged(welding_run):
    from cellsim.dashboard.model import CellModel

    with BlackBox(welding_run / "blackbox.sqlite") as bb:
        model = CellModel.from_blackbox(bb)
    model.apply_channel("light_barrier.twin_mode", 1.0, "shadow")
    model.apply_channel("light_barrier.physical_link", 1.0, "ok")
    row = lambda: next(r for r in model.entity_rows() if r["entity"] == "light_barrier")  # noqa: E731
    assert row()["level"] == "OK"
    model.apply_diagnostics("light_barrier", {"level": "OK", "message": "trusted", "counts": {"crc": 0}})
    model.apply_diagnostics("light_barrier", {"level": "ERROR", "message": "failed: crc 1", "counts": {"crc": 1}})
    assert row()["level"] == "ERROR" and row()["diagnostics"] == "ERROR"  # the worse of the twin's and the daemon's
    assert model.events[-1].text == "light_barrier: link OK -> ERROR (failed: crc 1)"
    # (the audit's: a daemon gone, a twin gone, their last levels stood as fresh) no word for three of its periods:
    # its level is stale; the twin gone: the link it last saw is too
    now = [100.0]
    model.clock = lambda: now[0]
    model.apply_diagnostics("light_barrier", {"level": "OK", "message": "trusted", "counts": {}, "every_s": 1.0})
    now[0] += 2.9
    assert model.diagnostics_level("light_barrier") == "OK" and row()["level"] == "OK"
    now[0] += 0.2
    assert model.diagnostics_level("light_barrier") == "STALE" and row()["level"] == "STALE"
    model.apply_diagnostics("light_barrier", {"level": "OK", "message": "trusted", "counts": {}, "every_s": 1.0})
    assert row()["level"] == "OK"
    model.set_twin("gone")
    assert row()["level"] == "STALE"
    model.apply_diagnostics("robot", {"level": "OK", "counts": {}, "every_s": 1e9})  # a period no bridge can have
    now[0] += 181.0
    assert model.diagnostics_level("robot") == "STALE"


def test_a_twin_slower_than_its_scenario_assumes_is_shown_in_the_header_and_logged_once(welding_run):
    from cellsim.dashboard.model import CellModel

    with BlackBox(welding_run / "blackbox.sqlite") as bb:
        model = CellModel.from_blackbox(bb)
    reaction = {"slowest": {"light_barrier": 0.031, "robot": 0.024}, "assumed": {"light_barrier": 0.06}, "slower": []}
    model.apply_status({"sim_time": 3.0, "lag": 0.001, "reaction": reaction})
    assert model.reaction_text() == ("  reaction 31 ms", False)
    logged = model.event_count
    for t in (4.0, 5.0):  # said once, however many statuses repeat it
        model.apply_status({"sim_time": t, "reaction": {**reaction, "slowest": {"light_barrier": 0.21},
                                                         "slower": ["light_barrier"]}})
    assert model.reaction_text() == ("  reaction 210 ms (slower than assumed: light_barrier)", True)
    assert model.event_count == logged + 1 and model.events[-1].level == "ERROR"
    assert model.events[-1].text.startswith("light_barrier: the twin reacts to its samples slower than the 60 ms")
    model.apply_status({"sim_time": 6.0, "reaction": {"slower": "everyone"}})  # malformed: nothing more said
    assert model.event_count == logged + 1


def test_each_kind_says_what_the_dashboard_shows_of_it_and_a_kind_not_installed_shows_nothing():
    """The panels are asked of the kinds (ModuleKind.glance, .comparison), not written per kind."""
    import math

    import yaml

    from cellsim.dashboard.model import CellModel
    from cellsim.scenario import export_scenario, load_scenario

    scenario = yaml.safe_load(export_scenario(load_scenario(ROOT / "scenarios" / "welding_cell.yaml")))
    scenario["entities"]["door"] = {"kind": "guard_door"}  # a plug-in this machine does not have
    model = CellModel({"scenario": scenario, "channels": {}, "hazards": {}})
    model.values.update({"robot.safety_mode": "pflim", "robot.tool_speed": 0.25, "ground_truth.separation": 2e9,
                         "process_controller.cycles_completed": 3.0, "robot.joint_positions": [0.0] * 6})
    assert model.cell_rows()[:3] == [("robot safety mode", "pflim"), ("process step", "-"), ("cycles completed", "3")]
    assert model.robot_rows() == [("robot location", "-"), ("robot activity", "-"), ("robot tool speed", "0.250 m/s"),
                                  ("true separation", "far")]
    # the robot's comparison: its joints in degrees, differing beyond 20 degrees
    model.physical["robot"] = {"fields": {f"q{i}": (math.radians(25.0) if i == 2 else 0.0) for i in range(6)}}
    robot = next(row for row in model.entity_rows() if row["entity"] == "robot")
    assert (robot["twin"], robot["physical"], robot["diverges"]) == ("0 0 0 0 0 0 deg", "0 0 25 0 0 0 deg", True)
    door = next(row for row in model.entity_rows() if row["entity"] == "door")
    assert (door["kind"], door["twin"]) == ("guard_door", "-")


def test_a_refresh_that_fires_as_the_dashboard_closes_draws_nothing_and_raises_nothing(welding_run):
    """The refresh timer may fire while the app takes its screens down (the full suite saw it: NoMatches for the
    header, failing the app); with no views left to draw on, a refresh does nothing."""
    from cellsim.dashboard.app import Dashboard
    from cellsim.dashboard.feeds import ReplayFeed

    async def drive() -> tuple[str, Dashboard]:
        app = Dashboard(ReplayFeed(welding_run, speed=1.0, start=5.0))
        async with app.run_test(size=(120, 40)) as pilot:
            await pilot.pause()
            shown = str(app.query_one("#header").render())
        return shown, app

    shown, app = asyncio.run(drive())
    assert "welding_cell" in shown
    app.refresh_views()  # its screens are gone: as the timer's last tick finds them


def test_a_replay_shows_the_default_conditions_the_cell_is_judged_by(welding_run):
    """An audit found the dashboard compiled only the scenario's own conditions: NoHarm, NoClamping (and TrueSSM
    where a monitor is) never showed, live or replayed, though check judges every cell by them."""
    screen = TmuxScreen(["dashboard", "--replay", str(welding_run), "--start", "5", "--speed", "4"])
    try:
        screen.wait_for(lambda s: _row(s, "NoHarm")[1:3] == ["holds", "so"], 30, "NoHarm holding so far")
        screen.keys("c")  # every condition in full (the panel shows as many as fit)
        full = screen.wait_for(lambda s: "Safety conditions over the trace so far" in s, 10, "the conditions in full")
        assert "No robot pins a person's body region against something beyond its quasi-static limit" in " ".join(
            full.split())
    finally:
        screen.stop()


def test_a_replay_of_an_interrupted_run_ends_where_its_record_does(welding_run, tmp_path):
    """An audit found the replay played on to the planned duration (an interrupted 5000 s run to t = 5000 s, a killed
    twin started without --duration to a day): it ends where check and replay end the record."""
    import shutil
    import sqlite3

    from cellsim.dashboard.feeds import ReplayFeed

    copy = shutil.copytree(welding_run, tmp_path / "interrupted")
    db = sqlite3.connect(copy / "blackbox.sqlite")
    db.execute("UPDATE metadata SET value = '\"interrupted\"' WHERE key = 'status'")
    db.execute("INSERT OR REPLACE INTO metadata (key, value) VALUES ('recorded_until', '5.0')")
    db.commit()
    db.close()
    feed = ReplayFeed(copy)
    assert feed.end == 5.0 and not feed.complete
    assert ReplayFeed(welding_run).end == BlackBox(welding_run / "blackbox.sqlite").metadata()["duration"]


def test_a_twin_that_comes_back_is_a_new_run_its_description_asked_again(welding_run):
    """An audit restarted the twin under a running dashboard: its header stayed at the old run's last time, hazards
    read their old ages and every event was stamped 44.9 s. A twin that goes and comes back is a new run: the
    dashboard asks its description again and starts its values and times afresh, its log kept."""
    import threading
    import time
    from types import SimpleNamespace

    from cellsim import codec
    from cellsim.dashboard.feeds import LiveFeed
    from cellsim.dashboard.model import CellModel

    with BlackBox(welding_run / "blackbox.sqlite") as bb:
        first = CellModel.from_blackbox(bb)
    description = {"scenario": first.scenario, "channels": first.channels, "hazards": {}}
    asked = []

    class Session:  # what the feed asks of Zenoh: the description, subscribers that hold nothing yet
        def get(self, key, timeout=None, payload=None):
            asked.append(key)
            return [SimpleNamespace(ok=SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: codec.dumps(description))))]

        def declare_subscriber(self, key, handler):
            return SimpleNamespace(try_recv=lambda: None, undeclare=lambda: None)

        def liveliness(self):
            return SimpleNamespace(declare_subscriber=lambda key, callback, history=True: SimpleNamespace(undeclare=lambda: None))

    def model_of(feed):
        deadline = time.monotonic() + 30
        while feed.model is None:  # (found on the feed's own thread)
            assert time.monotonic() < deadline, "no model"
            threading.Event().wait(0.01)
        return feed.model

    feed = LiveFeed(Session(), cell="welding_cell")
    try:
        old = model_of(feed)
        old.apply_channel("light_barrier.broken", 44.9, True)
        assert old.sim_time == 44.9 and len(asked) == 1
        feed._alive.append(False)
        feed.drain()
        assert old.twin == "gone"
        feed._alive.append(True)  # its liveliness token again: a new run
        feed.drain()
        new = model_of(feed)
        assert new is not old and new.sim_time == 0.0 and new.twin == "running" and len(asked) == 2
        texts = [e.text for e in new.events]
        assert "the twin is gone" in texts and texts[-2].startswith("a new run of the twin")
    finally:
        feed.close()
