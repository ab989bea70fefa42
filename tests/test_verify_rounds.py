"""What a refinement's round reuses of the rounds before it, and what its model leaves out, none of it changing an
answer: the floor's measurements (a pace measures no pose again, a finer grid only the new ones), a pace's counter
that stops where no step's guard counts further, and the decision diagrams' tables sized on the states reached."""

from __future__ import annotations

import re

import pytest

from conftest import ROOT
from cellsim.scenario import load_scenario
from cellsim.verify.run import DD_MEMORY, SMALL_DD_MEMORY, abstract_model, dd_memory

WELDING = ROOT / "scenarios" / "welding_cell.yaml"
PACE = frozenset({"operator:pace"})
FINE = frozenset({"operator:pace", "operator:fine"})


@pytest.fixture(scope="module")
def welding():
    return load_scenario(WELDING)


def test_a_finer_grid_measures_a_new_point_only_where_the_coarser_grids_readings_around_it_differ():
    """A new point of the 0.05 m grid between points of the 0.1 m grid measured before: where they all read the same
    (every signal, at its heading and reach) it reads as they do, unmeasured; where one differs, or one was not
    measured (a reach's heading is its own), it is measured; a point of the coarser grid not measured is too."""
    from cellsim.verify.floor import _inherit
    from cellsim.verify.model import Pose, PersonRole

    person = PersonRole("op", [], Pose(0.0, 0.0, 0.0), lambda context, pose: None, step=0.05, refines=0.1)
    signals = ["op.zone", "scanner.field"]
    known = {}
    for x, y in ((0.0, 0.0), (0.1, 0.0), (0.0, 0.1), (0.1, 0.1), (0.2, 0.0), (0.2, 0.1)):
        for s in signals:
            known[("op", s, Pose(x, y, 0.0))] = "free" if x < 0.2 or s == "op.zone" else "protective"
    middle = Pose(0.05, 0.05, 0.0)  # four corners, all alike
    edge = Pose(0.05, 0.0, 0.0)  # two corners, alike
    border = Pose(0.15, 0.05, 0.0)  # its corners at x = 0.2 read the protective field
    turned = Pose(0.05, 0.05, 1.0)  # no corner measured at this heading
    reaching = Pose(0.05, 0.0, 0.0, (1.0, 1.0, 1.0))
    corner = Pose(0.3, 0.0, 0.0)  # a point of the coarser grid itself
    left = _inherit(person, [middle, edge, border, turned, reaching, corner], signals, known)
    assert left == [border, turned, reaching, corner]
    assert known[("op", "scanner.field", middle)] == known[("op", "scanner.field", edge)] == "free"
    assert ("op", "scanner.field", border) not in known


def test_a_refined_round_measures_only_the_poses_no_earlier_round_did_and_builds_the_same_model(welding):
    """A pace measures nothing again; the finer grid measures its new points only where the coarser grid's readings
    around them differ, and its model is the one measuring every point gives (the welding cell's)."""
    measured: dict = {}
    first = abstract_model(welding, measured=measured)
    assert first.cell.places.poses_measured > 0 and measured
    paced = abstract_model(welding, refinements=PACE, measured=measured)
    assert paced.cell.places.poses_measured == 0  # the same grid: nothing to measure again
    fine = abstract_model(welding, refinements=FINE, measured=measured)
    fresh = abstract_model(welding, refinements=FINE)
    assert 0 < fine.cell.places.poses_measured < fresh.cell.places.poses_measured  # the finer grid's new poses only
    for reused, anew in ((paced, abstract_model(welding, refinements=PACE)), (fine, fresh)):
        assert _cut(reused) == _cut(anew)
        # a contact's bound, which cuts nothing, a finer pose reads from the coarser ones around it less its distance
        # to them, never more than measuring it gives (tests/test_verify_harm.py): each place's least, no higher
        for ours, theirs in zip(reused.cell.places.people[0].places, anew.cell.places.people[0].places):
            assert ours.least.keys() == theirs.least.keys() and ours.least
            assert all(ours.least[s][1] <= theirs.least[s][1] + 1e-9 for s in ours.least)


def _cut(model) -> str:
    """The model's program but the formulas of the harm service's contact bounds (which cut no place)."""
    return "\n".join(line for line in model.cell.program(model.header).text().splitlines()
                     if not line.startswith("formula harm__contact"))


