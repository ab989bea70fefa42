"""A robot's moves and a process's dwells refined where a witness is faster than the cell (issue 36, item 2): each
kind says, from the witness alone, where it departs from the cell, and the loop refines where it departs first."""

from __future__ import annotations

import pytest

from cellsim.scenario import load_scenario
from cellsim.verify.refine import _offers
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
    bring_back = next(code for code, index in process.system.restart.items() if index == 4)
    restarted = [dict(s) for s in witness]
    for k in range(6, 12):
        restarted[k].update(process_controller_step=4, process_controller_request=bring_back)
    assert process.refinement(welding.cell, restarted) is None


@pytest.mark.parametrize("entered", ["in turn", "by a restart"])
def test_a_step_entered_by_a_restart_takes_its_first_update_in_the_one_that_enters_it(welding, entered):
    """'weld' operates the welder 2 s: 50 of the process's 0.04 s updates. Entered by the controller's request
    (restart_on_request: welding), the update that enters it is its first, as in the twin's process: 49 more
    may end it; entered in turn from 'carry', it takes 50 of its own."""
    process = _part(welding, "process_controller")
    welding_code = next(code for code, index in process.system.restart.items() if index == 3)
    request = welding_code if entered == "by a restart" else -1

    def witness(updates: int) -> list[dict]:
        states = _still(welding, 4)
        for state in states:
            state["process_controller_step"] = 2  # carry
        last = 4 + 2 * (updates - 1)  # updates at the even steps 4, 6, ..., last
        states += [dict(states[0], process_controller_step=3, process_controller_request=request)
                   for _ in range(4, last + 1)]
        return states + [dict(states[-1], process_controller_step=4)]  # on to bring_back

    enough = 49 if entered == "by a restart" else 50
    assert process.refinement(welding.cell, witness(enough)) is None
    key, why, _ = process.refinement(welding.cell, witness(enough - 1))
    assert key == "process_controller:timed" and f"its operation takes at least {enough} " in why


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
    (key, _), *_ = _offers(welding, witness)
    assert key == "robot:timed"
    for k in range(2, 10):
        witness[k].update(robot_segment=0, robot_region=0)
    (key, _), *_ = _offers(welding, witness)
    assert key == "operator:pace"


def test_the_timed_robot_asks_no_more_of_a_region_than_the_twin_spends_there(tmp_path, welding):
    """Soundness of ``<robot>:timed``: in a twin run of the welding cell, every region the tool passes through on a
    move (neither the one it leaves nor the one it arrives in, where it also rests) lasts at least the robot updates
    the timed model asks for there (its least periods, plus the update that leaves)."""
    import json
    import sqlite3

    from cellsim.simulation import simulate

    sf = load_scenario(WELDING_CELL)
    simulate(sf, tmp_path / "run", seed=0)
    with sqlite3.connect(tmp_path / "run" / "blackbox.sqlite") as db:  # read back with plain SQL
        rows = db.execute("SELECT t, channel, payload FROM messages WHERE channel IN ('robot.location', "
                          "'robot.reached_pose') ORDER BY t, channel").fetchall()
    robot = _part(welding, "robot")
    period = welding.cell.period * welding.cell.every("robot")
    table = robot._moves(period, True)
    names = robot.system.pose_names
    location, reached, move, compared = None, None, None, 0
    for t, channel, payload in rows:
        value = json.loads(payload)["value"]
        if channel == "robot.reached_pose":
            if reached not in (None, "moving") and value == "moving":
                move = (names.index(reached), t, [(location, t)])  # (from, since, [(location, since)])
            elif move is not None and value != "moving":
                goal = names.index(value)
                runs = move[2]
                middle = [(loc, since, until) for (loc, since), (_, until) in zip(runs, runs[1:])][1:]
                expected = [(robot.system.locations(loc).code if loc else None) for loc, _, _ in middle]
                regions = table[(move[0], goal)][1:-1]
                if expected == [code for code, _ in regions]:
                    for (loc, since, until), (_, least) in zip(middle, regions):
                        assert round((until - since) / period) >= least + 1, (names[move[0]], value, loc, since)
                        compared += 1
                move = None
            reached = value
        else:
            location = value
            if move is not None:
                move[2].append((value, t))
    assert compared >= 3  # the welding cell's moves cross regions between their ends
