"""The default conditions: every cell with a robot and a person is judged by NoHarm and NoClamping, every
monitored arm by TrueSSM; a scenario is spared one only by waiving it with a reason, which is printed; a
limits table of the user's own replaces cellsim's. Run as the CLI, as a user would."""

from __future__ import annotations

import sqlite3

import pytest
from conftest import ROOT, WELDING_CELL
from test_bad_input import cellsim, one_line

from cellsim.scenario import load_scenario
from cellsim.validation.defaults import default_conditions, judged_validation

TENDING = ROOT / "scenarios" / "machine_tending.yaml"


def variant(tmp_path, base, text: str, name: str = "variant.yaml"):
    path = tmp_path / name
    path.write_text(f"base: {base}\n{text}")
    return path


def test_scenario_check_lists_the_default_conditions():
    done = cellsim("scenario", "check", str(TENDING))
    assert done.returncode == 0, done.stderr
    assert "default conditions: TrueSSM, NoHarm, NoClamping" in done.stdout
    done = cellsim("scenario", "check", str(WELDING_CELL))
    assert "default conditions: NoHarm, NoClamping" in done.stdout  # no speed and separation monitor there


def test_a_waived_condition_is_not_judged_and_its_reason_is_printed(tmp_path):
    path = variant(tmp_path, TENDING, "validation:\n  waive:\n    TrueSSM: the arm's own SSM function is certified\n")
    out = tmp_path / "run"
    done = cellsim("simulate", str(path), "--out", str(out), "--duration", "8", timeout=300)
    assert done.returncode in (0, 1), done.stderr
    assert "4 conditions" in done.stdout  # the scenario's two, NoHarm and NoClamping
    assert "waived" in done.stdout and "TrueSSM: the arm's own SSM function is certified" in done.stdout
    checked = cellsim("check", str(out), timeout=300)
    assert "waived: TrueSSM (the arm's own SSM function is certified)" in checked.stdout
    assert "TrueSSM" not in checked.stdout.replace("waived: TrueSSM", "") and "4 conditions" in checked.stdout
    listed = cellsim("scenario", "check", str(path))
    assert "default conditions: NoHarm, NoClamping" in listed.stdout
    assert "waived: TrueSSM (the arm's own SSM function is certified)" in listed.stdout


@pytest.mark.parametrize("text, key, expected", [
    ("validation:\n  waive:\n    NoHarms: typo\n", "waive.NoHarms", "'NoHarms' is no default condition"),
    ("validation:\n  waive:\n    NoHarm: ''\n", "waive.NoHarm", "say why the scenario is not judged by it"),
    ("validation:\n  conditions:\n    NoHarm: G(true)\n", "conditions.NoHarm", "is a default condition every cell"),
])
def test_waivers_and_names_that_would_hide_a_default_condition_are_refused(tmp_path, text, key, expected):
    path = variant(tmp_path, TENDING, text)
    out = tmp_path / "run"
    done = cellsim("simulate", str(path), "--out", str(out))
    assert done.returncode == 2
    line = one_line(done.stderr)
    assert expected in line and key in line and "variant.yaml" in line
    assert not out.exists()


def test_a_default_condition_needs_the_channels_it_reads():
    """Judged against a black box without the harm service's channels (a run recorded before it), NoHarm is not
    added: it is not left as missing data either."""
    sf = load_scenario(TENDING)
    assert set(default_conditions(sf.scenario)) == {"TrueSSM", "NoHarm", "NoClamping"}
    judged = judged_validation(sf, {"ssm.true_margin": None, "robot.safety_mode": None})
    assert "TrueSSM" in judged.conditions and "NoHarm" not in judged.conditions


def test_a_limits_table_of_ones_own_replaces_cellsims(tmp_path):
    """Halving every force halves every permissible speed: the same contact is twice as severe."""
    import yaml

    shipped = yaml.safe_load((ROOT / "cellsim" / "kinds" / "harm" / "body_limits.yaml").read_text())
    mine = {"source": "our own measurements (test)",
            "regions": {r: {**row, "force": row["force"] / 2} for r, row in shipped["regions"].items()}}
    (tmp_path / "limits.yaml").write_text(yaml.safe_dump(mine))
    ours = load_scenario(variant(tmp_path, TENDING, "services:\n  harm:\n    kind: harm\n    limits: limits.yaml\n"))
    from cellsim.kinds.harm.kind import _limits
    from cellsim.kinds.harm.limits import TRANSIENT, permissible_speed

    table = _limits(ours, "harm", ours.scenario.services["harm"])
    cellsims = _limits(load_scenario(TENDING), "harm", load_scenario(TENDING).scenario.services["harm"])
    assert table.source == "our own measurements (test)"
    for region in ("hand", "chest"):
        assert permissible_speed(table.regions[region], 16.0, TRANSIENT) == pytest.approx(
            permissible_speed(cellsims.regions[region], 16.0, TRANSIENT) / 2)


@pytest.mark.parametrize("edit, key", [
    (lambda t: t["regions"].pop("face"), "regions"),
    (lambda t: t["regions"]["hand"].update(force=-1), "regions.hand.force"),
    (lambda t: t.update(source=" "), "source"),
    # a review found a row for no region of the body (a misspelling, another table's name) read by nobody
    (lambda t: t["regions"].update(lower_arm=t["regions"]["forearm"]), "regions.lower_arm"),
])
def test_a_bad_limits_table_is_one_line_naming_its_file_and_key(tmp_path, edit, key):
    import yaml

    table = yaml.safe_load((ROOT / "cellsim" / "kinds" / "harm" / "body_limits.yaml").read_text())
    edit(table)
    (tmp_path / "limits.yaml").write_text(yaml.safe_dump(table))
    path = variant(tmp_path, TENDING, "services:\n  harm:\n    kind: harm\n    limits: limits.yaml\n")
    out = tmp_path / "run"
    done = cellsim("simulate", str(path), "--out", str(out))
    assert done.returncode == 2
    line = one_line(done.stderr)
    assert "limits.yaml" in line and key in line
    assert not out.exists()


def test_the_resolved_scenario_keeps_the_harm_service(tmp_path):
    """A run's scenario.yaml names the harm service it ran with (every default written out), and runs again."""
    out = tmp_path / "run"
    assert cellsim("simulate", str(WELDING_CELL), "--out", str(out), "--duration", "2", timeout=300).returncode == 0
    resolved = (out / "scenario.yaml").read_text()
    assert "harm:" in resolved and "kind: harm" in resolved
    db = sqlite3.connect(out / "blackbox.sqlite")
    channels = {name for (name,) in db.execute("SELECT name FROM channels")}
    db.close()
    assert {"harm.severity", "harm.clamping", "harm.separation_robot"} <= channels
    again = tmp_path / "again"
    assert cellsim("simulate", str(out / "scenario.yaml"), "--out", str(again), "--duration", "2", timeout=300).returncode == 0


def test_a_look_too_rare_for_its_cut_off_is_refused(tmp_path):
    """Between two looks nothing may close the cut-off: a far_period too long for it is one line, exit 2."""
    out = tmp_path / "run"
    done = cellsim("simulate", str(TENDING), "--out", str(out), "--set", "harm.cutoff=0.1", "--set", "harm.far_period=0.05")
    assert done.returncode == 2
    line = one_line(done.stderr)
    assert "far_period" in line and "shorten far_period or widen cutoff" in line
    assert not out.exists()
