"""How near an arm's shapes may come to a person's body, bounded from below, for the abstract cell.

A true separation (the ``ssm`` monitor's true margin, the harm service's contact) is a distance
between the arm's collision shapes, wherever the arm is on its path, and the body regions of a
person standing at a pose of the floor. The abstract cell needs it per place of the floor and per
state of the abstract robot (a stretch of a move, a pose it rests at), so it is bounded from
below here, in numpy and a k-d tree, for every pose against every such stretch:

* every shape is covered by spheres (:func:`cover`): a cylinder or capsule by spheres along its
  axis, a box by spheres over its cells, each sphere holding its slab or cell whole, so the
  union of the spheres holds the shape and a distance between two unions is at most the
  distance between the shapes;
* a stretch of a move is the arm at each of the move's sample points in it and at the sample on
  either side (:class:`ArmSweep`), its spheres grown by half the farthest any of the arm's points
  moves from one sample to the next (an arm between two samples is within that of one of them);
* a pose's distance to a stretch is the least, over the body's spheres, of the distance from the
  sphere's centre to the nearest sphere centre of the stretch less both radii (the stretch's
  largest): a lower bound, never more than the true distance.

The bound is loose by the covering's tolerance (``TOLERANCE``) and the stretch's largest sphere:
a state the bound calls near may not be (a witness the twin then refutes), never the reverse.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

TOLERANCE = 0.02
"""m: how far a covering sphere may reach beyond the shape it covers (at most)."""
VOXEL = 0.01
"""m: an arm's stretch keeps one sphere centre per cube of this edge (the samples' spheres overlap), each grown by
the cube's half-diagonal."""
COARSE = 0.05
"""m: the cubes of a stretch's grid of distances, which tell which body spheres may be nearest."""
BODY_TOLERANCE = 0.04
"""m: the same for a person's body regions (coarser: the body's shapes are many, its poses thousands)."""


def cover(shape, pose, tolerance: float = TOLERANCE) -> tuple[np.ndarray, np.ndarray]:
    """Spheres whose union holds ``shape`` posed at ``pose`` in its frame: (centres in the frame (n, 3), radii (n,)),
    each reaching at most about ``tolerance`` (m) beyond the shape. A shape this does not know is held by its
    bounding sphere (:func:`cellsim.proximity.bounding_sphere`)."""
    from pydrake.geometry import Box, Capsule, Cylinder, Ellipsoid, Sphere

    from cellsim.proximity import bounding_sphere

    if isinstance(shape, Sphere):
        local, radii = np.zeros((1, 3)), np.array([shape.radius()])
    elif isinstance(shape, (Cylinder, Capsule)):
        r, length = shape.radius(), shape.length()
        # slabs of half-height h along z, each held by a sphere of radius sqrt(r^2 + h^2) <= r + tolerance
        h_most = math.sqrt((r + tolerance) ** 2 - r * r)
        n = max(1, math.ceil(length / (2.0 * h_most)))
        h = length / (2.0 * n)
        z = -length / 2.0 + h * (2.0 * np.arange(n) + 1.0)
        local = np.column_stack([np.zeros(n), np.zeros(n), z])
        radii = np.full(n, math.hypot(r, h))
        if isinstance(shape, Capsule):  # its two hemispherical ends
            local = np.vstack([local, [[0.0, 0.0, -length / 2.0], [0.0, 0.0, length / 2.0]]])
            radii = np.concatenate([radii, [r, r]])
    elif isinstance(shape, (Box, Ellipsoid)):
        size = (np.array([shape.width(), shape.depth(), shape.height()]) if isinstance(shape, Box)
                else 2.0 * np.array([shape.a(), shape.b(), shape.c()]))  # an ellipsoid: its bounding box
        # cells of edge e, each held by the sphere of its half-diagonal: e sqrt(3) / 2 - e / 2 <= tolerance
        edge = tolerance / ((math.sqrt(3.0) - 1.0) / 2.0)
        counts = np.maximum(1, np.ceil(size / edge)).astype(int)
        cells = size / counts
        axes = [-size[i] / 2.0 + cells[i] * (np.arange(counts[i]) + 0.5) for i in range(3)]
        # every cell, inner ones too: a shape the other overlaps deeply must still read as overlapping
        local = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        radii = np.full(len(local), 0.5 * float(np.linalg.norm(cells)))
    else:
        centre, radius = bounding_sphere(shape, pose)
        return np.asarray(centre, float)[None, :], np.array([radius])
    return (local @ pose.rotation().matrix().T + pose.translation()), radii


