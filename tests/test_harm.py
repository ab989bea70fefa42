"""Harm measured on the body: contact per region, its kind and its severity, against hand computations.

The arm is put in contact with a person standing still (their pose and previous pose equal), and the
contacting link is given a pure translation along the contact normal at a chosen speed (its joint
velocities from the link's Jacobian), so the relative speed is known. The permissible speeds are
computed here from the shipped limits table and the UR10 model's link masses, read with ElementTree.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import numpy as np
import pytest
import yaml
from pydrake.multibody.tree import JacobianWrtVariable
from pydrake.systems.analysis import Simulator

from cellsim.body import TRUNK
from cellsim.diagrams.cell import build_cell
from cellsim.kinematics import solve_tool_target
from cellsim.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
CELL = ROOT / "scenarios" / "machine_tending.yaml"
LIMITS = yaml.safe_load((ROOT / "cellsim" / "kinds" / "harm" / "body_limits.yaml").read_text())["regions"]


def robot_mass() -> float:
    """m_R by hand (Annex A's M/2 + m_L): half the UR10's jointed links but its base, plus whole the links fixed to
    a moving one (the tool flange, tooling) and the cell's 2 kg payload."""
    tree = ElementTree.parse(ROOT / "scenarios" / "models" / "ur10.urdf")
    masses = {link.get("name"): float(link.find("inertial/mass").get("value"))
              for link in tree.iter("link") if link.find("inertial/mass") is not None}
    fixed = {joint.find("child").get("link") for joint in tree.iter("joint") if joint.get("type") == "fixed"}
    tooling = fixed - {"base_link"}
    assert tooling == {"tool0", "tcp"}, tooling  # what this hand computation takes the UR10 model to be
    jointed = sum(m for name, m in masses.items() if name != "base_link" and name not in tooling)
    return 0.5 * jointed + sum(masses.get(name, 0.0) for name in tooling) + 2.0


def v_max(region: str, transient: bool) -> float:
    """ISO/TS 15066 Annex A's permissible speed, by hand from the table: a transient contact against the reduced mass
    of region and robot; a pinned region cannot move away, so against the robot's mass alone."""
    row = LIMITS[region]
    force = row["force"] * (row["transient_factor"] if transient else 1.0)
    mu = 1.0 / (1.0 / row["effective_mass"] + 1.0 / robot_mass()) if transient else robot_mass()
    return force / math.sqrt(row["spring_constant"] * 1000.0 * mu)


@pytest.fixture(scope="module")
def cell():
    built = build_cell(load_scenario(CELL), seed=0, duration=1.0, record=False)
    simulator = Simulator(built.diagram)
    built.set_initial_state(simulator.get_mutable_context())
    return built, simulator.get_mutable_context()


def stand(built, context, x, y, yaw, reach=None):
    """The operator standing still at (x, y) facing yaw, reaching fully for ``reach`` if given."""
    pose = [x, y, yaw, 0.0, 0.0, 0.0, 0.0] if reach is None else [x, y, yaw, 1.0, *reach]
    built.modules["operator"].set_pose(context, pose)


def region_geometry(built, context, region: str, side: str = ""):
    person = built.modules["operator"]
    query = built.modules["harm"].query_port.Eval(built.modules["harm"].GetMyContextFromRoot(context))
    for geometry, name in person.regions.items():
        if name == region and (not side or f"{region}_{side}/" in query.inspector().GetName(geometry)):
            return geometry, query
    raise LookupError(region)


def tool_at(built, context, point, rpy=None) -> None:
    robot = built.modules["robot"]
    cfg = robot.cfg
    q = solve_tool_target(robot.kinematics.model_path, (*cfg.base_position, cfg.base_yaw_deg), cfg.tool_frame,
                          tuple(float(v) for v in point), rpy, (tuple(robot.initial_positions),)).q
    assert q is not None, f"the arm cannot put its tool at {point}"
    plant = built.plant
    plant_context = plant.GetMyMutableContextFromRoot(context)
    plant.SetPositions(plant_context, built.robots["robot"], np.array(q))
    plant.SetVelocities(plant_context, built.robots["robot"], np.zeros(6))


def nearest_part(built, context, geometry):
    """The robot part nearest ``geometry``: (distance, its pair, its body's name)."""
    harm = built.modules["harm"]
    query = harm.query_port.Eval(harm.GetMyContextFromRoot(context))
    best = min(((query.ComputeSignedDistancePairClosestPoints(part, geometry), part) for part in harm.parts),
               key=lambda found: found[0].distance)
    pair, part = best
    return pair.distance, pair, harm.parts[part]


def touch(built, context, geometry, start, end, rpy=None, depth=0.004):
    """Move the tool from ``start`` (clear of the region) towards ``end`` until the arm overlaps it by about ``depth``."""
    start, end = np.asarray(start, float), np.asarray(end, float)
    lo, hi = 0.0, 1.0  # fractions of the way: clear at lo, overlapping at hi
    tool_at(built, context, end, rpy)
    assert nearest_part(built, context, geometry)[0] < 0, "the end point does not reach the region"
    for _ in range(30):
        mid = (lo + hi) / 2
        tool_at(built, context, start + mid * (end - start), rpy)
        distance = nearest_part(built, context, geometry)[0]
        if -depth <= distance < 0:
            return
        lo, hi = (mid, hi) if distance >= 0 else (lo, mid)
    raise AssertionError("no contact found")


def drive(built, context, body_index, velocity) -> None:
    """Joint velocities giving the arm's body ``body_index`` a pure translation at ``velocity`` (m/s)."""
    plant = built.plant
    plant_context = plant.GetMyMutableContextFromRoot(context)
    frame = plant.get_body(body_index).body_frame()
    J = plant.CalcJacobianSpatialVelocity(plant_context, JacobianWrtVariable.kV, frame, np.zeros(3),
                                          plant.world_frame(), plant.world_frame())
    v = np.linalg.lstsq(J, np.concatenate([np.zeros(3), velocity]), rcond=None)[0]
    assert np.allclose(J @ v, np.concatenate([np.zeros(3), velocity]), atol=1e-9), "the arm cannot move so here"
    plant.SetVelocities(plant_context, built.robots["robot"], v)


def reading_at(built, context, geometry, speed):
    """Drive the contacting link into the region at ``speed`` (m/s) along the contact normal; the harm reading."""
    _, pair, part = nearest_part(built, context, geometry)
    push = pair.nhat_BA_W if pair.id_A == geometry else -pair.nhat_BA_W  # from the arm into the region
    drive(built, context, part.body, speed * push)
    harm = built.modules["harm"]
    return harm.reading(harm.GetMyContextFromRoot(context)), part


def test_the_effective_masses_are_the_hand_computed_ones(cell):
    built, _ = cell
    assert built.modules["harm"].parts and all(
        part.mass == pytest.approx(robot_mass(), rel=1e-9) for part in built.modules["harm"].parts.values())


@pytest.mark.parametrize("region, side, placement", [
    # a hand stretched out in front, touched from above
    ("hand", "right", dict(person=(0.3, -1.15, math.pi / 2), reach=(0.3, -0.45, 1.05), approach=(0.0, 0.0, 0.25))),
    # the chest, touched from in front
    ("chest", "", dict(person=(0.3, -1.0, math.pi / 2), reach=None, approach=(0.0, 0.35, 0.0))),
])
def test_severity_crosses_one_at_the_hand_computed_permissible_speed(cell, region, side, placement):
    built, context = cell
    x, y, yaw = placement["person"]
    stand(built, context, x, y, yaw, placement["reach"])
    geometry, query = region_geometry(built, context, region, side)
    centre = query.GetPoseInWorld(geometry).translation()
    touch(built, context, geometry, centre + placement["approach"], centre)
    limit = v_max(region, transient=True)
    for fraction in (0.5, 0.99, 1.01, 1.5):
        reading, part = reading_at(built, context, geometry, fraction * limit)
        assert reading["contact_region"] == region and reading["contact_kind"] == "transient"
        assert reading["contact_part"] == part.name
        assert reading["contact_speed"] == pytest.approx(fraction * limit, rel=1e-5)
        assert reading["severity"] == pytest.approx(fraction, rel=1e-5)
        assert (reading["severity"] > 1) is (fraction > 1)
    # moving away from the region is no harm, however fast
    reading, _ = reading_at(built, context, geometry, -2.0)
    assert reading["contact_region"] == region and reading["severity"] == 0.0


def hand_on_the_bench(built, context):
    """The person at the bench's south end, their right hand resting on its top: (the hand's geometry, its centre)."""
    # lower the reach until the hand rests on the top
    for z in np.arange(1.05, 0.85, -0.005):
        stand(built, context, -0.95, -0.95, math.pi / 2, (-0.95, -0.45, z))
        hand, query = region_geometry(built, context, "hand", "right")
        bench = next(g for g, name in built.modules["harm"].fixtures.items() if name == "bench")
        gap = query.ComputeSignedDistancePairClosestPoints(hand, bench).distance
        if 0.0 < gap <= 0.01:
            return hand, query.GetPoseInWorld(hand).translation()
    raise AssertionError("the hand never rests on the bench")


def test_a_hand_pressed_onto_the_bench_is_clamped(cell):
    """The hand on the bench's top, the tool pressing down on it: quasi-static, judged by the quasi-static force
    against the arm's whole mass (a review found the two-mass reduced mass used: five times the speed allowed)."""
    built, context = cell
    bench_top = 0.9
    hand, centre = hand_on_the_bench(built, context)
    touch(built, context, hand, centre + [0.0, 0.0, 0.25], centre, rpy=(0.0, 180.0, 0.0))
    assert centre[2] > bench_top
    limit = v_max("hand", transient=False)
    for fraction in (0.9, 1.1):
        reading, _ = reading_at(built, context, hand, fraction * limit)
        assert reading["contact_region"] == "hand" and reading["contact_kind"] == "quasi_static"
        assert reading["severity"] == pytest.approx(fraction, rel=1e-5)
        assert reading["clamping"] == pytest.approx(fraction, rel=1e-5)


def measured(built, context, look: bool = False) -> dict:
    """The harm service's channels after one of its updates measuring at a plant step (decoded), its state kept;
    ``look``: at a look of its schedule (where it also measures what lies farther, to the cut-off)."""
    from cellsim.kinds.harm.system import NEAR

    harm = built.modules["harm"]
    own = harm.GetMyMutableContextFromRoot(context)
    own.get_mutable_discrete_state(harm.group("near")).SetAtIndex(0, NEAR)  # measuring at every plant step
    steps, looks = harm._looks
    step = next(k for k in range(steps) if looks[k] == look)
    context.SetTime(step * harm.period)
    own.SetDiscreteState(harm.EvalUniquePeriodicDiscreteUpdate(own))
    context.SetTime(0.0)
    return {spec.signal: spec.type.decode([own.get_discrete_state(harm.group(spec.signal)).GetAtIndex(0)])
            for spec, _ in harm.channels}


def pushes(built, context) -> list[np.ndarray]:
    """The harm service's kept pushes of the contacts going on (its ``onset`` state)."""
    harm = built.modules["harm"]
    kept = harm.GetMyContextFromRoot(context).get_discrete_state(harm.group("onset")).get_value()
    return [kept[k:k + 3].copy() for k in range(0, len(kept), 3) if kept[k:k + 3].any()]


@pytest.fixture
def forgetting(cell):
    """The module's cell, its harm service's kept pushes cleared after the test, whatever it left."""
    yield cell
    built, context = cell
    harm = built.modules["harm"]
    for kept in ("onset", "region_jump"):
        harm.GetMyMutableContextFromRoot(context).get_mutable_discrete_state(harm.group(kept)).SetZero()


def test_a_press_that_sinks_into_the_hand_is_judged_along_its_push_at_onset(forgetting):
    """The twin's hand does not give way: the tool pressing down on it sinks in, until the direction of least overlap
    turns sideways. The press is still judged along the push it began with, at its speed, and it ends when the tool
    is lifted clear (the next contact starts afresh)."""
    built, context = forgetting
    hand, centre = hand_on_the_bench(built, context)
    touch(built, context, hand, centre + [0.0, 0.0, 0.25], centre, rpy=(0.0, 180.0, 0.0))
    first = nearest_part(built, context, hand)[0]
    speed = 0.9 * v_max("hand", transient=False)
    down = np.array([0.0, 0.0, -1.0])
    tool = built.modules["robot"].kinematics.tool_position
    q = built.plant.GetPositions(built.plant.GetMyContextFromRoot(context), built.robots["robot"])
    top = tool(q)
    turned = False
    for sunk in np.arange(0.0, 0.07, 0.005):  # the tool sinks 7 cm into the hand, pushing down all the while
        tool_at(built, context, top + sunk * down, rpy=(0.0, 180.0, 0.0))
        distance, pair, part = nearest_part(built, context, hand)
        now = pair.nhat_BA_W if pair.id_A == hand else -pair.nhat_BA_W
        turned = turned or now @ down < 0.5
        drive(built, context, part.body, speed * down)
        reading = measured(built, context)
        assert distance <= first
        assert reading["contact_region"] == "hand" and reading["contact_kind"] == "quasi_static", sunk
        assert reading["severity"] == pytest.approx(0.9, rel=1e-3), sunk
        assert reading["contact_speed"] == pytest.approx(speed, rel=1e-3), sunk
    assert turned, "the tool never sank far enough for the direction of least overlap to turn"
    tool_at(built, context, top + [0.0, 0.0, 0.25], rpy=(0.0, 180.0, 0.0))
    assert measured(built, context)["contact_region"] == "none" and not pushes(built, context)


def test_a_tool_that_slides_over_the_hand_and_then_presses_is_judged_along_the_press(forgetting):
    """A review found the push kept from the first instant stale: the tool touching the side of the hand, sliding over
    its top (never parting, a few millimetres deep) and pressing down read severity 0, where the same press on a
    fresh contact reads 0.9. While the overlap is shallow the push follows the contact normal."""
    built, context = forgetting
    hand, centre = hand_on_the_bench(built, context)
    speed = 0.9 * v_max("hand", transient=False)
    down = np.array([0.0, 0.0, -1.0])
    for degrees in range(0, 91, 10):  # from the hand's side (horizontal) to its top, touching all the way
        theta = math.radians(degrees)
        side = np.array([math.cos(theta), 0.0, math.sin(theta)])
        touch(built, context, hand, centre + 0.25 * side, centre, rpy=(0.0, 180.0, 0.0))
        assert measured(built, context)["contact_region"] != "none", degrees
        distance, pair, _ = nearest_part(built, context, hand)
        assert distance < 0.0
        normal = pair.nhat_BA_W if pair.id_A == hand else -pair.nhat_BA_W
        assert any(np.allclose(kept, normal) for kept in pushes(built, context)), degrees  # shallow: it follows
    drive(built, context, nearest_part(built, context, hand)[2].body, speed * down)
    reading = measured(built, context)
    assert reading["contact_region"] == "hand" and reading["contact_kind"] == "quasi_static"
    assert reading["severity"] == pytest.approx(0.9, rel=1e-3) and reading["clamping"] == pytest.approx(0.9, rel=1e-3)


@pytest.mark.parametrize("yaw, approach, kind", [
    # facing the arm, the back against the machine: the chest pushed back is pinned through the body
    (math.pi, (-0.35, 0.0, 0.0), "quasi_static"),
    # the machine at the person's side: the chest pushed sideways along it can recoil
    (math.pi / 2, (0.0, 0.35, 0.0), "transient"),
])
def test_a_chest_pushed_against_a_machine_behind_the_body_is_clamped_and_beside_it_is_not(cell, yaw, approach, kind):
    """Pinning is judged on the whole person: the chest touches nothing but the arm, while the back, the far side of
    the body along the push, rests against the CNC."""
    built, context = cell
    cnc = next(g for g, name in built.modules["harm"].fixtures.items() if name == "cnc")
    for x in np.arange(0.55, 0.95, 0.002):  # step towards the machine until some region rests against it
        stand(built, context, x, 0.0, yaw)
        chest, query = region_geometry(built, context, "chest")
        gaps = [query.ComputeSignedDistancePairClosestPoints(g, cnc).distance for g in built.modules["operator"].regions]
        if 0.0 < min(gaps) <= 0.005:
            break
    else:
        raise AssertionError("the person never rests against the machine")
    assert query.ComputeSignedDistancePairClosestPoints(chest, cnc).distance > built.modules["harm"].cfg.clamp_gap
    centre = query.GetPoseInWorld(chest).translation()
    touch(built, context, chest, centre + approach, centre)
    limit = v_max("chest", transient=kind == "transient")
    for fraction in (0.9, 1.1):
        reading, _ = reading_at(built, context, chest, fraction * limit)
        assert reading["contact_region"] == "chest" and reading["contact_kind"] == kind
        assert reading["severity"] == pytest.approx(fraction, rel=1e-5)
        assert reading["clamping"] == (pytest.approx(fraction, rel=1e-5) if kind == "quasi_static" else 0.0)


def _back_against_the_machine(built, context, reach=None) -> float:
    """Step the person, facing the arm, towards the CNC behind them until some region rests against it (one of the
    trunk's: the back or the pelvis); returns their x."""
    cnc = next(g for g, name in built.modules["harm"].fixtures.items() if name == "cnc")
    for x in np.arange(0.55, 0.95, 0.002):
        stand(built, context, x, 0.0, math.pi, None if reach is None else (x - 0.45, *reach))
        _, query = region_geometry(built, context, "chest")
        gaps = {built.modules["operator"].regions[g]: query.ComputeSignedDistancePairClosestPoints(g, cnc).distance
                for g in built.modules["operator"].regions}
        if 0.0 < min(gaps.values()) <= 0.005:
            assert min(gaps, key=gaps.get) in TRUNK
            return x
    raise AssertionError("the person never rests against the machine")


@pytest.mark.parametrize("approach", [(-0.3, 0.0, 0.05), (0.0, 0.3, 0.05)], ids=["from the front", "from the side"])
def test_a_head_is_not_pinned_by_the_machine_the_back_rests_on(cell, approach):
    """The back against the CNC, the head clear of it: a push on the head is transient (the head turns away), so
    harm at any speed, not judged as clamping against the quasi-static force."""
    built, context = cell
    _back_against_the_machine(built, context)
    head, query = region_geometry(built, context, "head")
    centre = query.GetPoseInWorld(head).translation()
    touch(built, context, head, centre + approach, centre)
    for speed in (0.0, 0.05):
        reading, _ = reading_at(built, context, head, speed)
        assert reading["contact_region"] in ("head", "face") and reading["contact_kind"] == "transient"
        assert reading["severity"] >= 2.0 and reading["clamping"] == 0.0


def test_a_throat_pushed_back_while_the_back_rests_on_the_machine_is_pinned(cell):
    """A review found the neck judged alone: with the back against the CNC, the throat pushed back towards it read
    transient (twice the speed allowed), though the spine behind it cannot move away. Pushed sideways, away from
    anything, it is free."""
    built, context = cell
    built.set_initial_state(context)  # the arm where the cell starts it, not where an earlier test left it
    _back_against_the_machine(built, context)
    harm = built.modules["harm"]
    neck, query = region_geometry(built, context, "neck")
    cnc = next(g for g, name in harm.fixtures.items() if name == "cnc")
    assert query.ComputeSignedDistancePairClosestPoints(neck, cnc).distance > harm.cfg.clamp_gap  # not resting itself
    throat = query.GetPoseInWorld(neck).translation() + [-0.06, 0.0, 0.0]  # facing -x: the front of the neck
    part_id, part = next(iter(harm.parts.items()))
    person = harm.bodies[neck].person
    assert harm._pinned(query, person, "neck", throat, part_id, part, np.array([1.0, 0.0, 0.0]), neck)  # back
    # sideways, to the side away from the arm (whose links beside the trunk pin a push towards them)
    assert not harm._pinned(query, person, "neck", throat, part_id, part, np.array([0.0, -1.0, 0.0]), neck)


def test_an_outstretched_hand_is_not_pinned_by_the_machine_the_back_rests_on(cell):
    """The back against the CNC, the right hand out in front, half a metre from anything: pushed towards the
    machine it recoils (transient), judged against the transient limit."""
    built, context = cell
    _back_against_the_machine(built, context, reach=(0.45, 1.25))
    hand, query = region_geometry(built, context, "hand", "right")
    harm = built.modules["harm"]
    assert min(query.ComputeSignedDistancePairClosestPoints(hand, f).distance for f in harm.fixtures) > 0.3
    centre = query.GetPoseInWorld(hand).translation()
    touch(built, context, hand, centre + [-0.3, 0.0, 0.0], centre, rpy=(0.0, 90.0, 0.0))
    reading, _ = reading_at(built, context, hand, 1.0)
    assert reading["contact_region"] == "hand" and reading["contact_kind"] == "transient"
    assert reading["severity"] == pytest.approx(1.0 / v_max("hand", transient=True), rel=1e-5)


def test_a_tool_welded_to_the_pushing_link_pins_nothing(cell):
    """The wrist's last link and the tool on its flange both overlap a forearm: one rigid body, so the tool behind
    the region moves with the push and cannot pin it against the link (transient, no clamping)."""
    built, context = cell
    harm = built.modules["harm"]
    wrist, tool = (next(p for p in harm.parts.values() if p.name == f"robot_{n}") for n in ("wrist_3_link", "tool0"))
    assert wrist.body != tool.body and wrist.rigid == tool.rigid
    stand(built, context, 0.3, -1.15, math.pi / 2, (0.3, -0.45, 1.05))
    plant = built.plant
    plant_context = plant.GetMyMutableContextFromRoot(context)
    plant.SetPositions(plant_context, built.robots["robot"], np.array([-1.28614, -0.8009, 1.23712, 1.0778, -1.92133,
                                                                       1.91707]))
    plant.SetVelocities(plant_context, built.robots["robot"], np.zeros(6))
    forearm, query = region_geometry(built, context, "forearm", "right")
    touching = {harm.parts[g].name for g in harm.parts
                if query.ComputeSignedDistancePairClosestPoints(g, forearm).distance < 0}
    assert touching == {"robot_wrist_3_link", "robot_tool0"}
    reading, part = reading_at(built, context, forearm, 0.5)
    assert reading["contact_kind"] == "transient" and reading["clamping"] == 0.0


def test_a_head_contact_is_harm_at_any_speed(cell):
    built, context = cell
    stand(built, context, 0.3, -1.0, math.pi / 2)
    head, query = region_geometry(built, context, "head")
    centre = query.GetPoseInWorld(head).translation()
    touch(built, context, head, centre + [0.3, 0.0, 0.1], centre)  # from the person's right side, a little above
    for speed in (0.0, 0.01, 0.05):
        reading, _ = reading_at(built, context, head, speed)
        assert reading["contact_region"] == "head" and reading["contact_kind"] == "transient"
        assert reading["severity"] == pytest.approx(2.0 + speed / v_max("head", transient=False), rel=1e-5)
    # drawing apart is harm too: an audit saw a stopped arm's solver noise (-1e-7 m/s) read a face it touched as
    # severity 0, and a head that stepped into an arm backing away touched it all the same
    for speed in (-1e-7, -0.05):
        reading, _ = reading_at(built, context, head, speed)
        assert reading["contact_region"] == "head" and reading["severity"] == 2.0


def test_nobody_near_reads_no_contact_and_the_cut_off(cell):
    built, context = cell
    stand(built, context, -3.5, -2.0, 0.0)
    tool_at(built, context, (0.6, 0.3, 1.2))
    harm = built.modules["harm"]
    reading = harm.reading(harm.GetMyContextFromRoot(context))
    assert reading["severity"] == 0.0 and reading["contact_region"] == "none" and reading["nearest_region"] == "none"
    assert reading["separation_robot"] == pytest.approx(harm.cfg.cutoff)


def test_a_person_walking_into_a_still_arm_brings_the_speed(cell):
    """The relative speed counts the person's own motion: their chest moving at 0.25 m/s onto a still tool."""
    built, context = cell
    stand(built, context, 0.3, -1.0, math.pi / 2)
    chest, query = region_geometry(built, context, "chest")
    centre = query.GetPoseInWorld(chest).translation()
    touch(built, context, chest, centre + [0.0, 0.35, 0.0], centre)
    person = built.modules["operator"]
    step = 0.25 * person.period  # walked forward (+y) this far in their last update
    own = person.GetMyMutableContextFromRoot(context)
    own.get_mutable_discrete_state(person.group("previous_pose")).SetFromVector(
        np.array([0.3, -1.0 - step, math.pi / 2, 0.0, 0.0, 0.0, 0.0]))
    harm = built.modules["harm"]
    reading = harm.reading(harm.GetMyContextFromRoot(context))
    assert reading["contact_region"] == "chest"
    assert reading["contact_speed"] == pytest.approx(0.25, rel=1e-3)
    assert reading["severity"] == pytest.approx(0.25 / v_max("chest", transient=True), rel=1e-3)


def test_the_touched_region_is_drawn_amber_within_its_limit_and_red_above_it(cell):
    """Meshcat's cues and the Foxglove export's colours name the same region, by the recorded contact."""
    from cellsim.visual.cues import CueView

    built, _ = cell
    harm = built.modules["harm"]
    cues = {cue.name: cue for cue in harm.visual_cues(CueView(built.scene_graph))}
    hand = {"harm.contact_person": "operator", "harm.contact_region": "hand", "harm.severity": 1.4}
    assert cues["harm/operator/hand"].choose(hand) == "harm"
    assert cues["harm/operator/hand"].choose({**hand, "harm.severity": 0.6}) == "touched"
    assert cues["harm/operator/chest"].choose(hand) is None
    assert cues["harm/operator/hand"].choose({**hand, "harm.contact_region": "none"}) is None
    coloured = harm.recolour(hand)
    hands = {g for g, body in harm.bodies.items() if body.region == "hand"}
    assert set(coloured) == hands and len(hands) == 2 and all(rgba == harm.LOOKS["harm"] for rgba in coloured.values())
    assert harm.recolour({}) == {}


def test_a_far_period_between_plant_steps_looks_sooner_not_later():
    """``far_period`` 0.035 s on a 2 ms plant: a look every 17 steps (34 ms), and the reach that switches on the
    plant-step measuring is what closes in those 34 ms, not in a rounded-up 36."""
    built = build_cell(load_scenario(CELL, ["harm.far_period=0.035"]), seed=0, duration=1.0, record=False)
    harm = built.modules["harm"]
    assert harm.far_every == 17 and harm.reach == pytest.approx(harm.cfg.max_part_speed * 0.034)


@pytest.mark.parametrize("push, pinned", [
    ((0.0, 0.0, -1.0), True),  # straight down onto the floor it stands on
    ((0.5, 0.0, -0.866), True),  # 30 degrees off the vertical: within clamp_angle_deg (60)
    ((0.866, 0.0, -0.5), False),  # 60 degrees off and more: it slides aside
    ((1.0, 0.0, 0.0), False),  # level: the leg is swept aside, nothing behind it
])
def test_a_lower_leg_pushed_down_onto_the_floor_is_pinned(cell, push, pinned):
    """An audit found the floor no blocker: a foot or shin pressed down under the arm was judged transient. The floor
    (z = 0) now pins a region resting on it (the lower legs stand on it) as a fixture does; a person standing clear
    of the layout's fixtures, so only the floor can pin. (The arm cannot reach a standing shin from above past the
    thigh, so the rule is asked here directly, at the ankle.)"""
    built, context = cell
    harm = built.modules["harm"]
    stand(built, context, 0.3, -1.0, math.pi / 2)
    leg, query = region_geometry(built, context, "lower_leg", "right")
    ankle = query.GetPoseInWorld(leg).translation() + [0.0, 0.0, -0.15]
    part_id, part = next(iter(harm.parts.items()))
    person = harm.bodies[leg].person
    assert harm._pinned(query, person, "lower_leg", ankle, part_id, part, np.array(push)) is pinned
    # a hand held out at the waist touches no floor, pushed down or not
    hand, _ = region_geometry(built, context, "hand", "left")
    wrist = query.GetPoseInWorld(hand).translation()
    assert not harm._pinned(query, person, "hand", wrist, part_id, part, np.array([0.0, 0.0, -1.0]))


def test_the_lowest_point_of_each_body_shape_is_found_however_it_is_turned():
    from pydrake.geometry import Box, Capsule, Cylinder, Ellipsoid, Sphere
    from pydrake.math import RigidTransform, RotationMatrix

    from cellsim.proximity import lowest_point_z

    upright = RigidTransform([0.0, 0.0, 1.0])
    tilted = RigidTransform(RotationMatrix.MakeYRotation(math.pi / 2), [0.0, 0.0, 1.0])  # its z axis lying along x
    assert lowest_point_z(Sphere(0.1), upright) == pytest.approx(0.9)
    assert lowest_point_z(Capsule(0.1, 0.6), upright) == pytest.approx(0.6)
    assert lowest_point_z(Capsule(0.1, 0.6), tilted) == pytest.approx(0.9)
    assert lowest_point_z(Cylinder(0.1, 0.6), upright) == pytest.approx(0.7)
    assert lowest_point_z(Cylinder(0.1, 0.6), tilted) == pytest.approx(0.9)
    assert lowest_point_z(Box(0.2, 0.4, 0.6), upright) == pytest.approx(0.7)
    assert lowest_point_z(Box(0.2, 0.4, 0.6), tilted) == pytest.approx(0.9)
    assert lowest_point_z(Ellipsoid(0.1, 0.2, 0.3), tilted) == pytest.approx(0.9)
    quarter = RigidTransform(RotationMatrix.MakeXRotation(math.pi / 4), [0.0, 0.0, 1.0])
    assert lowest_point_z(Box(0.2, 0.4, 0.6), quarter) == pytest.approx(1.0 - 0.5 * (0.4 + 0.6) * math.sqrt(0.5))


def test_the_heights_a_shape_spans_are_found_however_it_is_turned():
    """What an area scanner asks to pass over a body region wholly above or below its beams (``height_span``)."""
    from pydrake.geometry import Box, Capsule, Convex, Cylinder, Ellipsoid, Sphere
    from pydrake.math import RigidTransform, RotationMatrix

    from cellsim.proximity import height_span

    upright = RigidTransform([0.0, 0.0, 1.0])
    tilted = RigidTransform(RotationMatrix.MakeYRotation(math.pi / 2), [0.0, 0.0, 1.0])
    quarter = RigidTransform(RotationMatrix.MakeXRotation(math.pi / 4), [0.0, 0.0, 1.0])
    assert height_span(Sphere(0.1), upright) == pytest.approx((0.9, 1.1))
    assert height_span(Capsule(0.1, 0.6), upright) == pytest.approx((0.6, 1.4))
    assert height_span(Capsule(0.1, 0.6), tilted) == pytest.approx((0.9, 1.1))
    assert height_span(Cylinder(0.1, 0.6), quarter) == pytest.approx(
        (1.0 - 0.3 * math.sqrt(0.5) - 0.1 * math.sqrt(0.5), 1.0 + 0.3 * math.sqrt(0.5) + 0.1 * math.sqrt(0.5)))
    half = 0.5 * (0.4 + 0.6) * math.sqrt(0.5)
    assert height_span(Box(0.2, 0.4, 0.6), quarter) == pytest.approx((1.0 - half, 1.0 + half))
    assert height_span(Ellipsoid(0.1, 0.2, 0.3), tilted) == pytest.approx((0.9, 1.1))
    assert height_span(Convex(str(ROOT / "models" / "no_such.obj")), upright) is None  # not known: may be anywhere


def _with_fixture(name: str, size, center):
    """The machine-tending cell with a fixture of its own (a box of ``size`` at ``center``, m), built at its initial
    state: (the cell, its context, the fixture's GeometryId)."""
    from cellsim.config.layout import Fixture

    sf = load_scenario(CELL)
    sf.scenario.layout.fixtures[name] = Fixture(size=size, center=center)
    built = build_cell(sf, seed=0, duration=1.0, record=False)
    simulator = Simulator(built.diagram)
    built.set_initial_state(simulator.get_mutable_context())
    geometry = next(g for g, fixture in built.modules["harm"].fixtures.items() if fixture == name)
    return built, simulator.get_mutable_context(), geometry


def test_a_face_pushed_while_the_back_of_the_head_rests_on_a_shelf_is_pinned():
    """An audit found a blocker looked for near the touched region alone: a face pushed back while the back of the
    head rested on something read as transient, no clamping. The skull moves as one block, as the trunk does."""
    person_x = 0.3  # facing +y (yaw pi/2): the back of the head towards -y
    built, context, shelf = _with_fixture("shelf", (0.4, 0.1, 0.1), (person_x, -1.2, 1.62))
    harm = built.modules["harm"]
    for y in np.arange(-1.06, -0.8, 0.002):  # step away from the shelf until the head is just clear of it
        stand(built, context, person_x, y, math.pi / 2)
        head, query = region_geometry(built, context, "head")
        gap = query.ComputeSignedDistancePairClosestPoints(head, shelf).distance
        if 0.0 < gap <= harm.cfg.clamp_gap:
            break
    else:
        raise AssertionError("the back of the head never rests by the shelf")
    face, query = region_geometry(built, context, "face")
    assert query.ComputeSignedDistancePairClosestPoints(face, shelf).distance > harm.cfg.clamp_gap
    front = query.GetPoseInWorld(face).translation() + [0.0, 0.03, 0.0]
    part_id, part = next(iter(harm.parts.items()))
    person = harm.bodies[face].person
    assert harm._pinned(query, person, "face", front, part_id, part, np.array([0.0, -1.0, 0.0]))  # pushed back
    assert not harm._pinned(query, person, "face", front, part_id, part, np.array([1.0, 0.0, 0.0]))  # sideways


def test_a_forearm_lying_along_a_shelf_is_pinned_wherever_it_is_pressed_down(cell):
    """A review found a limb lying along a surface judged by the pair's one witness point, which sat at the wrist end:
    a press straight down at the elbow end read free (transient), with the shelf directly under it. Pressed down
    anywhere along it, it is pinned; pushed sideways, along the shelf's top, it is not."""
    reach = (0.3, -0.6, 1.39)  # straight out in front at shoulder height, facing +y
    built, context = cell
    stand(built, context, 0.3, -1.6, math.pi / 2, reach)
    forearm, query = region_geometry(built, context, "forearm", "right")
    X, shape = query.GetPoseInWorld(forearm), query.inspector().GetShape(forearm)
    ends = [X @ np.array([0.0, 0.0, side * shape.length() / 2]) for side in (-1, 1)]
    low = min(end[2] for end in ends) - shape.radius()
    ys = sorted(end[1] for end in ends)
    centre = (float(np.mean([end[0] for end in ends])), float(np.mean(ys)), low - 0.005 - 0.025)
    built, context, shelf = _with_fixture("shelf", (0.3, ys[1] - ys[0], 0.05), centre)  # its top 5 mm under the forearm
    harm = built.modules["harm"]
    stand(built, context, 0.3, -1.6, math.pi / 2, reach)
    forearm, query = region_geometry(built, context, "forearm", "right")
    assert 0.0 < query.ComputeSignedDistancePairClosestPoints(forearm, shelf).distance <= harm.cfg.clamp_gap
    X = query.GetPoseInWorld(forearm)
    part_id, part = next(iter(harm.parts.items()))
    person = harm.bodies[forearm].person
    for along in np.linspace(-1.0, 1.0, 9):
        top = X @ np.array([0.0, 0.0, along * shape.length() / 2]) + [0.0, 0.0, shape.radius()]
        assert harm._pinned(query, person, "forearm", top, part_id, part, np.array([0.0, 0.0, -1.0]), forearm), along
        assert not harm._pinned(query, person, "forearm", top, part_id, part, np.array([1.0, 0.0, 0.0]), forearm), along


def test_a_hand_is_pinned_only_by_what_rests_against_that_hand_not_the_other():
    """An audit found a limb's blockers looked for by region name: the left hand resting against a post pinned a
    push on the right hand. A limb is pinned only by what rests against that very limb."""
    built, context, post = _with_fixture("post", (0.1, 0.3, 1.2), (-0.2, -1.0, 0.6))
    harm = built.modules["harm"]
    for x in np.arange(0.2, 0.0, -0.002):  # facing +y, the left side towards the post (-x): step towards it
        stand(built, context, x, -1.0, math.pi / 2)
        left, query = region_geometry(built, context, "hand", "left")
        if 0.0 < query.ComputeSignedDistancePairClosestPoints(left, post).distance <= harm.cfg.clamp_gap:
            break
    else:
        raise AssertionError("the left hand never rests by the post")
    right, query = region_geometry(built, context, "hand", "right")
    assert query.ComputeSignedDistancePairClosestPoints(right, post).distance > 0.3
    p_W = query.GetPoseInWorld(right).translation()
    part_id, part = next(iter(harm.parts.items()))
    person = harm.bodies[right].person
    towards_post = np.array([-1.0, 0.0, 0.0])
    assert not harm._pinned(query, person, "hand", p_W, part_id, part, towards_post, right)
    assert harm._pinned(query, person, "hand", query.GetPoseInWorld(left).translation(), part_id, part, towards_post, left)


def test_the_nearest_region_is_named_with_whose_it_is_when_two_people_are_in_the_cell():
    """Two people, one at a time near the arm's tool: the nearest region's person is the one standing there."""
    built = build_cell(load_scenario(ROOT / "scenarios" / "two_operators.yaml"), seed=0, duration=1.0, record=False)
    simulator = Simulator(built.diagram)
    built.set_initial_state(simulator.get_mutable_context())
    context = simulator.get_mutable_context()
    harm = built.modules["harm"]
    tool_at(built, context, (0.6, -0.2, 1.1))
    near, far = [0.6, -0.65, math.pi / 2, 0.0, 0.0, 0.0, 0.0], [-3.4, -2.4, 0.0, 0.0, 0.0, 0.0, 0.0]
    for there, elsewhere in (("operator", "visitor"), ("visitor", "operator")):
        built.modules[there].set_pose(context, near)
        built.modules[elsewhere].set_pose(context, far)
        reading = harm.reading(harm.GetMyContextFromRoot(context))
        assert reading["nearest_person"] == there and reading["nearest_region"] != "none"
        assert reading["separation_robot"] < harm.cfg.cutoff


def test_a_runs_closest_approach_names_the_person_and_their_region(tmp_path):
    """The run summary's closest approach, read from the black box: within the cut-off, whose region it was."""
    import sqlite3

    from cellsim.api import simulate

    run = simulate(CELL, tmp_path / "run", seed=0, duration=20.0)
    closest = next(f for f in run.summary.findings if f.what == "closest approach")
    assert closest.data["distance"] < 0.5 and closest.data["person"] == "operator"
    assert f"operator's {closest.data['region'].replace('_', ' ')}" in closest.text
    # a near miss says how fast the arm went then (an audit found no speed but a touch's): the tool's, at that instant
    if closest.data["distance"] > 0:
        tool = run.blackbox().series("robot.tool_speed")
        assert closest.data["tool_speed"] == pytest.approx(tool.value_at(closest.start))
        assert f"its tool at {closest.data['tool_speed']:.3g} m/s" in closest.text
    # the channel the finding read, straight from the file
    db = sqlite3.connect(tmp_path / "run" / "blackbox.sqlite")
    assert db.execute("SELECT count(*) FROM channels WHERE name = 'harm.nearest_person'").fetchone()[0] == 1
    db.close()


def test_a_hand_swung_farther_in_one_update_than_it_and_a_part_are_thick_is_a_finding(forgetting, tmp_path):
    """The service sees a body where each update puts it: a hand that moves farther in one update than it and the
    thinnest robot part are thick together may pass through the part unseen. Near a robot, that is measured
    (region_jump) and is a finding of the run; the shipped cells' people never do it."""
    built, context = forgetting
    harm = built.modules["harm"]
    tool_at(built, context, (0.3, -0.5, 1.05))
    reach = [1.0, 0.3, -0.45, 1.05]  # the arm stretched out towards the tool
    operator = built.modules["operator"]
    operator.set_pose(context, [0.3, -1.15, math.pi / 2, *reach])
    assert measured(built, context, look=True)["region_jump"] == 0.0  # standing still: nothing moved
    own = operator.GetMyMutableContextFromRoot(context)
    own.get_mutable_discrete_state(operator.group("previous_pose")).SetFromVector(
        [0.3, -1.15, math.pi / 2 - 0.4, 1.0, 0.75, -0.45, 1.05])  # in one update: turned, the hand swung from 0.45 m away
    between = measured(built, context, look=False)["region_jump"]
    jumped = measured(built, context, look=True)["region_jump"]
    assert between == 0.0 and jumped > 0.1  # (looked at at a look of the schedule: one follows every update)
    from cellsim.kinds.harm.findings import _jumped

    class Box:  # the black box's view the findings read: the channel's series
        def channels(self):
            return ["harm.region_jump"]

        def series(self, channel):
            from cellsim.blackbox import Series

            return Series(channel, np.array([0.0, 2.0]), [0.0, jumped])

    found = _jumped("harm", Box())
    assert found is not None and found.what == "region jump" and found.start == 2.0
    assert f"{jumped:.3g} m farther" in found.text
