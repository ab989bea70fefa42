"""The arm's collision shapes are measuring geometry outside the plant, which simulates no contact."""

from __future__ import annotations

import numpy as np
from pydrake.systems.analysis import Simulator

from cellsim.kinds.robot.geometry import collision_shapes, model_without_collision
from cellsim.diagrams.cell import build_cell

from conftest import ROOT, welding_cell

UR10 = ROOT / "scenarios" / "models" / "ur10.urdf"


def test_the_cells_plant_has_no_collision_geometry_and_the_arms_shapes_are_measured():
    sf = welding_cell()
    built = build_cell(sf, seed=0, duration=1.0, record=False)
    assert built.plant.num_collision_geometries() == 0  # no contact query at every plant step
    sim = Simulator(built.diagram)
    built.set_initial_state(sim.get_mutable_context())
    shapes, _ = collision_shapes(UR10, "robot")
    truth = built.modules["ground_truth"]
    query = truth.query_port.Eval(truth.GetMyContextFromRoot(sim.get_context()))
    robot_ids = set(truth.robot_ids)
    assert len(robot_ids) == len(shapes) == 8
    # each shape sits where the plant puts its link: the base link's shape is at the base
    inspector = query.inspector()
    base = next(g for g in robot_ids if "base_link" in inspector.GetName(inspector.GetFrameId(g)))
    X_WG = query.GetPoseInWorld(base)
    assert np.linalg.norm(X_WG.translation()[:2]) < 0.2 and abs(X_WG.translation()[2] - 0.75) < 0.2


def test_a_model_without_collision_keeps_everything_else_and_finds_its_meshes(tmp_path):
    model = tmp_path / "arm" / "arm.urdf"
    model.parent.mkdir()
    model.write_text(
        '<robot name="a"><link name="l"><visual><geometry><mesh filename="meshes/l.obj"/></geometry></visual>'
        '<collision><geometry><box size="1 1 1"/></geometry></collision>'
        '<collision name="c2"><geometry><mesh filename="package://x/c.obj"/></geometry></collision></link></robot>'
    )
    text, file_type = model_without_collision(model)
    assert file_type == "urdf" and "<collision" not in text and "<visual>" in text
    assert f'filename="{(model.parent / "meshes" / "l.obj").resolve()}"' in text
