"""Cartesian tool targets: a named pose given by where the tool goes, solved at load time."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from cellsim.config.typed_yaml import ConfigError
from cellsim.kinds.robot.kind import resolve_poses
from cellsim.kinds.robot.system import ArmKinematics
from cellsim.scenario import load_scenario
from cellsim.blackbox import BlackBox
from cellsim.simulation import simulate

from conftest import WELDING_CELL

# The weld spot as a tool target: the tool 1 cm above the welding fixture's
# centre, pointing the way the joint pose of the welding cell points it.
TOOL_TARGET_CELL = """\
base: {base}
entities:
  robot:
    named_poses:
      weld_spot: {{tool_at: [{x}, 0.0, 0.95], tool_rpy_deg: [-45.0, 88.0, -55.0]}}
validation: !replace {{}}
"""


def cell(tmp_path, x: float = 0.95) -> str:
    path = tmp_path / "tool_target.yaml"
    path.write_text(TOOL_TARGET_CELL.format(base=WELDING_CELL, x=x))
    return str(path)


def test_a_tool_target_is_solved_into_joint_angles_that_put_the_tool_there(tmp_path):
    sf = load_scenario(cell(tmp_path))
    robot = sf.scenario.entities["robot"]
    poses = resolve_poses(sf, "robot", robot)
    kinematics = ArmKinematics(str(sf.resolve_path("entities.robot.model", robot.model)), robot)
    assert np.linalg.norm(kinematics.tool_position(poses["weld_spot"]) - [0.95, 0.0, 0.95]) < 2e-3
    # the joint poses are kept as written
    assert poses["home"].tolist() == list(robot.named_poses["home"])


def test_the_robot_moves_its_tool_to_the_target_in_simulation(tmp_path):
    simulate(load_scenario(cell(tmp_path)), tmp_path / "run", duration=12.0)
    with BlackBox(tmp_path / "run" / "blackbox.sqlite") as bb:
        reached = bb.series("robot.reached_pose")
        location = bb.series("robot.location")
    # the process carries the work-piece to the target: the tool arrives in the weld spot region
    assert "weld_spot" in reached.values
    assert "atWeldSpot" in location.values


def test_an_unreachable_target_is_a_load_error_naming_the_pose_and_the_step(tmp_path):
    with pytest.raises(ConfigError) as e:
        load_scenario(cell(tmp_path, x=2.5))
    assert e.value.key == "entities.robot.named_poses.weld_spot"
    assert "cannot reach [2.5, 0.0, 0.95]" in str(e.value)
    assert "step 'carry' of process_controller" in str(e.value)


def test_the_cli_reports_an_unreachable_target_in_one_line_and_writes_nothing(tmp_path):
    out = tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, "-m", "cellsim", "simulate", cell(tmp_path, x=2.5), "--out", str(out)],
        capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "tool_target.yaml:5: entities.robot.named_poses.weld_spot" in lines[0]
    assert not out.exists()
