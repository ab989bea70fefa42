"""When the harm service looks, and what it assumes between two looks.

Between two looks only the robots may move: a person's body moves only at their updates, each
followed by a look one plant step later (a turn moves a hand half a metre in one update), and a
robot part seen faster than half ``max_part_speed`` at a look keeps the service measuring at every
plant step. A part seen faster than ``max_part_speed`` is a finding of the run.

The service's update is evaluated at chosen instants (``EvalUniquePeriodicDiscreteUpdate``: what
its event at that time would write), with the person and the arm put where the test wants them.
"""

from __future__ import annotations

import json
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
    (FAR, NEAR, FAST) and the part speed found at the end of an unwatched interval."""
    harm = built.modules["harm"]
    context.SetTime(t)
    own = harm.GetMyContextFromRoot(context)
    after = harm.EvalUniquePeriodicDiscreteUpdate(own)
    return {name: after.get_vector(harm.group(name)).GetAtIndex(0)
            for name in ("contact_region", "near", "unwatched_part_speed")}


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


def test_with_a_look_at_every_step_every_step_is_a_look():
    """far_period of one plant step: the schedule leaves no step out (the people's updates included)."""
    built = build_cell(load_scenario(CELL, ["harm.far_period=0.002"]), seed=0, duration=1.0, record=False)
    steps, looks = built.modules["harm"]._looks
    assert looks.all() and steps == round(built.modules["operator"].period / 0.002)


def test_a_fast_robot_part_switches_the_plant_step_measuring_on_until_a_look_finds_it_slow(slow_looks):
    """The person far away, the arm's tool driven at 3 m/s (above half of max_part_speed, 5 m/s): the look keeps
    the service at every plant step, and records the speed seen at the end of the unwatched interval, no slower
    than the tool's; at 1 m/s it does not. Between looks the fast state holds, with nobody near."""
    built, context = slow_looks
    harm = built.modules["harm"]
    own = harm.GetMyMutableContextFromRoot(context)
    stand(built, context, -2.0, 2.0, 0.0)
    tool = built.plant.GetBodyByName("tool0", built.robots["robot"]).index()
    for speed, state in ((3.0, FAST), (1.0, FAR)):
        drive(built, context, tool, np.array([0.0, speed, 0.0]))
        after = update_at(built, context, 0.042)
        assert after["near"] == state, f"at {speed} m/s"
        assert speed <= after["unwatched_part_speed"] <= 3.0 * speed, "the bound misses the tool's speed, or is loose"
    # the event says it wrote: Drake keeps a written speed only from an update that did not return DidNothing
    drive(built, context, tool, np.array([0.0, 1.0, 0.0]))
    xd = own.get_discrete_state().Clone()
    context.SetTime(0.042)
    status = harm._on_update(own, xd)
    assert (status is None or not status.did_nothing()) and xd.get_vector(harm.group("unwatched_part_speed"))[0] >= 1.0
    # a step between looks, in the fast state, nobody near: still fast (measured at every step until a look)
    own.get_mutable_discrete_state(harm.group("near")).SetAtIndex(0, FAST)
    assert update_at(built, context, 0.044)["near"] == FAST
    # and a touch at such a step is measured, in the fast state as in the near one
    hand_on_the_arm(built, context)
    for state in (FAST, NEAR):
        own.get_mutable_discrete_state(harm.group("near")).SetAtIndex(0, state)
        assert update_at(built, context, 0.044)["contact_region"] != 0


def test_a_part_that_outruns_the_looks_is_a_finding_of_the_run(tmp_path):
    """Through the CLI, the machine-tending cell looked at every 0.1 s with max_part_speed 0.6 m/s: its arm, which
    reaches full speed (about 1 m/s) in 0.5 s, never gains 0.3 m/s between two looks, so nothing is found; made to
    reach it in 0.01 s, a look after an unwatched interval finds it above 0.6 m/s, and the summary says a contact
    may have been missed there."""
    def run(name, *overrides):
        out = tmp_path / name
        done = subprocess.run([sys.executable, "-m", "cellsim", "simulate", str(CELL), "--out", str(out), "--duration",
                               "8", "--set", "harm.max_part_speed=0.6", "--set", "harm.far_period=0.1",
                               *(a for o in overrides for a in ("--set", o))],
                              capture_output=True, text=True, timeout=600, env=WIDE)
        assert done.returncode in (0, 1), done.stderr
        return done.stdout, out

    gentle, _ = run("gentle")
    assert "fast part" not in gentle
    sudden, out = run("sudden", "robot.braking_time=0.01")
    assert "fast part" in sudden and "above the 0.6 m/s it assumes there" in sudden
    db = sqlite3.connect(out / "blackbox.sqlite")
    speeds = [json.loads(p)["value"] for (p,) in db.execute(
        "SELECT payload FROM messages WHERE channel = 'harm.unwatched_part_speed' ORDER BY t")]
    db.close()
    assert max(speeds) > 0.6, "the speed found after an unwatched interval is recorded"


@pytest.mark.parametrize("shape", ["Mesh", "Convex"])
def test_a_mesh_is_bounded_by_its_hull_so_a_part_made_of_one_has_a_finite_speed(tmp_path, shape):
    """A robot part whose collision shape is a mesh (as in most published arm models): its sphere holds every vertex
    of the scaled mesh, offset and rotated as it is fixed to its body, and is no larger than it must be."""
    from pydrake.geometry import Convex, Mesh
    from pydrake.math import RigidTransform, RollPitchYaw

    from cellsim.proximity import bounding_sphere

    corners = np.array([[x, y, z] for x in (-0.05, 0.15) for y in (-0.02, 0.02) for z in (0.0, 0.3)])
    obj = tmp_path / "link.obj"
    faces = "f 1 2 4 3\nf 5 7 8 6\nf 1 5 6 2\nf 3 4 8 7\nf 1 3 7 5\nf 2 6 8 4\n"
    obj.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in corners) + faces)
    pose = RigidTransform(RollPitchYaw(0.3, -0.2, 1.0), [0.1, -0.4, 0.25])
    made = (Mesh if shape == "Mesh" else Convex)(str(obj), 2.0)
    centre, radius = bounding_sphere(made, pose)
    placed = np.array([pose @ (2.0 * c) for c in corners])
    distances = np.linalg.norm(placed - centre, axis=1)
    assert math.isfinite(radius) and distances.max() <= radius + 1e-9
    assert radius <= 1.01 * 0.5 * np.linalg.norm(2.0 * (corners.max(axis=0) - corners.min(axis=0)))