@dataclass(frozen=True)
class Spheres:
    """Spheres in the world: centres (n, 3) and radii (n,), m."""

    centres: np.ndarray
    radii: np.ndarray


class ArmSweep:
    """The spheres of one arm's shapes at given joint positions (``configs``), through a kinematics plant.

    ``plant``, ``context``: a plant of the arm alone (its base where the cell's is); ``shapes``: each shape's
    (plant body, shape, pose in the body's frame)."""

    def __init__(self, plant, context, shapes: list):
        self.plant, self.context = plant, context
        self._local: list[tuple[object, np.ndarray, np.ndarray]] = []
        for body, shape, pose in shapes:
            centres, radii = cover(shape, pose)
            self._local.append((body, centres, radii))
        self.radii = np.concatenate([radii for _, _, radii in self._local]) if self._local else np.zeros(0)
        if not np.isfinite(self.radii).all():
            raise ValueError("an arm shape cannot be covered (a box, cylinder, capsule, sphere or ellipsoid can)")

    def centres(self, q) -> np.ndarray:
        """World positions (m) of every covering sphere's centre with the arm at joint positions ``q``."""
        self.plant.SetPositions(self.context, np.asarray(q, float))
        out = []
        for body, local, _ in self._local:
            X = self.plant.EvalBodyPoseInWorld(self.context, body)
            out.append(local @ X.rotation().matrix().T + X.translation())
        return np.vstack(out) if out else np.zeros((0, 3))

    def stretch(self, configs: np.ndarray) -> Spheres:
        """The spheres of the arm at each of ``configs`` (consecutive samples of one straight joint-space path), each
        grown by half the farthest any point of the arm moves from one sample to the next (so that the arm anywhere
        between two samples is inside them)."""
        positions = np.array([self.centres(q) for q in configs])  # (samples, spheres, 3)
        step = 0.0
        if len(configs) > 1:
            moved = np.linalg.norm(np.diff(positions, axis=0), axis=2)  # each centre's chord, sample to sample
            turned = np.abs(np.diff(np.asarray(configs, float), axis=0)).sum(axis=1)  # no link turns more than this
            step = float((moved + turned[:, None] * self.radii[None, :]).max())
        return Spheres(positions.reshape(-1, 3), np.tile(self.radii, len(configs)) + 0.5 * step)

    def reach(self, q) -> tuple[np.ndarray, float]:
        """A sphere (centre, radius; m) holding the arm in every configuration: about the origin of the body welded to
        the world, of the longest chain of joint-to-joint distances (fixed: each body's origin lies on the axis of
        the joint that moves it) to a body, plus that body's farthest sphere."""
        plant, context = self.plant, self.context
        plant.SetPositions(context, np.asarray(q, float))
        origin = {}
        links = []
        for j in plant.GetJointIndices():
            joint = plant.get_joint(j)
            links.append((joint.parent_body().index(), joint.child_body().index()))
        world = plant.world_body().index()
        length = {child: 0.0 for parent, child in links if parent == world}
        if not length:
            raise ValueError("the arm has no body joined to the world")
        base = next(iter(length))
        for body in {b for link in links for b in link}:
            origin[body] = plant.EvalBodyPoseInWorld(context, plant.get_body(body)).translation()
        changed = True
        while changed:
            changed = False
            for parent, child in links:
                if parent in length and child not in length:
                    length[child] = length[parent] + float(np.linalg.norm(origin[child] - origin[parent]))
                    changed = True
        radius = 0.0
        for body, local, radii in self._local:
            extent = float((np.linalg.norm(local, axis=1) + radii).max()) if len(radii) else 0.0
            radius = max(radius, length.get(body.index(), math.inf) + extent)
        # the joint-to-joint distances must not change with the joints (a body's origin off its joint's axis, a
        # prismatic joint): else no chain of them bounds the reach
        lower, upper = plant.GetPositionLowerLimits(), plant.GetPositionUpperLimits()
        for k in range(1, 6):
            turned = np.clip(np.asarray(q, float) + k * 0.7, np.maximum(lower, -10.0), np.minimum(upper, 10.0))
            plant.SetPositions(context, turned)
            moved = float(np.linalg.norm(plant.EvalBodyPoseInWorld(context, plant.get_body(base)).translation()
                                         - origin[base]))
            if moved > 1e-9:
                raise ValueError(f"its base {plant.get_body(base).name()} moves with the joints: the arm's reach cannot "
                                 "be bounded about it")
            for parent, child in links:
                if parent == world:
                    continue
                apart = float(np.linalg.norm(plant.EvalBodyPoseInWorld(context, plant.get_body(child)).translation()
                                             - plant.EvalBodyPoseInWorld(context, plant.get_body(parent)).translation()))
                if abs(apart - float(np.linalg.norm(origin[child] - origin[parent]))) > 1e-9:
                    raise ValueError(f"the distance between the origins of {plant.get_body(parent).name()} and "
                                     f"{plant.get_body(child).name()} changes with the joints: the arm's reach cannot "
                                     "be bounded from its joints")
        return np.asarray(origin[base], float), radius

    def point_rate(self, configs: np.ndarray, spacing: float) -> float:
        """The fastest any point of the arm moves (m) per unit of the path's parameter s, along a straight joint-space
        path sampled at ``configs``, ``spacing`` of s apart: each sphere centre's chord per unit of s, plus its radius
        turning at the joints' summed rate, and 5 % for a chord's shortfall from its arc."""
        if len(configs) < 2:
            return 0.0
        positions = np.array([self.centres(q) for q in configs])
        moved = np.linalg.norm(np.diff(positions, axis=0), axis=2) / spacing
        turned = np.abs(np.diff(np.asarray(configs, float), axis=0)).sum(axis=1) / spacing
        return 1.05 * float((moved + turned[:, None] * self.radii[None, :]).max())


