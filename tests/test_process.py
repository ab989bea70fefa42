"""The generic process controller: robot moves and dwells, machine cycles started and awaited."""

from __future__ import annotations

import pytest

from cellsim.config.typed_yaml import ConfigError
from cellsim.scenario import load_scenario
from cellsim.blackbox import BlackBox
from cellsim.simulation import simulate

from conftest import WELDING_CELL, values_between

PRESS_CELL = """\
base: {base}
name: press_cell
entities:
  robot:
    activities: [waiting, loading, down]
  welder: !replace
    kind: machine
    activities: [open, pressing, off]
    rest: open
    working: pressing
    cycle_time: {cycle}
behaviours: !replace
  process_controller:
    kind: process
    steps:
      - {{name: load, move_to: weld_spot, activity: loading}}
      - {{name: stroke, start: welder, activity: waiting}}
      - {{name: away, move_to: shared_table, activity: waiting}}
      - {{name: wait, wait_for: welder, activity: waiting}}
      - {{name: fetch, move_to: home, activity: loading}}
validation: !replace {{}}
"""


def press_cell(tmp_path, cycle: float = 3.0, **edits) -> str:
    text = PRESS_CELL.format(base=WELDING_CELL, cycle=cycle)
    for old, new in edits.items():
        assert old in text
        text = text.replace(old, new)
    path = tmp_path / "press_cell.yaml"
    path.write_text(text)
    return path


def test_a_machine_cycle_runs_in_parallel_with_the_robot_and_the_process_waits_for_it(tmp_path):
    simulate(load_scenario(press_cell(tmp_path)), tmp_path / "run", duration=30.0)
    with BlackBox(tmp_path / "run" / "blackbox.sqlite") as bb:
        press, step = bb.series("welder.activity"), bb.series("process_controller.step")
        speed = bb.series("robot.tool_speed")
        done = bb.series("process_controller.cycles_completed")
    start = next(t for t, v in zip(press.times, press.values) if v == "pressing")
    end = next(t for t, v in zip(press.times, press.values) if t > start and v == "open")
    assert end - start == pytest.approx(3.0, abs=0.05)
    # while the press strokes, the robot moves away: the two happen at once
    moving = [t for t, v in zip(speed.times, speed.values) if start < t < end and v > 0.05]
    assert moving
    # the process waits for the stroke: 'fetch' only after the press is open again
    fetch = next(t for t, v in zip(step.times, step.values) if t > start and v == "fetch")
    assert fetch >= end - 0.05 and "wait" in values_between(step, start, fetch)
    assert done.values[-1] >= 2


@pytest.mark.parametrize(
    "edits, key, expected",
    [
        ({"start: welder": "start: pres"}, "behaviours.process_controller.steps.1.start", "no machine entity named 'pres'"),
        ({"cycle_time: 3.0": "cycle_time: 0"}, "behaviours.process_controller.steps.1.start", "has no cycle_time"),
        ({"activity: waiting}\n      - {name: away": "activity: resting}\n      - {name: away"},
         "behaviours.process_controller.steps.1.activity", "'resting' is not an activity of robot"),
        ({"{name: away, move_to: shared_table,": "{name: away, move_to: shared_table, dwell: 1.0,"},
         "behaviours.process_controller.steps.2.name", "exactly one of move_to, dwell, start, wait_for, wait_until, operate"),
        ({"{name: stroke, start: welder,": "{name: stroke, operate: {machine: welder, seconds: 2.0},"},
         "behaviours.process_controller.steps.1.operate.machine", "runs cycles: start it and wait_for it"),
        ({"{name: stroke, start: welder,": "{name: stroke, operate: {machine: weldr, seconds: 2.0},"},
         "behaviours.process_controller.steps.1.operate.machine", "no machine entity named 'weldr'"),
    ],
)
def test_process_steps_are_checked_at_load_time(tmp_path, edits, key, expected):
    with pytest.raises(ConfigError) as e:
        load_scenario(press_cell(tmp_path, **edits))
    assert e.value.key == key and expected in e.value.problem


