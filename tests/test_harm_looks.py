"""When the harm service looks, and what it assumes between two looks.

Between two looks only the robots may move: a person's body moves only at their updates, each
followed by a look one plant step later (a turn moves a hand half a metre in one update), and a
robot part seen faster than half ``max_part_speed`` at a look keeps the service measuring at every
plant step. A part seen faster than ``max_part_speed`` is a finding of the run.

The service's update is evaluated at chosen instants (``EvalUniquePeriodicDiscreteUpdate``: what
its event at that time would write), with the person and the arm put where the test wants them.
"""

from __future__ import annotations

import math
import os
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from cellsim.diagrams.cell import build_cell
from cellsim.kinds.harm.system import FAR, FAST, NEAR
from cellsim.scenario import load_scenario
from test_harm import CELL, drive, region_geometry, stand, touch

ROOT = Path(__file__).resolve().parents[1]
WIDE = {**os.environ, "COLUMNS": "300"}  # the summary's table on one line per row


def built_cell(overrides):
    built = build_cell(load_scenario(CELL, overrides), seed=0, duration=1.0, record=False)
    simulator = Simulator(built.diagram)
    built.set_initial_state(simulator.get_mutable_context())
    return built, simulator.get_mutable_context()


@pytest.fixture(scope="module")
def slow_looks():
    """The machine-tending cell looked at only every 0.1 s (its person is updated every 0.04 s)."""
    built, context = built_cell(["harm.far_period=0.1"])
    assert built.modules["operator"].period == pytest.approx(0.04)
    return built, context


def update_at(built, context, t: float) -> dict:
    """What the harm service's event at time ``t`` writes: the worst contact's region (its code: 0, none), the state
    (FAR, NEAR, FAST) and the fastest part speed."""
    harm = built.modules["harm"]
    context.SetTime(t)
    own = harm.GetMyContextFromRoot(context)
    after = harm.EvalUniquePeriodicDiscreteUpdate(own)
    return {name: after.get_vector(harm.group(name)).GetAtIndex(0)
            for name in ("contact_region", "near", "fastest_part_speed")}


def hand_on_the_arm(built, context) -> None:
    """The person standing still beside the bench, their right hand just touched by the still tool."""
    stand(built, context, 0.3, -1.15, math.pi / 2, reach=(0.3, -0.45, 1.05))
    hand, query = region_geometry(built, context, "hand", "right")
    centre = query.GetPoseInWorld(hand).translation()
    touch(built, context, hand, centre + (0.0, 0.0, 0.25), centre)
    harm = built.modules["harm"]
    harm.GetMyMutableContextFromRoot(context).get_mutable_discrete_state(harm.group("near")).SetAtIndex(0, FAR)


def test_a_person_s_update_is_looked_at_one_plant_step_later_whatever_far_period(slow_looks):
    """A hand that reached the arm at the person's update at 0.04 s is measured at 0.042 s, not at the far look
    0.1 s later; at the update itself (Drake's events at one time read the state before any) and at steps between
    looks, nothing is looked at."""
    built, context = slow_looks
    hand_on_the_arm(built, context)
    assert update_at(built, context, 0.042)["contact_region"] != 0, "the person's update at 0.04 s was not looked at"
    assert update_at(built, context, 0.102)["contact_region"] != 0  # the far look, one step after its multiple
    for t in (0.040, 0.044, 0.070, 0.100):
        assert update_at(built, context, t)["contact_region"] == 0, f"a look at {t} s"


def test_a_fast_robot_part_switches_the_plant_step_measuring_on_and_is_the_fastest_seen(slow_looks):
    """The person far away, the arm's tool driven at 3 m/s (above half of max_part_speed, 5 m/s): the look keeps
    the service at every plant step, and records a part speed no slower than the tool's. At 1 m/s it does not."""
    built, context = slow_looks
    stand(built, context, -2.0, 2.0, 0.0)
    plant = built.plant
    tool = plant.GetBodyByName("tool0", built.robots["robot"]).index()
    for speed, state in ((3.0, FAST), (1.0, FAR)):
        drive(built, context, tool, np.array([0.0, speed, 0.0]))
        after = update_at(built, context, 0.042)
        assert after["near"] == state, f"at {speed} m/s"
        assert speed <= after["fastest_part_speed"] <= 3.0 * speed, "the bound misses the tool's speed, or is loose"
    # measuring at every step while fast: a non-look step with the state FAST still measures (a touch)
    harm = built.modules["harm"]
    hand_on_the_arm(built, context)
    own = harm.GetMyMutableContextFromRoot(context)
    own.get_mutable_discrete_state(harm.group("near")).SetAtIndex(0, FAST)
    assert update_at(built, context, 0.044)["contact_region"] != 0
    own.get_mutable_discrete_state(harm.group("near")).SetAtIndex(0, NEAR)
    assert update_at(built, context, 0.044)["contact_region"] != 0


def test_a_part_faster_than_assumed_is_a_finding_of_the_run(tmp_path):
    """Through the CLI: with max_part_speed below what the machine-tending arm moves at (about 1 m/s), the summary
    says a contact between looks may have been missed; at the default it says nothing of it."""
    out = tmp_path / "run"
    done = subprocess.run([sys.executable, "-m", "cellsim", "simulate", str(CELL), "--out", str(out), "--duration", "8",
                           "--set", "harm.max_part_speed=0.6"], capture_output=True, text=True, timeout=600, env=WIDE)
    assert done.returncode in (0, 1), done.stderr
    assert "fast part" in done.stdout and "above the 0.6 m/s the harm service assumes" in done.stdout
    db = sqlite3.connect(out / "blackbox.sqlite")
    (count,) = db.execute("SELECT count(*) FROM messages WHERE channel = 'harm.fastest_part_speed'").fetchone()
    db.close()
    assert count >= 2, "the fastest part speed is recorded as it rises"
    default = subprocess.run([sys.executable, "-m", "cellsim", "simulate", str(CELL), "--out", str(tmp_path / "d"),
                              "--duration", "8"], capture_output=True, text=True, timeout=600, env=WIDE)
    assert default.returncode in (0, 1), default.stderr
    assert "fast part" not in default.stdout
