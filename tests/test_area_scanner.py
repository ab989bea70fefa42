"""The area scanner: named fields, the innermost occupied one, never seen through fixtures."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from cellsim.config.typed_yaml import ConfigError
from cellsim.scenario import load_scenario
from cellsim.blackbox import BlackBox
from cellsim.simulation import simulate
from cellsim.diagrams.cell import build_cell

from conftest import WELDING_CELL, legs_distance, place_operator
from test_sensors import put_operator

# A scanner at the welder's south-west corner, 0.2 m above the floor. The
# protective field is an L on the floor (not convex: the notch at x 0.8-1.3,
# y -0.6-0.5 is outside it); the warning field a box over most of the cell.
SCANNER_CELL = """\
base: {base}
entities:
  press_scanner:
    kind: area_scanner
    position: [1.3, -0.45, 0.2]
    fields:
      protective:
        polygon: [[0.3, -1.5], [1.3, -1.5], [1.3, -0.6], [0.8, -0.6], [0.8, 0.5], [0.3, 0.5]]
        heights: [0.0, 0.4]
      warning: {{box: {{min: [-1.0, -1.55, 0.0], max: [1.95, 1.55, 0.4]}}}}
    clear: free
    {extra}
validation: !replace {{}}
"""


def scanner_cell(tmp_path, extra: str = "", **edits) -> str:
    text = SCANNER_CELL.format(base=WELDING_CELL, extra=extra)
    for old, new in edits.items():
        assert old in text
        text = text.replace(old, new)
    path = tmp_path / "scanner_cell.yaml"
    path.write_text(text)
    return str(path)


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    sf = load_scenario(scanner_cell(tmp_path_factory.mktemp("scanner")))
    built = build_cell(sf, seed=0, duration=1.0, record=False)
    sim = Simulator(built.diagram)
    built.set_initial_state(sim.get_mutable_context())
    return built, sim.get_mutable_context()


def reading(cell, context, x, y):
    put_operator(cell, context, x, y)
    scanner = cell.modules["press_scanner"]
    code, distance = scanner.measure(scanner.GetMyContextFromRoot(context))
    return scanner.readings.from_code(code).value, distance


BEHIND_PEDESTAL = (-0.567, 0.196)  # on the line from the scanner through the robot's pedestal


@pytest.mark.parametrize(
    "where, expected",
    [
        ((0.55, 0.2), "protective"),  # in the L's long arm: innermost wins over warning
        ((0.55, -1.2), "protective"),  # in its foot
        ((1.05, 0.1), "warning"),  # in the notch of the L: only the warning field
        ((-0.5, -1.0), "warning"),
        (BEHIND_PEDESTAL, "free"),  # in the warning field, hidden behind the pedestal
        ((-2.5, -1.0), "free"),  # outside every field
    ],
)
def test_the_scanner_reports_the_innermost_field_it_sees_a_person_in(cell, where, expected):
    built, context = cell
    assert reading(built, context, *where)[0] == expected


def test_the_scanner_does_not_see_through_a_fixture(cell):
    built, context = cell
    _, hidden = reading(built, context, *BEHIND_PEDESTAL)
    field, seen = reading(built, context, BEHIND_PEDESTAL[0], BEHIND_PEDESTAL[1] + 0.6)  # stepped out from behind
    assert hidden == pytest.approx(10.0)  # nobody seen: max_range
    assert field == "warning" and seen == pytest.approx(
        legs_distance((1.3, -0.45), (BEHIND_PEDESTAL[0], BEHIND_PEDESTAL[1] + 0.6)), abs=1e-6)


def test_without_the_pedestal_the_same_spot_is_in_the_warning_field(tmp_path):
    sf = load_scenario(scanner_cell(tmp_path))
    del sf.scenario.layout.fixtures["robot_pedestal"]
    built = build_cell(sf, seed=0, duration=1.0, record=False)
    sim = Simulator(built.diagram)
    built.set_initial_state(sim.get_mutable_context())
    assert reading(built, sim.get_mutable_context(), *BEHIND_PEDESTAL)[0] == "warning"


def test_a_walk_through_the_fields_is_recorded_in_the_cells_words(tmp_path):
    from cellsim.kinds.operator.config import Waypoint

    sf = place_operator(
        load_scenario(scanner_cell(tmp_path)), (-2.5, -1.0),
        {"in": Waypoint((0.55, -1.0), 1.0), "out": Waypoint((-2.5, -1.0), 100.0)},
    )
    simulate(sf, tmp_path / "run", duration=8.0)
    with BlackBox(tmp_path / "run" / "blackbox.sqlite") as bb:
        field = bb.series("press_scanner.field").values
        distance = bb.series("press_scanner.distance").values
    assert field[:4] == ["free", "warning", "protective", "warning"] and field[-1] == "free"
    # nearest at the waypoint, facing east (+x) as they walked: the scanner's beams meet the lower legs
    assert min(distance) == pytest.approx(legs_distance((1.3, -0.45), (0.55, -1.0), yaw=0.0), abs=0.03)
    # within range from the first update to the last: its max_range (10 m), the state before any update,
    # is never recorded (it was, as a reading at t = 0, while the distance was recorded every 0.1 s)
    assert 10.0 not in distance and distance[0] == pytest.approx(distance[-1], abs=1e-6)


def test_shadowing_with_no_sample_the_scanner_fails_safe_to_its_innermost_field(tmp_path):
    path = scanner_cell(tmp_path, extra="twin: {mode: shadow}")
    simulate(load_scenario(path), tmp_path / "run", duration=2.0)
    with BlackBox(tmp_path / "run" / "blackbox.sqlite") as bb:
        assert bb.series("press_scanner.field").values[-1] == "protective"
        assert bb.series("press_scanner.distance").values[-1] == 0.0


def test_a_physical_sample_farther_than_the_scanner_can_measure_is_corrupt(tmp_path):
    """A scanner's distance lies within 0..max_range (a transport's rounding allowed): a PLC-fed scanner reporting
    1e9 m would have driven an SSM reading its distance (the live-twin audit)."""
    from cellsim.diagrams.cell import build_cell
    from cellsim.kinds.sensing import SAMPLE_ROUNDING

    built = build_cell(load_scenario(scanner_cell(tmp_path, extra="twin: {mode: shadow}")), seed=0, duration=1.0,
                       record=False)
    scanner = built.modules["press_scanner"]
    free, reach = scanner.readings("free").code, scanner.cfg.max_range
    assert scanner.sample_is_valid([free, reach]) and scanner.sample_is_valid([free, reach + 0.5 * SAMPLE_ROUNDING])
    assert not scanner.sample_is_valid([free, reach + 2 * SAMPLE_ROUNDING])
    assert not scanner.sample_is_valid([free, 1e9]) and not scanner.sample_is_valid([free, -0.1])


@pytest.mark.parametrize(
    "edits, key, expected",
    [
        ({"[1.95, 1.55, 0.4]": "[3.5, 1.55, 0.4]"}, "entities.press_scanner.fields.warning", "outside the cell"),
        ({"position: [1.3, -0.45, 0.2]": "position: [9.0, -0.45, 0.2]"}, "entities.press_scanner.position", "outside the cell"),
        ({"[0.8, 0.5], [0.3, 0.5]": "[0.3, 0.5], [0.8, 0.5]"}, "entities.press_scanner.fields.protective.polygon", "edges cross"),
        ({"heights: [0.0, 0.4]": "heights: [0.4, 0.0]"}, "entities.press_scanner.fields.protective.heights", "bottom height"),
        ({"clear: free": "clear: warning"}, "entities.press_scanner.clear", "also the name of a field"),
    ],
)
def test_bad_fields_are_load_errors_naming_the_key(tmp_path, edits, key, expected):
    with pytest.raises(ConfigError) as e:
        load_scenario(scanner_cell(tmp_path, **edits))
    assert e.value.key == key and expected in str(e.value)