def test_a_start_is_held_until_a_slower_machine_acknowledges_it(tmp_path):
    """A one-update pulse from a 20 ms process was missed by a machine looking every 200 ms."""
    path = press_cell(tmp_path, **{"    cycle_time: 3.0\n": "    cycle_time: 3.0\n    period: 0.2\n",
                                   "    kind: process\n": "    kind: process\n    period: 0.02\n"})
    simulate(load_scenario(path), tmp_path / "run", duration=30.0)
    with BlackBox(tmp_path / "run" / "blackbox.sqlite") as bb:
        strokes = bb.series("welder.cycles_completed").values[-1]
        done = bb.series("process_controller.cycles_completed").values[-1]
    assert strokes >= 2 and done >= strokes - 1


SECOND_ROBOT = """\
base: {base}
name: two_processes
entities:
  robot2:
    kind: robot
    model: {model}
    base_position: [0.0, 1.5, 0.75]
    tool_frame: tcp
    activities: [waiting, tending]
    named_poses:
      home: [0.0, -1.57, 1.57, -1.57, -1.57, 0.0]
      up: [0.5, -1.2, 1.2, -1.57, -1.57, 0.0]
    initial_pose: home
    twin: {{mode: model}}
behaviours:
  unloader:
    kind: process
    robot: robot2
    steps:
      - {{name: await_press, {verb}: press, activity: waiting}}
      - {{name: reach, move_to: up, activity: tending}}
      - {{name: back, move_to: home, activity: tending}}
"""


def second_robot(tmp_path, verb: str = "wait_for", robot: str = "robot2"):
    from conftest import ROOT

    text = SECOND_ROBOT.format(base=ROOT / "scenarios" / "palletising_cell.yaml", verb=verb,
                               model=ROOT / "scenarios" / "models" / "ur10.urdf")
    path = tmp_path / "two_processes.yaml"
    path.write_text(text.replace("robot: robot2", f"robot: {robot}"))
    return path


def test_a_second_process_may_wait_for_a_machine_another_starts(tmp_path):
    """Issue 23: one process starting the press and another waiting for its cycle crashed in Drake
    (ThrowIfInputAlreadyWired); waiting reads the machine's busy, it does not drive it."""
    simulate(load_scenario(second_robot(tmp_path)), tmp_path / "run", duration=20.0)
    with BlackBox(tmp_path / "run" / "blackbox.sqlite") as bb:
        press, unloader = bb.series("press.activity"), bb.series("unloader.step")
        strokes = bb.series("press.cycles_completed").values[-1]
    assert strokes >= 1  # the palletising process still drives the press
    stroke = next(t for t, v in zip(press.times, press.values) if v == "pressing")
    opened = next(t for t, v in zip(press.times, press.values) if t > stroke and v == "open")
    reach = next(t for t, v in zip(unloader.times, unloader.values) if t > stroke and v == "reach")
    assert reach >= opened - 0.05  # the second robot waited for the stroke to end


