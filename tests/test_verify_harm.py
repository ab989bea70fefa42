"""Harm in the abstract model (cellsim.kinds.harm.abstraction): ``NoHarm`` and ``NoClamping`` are checked, not left out.

Contact is possible in a state where an arm's bound distance to a person's body may be at most 0. The bound cuts the
floor nowhere (each place reads the least bound over its poses), so the model has exactly the states it had without
it. A witness is sought first where the arm moves, and the replay stands the person where the bound to the arm's
stretch is least: on the welding cell, an operator standing in the cell out of the range detector's reach (the
paper's misuse MU) is hit by the arm, and the twin confirms it (tests/test_verify.py, the welding cell's refinements).
"""

from __future__ import annotations

import math
from types import SimpleNamespace


import pytest

from cellsim.kinds.harm.abstraction import HarmAbstraction
from cellsim.scenario import load_scenario
from cellsim.logic.syntax import NumberDomain, parse, signed_comparisons
from cellsim.verify.prism import holds
from cellsim.verify.witness import walk_key
from cellsim.verify.run import abstract_model
from conftest import ROOT, WELDING_CELL


def test_a_guard_is_read_back_against_a_witness_state():
    state = {"robot_segment": 3, "robot_region": 1, "flag": True}
    assert holds("(robot_segment=3 & robot_region=1) | (robot_segment>=9)", state)
    assert not holds("robot_segment=4 & robot_region=1", state)
    assert not holds("!(robot_segment=3) | robot_region!=1", state)
    assert holds("robot_segment>=2+1 & flag & !false", state)
    assert holds("robot_segment-1=2 & (robot_region<2)", state)
    with pytest.raises(KeyError):
        holds("elsewhere=0", state)
    with pytest.raises(ValueError):
        holds("robot_segment=3 )", state)


def _waived(tmp_path):
    path = tmp_path / "waived.yaml"
    path.write_text(f"base: {WELDING_CELL}\nvalidation:\n  waive:\n    NoHarm: not judged here\n"
                    "    NoClamping: not judged here\n")
    return load_scenario(path)


@pytest.fixture(scope="module")
def modelled():
    """The welding cell's abstract model, its harm conditions read."""
    return abstract_model(load_scenario(WELDING_CELL))


def test_contact_adds_no_state_the_floor_is_cut_as_without_it(modelled, tmp_path):
    without = abstract_model(_waived(tmp_path))
    assert not any(isinstance(part, HarmAbstraction) and part.groups for part in without.parts)
    harm = next(part for part in modelled.parts if isinstance(part, HarmAbstraction))
    assert harm.groups and {"harm.severity", "harm.clamping"} <= set(modelled.cell.signals)
    ours, theirs = modelled.cell.places.people[0], without.cell.places.people[0]
    assert [p.poses for p in ours.places] == [p.poses for p in theirs.places]
    assert ours.neighbours == theirs.neighbours
    # the programs differ only in formulas: the same modules, the same variables
    assert [(m.name, m.variables) for m in modelled.cell.modules] == [(m.name, m.variables) for m in without.cell.modules]


