"""The generic process controller: robot moves and dwells, machine cycles started and awaited."""

from __future__ import annotations

import pytest

from cellsim.config.typed_yaml import ConfigError
from cellsim.scenario import load_scenario
from cellsim.services.blackbox import BlackBox
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
         "behaviours.process_controller.steps.2.name", "exactly one of move_to, dwell, start, wait_for, operate"),
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