@pytest.mark.parametrize("verb, robot, key, expected", [
    ("start", "robot2", "behaviours.unloader.steps.0.start",
     "machine 'press' is already driven by process 'process_controller' ({base}, line {line}, "
     "behaviours.process_controller.steps.8.start)"),
    ("wait_for", "robot", "behaviours.unloader.robot",
     "robot 'robot' is already moved by process 'process_controller' ({base}, line {robot_line})"),
])
def test_a_machine_or_robot_driven_by_two_processes_is_a_load_error_naming_both_places(tmp_path, verb, robot, key,
                                                                                        expected):
    import subprocess
    import sys

    from conftest import ROOT

    base = ROOT / "scenarios" / "palletising_cell.yaml"
    lines = base.read_text().splitlines()
    line = next(i for i, text in enumerate(lines, 1) if "{name: stroke, start: press" in text)
    robot_line = next(i for i, text in enumerate(lines, 1) if text.strip() == "robot: robot")
    path = second_robot(tmp_path, verb, robot)
    with pytest.raises(ConfigError) as e:
        load_scenario(path)
    assert e.value.key == key and expected.format(base=base, line=line, robot_line=robot_line) in e.value.problem
    proc = subprocess.run([sys.executable, "-m", "cellsim", "simulate", str(path), "--out", str(tmp_path / "run")],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1 and f"{path}:" in proc.stderr
    assert not (tmp_path / "run").exists()


def _until(tmp_path, condition: str):
    """The second robot's process waits until ``condition`` instead of the press's cycle."""
    path = second_robot(tmp_path)
    text = path.read_text().replace("{name: await_press, wait_for: press, activity: waiting}",
                                    f"{{name: await_arm, wait_until: '{condition}', activity: waiting}}")
    assert "await_arm" in text
    path.write_text(text)
    return path


def test_a_process_waits_until_a_condition_over_another_robots_channels_holds(tmp_path):
    """Issue 23: a hand-over: robot2 moves only once the first robot rests at its pallet pose and
    the press is pressing is not required (an or): it leaves the wait the period after it holds."""
    path = _until(tmp_path, "robot.reached_pose == pallet_place and (press.busy or not press.busy)")
    simulate(load_scenario(path), tmp_path / "run", duration=25.0)
    with BlackBox(tmp_path / "run" / "blackbox.sqlite") as bb:
        pose, unloader = bb.series("robot.reached_pose"), bb.series("unloader.step")
    at_pallet = [t for t, v in zip(pose.times, pose.values) if v == "pallet_place"]
    reaches = [t for t, v in zip(unloader.times, unloader.values) if v == "reach"]
    assert at_pallet and reaches, (pose.values, unloader.values)
    assert 0.0 <= reaches[0] - at_pallet[0] <= 0.04 + 1e-9  # within one process period of the condition
    assert unloader.values[0] == "await_arm" and unloader.times[1] == reaches[0]  # it waited until then


@pytest.mark.parametrize("condition, problem", [
    ("robot.reached_pose == pallet", "column 23 of the condition: 'pallet' is not a value of robot.reached_pose "
                                     "(moving, home, infeed_pick"),
    ("robott.reached_pose == home", "column 1 of the condition: unknown variable or macro 'robott.reached_pose' "
                                    "(did you mean 'robot.reached_pose'?)"),
    ("F robot.busy", "column 1 of the condition: temporal operator 'F' is not allowed here"),
])
def test_a_bad_wait_until_condition_is_one_error_at_its_key(tmp_path, condition, problem):
    import subprocess
    import sys

    from conftest import ROOT

    path = _until(tmp_path, condition)
    done = subprocess.run([sys.executable, "-m", "cellsim", "scenario", "check", str(path)], capture_output=True,
                          text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    line = next(i for i, text in enumerate(path.read_text().splitlines(), 1) if "await_arm" in text)
    assert f"{path}:{line}" in done.stderr and "behaviours.unloader.steps.0.wait_until" in done.stderr
    assert problem in done.stderr, done.stderr


def test_verify_translates_a_wait_until_exactly_as_the_wait_it_restates(tmp_path):
    """``wait_until: not welder.busy`` is ``wait_for: welder`` said another way: the abstract models
    have the same states and every property the same value."""
    import json
    import subprocess
    import sys

    results = []
    checked = {"validation: !replace {}": "validation: !replace {conditions: {never_fetching_while_pressing: "
               "'G(not (welder.activity == pressing and process_controller.step == fetch))'}, "
               "waive: {NoHarm: not this test's, NoClamping: not this test's}}"}
    for label, edits in (("wait_for", checked),
                         ("wait_until", {**checked, "wait_for: welder,": "wait_until: 'not welder.busy',"})):
        (tmp_path / label).mkdir()
        path = press_cell(tmp_path / label, **edits)
        done = subprocess.run([sys.executable, "-m", "cellsim", "verify", str(path), "--json", "--no-replay",
                               "--out", str(tmp_path / label / "out")], capture_output=True, text=True, timeout=600)
        assert done.returncode in (0, 1), done.stderr
        results.append(json.loads(done.stdout))
    waiting, until = results
    assert until["states"] == waiting["states"] > 0
    assert [(p["name"], p["value"]) for p in until["properties"]] == [(p["name"], p["value"]) for p in waiting["properties"]]
    assert [p["name"] for p in until["properties"]] == ["never_fetching_while_pressing"] and until["holds"]


def test_verify_with_nothing_to_check_says_so_in_one_line(tmp_path):
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "cellsim", "verify", str(press_cell(tmp_path)), "--no-replay"],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 2 and "nothing to verify: no safety controller's hazards" in done.stderr
    assert "Traceback" not in done.stderr
