"""The limits table and a contact's severity against it, by hand (cellsim.kinds.harm.limits): fast tests that the
mutation testing runs against every change to the formula (docs/mutation.md)."""

from __future__ import annotations

import math

import pytest

from cellsim.config.typed_yaml import ConfigError
from cellsim.kinds.harm.limits import (
    FORBIDDEN, QUASI_STATIC, SHIPPED, TRANSIENT, RegionLimits, load_limits, permissible_speed, reduced_mass, severity)

HAND = RegionLimits(force=140.0, pressure=200.0, spring_constant=75.0, effective_mass=0.6, transient_factor=2.0)
HEAD = RegionLimits(force=130.0, pressure=130.0, spring_constant=150.0, effective_mass=4.4, transient_factor=None)
ROBOT = 10.0  # kg: the robot's effective mass


def test_the_reduced_mass_is_the_two_masses_in_series():
    assert reduced_mass(0.6, 10.0) == pytest.approx(0.6 * 10.0 / 10.6, rel=1e-12)
    assert reduced_mass(40.0, 40.0) == pytest.approx(20.0, rel=1e-12)
    assert reduced_mass(4.0, 1e12) == pytest.approx(4.0, rel=1e-9)  # an immovable robot: the region's own mass


def test_the_permissible_speeds_are_the_hand_computed_ones():
    """v_max = F / sqrt(k mu): k in N/m (the table's N/mm times 1000); a transient contact's F doubled and mu the two
    masses in series; a pinned region cannot move away, so a quasi-static contact's mu is the robot's own mass (a
    review found the two-mass mu there: five times the speed a hand pressed on a table was allowed)."""
    mu = 0.6 * 10.0 / 10.6
    assert permissible_speed(HAND, ROBOT, QUASI_STATIC) == pytest.approx(140.0 / math.sqrt(75_000.0 * ROBOT), rel=1e-12)
    assert permissible_speed(HAND, ROBOT, TRANSIENT) == pytest.approx(280.0 / math.sqrt(75_000.0 * mu), rel=1e-12)
    assert permissible_speed(HEAD, ROBOT, TRANSIENT) == 0.0  # not permitted at all
    assert permissible_speed(HEAD, ROBOT, QUASI_STATIC) == pytest.approx(130.0 / math.sqrt(150_000.0 * ROBOT), rel=1e-12)


@pytest.mark.parametrize("kind", [TRANSIENT, QUASI_STATIC])
def test_severity_is_speed_over_the_permissible_speed_and_crosses_one_there(kind):
    v_max = permissible_speed(HAND, ROBOT, kind)
    assert severity(HAND, ROBOT, kind, v_max) == pytest.approx(1.0, rel=1e-12)
    assert severity(HAND, ROBOT, kind, 0.99 * v_max) < 1.0 < severity(HAND, ROBOT, kind, 1.01 * v_max)
    assert severity(HAND, ROBOT, kind, 0.5 * v_max) == pytest.approx(0.5, rel=1e-12)
    assert severity(HAND, ROBOT, kind, 0.0) == 0.0
    assert severity(HAND, ROBOT, kind, -0.3) == 0.0  # parting: no energy transferred


def test_a_contact_of_no_known_kind_is_refused():
    with pytest.raises(ValueError, match="kind"):
        permissible_speed(HAND, ROBOT, "glancing")
    with pytest.raises(ValueError, match="kind"):
        severity(HAND, ROBOT, None, 0.1)


def test_a_transient_head_contact_is_harm_at_any_speed_and_worse_the_faster():
    v_qs = permissible_speed(HEAD, ROBOT, QUASI_STATIC)
    assert severity(HEAD, ROBOT, TRANSIENT, 0.0) == FORBIDDEN == 2.0
    # drawing apart is harm too (an audit saw a stopped arm's solver noise, -1e-7 m/s, read a pierced face as none)
    assert severity(HEAD, ROBOT, TRANSIENT, -1e-7) == severity(HEAD, ROBOT, TRANSIENT, -1.0) == FORBIDDEN
    assert severity(HEAD, ROBOT, TRANSIENT, v_qs) == pytest.approx(3.0, rel=1e-12)
    assert severity(HEAD, ROBOT, TRANSIENT, 0.1) < severity(HEAD, ROBOT, TRANSIENT, 0.2)