def test_a_place_reads_the_least_bound_of_its_poses_and_keeps_where(modelled):
    harm = next(part for part in modelled.parts if isinstance(part, HarmAbstraction))
    person = modelled.cell.places.people[0]
    inner = modelled.cell.cell.modules["operator"]
    k = 0
    signal = f"harm.contact{k}"
    touching = 0
    context = modelled.cell.cell.diagram.CreateDefaultContext()
    system = harm.system

    def measured(pose) -> float:
        inner.set_pose(context, [pose.x, pose.y, pose.yaw, 0.0, 0.0, 0.0, 0.0] if pose.reach is None
                       else [pose.x, pose.y, pose.yaw, 1.0, *pose.reach])
        bound = harm.clearance.of(harm.bodies.at(system.query_port.Eval(system.GetMyContextFromRoot(context))))[k]
        return bound - harm.slack  # (read less half the grid's diagonal: a person between grid points)

    assert harm.slack == pytest.approx(0.1 * math.sqrt(2.0) / 2.0)

    for place in person.places:
        pose, least = place.least[signal]
        assert pose in place.poses and measured(pose) == pytest.approx(least)
        # the place's reading is its least pose's: no pose of the place reads less
        assert min(measured(other) for other in place.poses[:: max(1, len(place.poses) // 40)]) >= least - 1e-9
        touching += least <= 0.0
    assert touching, "some place of the welding cell's floor may touch the arm at its first stretch"


def test_the_witness_pose_is_where_the_bound_to_the_arm_s_stretch_is_least(modelled):
    harm = next(part for part in modelled.parts if isinstance(part, HarmAbstraction))
    person = modelled.cell.places.people[0]
    no_harm = next(p for p in modelled.properties if p.name == "NoHarm")
    mishap = next(p for p in modelled.properties if p.name == "HRW:mishap")
    for k, robot, group in harm._contacts():
        found = [(place, place.least[f"harm.contact{k}"]) for place in person.places
                 if place.least[f"harm.contact{k}"][1] <= 0.0]
        if not found or group.rate is None:
            continue
        place, (pose, _) = found[0]
        # a state on this group's stretch: the first of its guard's disjuncts, read as variable values
        first = group.guard.split(" | ")[0].strip("()")
        state = {v: int(x) for v, x in (term.split("=") for term in first.split(" & "))}
        state = {**{"robot_segment": -1, "robot_region": -1}, **state}
        assert holds(group.guard, state)
        assert harm.witness_pose(modelled.cell, no_harm, person, place.index, state) == pose
        # not for a property that reads no contact
        assert harm.witness_pose(modelled.cell, mishap, person, place.index, state) is None
        return
    pytest.fail("no stretch of a move the welding cell's floor may touch")


def test_the_harm_conditions_share_a_model_of_their_own_cone_not_the_mishaps():
    """The properties with no monitor share a model only with those of the same cone: on the assembly bench the harm
    conditions read the arms and the floor, and the mishaps' model still leaves the arms out."""
    model = abstract_model(load_scenario(ROOT / "scenarios" / "assembly_bench.yaml"))
    groups = {tuple(p.name for p in props): dropped for props, _, dropped in model.groups()}
    assert ("NoHarm", "NoClamping") in groups
    harm_dropped = groups[("NoHarm", "NoClamping")]
    assert not {"loader_motion", "assembler_motion"} & set(harm_dropped)
    for names, dropped in groups.items():
        if any(n.endswith(":mishap") for n in names):
            assert {"loader_motion", "assembler_motion"} <= set(dropped), names


def test_a_comparison_s_polarity_counts_negations_and_implications():
    voc = {"a": NumberDomain(), "b": NumberDomain()}
    signs = lambda text: [(c.var, c.op, positive) for c, positive in signed_comparisons(parse(text, voc))]
    assert signs("G(a <= 1)") == [("a", "<=", True)]
    assert signs("G(not (a <= 1))") == [("a", "<=", False)]
    assert signs("G(a > 0.5 -> b <= 1)") == [("a", ">", False), ("b", "<=", True)]
    assert signs("G(not (a > 0.5 -> b > 1))") == [("a", ">", True), ("b", ">", False)]


def test_a_condition_asking_for_a_high_severity_leaves_it_out_of_the_model(tmp_path):
    """A contact reads as the worst, above every number: sound only where a higher severity makes a condition the
    likelier to fail. A condition that asks for a high one would hold in the model where the twin's milder contact
    fails it: the signal is then left out, saying why (NoHarm with it)."""
    path = tmp_path / "high.yaml"
    path.write_text(f"base: {WELDING_CELL}\nvalidation:\n  conditions:\n"
                    "    Hard: 'G(harm.clamping > 0.5 -> harm.severity > 1)'\n")
    model = abstract_model(load_scenario(path))
    assert "harm.severity" not in model.cell.signals and "harm.clamping" in model.cell.signals
    skipped = {s.name: s.reason for s in model.skipped}
    assert {"Hard", "NoHarm"} <= set(skipped) and "NoClamping" not in skipped
    assert "ask it to stay below them" in skipped["NoHarm"]


def test_two_witnesses_are_replayed_as_one_only_where_they_are_written_as_one(modelled):
    harm = next(part for part in modelled.parts if isinstance(part, HarmAbstraction))
    path = [{"tick": 0}, {"tick": 1}]
    no_harm = next(p for p in modelled.properties if p.name == "NoHarm")
    no_clamping = next(p for p in modelled.properties if p.name == "NoClamping")
    final = next(p for p in modelled.properties if p.final)
    mishap = next(p for p in modelled.properties if p.name == "HRW:mishap")
    key = lambda prop: walk_key(modelled, SimpleNamespace(prop=prop, witness=path))
    assert key(no_harm) == key(no_clamping) and harm.chooses_pose_for(no_harm)
    assert key(no_harm) != key(mishap) != key(final)  # the harm's last stop; a Final's, the script's end
