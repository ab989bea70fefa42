"""The nearest pair found by bounding spheres first is the nearest pair of all (cellsim.proximity)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydrake.geometry import Box, Capsule, Convex, Cylinder, Ellipsoid, Sphere
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph, CoulombFriction
from pydrake.multibody.tree import SpatialInertia
from pydrake.systems.framework import DiagramBuilder

from cellsim.proximity import NearestPair, bounding_sphere


_alive: list = []


def _scene(tmp_path, shapes_a, shapes_b, seed):
    """Free bodies carrying ``shapes_a`` and ``shapes_b`` (two shapes per body), posed at random; returns
    (query object, ids of a, ids of b)."""
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
    rng = np.random.default_rng(seed)
    ids = {"a": [], "b": []}
    bodies = []
    for side, shapes in (("a", shapes_a), ("b", shapes_b)):
        for k in range(0, len(shapes), 2):
            body = plant.AddRigidBody(f"{side}{k}", SpatialInertia.SolidSphereWithMass(1.0, 0.1))
            bodies.append(body)
            for m, shape in enumerate(shapes[k:k + 2]):
                offset = RigidTransform(RollPitchYaw(*rng.uniform(-3, 3, 3)), rng.uniform(-0.2, 0.2, 3))
                ids[side].append(plant.RegisterCollisionGeometry(body, offset, shape, f"{side}{k}_{m}", CoulombFriction()))
    plant.Finalize()
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    plant_context = plant.GetMyMutableContextFromRoot(context)
    for body in bodies:
        pose = RigidTransform(RollPitchYaw(*rng.uniform(-3, 3, 3)), rng.uniform(-1.0, 1.0, 3))
        plant.SetFreeBodyPose(plant_context, body, pose)
    query = scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(context))
    _alive.append((diagram, context))  # the query object refers to them
    return query, ids["a"], ids["b"]


def _brute(query, a, b):
    return min((query.ComputeSignedDistancePairClosestPoints(x, y) for x in a for y in b), key=lambda p: p.distance)


@pytest.mark.parametrize("seed", range(12))
def test_the_nearest_pair_is_the_nearest_of_all_pairs(tmp_path, seed):
    a = [Cylinder(0.05, 0.4), Box(0.1, 0.2, 0.3), Capsule(0.04, 0.3), Sphere(0.1)]
    b = [Capsule(0.06, 0.35), Box(0.2, 0.1, 0.05), Sphere(0.08), Cylinder(0.1, 0.1), Ellipsoid(0.05, 0.2, 0.1),
         Box(0.3, 0.3, 0.02)]
    query, ida, idb = _scene(tmp_path, a, b, seed)
    nearest = NearestPair(query.inspector(), ida, idb)
    found, truth = nearest(query), _brute(query, ida, idb)
    assert found.distance == pytest.approx(truth.distance, abs=1e-12)
    assert {found.id_A, found.id_B} == {truth.id_A, truth.id_B} or found.distance == truth.distance
    # within: the nearest pair when it lies within, else none
    assert nearest(query, truth.distance + 1e-9).distance == pytest.approx(truth.distance)
    assert nearest(query, truth.distance - 1e-6) is None


def test_a_mesh_is_bounded_by_its_hull_and_a_shape_it_cannot_bound_is_always_measured(tmp_path):
    """A convex mesh's sphere holds its hull: its pairs are skipped only where no point of it can be nearer, so the
    nearest pair is the one measuring every pair finds. A shape with no bound (a half space) has an infinite radius:
    its pairs are never skipped."""
    from pydrake.geometry import HalfSpace

    mesh = tmp_path / "tetra.obj"
    mesh.write_text("v 0 0 0\nv 0.3 0 0\nv 0 0.3 0\nv 0 0 0.3\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    convex = Convex(str(mesh))
    assert bounding_sphere(convex, RigidTransform())[1] == pytest.approx(math.sqrt(3 * 0.15 ** 2))
    assert math.isinf(bounding_sphere(HalfSpace(), RigidTransform())[1])
    for seed in range(6):
        query, ida, idb = _scene(tmp_path, [convex, Sphere(0.05)], [Box(0.1, 0.1, 0.1), convex], seed)
        assert NearestPair(query.inspector(), ida, idb)(query).distance == pytest.approx(_brute(query, ida, idb).distance)


def test_no_geometry_on_one_side_finds_nothing(tmp_path):
    query, ida, _ = _scene(tmp_path, [Sphere(0.1), Sphere(0.1)], [Sphere(0.1), Sphere(0.1)], 0)
    nearest = NearestPair(query.inspector(), ida, [])
    assert not nearest and nearest(query) is None


@pytest.mark.parametrize("seed", range(12))
def test_each_groups_nearest_and_every_touching_pair_are_those_measuring_every_pair_finds(tmp_path, seed):
    """``nearest_and_touching``: for each group of ``these`` (an arm's shapes), its nearest pair if within the
    distance asked, and every pair that touches: the same pairs, with the same distances, as measuring all of them.
    The bodies sit close (a metre's cube): over the twelve seeds seven pairs touch."""
    a = [Cylinder(0.05, 0.4), Box(0.1, 0.2, 0.3), Capsule(0.04, 0.3), Sphere(0.1), Cylinder(0.08, 0.5), Sphere(0.15)]
    b = [Capsule(0.2, 0.35), Box(0.4, 0.3, 0.25), Sphere(0.25), Cylinder(0.2, 0.3), Ellipsoid(0.15, 0.3, 0.2),
         Box(0.5, 0.5, 0.2)]
    query, ida, idb = _scene(tmp_path, a, b, seed)
    groups = [[0, 1, 2, 3], [4, 5]]
    every = {(i, j): query.ComputeSignedDistancePairClosestPoints(ida[i], idb[j]) for i in range(len(ida))
             for j in range(len(idb))}
    touching = {key for key, pair in every.items() if pair.distance <= 0.0}
    for within in (0.05, 0.3, 2.0):
        found = NearestPair(query.inspector(), ida, idb).nearest_and_touching(query, within, groups)
        keys = [(ida.index(p.id_A), idb.index(p.id_B)) if p.id_A in ida else (ida.index(p.id_B), idb.index(p.id_A))
                for p in found]
        assert len(keys) == len(set(keys)) and keys == sorted(keys)
        expected = set(touching)
        for rows in groups:
            best = min((every[(i, j)].distance, (i, j)) for i in rows for j in range(len(idb)))
            if best[0] <= within:
                assert any(k[0] in rows and every[k].distance == pytest.approx(best[0], abs=1e-12) for k in keys)
                expected.add(next(k for k in keys if k[0] in rows and every[k].distance == pytest.approx(best[0], abs=1e-12)))
        assert set(keys) == expected
        for key, pair in zip(keys, found):
            assert pair.distance == pytest.approx(every[key].distance, abs=1e-12)


def test_the_inradius_is_the_half_thickness_of_each_shape_and_zero_for_a_mesh():
    """How deep the harm service takes an overlap to stay shallow: the largest ball inside the shape."""
    from pydrake.geometry import Mesh

    from cellsim.proximity import inradius

    assert inradius(Sphere(0.1)) == 0.1 and inradius(Capsule(0.045, 0.3)) == 0.045
    assert inradius(Cylinder(0.2, 0.1)) == 0.05 and inradius(Cylinder(0.04, 0.3)) == 0.04
    assert inradius(Box(0.3, 0.1, 0.5)) == 0.05 and inradius(Ellipsoid(0.2, 0.3, 0.1)) == 0.1
    assert inradius(Mesh("/nonexistent.obj")) == 0.0
