"""End to end on the welding cell: the scenarios of the published case study."""

from __future__ import annotations

import numpy as np

from cellsim.kinds.operator.config import Waypoint

from conftest import first_time, place_operator, run, welding_cell

PHASES = ("HRW", "HS", "HC")


def test_no_interference_two_cycles_and_no_hazard(tmp_path):
    sf = place_operator(welding_cell(), start=(-4.0, -3.0))  # stays outside, far away
    bb = run(sf, tmp_path / "run", duration=30.0)
    assert bb.series("process_controller.cycles_completed").values[-1] >= 2
    for hazard in PHASES:
        assert bb.series(f"safety_controller.{hazard}").values == ["inact"]
    assert set(bb.series("robot.safety_mode").values) == {"normal"}
    assert bb.metadata()["status"] == "completed"
    # the measured speed is recorded at each 20 ms update of the robot's controller where it changed: the arm
    # works throughout, so at every one
    speed = bb.series("robot.tool_speed")
    np.testing.assert_allclose(speed.times, [round(0.02 * k, 9) for k in range(1500)])
    assert max(speed.values) > 0.1  # it measures the moving arm


def walk_in_during_welding():
    """The operator waits at the cell's open side, walks to the welder during the first weld."""
    sf = welding_cell()
    entrance, welder_side = (-1.6, -1.1), (0.6, -0.7)
    return place_operator(
        sf,
        start=entrance,
        waypoints={"cell": Waypoint(welder_side, 3.0), "exit": Waypoint((-3.2, -2.2), 30.0)},
        start_delay=5.4,
    )


def test_walking_into_the_cell_during_welding_stops_the_cell(tmp_path):
    bb = run(walk_in_during_welding(), tmp_path / "run", duration=30.0)
    rng, hc = bb.series("range_detector.range"), bb.series("safety_controller.HC")
    ract, wact = bb.series("robot.activity"), bb.series("welder.activity")

    closed = first_time(rng, lambda v: v == "close")
    assert closed is not None
    assert ract.value_at(closed) == "welding" and wact.value_at(closed) == "welding"
    detected = first_time(hc, lambda v: v == "act")
    assert detected is not None and 0.0 <= detected - closed <= 0.5

    mitigated = first_time(hc, lambda v: v == "mit")
    assert first_time(wact, lambda v: v == "off", after=detected) <= mitigated + 0.1
    assert first_time(bb.series("robot.safety_mode"), lambda v: v == "stopped", after=detected) <= mitigated + 0.1
    braking = bb.metadata()["scenario"]["entities"]["robot"]["braking_time"]
    speed = bb.series("robot.tool_speed")
    left = first_time(rng, lambda v: v == "far", after=closed)
    still = [v for t, v in zip(speed.times, speed.values) if mitigated + braking + 0.1 <= t < left]
    assert still and max(still) < 0.01  # standstill while stopped

    # resumed after the operator leaves: back to normal, starting over with the work-piece
    resumed = first_time(hc, lambda v: v == "inact", after=mitigated)
    assert resumed is not None and resumed >= left
    assert bb.series("robot.safety_mode").value_at(resumed + 0.1) == "normal"
    assert bb.series("process_controller.step").value_at(resumed) == "bring_back"
    assert bb.series("process_controller.cycles_completed").values[-1] >= 1


def test_reaching_across_the_table_while_the_robot_is_there(tmp_path):
    bench = (-1.7, 0.0)
    sf = place_operator(
        welding_cell(),
        start=bench,
        waypoints={"bench": Waypoint(bench, 3.2, reach=(-1.05, 0.0, 1.0)), "exit": Waypoint((-3.2, -2.2), 30.0)},
    )
    bb = run(sf, tmp_path / "run", duration=12.0)
    hrw, mode = bb.series("safety_controller.HRW"), bb.series("robot.safety_mode")
    at_table = first_time(bb.series("robot.location"), lambda v: v == "sharedTbl")
    detected = first_time(hrw, lambda v: v == "act")
    assert at_table is not None and detected is not None and detected - at_table <= 0.5
    assert bb.series("light_barrier.broken").value_at(detected) is True

    pflim = first_time(mode, lambda v: v == "pflim")
    normal_again = first_time(mode, lambda v: v == "normal", after=pflim)
    assert pflim is not None and normal_again is not None
    assert bb.series("safety_controller.notif_leaveWrkb").value_at(pflim) is True
    assert first_time(hrw, lambda v: v == "inact", after=detected) <= normal_again + 0.05
    # collaborative speed at the tool once the transition (at most the braking time) is over
    speed = bb.series("robot.tool_speed")
    limited = [v for t, v in zip(speed.times, speed.values) if pflim + 0.5 <= t < normal_again]
    assert limited and max(limited) <= 0.25 * 1.1
    assert "mis" not in hrw.values
