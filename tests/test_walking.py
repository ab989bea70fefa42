"""People walk round the fixtures, by the shortest way, and cannot stand inside one."""

from __future__ import annotations

import numpy as np
import pytest

from cellsim.config.typed_yaml import ConfigError
from cellsim.kinds.operator.system import CLEARANCE, obstacles, plan_walk, pose_at
from cellsim.floorplan import point_in_polygon, points_in_polygon, shortest_path, signed_area, triangulate
from cellsim.scenario import load_scenario

from conftest import WELDING_CELL, welding_cell


def _inside(xy, outline) -> bool:
    """Strictly inside (a path may run along an edge), with a little slack for rounding."""
    centre = np.mean(outline, axis=0)
    shrunk = [centre + (np.array(c) - centre) * 0.999 for c in outline]
    return point_in_polygon(xy, shrunk)


def test_the_welding_cell_operator_never_walks_through_a_fixture():
    sf = welding_cell()
    cfg, layout = sf.scenario.entities["operator"], sf.scenario.layout
    legs = plan_walk(cfg, seed=0, layout=layout)
    outlines = obstacles(cfg, layout)
    times = np.arange(0.0, legs[-1].leave, 0.02)
    for t in times:
        xy = pose_at(legs, 0.0, t).xy
        for name, outline in outlines:
            assert not _inside(xy, outline), (t, xy, name)
    # the walk to the exit goes round the south fence's west end instead of through it
    assert legs[-1].corners and legs[-1].corners[0][0] == pytest.approx(-1.3 - 0.2 - CLEARANCE)


def test_straight_walks_cut_through_the_fence_when_asked_to():
    sf = welding_cell("operator.avoid_fixtures=false")
    cfg, layout = sf.scenario.entities["operator"], sf.scenario.layout
    legs = plan_walk(cfg, seed=0, layout=layout)
    fence = dict(obstacles(cfg, layout))["fence_south"]
    assert not any(leg.corners for leg in legs)
    assert any(_inside(pose_at(legs, 0.0, t).xy, fence) for t in np.arange(legs[-1].depart, legs[-1].arrive, 0.02))


def test_the_way_round_is_the_shortest():
    # a 2 m wide wall across the way: round its nearer end, not the farther one
    wall = [np.array(c) for c in ((-0.1, -0.5), (0.1, -0.5), (0.1, 1.5), (-0.1, 1.5))]
    path = shortest_path((-1.0, 0.0), (1.0, 0.0), [wall])
    assert [tuple(p) for p in path] == [(-0.1, -0.5), (0.1, -0.5), (1.0, 0.0)]
    # no way through a closed ring of walls
    ring = [[np.array(c) for c in box] for box in (
        ((-2, -2), (2, -2), (2, -1.8), (-2, -1.8)), ((-2, 1.8), (2, 1.8), (2, 2), (-2, 2)),
        ((-2, -2), (-1.8, -2), (-1.8, 2), (-2, 2)), ((1.8, -2), (2, -2), (2, 2), (1.8, 2)))]
    assert shortest_path((0.0, 0.0), (3.0, 0.0), ring) is None


def test_triangulating_a_non_convex_outline_keeps_its_area():
    ell = [(0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2)]
    triangles = triangulate(ell)
    assert len(triangles) == 4
    assert sum(signed_area(t) for t in triangles) == pytest.approx(signed_area(ell)) == pytest.approx(3.0)


def _with_waypoint(tmp_path, position, extra: str = "") -> str:
    path = tmp_path / "walk.yaml"
    path.write_text(
        f"base: {WELDING_CELL}\n{extra}entities:\n  operator:\n    waypoints:\n      bench: {{position: {position}}}\n"
    )
    return str(path)


def test_a_waypoint_inside_a_fixture_is_a_load_error_naming_it(tmp_path):
    with pytest.raises(ConfigError) as e:
        load_scenario(_with_waypoint(tmp_path, "[-1.05, 0.0]"))
    assert e.value.key == "entities.operator.waypoints.bench.position"
    assert "inside fixture 'shared_table'" in str(e.value) and e.value.line == 5


def test_a_waypoint_walled_in_is_a_load_error_naming_it(tmp_path):
    walls = (
        "layout:\n  fixtures:\n"
        "    w1: {size: [2.0, 0.1, 2.0], center: [-2.0, 3.0, 1.0]}\n"
        "    w2: {size: [2.0, 0.1, 2.0], center: [-2.0, 5.0, 1.0]}\n"
        "    w3: {size: [0.1, 2.1, 2.0], center: [-3.0, 4.0, 1.0]}\n"
        "    w4: {size: [0.1, 2.1, 2.0], center: [-1.0, 4.0, 1.0]}\n"
    )
    with pytest.raises(ConfigError) as e:
        load_scenario(_with_waypoint(tmp_path, "[-2.0, 4.0]", walls))
    assert e.value.key == "entities.operator.waypoints.bench.position" and "no way round the fixtures" in str(e.value)


