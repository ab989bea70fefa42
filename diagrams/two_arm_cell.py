#!/usr/bin/env python3
"""A small two-arm cell, built in Python: two arms hand a part over at a shared fixture while a person walks past.

A loader picks a part at a bench and places it on the fixture; an assembler waits for it, works it and retreats;
each waits for the other through its process's ``wait_until`` (no risk model: the point here is two arms and
their clearance). The ground truth measures how near the arms come to each other and to the person, the harm
service (every cell has it) judges any contact, and the conditions are written here, in code.

    python diagrams/two_arm_cell.py [--seed N] [--out FOLDER]
"""

from __future__ import annotations

import cellsim
from run_cell import SCENARIOS  # noqa: F401  (where the files this cell names are found)


def arm(base_y: float, yaw: float, activities: list[str], poses: dict) -> object:
    """A UR10-class arm on a pedestal at (0, base_y), facing the fixture."""
    return cellsim.module(
        "robot", model="models/ur10.urdf", base_position=(0.0, base_y, 0.75), base_yaw_deg=yaw, tool_frame="tcp",
        activities=activities, initial_pose="home",
        named_poses={"home": [0.0, -1.57, 1.57, -1.57, -1.57, 0.0],
                     **{name: {"tool_at": at, "tool_rpy_deg": [0.0, 90.0, 0.0]} for name, at in poses.items()}},
        speed_limits={"normal": 1.0, "hguid": 0.25, "ssmon": 1.0, "pflim": 0.25}, braking_time=0.4,
        twin={"mode": "model"})


def two_arm_cell() -> cellsim.Scenario:
    grey, dark = (0.35, 0.35, 0.4, 1.0), (0.3, 0.3, 0.33, 1.0)
    layout = cellsim.Layout(
        fixtures={
            "fixture": cellsim.Fixture(size=(0.6, 0.5, 0.8), center=(0.0, 0.0, 0.4), color=grey),
            "loader_pedestal": cellsim.Fixture(size=(0.4, 0.4, 0.75), center=(0.0, -0.85, 0.375), color=dark),
            "assembler_pedestal": cellsim.Fixture(size=(0.4, 0.4, 0.75), center=(0.0, 0.85, 0.375), color=dark),
            "bench": cellsim.Fixture(size=(0.6, 0.7, 0.85), center=(-1.15, -0.9, 0.425), color=(0.2, 0.45, 0.25, 1.0)),
        },
        robot_regions={"atFixture": cellsim.Region(min=(-0.35, -0.3, 0.8), max=(0.35, 0.3, 1.3)),
                       "atBench": cellsim.Region(min=(-1.45, -1.25, 0.85), max=(-0.85, -0.55, 1.5))},
        robot_elsewhere="clear",
        operator_zones={"nearCell": cellsim.Region(min=(-2.0, -2.0, 0.0), max=(2.0, 2.0, 2.5))},
        operator_outside="away",
    )
    loading = [
        {"name": "to_bench", "move_to": "bench_pick", "activity": "picking"},
        {"name": "grip", "dwell": 0.5, "activity": "picking"},
        {"name": "to_clear", "move_to": "loader_clear", "activity": "loading"},
        {"name": "await_fixture", "wait_until": "assembling.step == await_part", "activity": "waiting"},
        {"name": "to_fixture", "move_to": "fixture_place", "activity": "loading"},
        {"name": "release", "dwell": 0.5, "activity": "loading"},
        {"name": "retreat", "move_to": "loader_clear", "activity": "loading"},
        {"name": "handed", "wait_until": "assembling.step != await_part", "activity": "waiting"},
    ]
    assembling = [
        {"name": "clear", "move_to": "assembler_clear", "activity": "waiting"},
        {"name": "await_part", "wait_until": "loading.step == handed", "activity": "waiting"},
        {"name": "to_fixture", "move_to": "fixture_work", "activity": "assembling"},
        {"name": "join", "dwell": 1.5, "activity": "assembling"},
        {"name": "retreat", "move_to": "assembler_clear", "activity": "assembling"},
    ]
    return cellsim.Scenario(
        name="two_arm_cell",
        description="Two arms hand a part over at a shared fixture while a person walks past.",
        duration=20.0, seed=0, time_step=0.002, layout=layout,
        entities={
            "loader": arm(-0.85, 90.0, ["waiting", "picking", "loading"],
                          {"loader_clear": [-0.45, -0.95, 1.35], "bench_pick": [-1.0, -0.9, 1.0],
                           "fixture_place": [0.0, -0.1, 0.95]}),
            "assembler": arm(0.85, -90.0, ["waiting", "assembling"],
                             {"assembler_clear": [-0.4, 1.0, 1.35], "fixture_work": [0.0, 0.1, 0.95]}),
            "operator": cellsim.module(
                "operator", start=(-2.6, -2.2), walking_speed=1.2,
                waypoints={"past": {"position": [-1.8, 1.8], "wait": 2.0}, "away": {"position": [2.6, 2.2], "wait": 1.0}},
                twin={"mode": "model"}),
        },
        behaviours={
            "loading": cellsim.module("process", robot="loader", steps=loading),
            "assembling": cellsim.module("process", robot="assembler", steps=assembling),
            "ground_truth": cellsim.module("ground_truth"),
        },
        services={"blackbox": cellsim.module("blackbox")},
        validation=cellsim.Validation(conditions={
            "ArmsApart": "G(ground_truth.clearance_loader_assembler > 0.05)",
            "PartHanded": "F(assembling.step == join)",
        }),
    )


if __name__ == "__main__":
    from run_cell import main

    main(two_arm_cell, __doc__.splitlines()[0])