class Clearance:
    """Lower bounds on the distance from a person's body to each of several stretches of an arm (:class:`Spheres`
    each), told apart only up to each stretch's ``thresholds`` (m): the bound returned lies in the same interval
    between two of them as the finest bound here does, and ``within`` (above every threshold) where the stretch is
    farther than that.

    Each stretch keeps its sphere centres one per cube of ``VOXEL`` (the fine centres), and a grid of cubes of
    ``COARSE`` holding each cube's distance to the nearest cube with a fine centre (SciPy's exact Euclidean distance
    transform): a body sphere's distance to the fine centres is within a cube's diagonal of its cube's value. Where
    that leaves the bound between the same two thresholds, the coarse bound is returned; else the body spheres the
    coarse distances leave as possibly nearest are measured against the fine centres (a k-d tree)."""

    def __init__(self, stretches: list[Spheres], thresholds: list[list[float]], within: float):
        self.within = within
        self._stretches = []
        points = []
        for spheres, cuts in zip(stretches, thresholds):
            most = float(spheres.radii.max())
            if len(spheres.centres) == 1:  # one sphere (an arm at rest, or anywhere in its reach): measured exactly
                self._stretches.append((spheres.centres[0], most, None))
                continue
            fine = _voxels(spheres.centres, VOXEL)
            most += VOXEL * math.sqrt(3.0) / 2.0
            points.append(fine)
            self._stretches.append((cKDTree(fine), most, np.array(sorted(cuts), float)))
        margin = within + max((most for _, most, cuts in self._stretches if cuts is not None), default=0.0) + 0.5
        self._grid = _Grid(points, margin) if points else None
        # each stretch's bounding sphere (its points' and their spheres'): a body farther than ``within`` from every one
        # is answered at once (most of a floor is)
        holding = [(s.centres.min(axis=0) + s.centres.max(axis=0)) / 2.0 for s in stretches]
        self._around = np.array(holding, float).reshape(-1, 3)
        self._around_radius = np.array([float((np.linalg.norm(s.centres - c, axis=1) + s.radii).max())
                                        for s, c in zip(stretches, holding)])

    def of(self, body: Spheres) -> list[float]:
        """Each stretch's distance (m) from the body's spheres, bounded from below; ``within`` where it is farther."""
        if len(self._around) and len(body.centres):
            low, high = body.centres.min(axis=0), body.centres.max(axis=0)  # the body's sphere about its box
            apart = np.linalg.norm(self._around - (low + high) / 2.0, axis=1) - float(np.linalg.norm(high - low)) / 2.0
            if (apart - self._around_radius - float(body.radii.max()) >= self.within).all():
                return [self.within] * len(self._stretches)
        out = []
        grid = self._grid
        roughs = iter(grid.distances(body.centres) if grid else ())  # inf outside the grid: farther than within
        slack = grid.slack if grid else 0.0
        for fine, most, cuts in self._stretches:
            if cuts is None:
                least = float((np.linalg.norm(body.centres - fine, axis=1) - body.radii).min()) - most
                out.append(min(least, self.within))
                continue
            rough = next(roughs)
            lower = float((rough - slack - body.radii).min()) - most  # the fine bound lies in [lower, upper]
            if lower >= self.within:
                out.append(self.within)
                continue
            upper = float((rough + slack - body.radii).min()) - most
            if np.searchsorted(cuts, lower, "left") == np.searchsorted(cuts, upper, "right"):
                out.append(lower)  # no threshold between them
                continue
            maybe = rough - slack - body.radii - most <= upper
            bound = upper + most + float(body.radii[maybe].max()) + 1e-9  # the nearest's centre is no farther
            distances, _ = fine.query(body.centres[maybe], distance_upper_bound=bound)
            out.append(min(float((distances - body.radii[maybe]).min()) - most, self.within))
        return out


