"""A property's cone of influence: only the modules its labels can observe are built, with the same values."""

from __future__ import annotations

import math
from types import SimpleNamespace

from cellsim.scenario import load_scenario
from cellsim.verify.cone import cone, within_cone
from cellsim.verify.prism import Command, Module, Program, Var
from cellsim.verify.run import abstract_model
from cellsim.verify.storm import build, build_symbolic, check
from cellsim.verify.witness import walks

from conftest import ROOT, WELDING_CELL

ASSEMBLY_BENCH = ROOT / "scenarios" / "assembly_bench.yaml"


def _counter(name: str, reads_expr: str) -> Module:
    var = f"{name}_x"
    return Module(name, [Var(var, 0, 3)], [Command("true", (("1", {var: f"min(3, {reads_expr})"}),)),
                                           Command(f"{var} > 0", (("1", {var: "0"}),))])


def _program() -> Program:
    """``watched`` (read by the label) reads ``source`` through a formula; ``bystander`` reads ``watched`` (its
    guards may read the cone) but nobody reads it; ``noise`` reads only itself."""
    modules = [_counter("source", "source_x + 1"), _counter("watched", "seen + 1"),
               _counter("bystander", "watched_x + bystander_x"), _counter("noise", "noise_x + 1")]
    formulas = {"seen": "source_x", "loud": "noise_x + bystander_x"}
    return Program(modules, formulas, {"bad": "watched_x = 3 & seen = 3"})


def test_the_cone_is_what_the_labels_read_and_everything_that_feeds_it():
    program = _program()
    assert cone(program) == ["source", "watched"]
    kept, dropped = within_cone(program)
    assert [m.name for m in kept.modules] == ["source", "watched"]
    assert dropped == ["bystander", "noise"]
    assert kept.formulas == {"seen": "source_x"}  # a formula of dropped variables only goes with them
    assert kept.labels == program.labels


def test_a_program_without_labels_is_kept_whole():
    program = _program()
    program.labels = {}
    assert within_cone(program) == (program, [])


def test_the_cone_keeps_the_value_and_the_witness_length_and_has_fewer_states(tmp_path):
    """Storm on the whole program and on its cone: the same probability of the label, the same shortest path
    length to it, fewer states (the modules left out multiplied them)."""
    program = _program()
    kept, _ = within_cone(program)
    prop = SimpleNamespace(name="bad", pctl=None, response=False, sustained=None)
    found = {}
    for name, text in (("whole", program.text()), ("cone", kept.text())):
        path = tmp_path / f"{name}.prism"
        path.write_text(text)
        parsed, model, stats = build(path)
        checked = check(parsed, model, prop, "bad")
        found[name] = (checked.value, len(checked.witness), stats.states)
    assert found["whole"][:2] == found["cone"][:2] == (1.0, found["cone"][1])
    assert found["cone"][2] < found["whole"][2]


def test_the_assembly_benchs_mishaps_are_checked_without_the_arms_which_no_hazard_reads(tmp_path):
    """The assembly bench's hazards read the people's zone and the curtain, not the arms' motion: the mishaps'
    model leaves the arms and their processes out, and Storm gives every property the value of the whole cell."""
    model = abstract_model(load_scenario(ASSEMBLY_BENCH))
    props, group, dropped = model.groups()[0]
    assert {"loader_motion", "assembler_motion", "loading", "assembling"} <= set(dropped)
    whole = model.cell.program(model.header, [], group.labels)
    values = {}
    for name, program in (("whole", whole), ("cone", group)):
        path = tmp_path / f"{name}.prism"
        path.write_text(program.text())
        parsed, built, stats = build_symbolic(path, 256)
        values[name] = ({p.name: check(parsed, built, p, model.labels.get(p.name)).value for p in props}, stats.states)
    assert values["cone"][0] == values["whole"][0]
    assert values["cone"][1] * 100 < values["whole"][1]


def test_a_person_outside_the_cone_stays_where_it_starts_in_the_witness_walk():
    """A witness of a model that left a person out has no place for them: the walk written for the twin keeps
    them at their start (what they do cannot change the property)."""
    model = abstract_model(load_scenario(WELDING_CELL))
    person = model.cell.places.people[0]
    checked = SimpleNamespace(prop=SimpleNamespace(final=False), witness=[{"tick": k} for k in range(5)])
    entities, _ = walks(model, checked, 0.0)
    config = entities[person.role.module]
    start = person.role.start
    assert config["start"] == [start.x, start.y]
    waypoints = list(config["waypoints"].values())
    assert waypoints[-1]["position"] == [start.x, start.y]  # (before it, one grid step back: it turns to face its way)
    assert all(math.dist(w["position"], (start.x, start.y)) <= person.role.step + 1e-9 for w in waypoints)


def test_a_probability_that_reads_a_module_keeps_it_in_the_cone():
    """A plug-in kind's branch whose probability reads another module: that module feeds the cone."""
    coin = Module("coin", [Var("coin_x", 0, 2)], [Command("true", (("weight_x/4", {"coin_x": "1"}),
                                                                  ("1 - weight_x/4", {"coin_x": "2"})))])
    weight = _counter("weight", "weight_x + 1")
    program = Program([weight, coin], {}, {"bad": "coin_x = 1"})
    assert cone(program) == ["weight", "coin"]


def test_labels_that_read_no_variable_keep_the_program_whole():
    program = _program()
    program.labels = {"bad": "true"}
    assert within_cone(program) == (program, [])
