#!/usr/bin/env python3
"""The collaborative spot-welding cell, built in Python: the same cell as ``scenarios/welding_cell.yaml``.

Every module is its kind's config dataclass, made by ``cellsim.module(kind, **fields)`` from the fields as a
scenario file writes them (converted and checked as a file's: an error names the field). The risk model and the validation (the safety conditions) stay in their files beside the
YAML scenario, which this one names, so both cells are judged by the same evidence; built from the same
values, they give the same black box for the same seed (tests/test_api.py).

    python diagrams/welding_cell.py [--seed N] [--out FOLDER]
"""

from __future__ import annotations

import cellsim
from run_cell import SCENARIOS  # noqa: F401  (where the files this cell names are found)


def welding_cell() -> cellsim.Scenario:
    """The welding cell's scenario (paper, section 5; docs/welding-cell.md): a UR10-class arm exchanges a work-piece
    with an operator over a shared table and presents it to a spot welder; a light curtain guards the table and a
    safety scanner at the welder's base measures how near the operator is."""
    module = cellsim.module
    model = {"mode": "model"}

    def box(size, center, color):
        return cellsim.Fixture(size=size, center=center, color=color)

    steel, wood, fence = (0.3, 0.3, 0.3, 1.0), (0.6, 0.5, 0.35, 1.0), (0.9, 0.8, 0.1, 0.35)
    layout = cellsim.Layout(
        fixtures={
            "robot_pedestal": box((0.4, 0.4, 0.75), (0.0, 0.0, 0.375), (0.3, 0.3, 0.33, 1.0)),
            "robot_table": box((0.6, 0.5, 0.8), (0.0, 0.95, 0.4), (0.45, 0.4, 0.35, 1.0)),
            "shared_table": box((0.6, 0.8, 0.85), (-1.05, 0.0, 0.425), wood),
            "operator_bench": box((0.5, 1.0, 0.9), (-2.35, 0.0, 0.45), wood),
            "welder_body": box((0.5, 0.6, 1.6), (1.6, 0.0, 0.8), (0.85, 0.55, 0.1, 1.0)),
            "welder_upper_arm": box((0.4, 0.1, 0.1), (1.2, 0.0, 1.14), (0.35, 0.35, 0.35, 1.0)),
            "welder_lower_arm": box((0.4, 0.1, 0.1), (1.2, 0.0, 0.86), (0.35, 0.35, 0.35, 1.0)),
            "welding_fixture": box((0.3, 0.3, 0.05), (1.05, 0.0, 0.78), steel),
            "fence_north": box((3.3, 0.05, 1.8), (0.35, 1.6, 0.9), fence),
            "fence_east": box((0.05, 3.2, 1.8), (2.0, 0.0, 0.9), fence),
            "fence_south": box((3.3, 0.05, 1.8), (0.35, -1.6, 0.9), fence),
        },
        # the cell's vocabulary of places (the case study's short names)
        robot_regions={
            "atTable": cellsim.Region(min=(-0.3, 0.45, 0.8), max=(0.3, 1.1, 1.5)),
            "sharedTbl": cellsim.Region(min=(-1.35, -0.4, 0.85), max=(-0.75, 0.4, 1.4)),
            "atWeldSpot": cellsim.Region(min=(0.8, -0.15, 0.85), max=(1.1, 0.15, 1.2)),
        },
        robot_elsewhere="inCell",
        operator_zones={"inCell": cellsim.Region(min=(-1.3, -1.6, 0.0), max=(2.0, 1.6, 2.5))},
        operator_outside="none",
        operator_flags={"at_table": cellsim.Region(min=(-2.0, -0.5, 0.0), max=(-1.4, 0.5, 2.5))},
    )
    entities = {
        "robot": module(
            "robot", model="models/ur10.urdf", base_position=(0.0, 0.0, 0.75), tool_frame="tcp",
            activities=["idle", "exchWrkp", "welding", "off"],
            named_poses={
                "home": [1.3576, -1.4486, 1.7785, -1.8815, -1.5766, 0.0],
                "shared_table": [2.9814, -1.0324, 1.3301, -1.8885, -1.5721, 0.0],
                "weld_spot": [-0.1654, -1.1151, 1.4376, -1.9075, -1.5848, 0.0],
            },
            initial_pose="home", speed_limits={"normal": 1.0, "hguid": 0.25, "ssmon": 0.5, "pflim": 0.25},
            braking_time=0.5, twin=model),
        # the spot welder: welds while the process operates it, and obeys only a stop
        "welder": module("machine", activities=["idle", "welding", "off"], rest="idle", working="welding",
                          off="off", safety_modes=["normal", "stopped"], unsupported_request="ignore", twin=model),
        # a vertical curtain along the operator-side edge of the shared table
        "light_barrier": module("light_barrier", center=(-1.37, 0.0, 1.25), size=(0.02, 0.9, 0.7), twin=model),
        "range_detector": module("range_detector", position=(1.3, -0.4, 0.2), near_below=2.0,
                                  close_below=1.0, twin=model),
        # the five waypoints of the published test campaign, in order
        "operator": module(
            "operator", notifications=["ok", "leaveArea"], alerts=["leave_workbench"], start=(-3.2, -1.8),
            walking_speed=1.2, speed_jitter=0.1,
            waypoints={
                "bench_entrance": {"position": [-2.8, -1.0], "wait": 3.0},
                "bench": {"position": [-1.7, 0.0], "wait": 7.0, "reach": [-1.05, 0.0, 1.0]},
                "cell_entrance": {"position": [-1.6, -1.1], "wait": 1.0},
                "cell": {"position": [0.6, -0.7], "wait": 7.0},
                "exit": {"position": [-3.2, -2.2], "wait": 2.0},
            },
            twin=model),
    }
    behaviours = {
        "process_controller": module(
            "process", robot="robot",
            steps=[
                {"name": "fetch", "move_to": "shared_table", "activity": "exchWrkp"},
                {"name": "pick", "dwell": 0.5, "activity": "exchWrkp"},
                {"name": "carry", "move_to": "weld_spot", "activity": "exchWrkp"},
                {"name": "weld", "operate": {"machine": "welder", "seconds": 2.0}, "activity": "welding"},
                {"name": "bring_back", "move_to": "shared_table", "activity": "exchWrkp"},
                {"name": "place", "dwell": 0.5, "activity": "exchWrkp"},
            ],
            restart_on_request={"exchWrkp": "bring_back", "welding": "weld"}),
        "safety_controller": module(
            "safety_controller", risk_model="welding_cell_risk_model.yaml",
            monitors={"safmod": "robot.safety_mode", "rloc": "robot.location", "wact": "welder.activity",
                      "ract": "robot.activity", "rngDet": "range_detector.range", "lgtBar": "light_barrier.broken",
                      "notif": "safety_controller.notif", "notif_leaveWrkb": "safety_controller.notif_leaveWrkb"},
            commands={"safmod": ["robot.safety_mode_request", "welder.safety_mode_request"],
                      "ract": ["process_controller.activity_request"], "wact": ["welder.activity_request"],
                      "notif": ["operator.notification"], "notif_leaveWrkb": ["operator.leave_workbench"]}),
        "ground_truth": module("ground_truth"),
    }
    waits = [f"operator.waypoints.{w}.wait" for w in ("bench_entrance", "bench", "cell_entrance", "cell", "exit")]
    return cellsim.Scenario(
        name="welding_cell",
        description="A UR10-class cobot exchanges a work-piece with an operator over a shared table and presents "
                    "it to a spot welder; a light barrier guards the table and a safety scanner at the welder's "
                    "base measures how near the operator is.",
        duration=30.0, seed=0, time_step=0.002, layout=layout, entities=entities, behaviours=behaviours,
        services={"blackbox": module("blackbox")},
        configuration_points={
            "operator_waits": cellsim.ConfigurationPoint(
                paths=waits, description="Seconds the operator waits at each of the five waypoints (the test vector)."),
            "range_thresholds": cellsim.ConfigurationPoint(
                paths=["range_detector.near_below", "range_detector.close_below"],
                description="Distances (m) below which the scanner reports near and close."),
        },
        validation=cellsim.Validation(file="welding_cell_validation.yaml"),
        campaign=cellsim.CampaignConfig(runs=100, samplers={"operator_waits": {"kind": "simplex", "total": 20.0}}),
    )


if __name__ == "__main__":
    from run_cell import main

    main(welding_cell, __doc__.splitlines()[0])