def test_a_pinned_contact_begins_as_an_impact_so_pinning_never_lowers_a_severity():
    """An audit found a head pinned against a machine judged by the quasi-static force alone: 0.28 at 5 cm/s where the
    same touch on a free head was 2.28. A clamp starts with an impact: its severity is the larger of the two."""
    v_qs = permissible_speed(HEAD, ROBOT, QUASI_STATIC)
    for speed in (0.0, 0.05, 0.5 * v_qs, v_qs, 3.0 * v_qs):
        assert severity(HEAD, ROBOT, QUASI_STATIC, speed) == pytest.approx(2.0 + speed / v_qs, rel=1e-12)
        assert severity(HEAD, ROBOT, QUASI_STATIC, speed) == severity(HEAD, ROBOT, TRANSIENT, speed)
    # where transient contact is permitted, its limit is the higher: the quasi-static one decides a clamp
    v_hand = permissible_speed(HAND, ROBOT, QUASI_STATIC)
    for speed in (0.0, 0.3 * v_hand, v_hand, 2.0 * v_hand):
        assert severity(HAND, ROBOT, QUASI_STATIC, speed) == pytest.approx(speed / v_hand, rel=1e-12)
        assert severity(HAND, ROBOT, QUASI_STATIC, speed) >= severity(HAND, ROBOT, TRANSIENT, speed)
    assert severity(HEAD, ROBOT, QUASI_STATIC, -0.1) == FORBIDDEN  # a head touched is harm, parting or not
    assert severity(HAND, ROBOT, QUASI_STATIC, -0.1) == 0.0  # elsewhere parting presses nothing


def test_the_shipped_table_names_its_source_and_every_region(tmp_path):
    from cellsim.body import REGIONS

    table = load_limits(SHIPPED, REGIONS).value
    assert "ISO/TS 15066" in table.source and set(REGIONS) <= set(table.regions)
    assert table.regions["head"].transient_factor is None and table.regions["face"].transient_factor is None


def _table(tmp_path, source: str, regions: str, source_first: bool = False):
    """A table file under a comment line; the key written first is on line 2 (as is the file's own root)."""
    path = tmp_path / "limits.yaml"
    keys = [f"source: {source}\n", f"regions:\n{regions}"]
    path.write_text("# our own measurements\n" + "".join(keys if source_first else keys[::-1]))
    return path


def test_a_table_without_a_source_or_missing_a_region_is_refused_naming_file_line_and_key(tmp_path):
    row = "  hand: {force: 140, pressure: 200, transient_factor: 2.0, spring_constant: 75, effective_mass: 0.6}\n"
    with pytest.raises(ConfigError) as e:
        load_limits(_table(tmp_path, "''", row), ("hand",))
    assert e.value.key == "source" and e.value.line == 4 and str(tmp_path / "limits.yaml") in str(e.value)
    assert e.value.problem == "name where the numbers come from"
    with pytest.raises(ConfigError) as e:
        load_limits(_table(tmp_path, "my lab", row, source_first=True), ("hand", "head", "face"))
    assert e.value.key == "regions" and e.value.line == 3 and "head, face" in str(e.value)
    assert e.value.source == str(tmp_path / "limits.yaml")
    assert "regions head" in str(e.value)
    with pytest.raises(ConfigError) as e:
        load_limits(_table(tmp_path, "my lab", row), ("hand", "head"))
    assert "region head" in str(e.value) and "regions" not in str(e.value).split("no limits for the body")[1]
    assert load_limits(_table(tmp_path, "my lab", row), ("hand",)).value.regions["hand"] == HAND
    bad = row.replace("force: 140", "force: 0")
    with pytest.raises(ConfigError) as e:
        load_limits(_table(tmp_path, "my lab", bad), ("hand",))
    assert "force" in e.value.key and e.value.line == 3


def test_a_table_with_a_row_for_no_body_region_is_refused_naming_the_row(tmp_path):
    """A review found a misspelt row (lower_arm beside forearm) loaded silently: read by nobody."""
    import yaml

    from cellsim.body import REGIONS

    table = yaml.safe_load(SHIPPED.read_text())
    table["regions"]["lower_arm"] = dict(table["regions"]["forearm"])
    path = tmp_path / "limits.yaml"
    path.write_text(yaml.safe_dump(table))
    with pytest.raises(ConfigError) as refused:
        load_limits(path, REGIONS)
    line = next(n for n, text in enumerate(path.read_text().splitlines(), 1) if text.strip() == "lower_arm:")
    assert (refused.value.source, refused.value.line, refused.value.key) == (str(path), line, "regions.lower_arm")
    assert refused.value.problem == f"no body region is called 'lower_arm' (the body's regions: {', '.join(REGIONS)})"
    assert set(load_limits(SHIPPED, REGIONS).value.regions) == set(REGIONS)  # the shipped table: every row a region
