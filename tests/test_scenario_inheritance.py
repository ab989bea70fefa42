"""Scenario inheritance: ``base: other.yaml`` plus only what differs."""

from __future__ import annotations

import pytest

from cellsim.config.typed_yaml import ConfigError, to_data
from cellsim.scenario import export_scenario, load_scenario

from conftest import ROOT, WELDING_CELL

TWO_OPERATORS = ROOT / "scenarios" / "two_operators.yaml"


def test_the_misuse_scenario_states_only_what_differs():
    base, derived = load_scenario(WELDING_CELL).scenario, load_scenario(TWO_OPERATORS).scenario
    assert derived.name == "two_operators" and "visitor" in derived.entities
    # merged key by key: the operator's positions come from the base, its waits from the file
    op = derived.entities["operator"]
    assert op.waypoints["bench"].reach == base.entities["operator"].waypoints["bench"].reach
    assert [w.wait for w in op.waypoints.values()] == [2.0, 6.0, 2.0, 4.0, 6.0]
    assert set(derived.campaign.samplers) == {"operator_waits", "visitor_waits", "visitor_start", "visitor_spot"}
    assert set(derived.validation.conditions) == set(base.validation.conditions) | {"Final:Visitor"}


def test_a_scenario_with_a_base_exports_whole_and_loads_back_equal(tmp_path):
    sf = load_scenario(TWO_OPERATORS)
    exported = tmp_path / "flat.yaml"
    exported.write_text(export_scenario(sf, destination_dir=tmp_path))
    assert "base:" not in exported.read_text()
    again = load_scenario(exported)
    a, b = to_data(sf.scenario), to_data(again.scenario)
    for d in (a, b):
        d["entities"]["robot"]["model"] = d["behaviours"]["safety_controller"]["risk_model"] = None
    assert a == b


def _derived(tmp_path, body: str, name: str = "derived.yaml"):
    folder = tmp_path / "elsewhere"
    folder.mkdir(exist_ok=True)
    path = folder / name
    path.write_text(f"base: {WELDING_CELL}\n" + body)
    return path


def test_paths_in_the_base_stay_relative_to_the_base(tmp_path):
    sf = load_scenario(_derived(tmp_path, "name: moved\n"))
    model = sf.resolve_path("entities.robot.model", sf.scenario.entities["robot"].model)
    assert model == (WELDING_CELL.parent / "models" / "ur10.urdf").resolve()
    assert sf.files[:2] == [str(tmp_path / "elsewhere" / "derived.yaml"), str(WELDING_CELL)]


def test_an_error_in_the_derived_file_names_that_file_and_line(tmp_path):
    path = _derived(tmp_path, "name: bad\nentities:\n  range_detector:\n    close_below: 5.0\n")
    with pytest.raises(ConfigError) as e:
        load_scenario(path)
    assert e.value.source == str(path) and e.value.line == 5
    assert e.value.key == "entities.range_detector.close_below"


def test_an_error_in_the_base_names_the_base_file(tmp_path):
    base = tmp_path / "base.yaml"
    base.write_text(WELDING_CELL.read_text().replace("close_below: 1.0", "close_below: 9.0").replace(
        "model: models/ur10.urdf", f"model: {WELDING_CELL.parent / 'models' / 'ur10.urdf'}").replace(
        "risk_model: welding_cell_risk_model.yaml", f"risk_model: {WELDING_CELL.parent / 'welding_cell_risk_model.yaml'}").replace(
        "file: welding_cell_validation.yaml", f"file: {WELDING_CELL.parent / 'welding_cell_validation.yaml'}"))
    derived = tmp_path / "derived.yaml"
    derived.write_text("base: base.yaml\nname: d\n")
    with pytest.raises(ConfigError) as e:
        load_scenario(derived)
    line = next(i for i, l in enumerate(base.read_text().splitlines(), 1) if "close_below: 9.0" in l)
    assert (e.value.source, e.value.line) == (str(base), line)


def test_a_cycle_of_bases_is_one_error(tmp_path):
    (tmp_path / "a.yaml").write_text("base: b.yaml\nname: a\n")
    (tmp_path / "b.yaml").write_text("base: a.yaml\nname: b\n")
    with pytest.raises(ConfigError, match="a base of itself"):
        load_scenario(tmp_path / "a.yaml")


def test_a_missing_base_is_one_error_at_its_line(tmp_path):
    (tmp_path / "a.yaml").write_text("name: a\nbase: nowhere.yaml\n")
    with pytest.raises(ConfigError) as e:
        load_scenario(tmp_path / "a.yaml")
    assert e.value.line == 2 and "file not found: nowhere.yaml" in str(e.value)


SHORT_CYCLE = "name: short_cycle\nbehaviours:\n  process_controller:\n    steps:\n      - {name: only, dwell: 1.0, activity: exchWrkp}\n"


def test_a_list_in_the_derived_file_replaces_the_base_list(tmp_path):
    # the base's restart_on_request still names the base's steps: found, at the base's line
    with pytest.raises(ConfigError) as e:
        load_scenario(_derived(tmp_path, SHORT_CYCLE))
    assert e.value.source == str(WELDING_CELL) and "'bring_back' is not a step" in str(e.value)
    # a mapping tagged !replace replaces the base's instead of merging into it
    path = _derived(tmp_path, SHORT_CYCLE + "    restart_on_request: !replace {}\n", "replaced.yaml")
    controller = load_scenario(path).scenario.behaviours["process_controller"]
    assert [s.name for s in controller.steps] == ["only"] and controller.restart_on_request == {}


