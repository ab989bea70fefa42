"""Time as the cell has it (issue 36): in the abstract model every module updates at its own period on the
controller's grid, and a sensor's readings are state taken at its period, so a person's move reaches the controller
as late as it does in the twin. Checked with stormpy on the exported model, against the twin's own record."""

from __future__ import annotations

import pytest
import stormpy

from cellsim.scenario import load_scenario
from cellsim.verify.run import abstract_model, write_export
from cellsim.verify.storm import _initial_value, _valuation_of

from conftest import WELDING_CELL


LOOKS = {  # labels of the places and readings the tests look at (PRISM formulas of the model)
    "in_beams": "light_barrier__broken__of_operator",
    "beams_read": "light_barrier__broken_read",
    "close": "range_detector__range__of_operator={close}",
    "close_read": "range_detector__range_read={close}",
}


@pytest.fixture(scope="module")
def welding(tmp_path_factory):
    """The welding cell's abstract model, exported with the tests' labels and built state by state by stormpy with
    its states' valuations."""
    model = abstract_model(load_scenario(WELDING_CELL))
    path, _ = write_export(model, tmp_path_factory.mktemp("time") / "welding.prism")
    close = model.cell.encoding("range_detector.range").code("close")
    path.write_text(path.read_text() + "".join(f'label "{k}" = {v.format(close=close)};\n' for k, v in LOOKS.items()))
    program = stormpy.parse_prism_program(str(path))
    options = stormpy.BuilderOptions(build_full=True)
    options.set_build_state_valuations(True)
    return model, program, stormpy.build_model(program, options=options)


def _soonest(program, built, label: str) -> float:
    """The fewest steps (the model's "periods" reward) to a state labelled ``label``."""
    formula = stormpy.parse_properties(f'R{{"periods"}}min=? [ F "{label}" ]', program)[0]
    return _initial_value(stormpy, built, formula)


def test_a_sensor_of_twice_the_step_reads_the_person_a_sensor_period_after_it_moved(welding):
    """The operator and the light curtain update every 0.04 s, the controller every 0.02 s (one step): the person
    enters the beams at an update (the state after step 2j), the curtain takes that at its next update two steps
    later, and the controller reads it the step after. Before, the curtain's reading was the person's place itself:
    the same step."""
    model, program, built = welding
    cell = model.cell
    assert cell.every("light_barrier") == cell.every("operator") == 2 and cell.every("safety_controller") == 1
    in_beams = _soonest(program, built, "in_beams")  # the person is where it breaks them
    read = _soonest(program, built, "beams_read")  # the curtain's reading says so
    assert in_beams % 2 == 1  # the person moves at even steps: its new place is in the state after one
    assert read - in_beams == 2
    # the range detector's reading lags the same way behind the place that makes it read "close"
    assert _soonest(program, built, "close_read") - _soonest(program, built, "close") == 2


def test_a_module_of_twice_the_step_keeps_its_state_at_the_odd_steps(welding):
    """Every transition from an odd step leaves the 0.04 s modules' variables (the welder, the process, the person,
    the sensors' readings) as they were, and the 0.02 s robot and controller still move there."""
    model, program, built = welding
    slower = {v.name for m in model.cell.modules if m.name in ("welder", "process_controller", "operator_floor",
                                                               "light_barrier_reading", "range_detector_reading")
              for v in m.variables}
    faster = {v.name for m in model.cell.modules if m.name.startswith(("robot_", "hazard_")) for v in m.variables}
    assert slower and faster
    of = _valuation_of(built, None)  # (as verify reads a witness's states)
    valuation = [of(s) for s in range(built.nr_states)]
    moved_fast, checked = False, 0
    for state in built.states:
        if valuation[state.id]["tick"] != 1:
            continue
        for action in state.actions:
            for entry in action.transitions:
                after = valuation[entry.column]
                assert all(after[v] == valuation[state.id][v] for v in slower), (valuation[state.id], after)
                moved_fast |= any(after[v] != valuation[state.id][v] for v in faster)
                checked += 1
    assert checked > 1000 and moved_fast


