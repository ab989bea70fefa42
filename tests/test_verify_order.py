"""The modules' order in the written program: readers after what they read, and nothing but speed changes."""

from __future__ import annotations

import stormpy

from cellsim.scenario import load_scenario
from cellsim.verify.order import forward_reads, ordered, reads
from cellsim.verify.prism import Command, Module, Program, Var
from cellsim.verify.run import abstract_model
from cellsim.verify.storm import _initial_value

from conftest import WELDING_CELL


def _module(name: str, reads_expr: str, high: int = 3) -> Module:
    var = f"{name}_x"
    return Module(name, [Var(var, 0, high)], [Command("true", (("1", {var: f"min({high}, {reads_expr})"}),))])


def test_a_module_is_written_after_the_modules_it_reads_even_through_a_formula():
    """A chain declared backwards (a reads b through a formula, b reads c) is ordered c, b, a: nothing read
    forwards."""
    a, b, c = _module("a", "seen_b"), _module("b", "c_x + 1"), _module("c", "0")
    formulas = {"seen_b": "b_x"}
    assert reads([a, b, c], formulas) == {"a": {"b"}, "b": {"c"}, "c": set()}
    order = ordered([a, b, c], formulas)
    assert [m.name for m in order] == ["c", "b", "a"]
    assert forward_reads(order, reads([a, b, c], formulas)) == 0


def test_a_module_nobody_reads_is_written_just_after_the_last_module_it_reads():
    """A monitor reads the hazard and the sensor; nobody reads it. It costs no forward read anywhere after them, and
    is written right after the later of the two, not at the end, beside the values it follows."""
    sensor, hazard = _module("sensor", "0"), _module("hazard", "sensor_x")
    robot, tail = _module("robot", "hazard_x"), _module("tail", "robot_x")
    monitor = _module("monitor", "hazard_x + sensor_x")
    order = [m.name for m in ordered([monitor, tail, robot, hazard, sensor], {})]
    assert order == ["sensor", "hazard", "monitor", "robot", "tail"]


def test_a_loop_is_broken_where_the_fewest_bits_flow_backwards_and_the_order_is_deterministic():
    """A controller that reads a wide sensor and commands a narrow actuator that the sensor reads: the loop costs
    least cut at the narrow read. The same program always gives the same order."""
    sensor = _module("sensor", "actuator_x", high=255)   # 8 bits, reads the actuator
    controller = _module("controller", "sensor_x", high=3)
    actuator = _module("actuator", "controller_x", high=1)  # 1 bit
    given = [controller, actuator, sensor]
    first = [m.name for m in ordered(given, {})]
    assert first == [m.name for m in ordered(given, {})]
    read = reads(given, {})
    best = min(forward_reads([m for n in order for m in given if m.name == n], read)
               for order in (["sensor", "controller", "actuator"], ["controller", "actuator", "sensor"],
                             ["actuator", "sensor", "controller"]))
    assert forward_reads(ordered(given, {}), read) == best


def test_the_welding_cell_in_either_order_has_the_same_states_transitions_and_values(tmp_path):
    """The order changes nothing but the decision diagrams' size: the welding cell written in its kinds' order and
    in the rule's has the same reachable states, transitions and every mishap's value."""
    model = abstract_model(load_scenario(WELDING_CELL))
    program = model.cell.program(model.header)  # the rule's order
    kinds = [model.cell.clock(), *model.cell.modules, *model.cell.monitors.values()]  # as the kinds declared them
    assert [m.name for m in program.modules] != [m.name for m in kinds]
    assert [m.name for m in program.modules] == [m.name for m in ordered(kinds, program.formulas)]
    declared = tmp_path / "declared.prism"
    declared.write_text(Program(kinds, program.formulas, program.labels, program.header).text())
    rule = tmp_path / "rule.prism"
    rule.write_text(program.text())
    assert declared.read_text() != rule.read_text()
    results = []
    for path in (declared, rule):
        parsed = stormpy.parse_prism_program(str(path))
        built = stormpy.build_model(parsed)
        values = [_initial_value(stormpy, built, stormpy.parse_properties(f'Pmax=? [ F "{label}" ]', parsed)[0])
                  for label in sorted(model.labels.values())]
        results.append((built.nr_states, built.nr_transitions, values))
    assert results[0] == results[1]
    assert any(v > 0 for v in results[0][2]) and any(v == 0 for v in results[0][2])  # both verdicts compared
