"""The abstract cell's true separation (cellsim.verify.clearance): every bound is a lower bound of SceneGraph's own.

The model calls a state safe for TrueSSM only where the bound, less S_p of the fastest speed, stays at or above 0;
a bound above the true distance would let it say "holds" where the twin's arm comes nearer. So: covering spheres
hold their shape; a stretch's bound never exceeds SceneGraph's distance from a body posed anywhere on the floor to
the arm anywhere on that stretch, between its samples too; a stretch's rate is never below the arm's own point
speed per unit of its path.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydrake.geometry import Box, Capsule, Cylinder, Ellipsoid, Sphere
from pydrake.math import RigidTransform, RollPitchYaw

from cellsim.kinds.ssm.abstraction import SsmAbstraction
from cellsim.scenario import load_scenario
from cellsim.verify.clearance import Clearance, cover
from cellsim.verify.run import abstract_model
from conftest import ROOT

TENDING = ROOT / "scenarios" / "machine_tending.yaml"


def _inside(shape, points: np.ndarray) -> np.ndarray:
    """Which of ``points`` (in the shape's own frame) lie in the shape."""
    x, y, z = points.T
    if isinstance(shape, Sphere):
        return np.linalg.norm(points, axis=1) <= shape.radius()
    if isinstance(shape, Box):
        return (np.abs(x) <= shape.width() / 2) & (np.abs(y) <= shape.depth() / 2) & (np.abs(z) <= shape.height() / 2)
    if isinstance(shape, Cylinder):
        return (np.hypot(x, y) <= shape.radius()) & (np.abs(z) <= shape.length() / 2)
    if isinstance(shape, Capsule):
        along = np.clip(z, -shape.length() / 2, shape.length() / 2)
        return np.sqrt(x * x + y * y + (z - along) ** 2) <= shape.radius()
    return (x / shape.a()) ** 2 + (y / shape.b()) ** 2 + (z / shape.c()) ** 2 <= 1.0


@pytest.mark.parametrize("shape", [Sphere(0.11), Box(0.3, 0.2, 0.55), Cylinder(0.06, 0.612), Capsule(0.045, 0.25),
                                   Ellipsoid(0.1, 0.2, 0.05), Box(0.01, 0.5, 0.02)])
def test_covering_spheres_hold_the_shape_and_reach_little_beyond_it(shape):
    pose = RigidTransform(RollPitchYaw(0.3, -0.7, 1.1), [0.2, -0.1, 0.4])
    centres, radii = cover(shape, pose, tolerance=0.02)
    rng = np.random.default_rng(1)
    half = {Sphere: lambda s: [s.radius()] * 3, Box: lambda s: [s.width() / 2, s.depth() / 2, s.height() / 2],
            Cylinder: lambda s: [s.radius(), s.radius(), s.length() / 2],
            Capsule: lambda s: [s.radius(), s.radius(), s.length() / 2 + s.radius()],
            Ellipsoid: lambda s: [s.a(), s.b(), s.c()]}[type(shape)](shape)
    local = rng.uniform(-np.array(half), np.array(half), (60_000, 3))  # (the shape's box: its inside, edges included)
    inside = local[_inside(shape, local)]
    assert len(inside) > 500
    points = inside @ pose.rotation().matrix().T + pose.translation()
    covered = (np.linalg.norm(points[:, None, :] - centres[None, :, :], axis=2) <= radii[None, :] + 1e-12).any(axis=1)
    assert covered.all(), f"{(~covered).sum()} points of the shape outside every sphere"
    # how far beyond the shape a sphere reaches: its points' distance to the shape's points (sampled) is small
    rng_points = rng.normal(size=(4000, 3))
    directions = rng_points / np.linalg.norm(rng_points, axis=1)[:, None]
    k = rng.integers(0, len(centres), 4000)
    on_spheres = centres[k] + radii[k, None] * directions
    nearest = np.array([np.linalg.norm(points[::7] - p, axis=1).min() for p in on_spheres[:400]])
    slack = 0.02 if not isinstance(shape, Ellipsoid) else max(shape.a(), shape.b(), shape.c())
    assert nearest.max() <= slack + 0.03  # (the sampled shape's points are a few mm apart)


@pytest.fixture(scope="module")
def tending():
    """The machine-tending cell's abstract model: TrueSSM modelled (its clearance measured at every pose)."""
    sf = load_scenario(TENDING)
    model = abstract_model(sf, only=("TrueSSM",))
    ssm = next(part for part in model.parts if isinstance(part, SsmAbstraction))
    return model, ssm


def _exact(model, ssm, context, person_ids) -> float:
    """SceneGraph's least signed distance between the arm's shapes and the person's body regions as posed."""
    system = ssm.system
    query = system.query_port.Eval(system.GetMyContextFromRoot(context))
    return min(query.ComputeSignedDistancePairClosestPoints(a, b).distance
               for a in system.pairs.a.ids for b in person_ids)


def _posable(model, ssm):
    """(the person's role, the built cell, a context of it, its plant's context, the monitored robot's instance): to
    stand the person and set the arm in."""
    built = model.cell.cell
    context = built.diagram.CreateDefaultContext()
    built.set_initial_state(context)
    return (model.cell.people[0], built, context, built.plant.GetMyMutableContextFromRoot(context),
            built.robots[ssm.cfg.robot])


def test_a_stretch_s_bound_never_exceeds_scenegraph_s_distance(tending):
    """Random poses of the floor (with and without a reach) and the arm at random points of each stretch's moves,
    between their samples: the stretch's bound is at most the exact distance, and within a few centimetres of it
    where they are near (the covering's tolerance, a voxel, the samples' step)."""
    model, ssm = tending
    person, built, context, plant_context, instance = _posable(model, ssm)
    rng = np.random.default_rng(7)
    poses = [p for p in person.poses if -2.3 < p.x < 0.6 and -1.8 < p.y < 1.8]
    person_ids = list(ssm.system.pairs.b.ids)
    # the model's own bounds are told apart only up to its thresholds; one told apart every centimetre gives the fine
    # bound itself, to see how far below the truth it lies
    fine = Clearance(ssm.clouds, [list(np.arange(-0.5, 2.5, 0.01))] * len(ssm.clouds), ssm.clearance.within)
    checked = near = 0
    gaps = []
    for k, (location, members) in enumerate(ssm.members.items()):
        if location is None:
            continue
        for _ in range(25):
            stretch, _ = members[rng.integers(len(members))]
            configs = stretch.lines[rng.integers(len(stretch.lines))]
            i = rng.integers(len(configs) - 1) if len(configs) > 1 else 0
            t = rng.uniform() if len(configs) > 1 else 0.0
            q = configs[i] + t * (configs[min(i + 1, len(configs) - 1)] - configs[i])
            built.plant.SetPositions(plant_context, instance, q)
            pose = poses[rng.integers(len(poses))]
            person.stand(context, pose)
            system = ssm.system
            body = ssm.bodies.at(system.query_port.Eval(system.GetMyContextFromRoot(context)))
            bound, finest = ssm.clearance.of(body)[k], fine.of(body)[k]
            exact = _exact(model, ssm, context, person_ids)
            assert bound <= exact + 1e-9 and finest <= exact + 1e-9, (stretch.words, pose, bound, finest, exact)
            checked += 1
            if exact < 0.8:
                near += 1
                gaps.append(exact - finest)
    assert checked >= 50 and near >= 5
    # a bound, not a guess: near the arm it is within the coverings, the voxel and the stretch's reach of the truth
    assert np.median(gaps) < 0.2


def test_the_lower_bound_is_also_below_the_truth_at_the_poses_nearest_the_arm(tending):
    """The poses whose bound is least (where a dip is called): reaching onto the bench beside the pick."""
    model, ssm = tending
    person, built, context, plant_context, instance = _posable(model, ssm)
    robot = built.modules[ssm.cfg.robot]
    pick = robot.poses[robot.pose_names.index("bench_pick")]
    built.plant.SetPositions(plant_context, instance, pick)
    k = next(i for i, (group, _) in enumerate(ssm.groups) if f"robot_segment={robot.pose_names.index('bench_pick')})" in group.guard)
    reaching = [p for p in person.poses if p.reach is not None and math.hypot(p.x + 0.95, p.y + 0.95) < 0.25]
    assert reaching
    for pose in reaching:
        person.stand(context, pose)
        system = ssm.system
        body = ssm.bodies.at(system.query_port.Eval(system.GetMyContextFromRoot(context)))
        bound = ssm.clearance.of(body)[k]
        assert bound <= _exact(model, ssm, context, list(system.pairs.b.ids)) + 1e-9


def test_a_stretch_s_rate_bounds_every_point_s_speed_along_its_path(tending):
    """Each covering sphere's centre, differentiated along the move's straight joint-space line at a step a hundred
    times finer than the samples, with its radius turning at the joints' summed rate: no point of the arm moves
    farther per unit of the move's parameter than the stretch's rate times the tool's metres per unit (the twin plans
    ds/dt at most a cap over the latter, so the arm's points move at most the rate times the cap)."""
    _, ssm = tending
    sweep = ssm.sweep
    seen = 0
    for location, members in ssm.members.items():
        for stretch, rate in members:
            if rate is None or stretch.tool_per_s == 0.0:
                continue
            spacing = stretch.spacing
            fine = spacing / 100.0
            for configs in stretch.lines:
                turning = np.abs(configs[1] - configs[0]).sum() / spacing  # the line's joints' summed rate per unit s
                for i in range(len(configs) - 1):
                    for t in (0.0, 0.37, 0.81):
                        q = configs[i] + t * (configs[i + 1] - configs[i])
                        dq = (configs[i + 1] - configs[i]) / 100.0
                        per_s = np.linalg.norm(sweep.centres(q + dq) - sweep.centres(q), axis=1) / fine
                        fastest = float((per_s + turning * sweep.radii).max())
                        assert fastest <= rate * stretch.tool_per_s + 1e-9, (stretch.words, i, fastest, rate)
                        seen += 1
    assert seen > 100


def test_true_ssm_is_modelled_with_a_firmer_witness_sought_first(tending):
    """TrueSSM is a property of the model now (not 'not checked'), and its witness is sought first where the arm
    moves at the cap in force (not braking from an earlier one) or stands still at a pose."""
    model, ssm = tending
    assert "TrueSSM" not in {s.name for s in model.skipped}
    prop = next(p for p in model.properties if p.name == "TrueSSM")
    assert prop.bad and prop.sustained and prop.sustained.startswith(f"({prop.bad}) & ")
    signal = model.cell.signals["ssm.true_margin"]
    assert signal.firm and model.cell.formulas[signal.firm] != model.cell.formulas[signal.formula]
    bounded = next(a for a in model.cell.assumptions if "true margin is bounded from below" in a)
    assert "measured at the floor's grid poses" in bounded  # (a person between them may stand nearer: said)
    assert any("speed limit is the highest its formula gives" in a for a in model.cell.assumptions)


def test_a_move_s_stretch_reaches_as_far_as_the_arm_goes_in_one_of_its_periods(tending):
    """The model's region is where the measured tool was at the robot's last update: until the next, the arm goes on
    up to a period at its fastest ds/dt. Each region's stretch holds the move's samples that far past its last one
    (the review found it held one sample, where the arm goes 1.4 to 13 in a period)."""
    model, ssm = tending
    robot_abstraction = next(p for p in model.parts if type(p).__name__ == "RobotAbstraction")
    robot = robot_abstraction.system
    poses = len(robot.poses)
    for i, (a, b) in enumerate(robot_abstraction._pairs()):
        motion = robot.start_segment(robot.poses[a], b)
        fastest = min(float(motion[4]), robot.normal_cap / float(motion[3]))
        configs = robot_abstraction._samples(a, b)[0]
        for region, (_, first, last) in enumerate(robot_abstraction._runs(a, b)):
            s_after = min(last / 200 + fastest * robot.period, 1.0)  # where the arm may be a period on
            q = robot.poses[a] + s_after * (robot.poses[b] - robot.poses[a])
            stretch = next(st for group in ssm.members.values() for st, _ in group
                           if st.guard == f"robot_segment={poses + i} & robot_region={region}")
            (line,) = stretch.lines
            reached = np.linalg.norm(line - q, axis=1).min()
            assert reached <= np.linalg.norm(configs[1] - configs[0]) / 2 + 1e-12, (a, b, region)


def _arm(joint: str, offset):
    """A one-body 'arm' joined to the world by a ``joint`` ('prismatic' or 'revolute'), its body's origin ``offset``
    (m) from the joint's frame, and a second body on a revolute joint at the first one's origin."""
    from pydrake.multibody.plant import MultibodyPlant
    from pydrake.multibody.tree import FixedOffsetFrame, PrismaticJoint, RevoluteJoint, SpatialInertia, UnitInertia

    plant = MultibodyPlant(0.0)
    inertia = SpatialInertia(1.0, np.zeros(3), UnitInertia.SolidSphere(0.1))
    first, second = plant.AddRigidBody("first", inertia), plant.AddRigidBody("second", inertia)
    if joint == "prismatic":
        plant.AddJoint(PrismaticJoint("slide", plant.world_frame(), first.body_frame(), [1.0, 0.0, 0.0]))
    else:
        plant.AddJoint(RevoluteJoint("turn", plant.world_frame(), first.body_frame(), [0.0, 0.0, 1.0]))
    hinge = plant.AddFrame(FixedOffsetFrame("hinge", first.body_frame(), RigidTransform([0.5, 0.0, 0.0])))
    child = plant.AddFrame(FixedOffsetFrame("child", second.body_frame(), RigidTransform(list(offset))))
    plant.AddJoint(RevoluteJoint("elbow", hinge, child, [0.0, 1.0, 0.0]))
    plant.Finalize()
    shapes = [(first, Box(0.1, 0.1, 0.1), RigidTransform()), (second, Box(0.1, 0.1, 0.1), RigidTransform())]
    return plant, plant.CreateDefaultContext(), shapes


@pytest.mark.parametrize("joint, offset, refused", [("revolute", (0.0, 0.0, 0.0), None),
                                                    ("prismatic", (0.0, 0.0, 0.0), "moves with the joints"),
                                                    ("revolute", (0.3, 0.0, 0.0), "changes with the joints")])
def test_an_arm_whose_reach_no_chain_of_its_joints_bounds_is_refused_in_one_line(joint, offset, refused):
    """The sphere a re-targeted arm may be anywhere in is about its base, of its joint-to-joint distances: sound only
    where the base stays put and each body's origin lies on its joint's axis. Else one clear error, not a bound."""
    from cellsim.verify.clearance import ArmSweep

    plant, context, shapes = _arm(joint, offset)
    sweep = ArmSweep(plant, context, shapes)
    if refused is None:
        centre, radius = sweep.reach(np.zeros(plant.num_positions()))
        for q in np.random.default_rng(3).uniform(-3, 3, (50, plant.num_positions())):
            assert (np.linalg.norm(sweep.centres(q) - centre, axis=1) + sweep.radii).max() <= radius + 1e-9
    else:
        with pytest.raises(ValueError, match=refused):
            sweep.reach(np.zeros(plant.num_positions()))
