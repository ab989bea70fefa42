"""A robot's moves and a process's dwells refined where a witness is faster than the cell (issue 36, item 2): each
kind says, from the witness alone, where it departs from the cell, and the loop refines where it departs first."""

from __future__ import annotations

import pytest

from cellsim.scenario import load_scenario
from cellsim.verify.refine import _offer
from cellsim.verify.run import abstract_model

from conftest import WELDING_CELL


@pytest.fixture(scope="module")
def welding():
    return abstract_model(load_scenario(WELDING_CELL))


def _part(model, name: str):
    return next(p for p in model.parts if getattr(p, "name", None) == name)


def _still(model, steps: int) -> list[dict]:
    """A witness of ``steps`` states in which nothing moves: the robot at rest at home, the process at its first
    step, the operator at its start."""
    person = model.cell.places.people[0]
    return [{"robot_segment": 0, "robot_region": 0, "process_controller_step": 0, "process_controller_request": -1,
             person.variable: person.start} for _ in range(steps)]


def test_a_dwell_left_sooner_than_its_seconds_is_refined_to_count_them(welding):
    """'pick' dwells 0.5 s: 13 of the process's 0.04 s updates. A witness leaving it after one is refined."""
    process = _part(welding, "process_controller")
    witness = _still(welding, 12)
    for k in range(4, 12):
        witness[k]["process_controller_step"] = 1 if k < 6 else 2  # pick at steps 4-5: one update (step 4)
    key, why, step = process.refinement(welding.cell, witness)
    assert key == "process_controller:timed" and step == 6  # the first state the cell cannot be in
    assert "leaves step 'pick' after 1 of its updates" in why and "at least 13 (0.52 s)" in why
    # as long as its seconds take: nothing to refine
    slow = _still(welding, 40)
    for k in range(4, 40):
        slow[k]["process_controller_step"] = 1 if k < 30 else 2  # 13 updates (4, 6, ..., 28)
    assert process.refinement(welding.cell, slow) is None
    # left by a restart (the controller's request), not by its end: nothing to refine either
    restarted = [dict(s) for s in witness]
    for k in range(6, 12):
        restarted[k]["process_controller_request"] = next(iter(process.system.restart), 0)
    if process.system.restart:
        assert process.refinement(welding.cell, restarted) is None


def test_a_move_through_a_region_faster_than_full_speed_is_refined_to_bound_it(welding):
    robot = _part(welding, "robot")
    moves = robot._moves(welding.cell.period, True)
    pairs = list(moves)
    segment = len(robot.system.poses) + pairs.index((0, 1))  # home -> shared_table
    least = moves[(0, 1)][0][1]
    witness = _still(welding, 8)
    for k in range(2, 8):
        witness[k].update(robot_segment=segment, robot_region=0 if k < 4 else 1)  # region 0 at steps 2-3
    key, why, step = robot.refinement(welding.cell, witness)
    assert key == "robot:timed" and step == 4
    assert f"region 0 of its move home -> shared_table in 2 update(s)" in why and f"at least {least + 1}" in why
    # refined, the robot has no more to say
    refined = abstract_model(load_scenario(WELDING_CELL), refinements=frozenset({"robot:timed"}))
    assert _part(refined, "robot").refinement(refined.cell, witness) is None
    assert any("robot's tool is located on the commanded path" in a and "at least their time at full speed" in a
               for a in refined.cell.assumptions)


def test_the_loop_refines_where_the_witness_departs_from_the_cell_first(welding):
    """The operator leaves its start place at step 7, sooner than it can walk across it; the robot leaves a region
    at step 4, sooner than full speed allows: the robot's refinement comes first. With the robot at rest, the
    operator's."""
    robot, person = _part(welding, "robot"), welding.cell.places.people[0]
    segment = len(robot.system.poses) + list(robot._moves(welding.cell.period, True)).index((0, 1))
    neighbour = next(iter(person.neighbours[person.start]))
    witness = _still(welding, 10)
    for k in range(2, 10):
        witness[k].update(robot_segment=segment, robot_region=0 if k < 4 else 1)
    for k in range(7, 10):
        witness[k][person.variable] = neighbour
    key, _ = _offer(welding, witness)
    assert key == "robot:timed"
    for k in range(2, 10):
        witness[k].update(robot_segment=0, robot_region=0)
    key, _ = _offer(welding, witness)
    assert key == "operator:pace"
