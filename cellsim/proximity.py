"""Nearest pairs of SceneGraph geometries: by bounding spheres first, then exact distances.

SceneGraph's broadphase (``ComputeSignedDistancePairwiseClosestPoints``) returns every unfiltered pair within a
distance, each one's exact distance computed and handed to Python: cheap within a few centimetres, dear within
metres, where the sensors' volumes and the body regions make dozens of pairs. To find the one nearest pair of
two small sets (an arm's shapes and a person's body regions), :class:`NearestPair` bounds every pair's
distance from below by the bounding spheres of its two shapes (one pose per frame, one numpy expression) and
asks SceneGraph for exact distances (``ComputeSignedDistancePairClosestPoints``, a microsecond or two each) in
order of that bound, until the bound exceeds the nearest found: usually one to three pairs.
"""

from __future__ import annotations

import math

import numpy as np


def witness_on(query, pair, geometry) -> np.ndarray:
    """The signed-distance ``pair``'s witness point on ``geometry`` (one of its two), in the world (m): SceneGraph may
    order a pair either way."""
    return query.GetPoseInWorld(geometry) @ (pair.p_ACa if pair.id_A == geometry else pair.p_BCb)


def nearest_on_box(shape, X_WG, p_W) -> np.ndarray | None:
    """The point of a Box ``shape`` posed at ``X_WG`` nearest the world point ``p_W`` (``p_W`` itself inside it), in
    the world (m); None for another shape."""
    from pydrake.geometry import Box

    if not isinstance(shape, Box):
        return None
    half = 0.5 * np.array([shape.width(), shape.depth(), shape.height()])
    return np.asarray(X_WG @ np.clip(X_WG.inverse() @ np.asarray(p_W, float), -half, half), float)


def bounding_sphere(shape, pose) -> tuple[np.ndarray, float]:
    """(centre in the frame, radius) of a sphere holding ``shape`` posed at ``pose`` in its frame (m); an infinite
    radius for a shape this does not know (every pair with it is then measured exactly). A mesh is bounded by its
    convex hull's vertices (as SceneGraph measures distances to a mesh)."""
    from pydrake.geometry import Box, Capsule, Convex, Cylinder, Ellipsoid, Mesh, Sphere

    if isinstance(shape, (Mesh, Convex)):
        try:
            hull = shape.GetConvexHull()
        except Exception:  # noqa: BLE001 - a file SceneGraph can read but not hull: measure every pair exactly
            return np.asarray(pose.translation(), float), math.inf
        vertices = np.array([hull.vertex(i) for i in range(hull.num_vertices())], float)
        middle = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
        return np.asarray(pose @ middle, float), float(np.linalg.norm(vertices - middle, axis=1).max())
    if isinstance(shape, Sphere):
        radius = shape.radius()
    elif isinstance(shape, Box):
        radius = 0.5 * math.sqrt(shape.width() ** 2 + shape.depth() ** 2 + shape.height() ** 2)
    elif isinstance(shape, Cylinder):
        radius = math.hypot(shape.radius(), shape.length() / 2)
    elif isinstance(shape, Capsule):
        radius = shape.radius() + shape.length() / 2
    elif isinstance(shape, Ellipsoid):
        radius = max(shape.a(), shape.b(), shape.c())
    else:
        radius = math.inf
    return np.asarray(pose.translation(), float), radius


def inradius(shape) -> float:
    """How deep (m) another shape can reach into ``shape`` before passing its middle: the radius of the largest ball
    inside it (its half-thickness); 0 for a shape this does not know (a mesh)."""
    from pydrake.geometry import Box, Capsule, Cylinder, Ellipsoid, Sphere

    if isinstance(shape, (Sphere, Capsule)):
        return shape.radius()
    if isinstance(shape, Cylinder):
        return min(shape.radius(), shape.length() / 2)
    if isinstance(shape, Box):
        return min(shape.width(), shape.depth(), shape.height()) / 2
    if isinstance(shape, Ellipsoid):
        return min(shape.a(), shape.b(), shape.c())
    return 0.0


def lowest_point_z(shape, X_WG) -> float | None:
    """The height (m, world z) of the lowest point of ``shape`` posed at ``X_WG``; None for a shape this does not
    know (a mesh: not taken to rest on the floor)."""
    span = height_span(shape, X_WG)
    return None if span is None else span[0]


def height_span(shape, X_WG, reach=None) -> tuple[float, float] | None:
    """(lowest, highest) heights (m, world z) of the points of ``shape`` posed at ``X_WG``; None for a shape this does
    not know (a mesh). ``reach``: the shape's :func:`vertical_reach`, where the caller keeps it (else found now)."""
    reach = vertical_reach(shape) if reach is None else reach
    if reach is None:
        return None
    u0, u1, u2, z = X_WG.GetAsMatrix34()[2].tolist()
    height = reach(u0, u1, u2)
    return z - height, z + height


def vertical_reach(shape):
    """How far (m) ``shape`` reaches above and below its centre, as a function of the world's z axis in the shape's
    frame (its three components); None for a shape this does not know (a mesh). Found once per shape, so that a caller
    asking at every pose pays only the arithmetic."""
    from pydrake.geometry import Box, Capsule, Cylinder, Ellipsoid, Sphere

    if isinstance(shape, Sphere):
        radius = shape.radius()
        return lambda u0, u1, u2: radius
    if isinstance(shape, Capsule):
        half, radius = 0.5 * shape.length(), shape.radius()
        return lambda u0, u1, u2: half * abs(u2) + radius
    if isinstance(shape, Cylinder):
        half, radius = 0.5 * shape.length(), shape.radius()
        return lambda u0, u1, u2: half * abs(u2) + radius * math.sqrt(max(0.0, 1.0 - u2 * u2))
    if isinstance(shape, Box):
        x, y, z = 0.5 * shape.width(), 0.5 * shape.depth(), 0.5 * shape.height()
        return lambda u0, u1, u2: x * abs(u0) + y * abs(u1) + z * abs(u2)
    if isinstance(shape, Ellipsoid):
        a, b, c = shape.a(), shape.b(), shape.c()
        return lambda u0, u1, u2: math.sqrt((a * u0) ** 2 + (b * u1) ** 2 + (c * u2) ** 2)
    return None