class _Grid:
    """One grid of cubes of ``COARSE`` over every stretch's points, their box grown by ``margin`` (m): for each stretch,
    each cube's distance from its centre to the nearest cube centre with one of that stretch's points in it."""

    def __init__(self, stretches: list[np.ndarray], margin: float):
        from scipy.ndimage import distance_transform_edt

        every = np.vstack(stretches)
        self.origin = every.min(axis=0) - margin
        self.shape = np.ceil((every.max(axis=0) + margin - self.origin) / COARSE).astype(int) + 1
        self.values = np.empty((len(stretches), *self.shape), np.float32)
        for k, points in enumerate(stretches):
            free = np.ones(self.shape, bool)
            free[tuple(np.floor((points - self.origin) / COARSE).astype(int).T)] = False
            self.values[k] = distance_transform_edt(free, sampling=COARSE)
        self.slack = COARSE * math.sqrt(3.0)
        """m: a point's distance to the nearest of a stretch's points is within this of its cube's value (half a
        cube's diagonal at either end)."""

    def distances(self, centres: np.ndarray) -> np.ndarray:
        """Each centre's cube's value for each stretch (m; (stretches, centres)); inf outside the grid."""
        cells = np.floor((centres - self.origin) / COARSE).astype(int)
        inside = ((cells >= 0) & (cells < self.shape)).all(axis=1)
        out = np.full((len(self.values), len(centres)), np.inf)
        out[:, inside] = self.values[(slice(None), *cells[inside].T)]
        return out - 1e-6  # (the values are single precision: never above their exact value)