OWN_WORDS = """\
base: {base}
name: own_words
layout:
  robot_regions: !replace
    infeed: {{min: [-0.3, 0.45, 0.8], max: [0.3, 1.1, 1.5]}}
    press: {{min: [-1.35, -0.4, 0.85], max: [-0.75, 0.4, 1.4]}}
  robot_elsewhere: aisle
  operator_zones: !replace
    pressArea: {{min: [-1.3, -1.6, 0.0], max: [2.0, 1.6, 2.5]}}
  operator_outside: away
  operator_flags: !replace
    at_pallet: {{min: [-2.0, -0.5, 0.0], max: [-1.4, 0.5, 2.5]}}
entities:
  robot:
    activities: [waiting, loading, down]
behaviours: !replace
  process_controller:
    kind: process
    steps:
      - {{name: fetch, move_to: shared_table, activity: loading}}
      - {{name: carry, move_to: weld_spot, activity: loading}}
    restart_on_request: {{loading: fetch}}
validation: !replace {{}}
"""


def test_a_cell_speaks_its_own_words_in_its_black_box(tmp_path):
    """Places are the layout's names: no welding-cell word reaches the evidence."""
    from cellsim.blackbox import BlackBox
    from cellsim.simulation import simulate

    path = tmp_path / "own_words.yaml"
    path.write_text(OWN_WORDS.format(base=WELDING_CELL))
    simulate(load_scenario(path), tmp_path / "run", duration=20.0)
    with BlackBox(tmp_path / "run" / "blackbox.sqlite") as bb:
        channels = bb.channels()
        robot_at = set(bb.series("robot.location").values)
        person_at = set(bb.series("operator.location").values)
        at_pallet = set(bb.series("operator.at_pallet").values)
    assert channels["robot.location"].domain == ["infeed", "press", "aisle", "unknown"]
    assert channels["robot.activity"].domain == ["waiting", "loading", "down", "unknown"]
    assert channels["operator.location"].domain == ["away", "pressArea"]
    assert robot_at == {"infeed", "press", "aisle"} and person_at == {"away", "pressArea"} and at_pallet == {False, True}
    assert "operator.at_table" not in channels
    words = {"atTable", "sharedTbl", "atWeldSpot", "inCell", "none", "exchWrkp"}
    # the harm service's own "none" (no contact) and a sensor's blind-spot "none" (nobody unseen) are cellsim's
    # words, not the welding cell's place
    ours = lambda name: name.startswith("harm.") or name.endswith(".unseen")  # noqa: E731
    assert not words & {v for name, c in channels.items() if isinstance(c.domain, list) and not ours(name)
                        for v in c.domain}


@pytest.mark.parametrize(
    "layout, expected",
    [
        ("  robot_regions: !replace {unknown: {min: [0, 0, 0], max: [1, 1, 1]}}\n", "already the name of the location outside"),
        ("  robot_regions: !replace {in cell: {min: [0, 0, 0], max: [1, 1, 1]}}\n", "must be an identifier"),
        ("  operator_zones: !replace {none: {min: [0, 0, 0], max: [1, 1, 1]}}\n", "already the name of the location outside"),
        ("  operator_flags: {location: {min: [0, 0, 0], max: [1, 1, 1]}}\n", "cannot name a person's channel"),
    ],
)
def test_bad_place_names_are_refused(tmp_path, layout, expected):
    path = tmp_path / "bad.yaml"
    path.write_text(f"base: {WELDING_CELL}\nname: bad\nlayout:\n{layout}")
    with pytest.raises(ConfigError, match=expected):
        load_scenario(path)


@pytest.mark.parametrize(
    "edit, key, expected",
    [
        (("activity: loading}}\n      - {{name: carry", "activity: lading}}\n      - {{name: carry"),
         "behaviours.process_controller.steps.0.activity", "'lading' is not an activity of robot"),
        (("restart_on_request: {{loading: fetch}}", "restart_on_request: {{welding: fetch}}"),
         "behaviours.process_controller.restart_on_request.welding", "'welding' is not an activity of robot"),
    ],
)
def test_activities_must_be_the_robots(tmp_path, edit, key, expected):
    path = tmp_path / "bad.yaml"
    text = OWN_WORDS.replace(*edit)
    assert text != OWN_WORDS
    path.write_text(text.format(base=WELDING_CELL))
    with pytest.raises(ConfigError) as e:
        load_scenario(path)
    assert e.value.key == key and expected in e.value.problem


def test_what_the_cell_tells_a_person_is_in_its_own_words(tmp_path):
    from cellsim.diagrams.cell import build_cell

    words = (
        f"base: {WELDING_CELL}\nentities:\n  operator:\n    notifications: [quiet, stepBack, stop]\n"
        "    alerts: [leave_workbench, wear_goggles]\n"
    )
    path = tmp_path / "words.yaml"
    path.write_text(words)
    # the welding risk model still commands ok / leaveArea: the wiring check refuses it
    with pytest.raises(ConfigError, match=r"notif takes \['ok', 'leaveArea'\] but the channel carries"):
        build_cell(load_scenario(path), seed=0, duration=1.0, record=False)
    path.write_text(words + "behaviours: !replace {}\nvalidation: !replace {}\n")
    person = build_cell(load_scenario(path), seed=0, duration=1.0, record=False).modules["operator"]
    assert [m.value for m in person.notification_type] == ["quiet", "stepBack", "stop"]
    assert person.HasInputPort("wear_goggles") and person.command_fields == ("notification", "leave_workbench", "wear_goggles")