class _Spheres:
    """Bounding spheres of a set of geometries, grouped by the frame each is fixed to."""

    def __init__(self, inspector, geometries):
        self.ids = list(geometries)
        world = inspector.world_frame_id()
        frames: dict = {}
        centres, radii = [], []
        for i, g in enumerate(self.ids):
            frame = inspector.GetFrameId(g)
            centre, radius = bounding_sphere(inspector.GetShape(g), inspector.GetPoseInFrame(g))
            centres.append(centre)
            radii.append(radius)
            frames.setdefault(frame, []).append(i)
        self.local = np.array(centres, float).reshape(-1, 3)
        self.radii = np.array(radii, float)
        # anchored geometry (the world frame) does not move: its centres are fixed once
        self.fixed = np.array(frames.pop(world, []), int)
        self.moving = [(frame, np.array(members, int)) for frame, members in frames.items()]
        self._frames = [frame for frame, _ in self.moving]
        self._members = np.array([i for _, members in self.moving for i in members], int)
        self._frame_of = np.array([k for k, (_, members) in enumerate(self.moving) for _ in members], int)

    def centres(self, query) -> np.ndarray:
        """World positions (m) of the spheres' centres now (every frame's pose at once: one numpy expression)."""
        out = self.local.copy()
        if self._frames:
            poses = np.array([query.GetPoseInWorld(frame).GetAsMatrix34() for frame in self._frames])[self._frame_of]
            out[self._members] = np.einsum("nij,nj->ni", poses[:, :, :3], self.local[self._members]) + poses[:, :, 3]
        return out


class NearestPair:
    """The nearest pair of one of ``these`` and one of ``those`` (GeometryIds), found by bounds first.

    ``inspector``: SceneGraph's model inspector (shapes, frames). Pairs the collision filters exclude are
    measured all the same: a pair query does not consult the filters."""

    def __init__(self, inspector, these, those):
        self.a, self.b = _Spheres(inspector, these), _Spheres(inspector, those)
        self._radii = self.a.radii[:, None] + self.b.radii[None, :]
        self._columns = len(self.b.ids)

    def __bool__(self) -> bool:
        return bool(self.a.ids and self.b.ids)

    def _bounds(self, query) -> np.ndarray:
        """Each pair's distance bounded from below (m), by the bounding spheres: [i of these, j of those]."""
        return self.bounds_from(self.a.centres(query), self.b.centres(query))

    def bounds_from(self, ca: np.ndarray, cb: np.ndarray) -> np.ndarray:
        """Each pair's distance bounded from below (m) by the spheres at centres ``ca`` (of these) and ``cb`` (of
        those) in the world (``_Spheres.centres``)."""
        return np.sqrt(((ca[:, None, :] - cb[None, :, :]) ** 2).sum(axis=2)) - self._radii

    def nearest_and_touching(self, query, within: float, groups: list[list[int]]) -> list:
        """For each group of ``these`` (their indices), its nearest pair with one of ``those`` if no farther apart
        than ``within`` (m); and every pair of a group touching (signed distance <= 0), looked for only in a group
        whose nearest pair touches. SignedDistancePairs, each once, in the order of ``these`` then ``those``; exact
        distances asked only of the pairs whose bound could be that near."""
        if not self:
            return []
        bound = self._bounds(query)
        columns = self._columns
        found: dict[tuple[int, int], object] = {}

        def exact(i: int, j: int):
            pair = found.get((i, j))
            if pair is None:
                pair = found[(i, j)] = query.ComputeSignedDistancePairClosestPoints(self.a.ids[i], self.b.ids[j])
            return pair

        keep = set()
        for rows in groups:
            flat = bound[rows].ravel()
            best, best_distance = None, within
            for k in np.argsort(flat, kind="stable"):
                if flat[k] > best_distance + 1e-9:
                    break  # no pair from here on can be nearer than the one found
                row, j = divmod(int(k), columns)
                pair = exact(rows[row], j)
                if pair.distance < best_distance or (best is None and pair.distance <= within):
                    best, best_distance = (rows[row], j), pair.distance
            if best is None:
                continue
            keep.add(best)
            if best_distance <= 0.0:  # a group whose nearest pair is apart touches nowhere: nothing more to ask
                for row, j in zip(*np.nonzero(bound[rows] <= 1e-9)):
                    if exact(rows[int(row)], int(j)).distance <= 0.0:
                        keep.add((rows[int(row)], int(j)))
        return [found[key] for key in sorted(keep)]

    def __call__(self, query, within: float = math.inf):
        """The nearest pair now (a SignedDistancePair) if it is within ``within`` (m), else None."""
        if not self:
            return None
        flat = self._bounds(query).ravel()
        best, best_distance = None, within
        for k in np.argsort(flat, kind="stable"):
            if flat[k] > best_distance:
                break  # no pair from here on can be nearer than the one found
            i, j = divmod(int(k), self._columns)
            pair = query.ComputeSignedDistancePairClosestPoints(self.a.ids[i], self.b.ids[j])
            if pair.distance < best_distance or (best is None and pair.distance <= within):
                best, best_distance = pair, pair.distance
        return best
