"""``Final`` conditions (``F G p``: how a run ends) judged by ``verify`` where a run can end (issue 36, item 4): in every
state where each person stands where its script leaves it. A condition on where the people end is decided at their
last stops; one on the cell is a property of the model; a person whose script may not be over by the run's end may
stand anywhere then, and the twin confirms the run that ends so."""

from __future__ import annotations

import json
import re

import stormpy

from cellsim.scenario import load_scenario
from cellsim.verify.run import abstract_model
from cellsim.verify.storm import _valuation_of

from conftest import ROOT
from test_verify import _verify

CONDITIONS = {
    "Final:Out": "F G(oloc == away)",  # where the operator ends: decided at its last stop
    "Final:Resting": "F G(arm_mode == normal)",  # the arm's mode as the run ends: a property of the model
}


def _final_cell(folder, duration: float | None = None):
    """The machine-tending cell with the two Final conditions (its operator's script is over by about 21 s)."""
    path = folder / "final.yaml"
    lines = [f"base: {ROOT / 'scenarios' / 'machine_tending.yaml'}", "name: machine_tending_final"]
    if duration is not None:
        lines.append(f"duration: {duration}")
    lines += ["validation:", "  waive:", "    TrueSSM: these tests are about the Final conditions (tests/test_verify.py verifies it)",
              "  variables:", "    oloc: operator.location", "  conditions:"]
    lines += [f'    "{name}": {formula}' for name, formula in CONDITIONS.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_final_condition_is_judged_where_the_people_s_scripts_leave_them(tmp_path):
    scenario = _final_cell(tmp_path)
    export = tmp_path / "final.prism"
    done = _verify(str(scenario), "--json", "--no-replay", "--refine", "0", "--export", str(export),
                   "--out", str(tmp_path / "out"), "--only", "Final:*")
    result = json.loads(done.stdout)
    by_name = {p["name"]: p for p in result["properties"]}
    assert not {s["name"] for s in result["not_checked"]} & set(CONDITIONS)
    # the operator ends away: holds; the arm may not be back to normal the moment the operator gets there
    assert by_name["Final:Out"]["ending"] == "holds"
    assert by_name["Final:Resting"]["holds"] is False and by_name["Final:Resting"]["ending"] == "undecided"
    assumption = next(a for a in result["assumptions"] if a.startswith("a Final condition"))
    assert "operator ends at its last stop (-3.5, 2.0)" in assumption

    # stormpy on the exported model, on its own: the same values; the bad states of Final:Resting are all where
    # the operator stands at its last stop's place, and some such state has the arm in another mode
    program = stormpy.parse_prism_program(str(export))
    options = stormpy.BuilderOptions(build_full=True)
    options.set_build_state_valuations(True)
    model = stormpy.build_model(program, options=options)
    lines = dict(re.fullmatch(r'"([^"]+)": (.*);', line).groups()
                 for line in export.with_suffix(".props").read_text().splitlines() if line and not line.startswith("//"))
    for name in CONDITIONS:
        (formula,) = stormpy.parse_properties(lines[re.sub(r"\W", "_", name)], program)
        value = stormpy.model_checking(model, formula).get_value(model.initial_states[0])
        assert value == by_name[name]["value"], name

    sf = load_scenario(scenario)
    abstract = abstract_model(sf, only=("Final:*",))  # (the model verify exported: its labels)
    (person,) = abstract.cell.places.people
    end = abstract.cell.places.people[0].at(person.end)
    assert any(abs(p.x + 3.5) < 1e-9 and abs(p.y - 2.0) < 1e-9 for p in end.poses)
    bad = model.labeling.get_states(abstract.labels["Final:Resting"])
    valuation = _valuation_of(model, None)
    places = {valuation(s)[person.variable] for s in range(model.nr_states) if bad.get(s)}
    assert places == {person.end}
    # deciding Final:Out at the last stop did not cut the floor by the operator's zone
    plain_path = tmp_path / "plain.yaml"  # the shipped cell with the same waiver, its floor cut by the scanner alone
    plain_path.write_text(f"base: {ROOT / 'scenarios' / 'machine_tending.yaml'}\nname: plain\nvalidation:\n  waive:\n"
                          "    TrueSSM: as the Final cell waives it\n")
    plain = abstract_model(load_scenario(plain_path))
    assert len(person.places) == len(plain.cell.places.people[0].places)


def test_a_run_that_may_end_before_the_script_is_over_ends_anywhere_and_the_twin_shows_it(tmp_path):
    """8 s runs: the operator is still at the bench when the run ends. Both conditions are violated in the model, and
    the twin's run of each witness ends so."""
    done = _verify(str(_final_cell(tmp_path, duration=8.0)), "--json", "--refine", "0", "--out", str(tmp_path / "out"),
                   "--only", "Final:*")
    assert done.returncode == 1, done.stderr
    result = json.loads(done.stdout)
    by_name = {p["name"]: p for p in result["properties"]}
    for name in CONDITIONS:
        assert by_name[name]["ending"] == "violated" and by_name[name]["twin"]["confirmed"], name
    assumption = next(a for a in result["assumptions"] if a.startswith("a Final condition"))
    assert "may not be over by its last update" in assumption and "may stand anywhere then" in assumption


def test_a_person_whose_last_stop_shares_its_starting_place_is_walked_there_by_the_witness(tmp_path):
    """The welding cell with the operator's last stop moved into the cell: ``Final:Cell`` reads only the operator's own
    zone, so it is decided at the last stop without cutting the floor by it, and the last stop lies in the operator's
    starting place. The witness is the initial state; its replay must walk to the last stop and stay, not stand at
    the start (a helper's audit found the twin 'refuting' it so, and the property left undecided)."""
    from conftest import WELDING_CELL

    scenario = tmp_path / "end_in_cell.yaml"
    scenario.write_text(f"base: {WELDING_CELL}\nname: welding_cell_end_in_cell\nentities:\n  operator:\n"
                        "    waypoints:\n      exit: {position: [-1.0, -1.2], wait: 2.0}\n")
    done = _verify(str(scenario), "--json", "--refine", "0", "--out", str(tmp_path / "out"), "--only", "Final:Cell")
    assert done.returncode == 1, done.stderr
    final = {p["name"]: p for p in json.loads(done.stdout)["properties"]}["Final:Cell"]
    assert final["ending"] == "violated" and final["twin"]["confirmed"]
    witness = (tmp_path / "out" / "Final_Cell.yaml").read_text()
    assert "-1.0" in witness and "-1.2" in witness  # its walk ends at the last stop


def _slowest_script_end(sf) -> float:
    """When the operator's script is over at the slowest pace its jitter allows, by the twin's own walk planner."""
    import dataclasses

    from cellsim.kinds.operator.system import plan_walk

    cfg = sf.scenario.entities["operator"]
    slowest = dataclasses.replace(cfg, walking_speed=cfg.walking_speed * (1.0 - cfg.speed_jitter), speed_jitter=0.0)
    return plan_walk(slowest, 0, layout=sf.scenario.layout)[-1].leave


def _final_assumption(model) -> str:
    return next(a for a in model.cell.assumptions if a.startswith("a Final condition"))


def test_the_last_stop_counts_only_if_the_script_is_over_by_the_person_s_last_update(tmp_path):
    """The twin records a person at its updates (every 0.04 s) and makes none at the run's end: a script over after
    the last update before the end leaves the person still on its way in the record, so it may stand anywhere."""
    welding = ROOT / "scenarios" / "welding_cell.yaml"
    over = _slowest_script_end(load_scenario(welding))
    last_update_before = (int(over / 0.04) + 1) * 0.04  # the first update at or after the script's end
    late = abstract_model(load_scenario(welding, [f"duration={last_update_before - 0.01:.4f}"]))
    assert late.cell.people[0].end is None and "may not be over by its last update" in _final_assumption(late)
    on_time = abstract_model(load_scenario(welding, [f"duration={last_update_before + 0.01:.4f}"]))
    end = on_time.cell.people[0].end
    assert (end.x, end.y) == (-3.2, -2.2) and "ends at its last stop (-3.2, -2.2)" in _final_assumption(on_time)
    # a campaign may sample the operator's waits: the verdict is the script's as written, and says so
    assert "as the scenario writes it (a campaign sampling operator_waits" in _final_assumption(on_time)


def test_a_person_following_its_physical_twin_may_end_anywhere():
    model = abstract_model(load_scenario(ROOT / "scenarios" / "welding_cell.yaml", ["operator.twin.mode=shadow"]))
    assert model.cell.people[0].end is None
    assert "operator follows its physical twin" in _final_assumption(model)


def test_a_person_standing_still_at_its_start_is_recorded_where_it_stands(tmp_path):
    """The twin's location channel starts from the start pose (it was 'outside' until the person first moved, so a
    person who never moved was outside all run while the model put it in its zone)."""
    import sqlite3

    from cellsim.simulation import simulate

    path = tmp_path / "still.yaml"
    path.write_text(f"base: {ROOT / 'scenarios' / 'welding_cell.yaml'}\nduration: 1.0\n"
                    "entities:\n  operator:\n    start: [0.6, -0.7]\n    waypoints: !replace {}\n"
                    "configuration_points: !replace {}\ncampaign: !replace {}\n")
    sf = load_scenario(path)
    simulate(sf, tmp_path / "run", seed=0)
    with sqlite3.connect(tmp_path / "run" / "blackbox.sqlite") as db:  # read back with plain SQL
        rows = db.execute("SELECT t, payload FROM messages WHERE channel = 'operator.location' ORDER BY t").fetchall()
    assert rows and rows[0][0] == 0.0 and {json.loads(payload)["value"] for _, payload in rows} == {"inCell"}