def _voxels(centres: np.ndarray, edge: float) -> np.ndarray:
    """One point per cube of ``edge`` (m) holding any of ``centres``: the cube's centre."""
    return (np.unique(np.floor(centres / edge), axis=0) + 0.5) * edge


@dataclass(frozen=True)
class ArmGroup:
    """Stretches of an arm's path where its tool is in one region of the layout: the states (``guard``), the fastest any
    of its points moves per m/s of its cap-equivalent tool speed (None: not known, a path not modelled), and the spheres
    holding the arm anywhere on them."""

    guard: str
    rate: float | None
    at_rest: tuple[str, ...]
    """The guards of its stretches where the arm rests at a pose (no motion of its own but settling)."""
    spheres: Spheres


def arm_groups(sweep: ArmSweep, stretches: list, reach: tuple[np.ndarray, float]) -> tuple[list[ArmGroup], dict]:
    """An arm's stretches (``RobotAbstraction.stretches``) grouped by the layout's region its tool is in (fewer places:
    the floor is cut by each group's clearance), each group's rate its fastest stretch's (at rest: settling, at the
    arm's fastest), a path not modelled held by ``reach`` (a sphere about its base, :meth:`ArmSweep.reach`). Returns
    (the groups, location -> [(stretch, its rate)])."""
    members: dict = {}
    fastest = 0.0
    for stretch in stretches:
        rate = None
        if stretch.lines is not None and stretch.tool_per_s > 0.0:
            rate = max(sweep.point_rate(line, stretch.spacing) for line in stretch.lines) / stretch.tool_per_s
            fastest = max(fastest, rate)
        members.setdefault(stretch.location, []).append((stretch, rate))
    groups = []
    for location, found in members.items():
        guard = " | ".join(f"({stretch.guard})" for stretch, _ in found)
        if location is None:  # a path not modelled: anywhere within its reach
            centre, radius = reach
            groups.append(ArmGroup(guard, None, (), Spheres(centre[None, :], np.array([radius]))))
            continue
        parts = [sweep.stretch(line) for stretch, _ in found for line in stretch.lines]
        rate = max(fastest if rate is None else rate for _, rate in found)
        at_rest = tuple(stretch.guard for stretch, _ in found if stretch.tool_per_s == 0.0)
        groups.append(ArmGroup(guard, rate, at_rest, Spheres(np.vstack([p.centres for p in parts]),
                                                             np.concatenate([p.radii for p in parts]))))
    return groups, members


class BodyCover:
    """The spheres covering every person's body regions (``regions``: GeometryIds), per SceneGraph frame, posed from a
    QueryObject."""

    def __init__(self, inspector, regions):
        frames: dict = {}
        for g in regions:
            centres, radii = cover(inspector.GetShape(g), inspector.GetPoseInFrame(g), BODY_TOLERANCE)
            frames.setdefault(inspector.GetFrameId(g), []).append((centres, radii))
        self.frames = [(frame, np.vstack([c for c, _ in parts]), np.concatenate([r for _, r in parts]))
                       for frame, parts in frames.items()]
        if not all(np.isfinite(radii).all() for _, _, radii in self.frames):
            raise ValueError("a body region's shape cannot be covered (a box, cylinder, capsule, sphere or ellipsoid "
                             "can)")
        self.radii = np.concatenate([r for _, _, r in self.frames]) if self.frames else np.zeros(0)

    def at(self, query) -> Spheres:
        out = []
        for frame, local, _ in self.frames:
            X = query.GetPoseInWorld(frame)
            out.append(local @ X.rotation().matrix().T + X.translation())
        return Spheres(np.vstack(out) if out else np.zeros((0, 3)), self.radii)
