"""Provenance: the content identity of a run's inputs, what differs between two, and
run folders that hold copies of what the run used (``cellsim simulate`` as the user runs it)."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT

import cellsim
from cellsim.config.typed_yaml import ConfigError
from cellsim.provenance import changes, read_inputs, snapshot_scenario, write_run_scenario
from cellsim.scenario import load_scenario
from cellsim.blackbox import BlackBox
from cellsim.simulation import BLACKBOX, simulate

RISK_MODEL = "welding_cell_risk_model.yaml"
VALIDATION = "welding_cell_validation.yaml"
# An edit that changes what the controller commands from t = 0: runs that read it differ.
NORMAL_DEFAULT = "stopped], default: normal}"
SSMON_DEFAULT = "stopped], default: ssmon}"


@pytest.fixture
def scenarios(tmp_path) -> Path:
    """A copy of the scenarios folder, free to edit."""
    return Path(shutil.copytree(ROOT / "scenarios", tmp_path / "scenarios"))


def add_condition(validation: Path, name: str, formula: str) -> None:
    text = validation.read_text()
    assert text.count("\nconditions:\n") == 1
    validation.write_text(text.replace("\nconditions:\n", f'\nconditions:\n  "{name}": {formula}\n'))


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _identity(scenario: Path, *overrides: str, seed=0, duration=3.0) -> dict:
    return read_inputs(load_scenario(scenario, list(overrides))).identity(overrides, seed, duration)


def test_the_identity_covers_every_input_file_by_content_not_path(scenarios, tmp_path):
    identity = _identity(scenarios / "welding_cell.yaml")
    files = identity["files"]
    assert {k: v["role"] for k, v in files.items()} == {
        "scenario": "scenario",
        "validation.file": "validation file",
        "entities.robot.model": "robot model",
        "behaviours.safety_controller.risk_model": "risk model",
    }
    assert files["behaviours.safety_controller.risk_model"]["sha256"] == _sha(scenarios / RISK_MODEL)
    assert files["entities.robot.model"]["sha256"] == _sha(scenarios / "models" / "ur10.urdf")
    assert identity["cellsim"] == cellsim.__version__
    # the same content elsewhere is the same identity: the hash names no path
    moved = shutil.copytree(scenarios, tmp_path / "elsewhere")
    assert _identity(moved / "welding_cell.yaml")["hash"] == identity["hash"]
    assert changes(identity, _identity(moved / "welding_cell.yaml")) == []


def test_what_changed_is_named(scenarios):
    scenario = scenarios / "welding_cell.yaml"
    before = _identity(scenario)
    risk = scenarios / RISK_MODEL
    risk.write_text(risk.read_text() + "\n# reviewed\n")
    validation = scenarios / VALIDATION
    add_condition(validation, "Always:stopped", "G(safmod == stopped)")
    after = _identity(scenario)
    assert after["hash"] != before["hash"]
    assert changes(before, after) == [f"validation file {validation} changed", f"risk model {risk} changed"]

    assert changes(after, _identity(scenario, "operator.walking_speed=1.0")) == [
        "overrides differ (none -> --set operator.walking_speed=1.0)"
    ]
    assert changes(after, _identity(scenario, seed=4, duration=None)) == ["seed 0 -> 4", "duration 3 s -> the scenario's"]
    assert changes({**after, "cellsim": "0.0.9"}, after) == [f"cellsim version 0.0.9 -> {cellsim.__version__}"]
    # a run's numbers depend on Drake and NumPy too: a campaign resumed after an upgrade would mix two simulators
    import importlib.metadata

    drake_now = importlib.metadata.version("drake")
    assert after["simulator"]["drake"] == drake_now and after["simulator"]["numpy"]
    older = {**after, "simulator": {**after["simulator"], "drake": "1.0.0"}}
    assert changes(older, after) == [f"drake version 1.0.0 -> {drake_now}"]
    # another risk model, named by an override
    other = scenarios / "other_risk_model.yaml"
    other.write_text(risk.read_text().replace(NORMAL_DEFAULT, SSMON_DEFAULT))
    moved = _identity(scenario, f"safety_controller.risk_model={other.name}")
    assert f"risk model {risk} -> {other} (other content)" in changes(after, moved)


def test_a_robot_model_s_meshes_are_inputs_copied_with_it(scenarios, tmp_path):
    urdf = scenarios / "models" / "ur10.urdf"
    mesh = scenarios / "models" / "meshes" / "base.obj"
    mesh.parent.mkdir()
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    text = urdf.read_text()
    first_visual = text.index("<visual>")
    urdf.write_text(
        text[:first_visual]
        + '<visual><geometry><mesh filename="meshes/base.obj"/></geometry></visual>'
        + '<visual><geometry><mesh filename="package://elsewhere/arm.obj"/></geometry></visual>'
        + text[first_visual:]
    )
    sf = load_scenario(scenarios / "welding_cell.yaml")
    inputs = read_inputs(sf)
    files = inputs.identity([], 0, 3.0)["files"]
    assert files["entities.robot.model:meshes/base.obj"]["sha256"] == _sha(mesh)
    assert not any("package://" in key for key in files)  # Drake's package map, not ours

    out = tmp_path / "run"
    out.mkdir()
    write_run_scenario(sf, inputs, out)
    assert (out / "inputs" / "robot" / "ur10.urdf").read_bytes() == urdf.read_bytes()
    assert (out / "inputs" / "robot" / "meshes" / "base.obj").read_bytes() == mesh.read_bytes()
    copied = load_scenario(out / "scenario.yaml")
    assert copied.scenario.entities["robot"].model == "inputs/robot/ur10.urdf"
    assert copied.scenario.validation == sf.scenario.validation and not copied.scenario.validation.file
    assert {k: v["sha256"] for k, v in read_inputs(copied).identity([], 0, 3.0)["files"].items() if k != "scenario"} == {
        k: v["sha256"] for k, v in files.items() if k not in ("scenario", "validation.file")
    }


def test_a_file_edited_while_a_run_is_prepared_stops_it(scenarios):
    inputs = read_inputs(load_scenario(scenarios / "welding_cell.yaml"))
    inputs.check_unchanged()
    (scenarios / RISK_MODEL).write_text((scenarios / RISK_MODEL).read_text() + "\n# edited\n")
    with pytest.raises(ConfigError, match="risk model changed while the run was being prepared"):
        inputs.check_unchanged()


def _cellsim(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "cellsim.cli", *args], cwd=cwd, capture_output=True, text=True, timeout=300,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )


def test_a_simulate_folder_re_runs_alone_after_its_originals_are_edited(scenarios, tmp_path):
    first = tmp_path / "first"
    done = _cellsim("simulate", str(scenarios / "welding_cell.yaml"), "--duration", "3", "--seed", "4",
                    "--out", str(first), "--quiet", cwd=tmp_path)
    assert done.returncode in (0, 1), done.stderr
    assert {p.relative_to(first).as_posix() for p in (first / "inputs").rglob("*") if p.is_file()} == {
        "inputs/robot/ur10.urdf", "inputs/safety_controller/welding_cell_risk_model.yaml"
    }
    with BlackBox(first / BLACKBOX) as bb:
        record = bb.metadata()["provenance"]
        rows = bb.rows()
    assert set(record["versions"]) >= {"python", "cellsim", "drake", "numpy"}
    assert "simulate" in record["command"] and "--seed 4" in record["command"]
    assert record["cwd"] == str(tmp_path) and record["created"]
    assert record["inputs"]["seed"] == 4 and record["inputs"]["duration"] == 3.0
    original_risk = record["inputs"]["files"]["behaviours.safety_controller.risk_model"]["sha256"]
    assert original_risk == _sha(scenarios / RISK_MODEL)

    # edit the original risk model, move the run folder: re-running it reads neither
    risk = scenarios / RISK_MODEL
    risk.write_text(risk.read_text().replace(NORMAL_DEFAULT, SSMON_DEFAULT))
    moved = Path(shutil.move(first, tmp_path / "archive" / "first"))
    again = tmp_path / "again"
    done = _cellsim("simulate", str(moved / "scenario.yaml"), "--out", str(again), "--quiet", cwd=tmp_path)
    assert done.returncode in (0, 1), done.stderr
    with BlackBox(again / BLACKBOX) as bb:
        assert bb.rows() == rows
        assert bb.metadata()["provenance"]["inputs"]["files"]["behaviours.safety_controller.risk_model"]["sha256"] == original_risk

    # the control: the same run with the edited risk model is another run
    edited = load_scenario(moved / "scenario.yaml", [f"safety_controller.risk_model={risk}"])
    simulate(edited, tmp_path / "edited")
    with BlackBox(tmp_path / "edited" / BLACKBOX) as bb:
        assert bb.rows() != rows


def test_a_campaign_snapshot_pins_files_named_by_absolute_paths(scenarios, tmp_path):
    elsewhere = tmp_path / "elsewhere" / RISK_MODEL
    elsewhere.parent.mkdir()
    shutil.move(scenarios / RISK_MODEL, elsewhere)
    scenario = scenarios / "welding_cell.yaml"
    scenario.write_text(scenario.read_text().replace(f"risk_model: {RISK_MODEL}", f"risk_model: {elsewhere}"))
    inputs = read_inputs(load_scenario(scenario))
    snapshot, pins = snapshot_scenario(inputs, tmp_path / "snap", [])
    assert any(p.startswith("behaviours.safety_controller.risk_model=") for p in pins)
    elsewhere.write_text("edited after the snapshot: never read again")
    again = read_inputs(load_scenario(snapshot, list(pins)))
    assert again.digests() == inputs.digests()
    assert all(f.path.is_relative_to(tmp_path / "snap") for f in again.files)


def test_a_scenario_s_base_is_an_input(scenarios, tmp_path):
    derived = scenarios / "derived.yaml"
    derived.write_text("base: welding_cell.yaml\nname: derived\nduration: 5.0\n")
    before = _identity(derived)
    assert before["files"]["base 1"] == {
        "role": "scenario base", "path": str(scenarios / "welding_cell.yaml"), "sha256": _sha(scenarios / "welding_cell.yaml")
    }
    base = scenarios / "welding_cell.yaml"
    base.write_text(base.read_text().replace("seed: 0\n", "seed: 1\n"))
    assert changes(before, _identity(derived)) == [f"scenario base {base} changed"]
    # a run folder's scenario is written whole: it names no base, and its files are copies
    sf = load_scenario(derived)
    out = tmp_path / "run"
    out.mkdir()
    write_run_scenario(sf, read_inputs(sf), out)
    assert "base:" not in (out / "scenario.yaml").read_text()
    assert [f.key for f in read_inputs(load_scenario(out / "scenario.yaml")).files] == [
        "scenario", "entities.robot.model", "behaviours.safety_controller.risk_model"
    ]