def test_the_readings_start_where_the_twins_sensors_start_and_the_time_is_stated(welding):
    model, program, built = welding
    variables = {v.name: v for m in model.cell.modules for v in m.variables}
    assert variables["light_barrier__broken_read"].init is False  # clear until its first reading
    far = model.cell.encoding("range_detector.range").code("far")
    assert variables["range_detector__range_read"].init == far
    (said,) = [a for a in model.cell.assumptions if a.startswith("one step is 0.02 s")]
    assert "every 2 steps" in said and "read a step later" in said
    slower = said[said.index("as in the twin (") + 16:said.index(" every 2 steps")].split(", ")
    assert sorted(slower) == ["light_barrier", "operator", "process_controller", "range_detector", "welder"]


def test_the_robot_publishes_the_activity_asked_of_it_a_step_later(welding):
    """The controller reads the robot's activity (`ract`): the twin's robot publishes what the process asked at its
    own update, so the model keeps it as the robot's state, starting where the twin's robot starts."""
    model, program, built = welding
    cell = model.cell
    (module,) = [m for m in cell.modules if m.name == "robot_activity"]
    (var,) = module.variables
    assert cell.formulas["robot__activity"] == var.name
    assert var.init == cell.initial_code("robot.activity")
    (command,) = [c for c in module.commands if "tick" not in c.guard]  # (the robot updates every step here)
    assert command.updates[0][1] == {var.name: cell.input("robot", "activity")}  # what the process asks


def test_a_person_who_could_walk_past_a_grid_point_in_its_period_is_taken_at_every_step():
    """The floor steps only to neighbouring places: a person is taken at its own period (0.04 s, two steps) only
    where it cannot walk past a grid point in that time. At 1.32 m/s that is 0.053 m: on the 0.1 m grid every other
    step, on the 0.05 m grid every step."""
    from cellsim.verify.floor import _person_every
    from cellsim.verify.model import PersonRole

    cell = abstract_model(load_scenario(WELDING_CELL)).cell
    role = lambda step, speed: PersonRole("operator", [], None, None, step=step, top_speed=speed)  # noqa: E731
    assert _person_every(cell, role(0.1, 1.32)) == 2
    assert _person_every(cell, role(0.05, 1.32)) == 1
    assert _person_every(cell, role(0.05, 1.25)) == 2  # exactly a grid step in a period: still a neighbour
    assert _person_every(cell, role(0.1, None)) == 1  # a speed nobody knows: every step


def test_a_module_whose_period_is_no_multiple_of_the_step_is_refused_in_one_line(tmp_path):
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "cellsim", "verify", str(WELDING_CELL), "--no-replay",
                           "--set", "range_detector.period=0.03", "--out", str(tmp_path / "w")],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    line = done.stderr.strip().splitlines()[-1]
    assert "range_detector updates every 0.03 s, which is no whole multiple of the model's step (0.02 s" in line


def test_the_person_steps_to_exactly_the_floor_s_neighbouring_places(welding):
    """A person's module takes one command per direction (its d-th neighbour a formula of the place), not one per
    pair of places: in the built model, the places a person can be in after an update of theirs are exactly its
    place and the floor's neighbours of it, from every place the model reaches."""
    model, program, built = welding
    person = model.cell.places.people[0]
    of = _valuation_of(built, None)
    valuation = [of(s) for s in range(built.nr_states)]
    seen: dict[int, set[int]] = {}
    for state in built.states:
        here = valuation[state.id]
        if here["tick"] != 0:  # the person updates at the even steps
            continue
        after = {valuation[entry.column][person.variable] for action in state.actions for entry in action.transitions}
        seen.setdefault(here[person.variable], set()).update(after)
    assert len(seen) == len(person.places)  # every place is reached at an update
    for place, after in seen.items():
        assert after == {place, *person.neighbours[place]}, place


def test_a_floor_formula_never_silently_replaces_another():
    """The floor's own formulas (each direction's neighbour and pace) are named after the person's place variable;
    a name some other formula took already is refused in words, not overwritten."""
    from types import SimpleNamespace

    from cellsim.verify.expressions import VerifyError
    from cellsim.verify.floor import _formula

    cell = SimpleNamespace(formulas={"operator_place_to0": "3"})
    with pytest.raises(VerifyError, match="operator_place_to0"):
        _formula(cell, "operator_place_to0", "(operator_place<2 ? 1 : 0)")
    assert cell.formulas == {"operator_place_to0": "3"}