def test_many_points_at_once_get_the_answer_each_gets_alone():
    """The abstract floor's grid is tested against the fixtures in one go (``points_in_polygon``): every point,
    on a 0.05 m grid that puts many exactly on an edge or a corner, and random ones, gets what ``point_in_polygon``
    says of it alone."""
    rng = np.random.default_rng(7)
    polygons = [[(0.0, 0.0), (1.0, 0.0), (1.0, 0.5), (0.0, 0.5)],  # a fixture's box
                [(-0.3, -0.2), (0.4, 0.35), (0.1, 0.9), (-0.5, 0.6)],  # a turned, non-convex one
                [(0.2, 0.2), (0.2, 0.2), (0.6, 0.2), (0.6, 0.6)]]  # a repeated corner, a horizontal edge
    grid = [(i * 0.05, j * 0.05) for i in range(-20, 30) for j in range(-20, 30)]
    points = grid + [tuple(p) for p in rng.uniform(-1.0, 1.5, (500, 2))]
    for polygon in polygons:
        together = points_in_polygon(points, polygon)
        alone = [point_in_polygon(q, polygon) for q in points]
        assert together.tolist() == alone
        assert 0 < sum(alone) < len(points)


def test_a_box_blocks_a_line_of_sight_exactly_when_the_segment_passes_through_its_inside():
    """``Box3.blocks`` (an area scanner's line of sight against every fixture) against a dense walk along each segment,
    on boxes turned any way and segments level with a face or not; cases within a hair of a face are left out."""
    import math
    import random

    from cellsim.floorplan import Box3

    rng = random.Random(7)
    checked = blocked = 0
    t = np.linspace(0.0, 1.0, 4001)
    for _ in range(3000):
        box = Box3(np.array([rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(0, 1.5)]),
                   np.array([rng.uniform(0.05, 1), rng.uniform(0.05, 1), rng.uniform(0.05, 1)]),
                   rng.choice([0.0, math.pi / 2, rng.uniform(-math.pi, math.pi)]))
        p0 = np.array([rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(0, 2)])
        p1 = np.array([rng.uniform(-3, 3), rng.uniform(-3, 3), rng.choice([rng.uniform(0, 2), p0[2]])])
        points = p0 + t[:, None] * (p1 - p0)
        c, s = math.cos(box.yaw), math.sin(box.yaw)
        d = points - box.center
        local = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]], axis=1)
        depth = np.min(box.half - np.abs(local), axis=1).max()  # > 0: some point of the walk inside the box
        if abs(depth) < 1e-3:
            continue  # grazing a face or an edge: the walk's resolution cannot tell
        checked += 1
        blocked += depth > 0
        assert box.blocks(p0, p1) == (depth > 0), (box, p0, p1, depth)
        assert box.blocks(tuple(p0), list(p1)) == (depth > 0)  # any sequence of three numbers
    assert checked > 2500 and 100 < blocked < checked - 100


def test_sight_lines_from_one_point_past_many_boxes_are_each_boxs_test_at_once():
    """``SightLines.reach`` (an area scanner's look at a limb's points) against ``Box3.blocks`` of every box, segment
    by segment: the same answers for 3,000 points past five boxes turned any way, some points level with the origin."""
    import math

    from cellsim.floorplan import Box3, SightLines

    rng = np.random.default_rng(3)
    for _ in range(4):
        origin = np.array([0.1, -0.2, 0.15])
        boxes = []
        while len(boxes) < 5:  # a scanner is never inside a box it looks past
            box = Box3(rng.uniform(-1, 1, 3), rng.uniform(0.05, 0.5, 3),
                       float(rng.choice([0.0, math.pi / 2, rng.uniform(-3, 3)])))
            if not box.contains(origin, margin=0.01):
                boxes.append(box)
        points = rng.uniform(-2, 2, (3000, 3))
        points[::7, 2] = origin[2]  # level with the origin: a step along z of exactly 0
        reached = SightLines(origin, boxes).reach(points)
        alone = np.array([not any(box.blocks(origin, p) for box in boxes) for p in points])
        assert reached.tolist() == alone.tolist()
        assert 100 < (~alone).sum() < 2900
    assert SightLines(origin, []).reach(points).all() and len(SightLines(origin, boxes).reach(np.empty((0, 3)))) == 0