def test_a_pace_counts_no_further_than_a_step_from_where_the_person_stands_asks_and_every_answer_is_the_same(
        welding, tmp_path):
    """The counter of periods a person has stayed in a place stops at the most any step from that place (for where
    they came from) counts to: past it every guard reads the same. The welding cell's refined model reaches a fifth of
    the states, each property's value unchanged (built again here with the counter going on to its top)."""
    import stormpy

    from cellsim.verify.storm import _initial_value, _quiet

    _quiet()
    model = abstract_model(welding, refinements=FINE)
    text = model.cell.program(model.header).text()
    counted = re.search(r"operator_place_dwell : \[0\.\.(\d+)\]", text)
    assert counted and "min(operator_place_dwell+1, operator_place_dwell_enough)" in text
    uncapped = text.replace("min(operator_place_dwell+1, operator_place_dwell_enough)",
                            f"min(operator_place_dwell+1, {counted.group(1)})")
    props = "\n".join(f'"p{i}": Pmax=? [ F "{label}" ];' for i, label in enumerate(sorted(model.labels.values())))
    found = {}
    for name, program in (("capped", text), ("uncapped", uncapped)):
        path = tmp_path / f"{name}.prism"
        path.write_text(program)
        parsed = stormpy.parse_prism_program(str(path))
        formulas = stormpy.parse_properties(props, parsed)
        built = stormpy.build_symbolic_model(parsed.substitute_formulas(), formulas)
        found[name] = (built.nr_states, [_initial_value(stormpy, built, f.get_raw_formula()) for f in formulas])
    assert found["capped"][1] == found["uncapped"][1] and len(found["capped"][1]) >= 17
    assert found["capped"][0] * 4 < found["uncapped"][0]


def test_a_refined_round_of_a_small_cell_starts_small_tables_whatever_its_counters_widen():
    assert dd_memory(1e20) == DD_MEMORY and dd_memory(1e16) == SMALL_DD_MEMORY
    assert dd_memory(1e20, grown_from=12_931) == SMALL_DD_MEMORY  # the welding cell's pace: 1e20 allowed, 19,665 reached
    assert dd_memory(1e20, grown_from=5_325_640) == DD_MEMORY  # the palletising cell's



def test_a_paced_person_held_where_they_start_builds_as_decision_diagrams(welding, tmp_path):
    """The stay counter's limit reads where the person came from, which a person held at their start (a witness of
    a model too large to make sparse, cellsim.verify.run.held) never changes: Storm folded it into a constant and
    could not translate the limit (the two-operator cell's verify failed). Held, it is the start's constant too."""
    from cellsim.verify.run import held
    from cellsim.verify.storm import build_symbolic, to_sparse, valuation_labels

    model = abstract_model(welding, refinements=PACE)
    program = held(model.cell.program(model.header), model.cell.places.people)
    path = tmp_path / "held.prism"
    path.write_text(program.text() + valuation_labels(program.variables()))  # made sparse, as a witness's model is
    _, symbolic, stats = build_symbolic(path, SMALL_DD_MEMORY)
    sparse, _ = to_sparse(symbolic, program.variables())
    assert sparse.nr_states == stats.states > 0
    assert "operator_place_from" not in program.text()


def test_a_refined_round_builds_a_group_state_by_state_where_its_monitors_grew_it_little_before(welding):
    """The welding cell's detection monitors could multiply its states 27 times (their ages' ranges): its paced
    model (19,458 states) times that is past what is surely small, so its witness's model was sized as decision
    diagrams first, then built again state by state. Its first round saw them add 3 %: told so, the refined round
    builds it state by state at once, the same model and the same witness."""
    from cellsim.verify.run import verify

    only = ("*:detected",)  # (the groups of the detection monitors)
    first = verify(welding, only=only)
    (key,) = [k for k in first.growth if k == ("HRW:detected",)]
    assert 1.0 <= first.growth[key] < 1.1

    def stages(growth):
        said = []
        result = verify(welding, refinements=PACE, on_stage=said.append, growth_seen=growth, only=only)
        return [s for s in said if "state space for HRW:detected" in s], result

    probed, coarse = stages(None)
    direct, told = stages(first.growth)
    assert [s.rsplit(", ", 1)[1] for s in probed] == ["as decision diagrams", "state by state"]
    assert [s.rsplit(", ", 1)[1] for s in direct] == ["state by state"]
    witness = {r.prop.name: r.witness for r in coarse.results}["HRW:detected"]
    assert witness and {r.prop.name: r.witness for r in told.results}["HRW:detected"] == witness