def test_one_point_s_sight_line_is_the_many_points_test_mount_and_all():
    """``SightLines.reaches`` (one point, in plain floats: the nearest point of a body region) gives what ``reach``
    gives for it, past five boxes and out of the box the origin is mounted in, its depth limit included."""
    import math

    from cellsim.floorplan import Box3, SightLines

    rng = np.random.default_rng(5)
    for _ in range(4):
        origin = np.array([0.1, -0.2, 0.15])
        inside = rng.uniform(0.01, 0.05, 3)  # the origin this far inside the mount's corner
        mount = Box3(origin - np.array([0.1, 0.1, 0.1]) + inside, np.full(3, 0.1), 0.0)
        boxes = [mount]
        while len(boxes) < 6:
            box = Box3(rng.uniform(-1, 1, 3), rng.uniform(0.05, 0.5, 3),
                       float(rng.choice([0.0, math.pi / 2, rng.uniform(-3, 3)])))
            if not box.contains(origin, margin=0.01):
                boxes.append(box)
        lines = SightLines(origin, boxes, mount_depth=0.08)
        assert lines.mounts == [mount]
        points = rng.uniform(-2, 2, (2000, 3))
        points[::7, 2] = origin[2]  # level with the origin
        one = [lines.reaches(p) for p in points]
        assert one == lines.reach(points).tolist()
        assert 100 < sum(one) < 1900


def _hand_points(built, context, times):
    """The world positions (m) of the operator's hands' geometry at each update time in ``times``."""
    from cellsim.kinds.operator.system import pose_at

    operator = built.modules["operator"]
    hands = [g for g, region in operator.regions.items() if region == "hand"]
    inspector = built.scene_graph.model_inspector()
    frames = [inspector.GetFrameId(g) for g in hands]
    placed = [inspector.GetPoseInFrame(g).translation() for g in hands]
    out = []
    for t in times:
        pose = operator._pose_vector(pose_at(operator.legs, operator.start_yaw, t, operator.turns))
        poses = operator.frame_poses(tuple(pose))
        out.append(np.array([poses.value(f) @ p for f, p in zip(frames, placed)]))
    return out


@pytest.mark.parametrize("cell", ["welding_cell", "machine_tending", "palletising_cell"])
def test_a_person_turns_at_their_turn_rate_so_no_hand_jumps_through_an_arm_in_one_update(cell):
    """An audit found a turn taken in one update swung a hand 0.5 m (12 m/s): the harm service, which sees the body
    where each update puts it, could miss a hand passing through a robot part, or judge a touch at 12 m/s. A person
    now turns at most turn_rate; a hand moves at most ~8 cm per update, less than a hand (9 cm) and the UR10's
    thinnest part (6 cm) are thick together."""
    from pathlib import Path

    from cellsim.diagrams.cell import build_cell
    from pydrake.systems.analysis import Simulator

    sf = load_scenario(Path(WELDING_CELL).parent / f"{cell}.yaml")
    built = build_cell(sf, seed=3, duration=1.0, record=False)
    context = Simulator(built.diagram).get_mutable_context()
    operator = built.modules["operator"]
    period, rate = operator.period, operator.cfg.turn_rate
    times = np.arange(0.0, sf.scenario.duration, period)
    yaws = [operator.turns.yaw_at(t) for t in times]
    turned = np.abs((np.diff(yaws) + np.pi) % (2 * np.pi) - np.pi)
    assert turned.max() <= rate * period + 1e-9
    assert turned.max() > 0.9 * rate * period  # the person does turn, as fast as allowed
    hands = _hand_points(built, context, times)
    jumps = [float(np.linalg.norm(b - a, axis=1).max()) for a, b in zip(hands, hands[1:])]
    assert max(jumps) < 0.1, max(jumps)
    # and each turn ends facing its aim: where a person reaches, they face the reach point within half a turn's time
    # of arriving (they turn and reach at once: the arm may be out first, pointing at the reach point all the same)
    for leg in operator.legs:
        if leg.reach is not None and leg.leave - leg.arrive > np.pi / rate:
            at = leg.arrive + np.pi / rate
            assert abs((operator.turns.yaw_at(at) - leg.facing + np.pi) % (2 * np.pi) - np.pi) < 1e-9


def test_after_a_reach_at_the_spot_the_person_stands_on_they_turn_back_to_the_way_they_walked():
    """A review found a reach at a waypoint where the person already stood (a leg of no length, no heading of its own)
    leaving them facing the reach point for good, where the instant rule and verify's end pose turn them back to the
    way they last walked."""
    from cellsim.kinds.operator.system import Leg, Turns

    here, there = np.array([0.0, 0.0]), np.array([1.0, 0.0])  # walk east, then reach north from the same spot
    legs = [Leg(0, here, there, 0.0, 1.0, 1.0, None, 0.0, None),
            Leg(1, there, there, 1.0, 1.0, 3.0, np.array([1.0, 1.0, 1.0]), None, np.pi / 2)]
    turns = Turns(legs, 0.0, np.pi)
    assert turns.yaw_at(2.0) == pytest.approx(np.pi / 2)  # facing the reach point
    assert turns.yaw_at(3.25) == pytest.approx(np.pi / 4)  # turning back, at pi rad/s
    assert turns.yaw_at(10.0) == pytest.approx(0.0)  # the way they walked
    assert pose_at(legs, 0.0, 10.0).yaw == pytest.approx(0.0)  # as the instant rule has it
