"""The cell's floor plan: fixtures as boxes, polygons on the floor, lines of sight and walking paths.

Plain geometry in the cell's frame (metres, z up), used once at load or build
time: an area scanner's fields are polygons turned into SceneGraph shapes, its
line of sight is a segment tested against the fixtures' boxes, and a person's
walk between waypoints is the shortest path around the fixtures' footprints
(grown by the person's body radius) through the corners of those footprints.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numpy as np

_EPS = 1e-9


# -- boxes -------------------------------------------------------------------------
@dataclass(frozen=True)
class Box3:
    """A fixture's box: centre (m), half sizes (m) along its own axes, yaw (rad) about z."""

    center: np.ndarray
    half: np.ndarray
    yaw: float

    @staticmethod
    def of(fixture) -> "Box3":
        return Box3(np.array(fixture.center, float), np.array(fixture.size, float) / 2.0, math.radians(fixture.yaw_deg))

    def to_local(self, p) -> np.ndarray:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        d = np.asarray(p, float) - self.center
        return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], d[2]])

    def contains(self, p, margin: float = 0.0) -> bool:
        return bool(np.all(np.abs(self.to_local(p)) <= self.half + margin))

    def blocks(self, p0, p1) -> bool:
        """Whether the segment p0-p1 passes through the box's inside (slab test in its frame).

        In plain floats: a line of sight is tested against every fixture for every point a scanner looks at."""
        inside = self._inside(p0, p1)
        return inside is not None and inside[1] - inside[0] > _EPS

    def leaves_at(self, p0, p1) -> float:
        """Where (the fraction of the way, at most 1) the segment p0-p1 from ``p0`` inside the box leaves it."""
        inside = self._inside(p0, p1)
        return 0.0 if inside is None else inside[1]

    def _inside(self, p0, p1) -> tuple[float, float] | None:
        """The part of the segment p0-p1 inside the box, as fractions of the way (t0, t1) within [0, 1] (slab test in
        the box's frame); None where it misses the box."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        cx, cy, cz = self.center
        x0, y0, z0 = p0[0] - cx, p0[1] - cy, p0[2] - cz
        x1, y1, z1 = p1[0] - cx, p1[1] - cy, p1[2] - cz
        a = (c * x0 + s * y0, -s * x0 + c * y0, z0)
        b = (c * x1 + s * y1, -s * x1 + c * y1, z1)
        t0, t1 = 0.0, 1.0
        for axis in range(3):
            hi = float(self.half[axis])
            start, d = a[axis], b[axis] - a[axis]
            if abs(d) < _EPS:
                if not -hi < start < hi:
                    return None
                continue
            u, v = (-hi - start) / d, (hi - start) / d
            t0, t1 = max(t0, min(u, v)), min(t1, max(u, v))
            if t1 - t0 <= _EPS:
                return None
        return t0, t1

    def footprint(self, grow: float = 0.0) -> list[np.ndarray]:
        """The box's outline on the floor, grown by ``grow`` (m) on every side, counter-clockwise."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        hx, hy = self.half[0] + grow, self.half[1] + grow
        return [
            self.center[:2] + np.array([c * x - s * y, s * x + c * y])
            for x, y in ((-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy))
        ]


class SightLines:
    """Lines of sight from one point (a scanner's head) past fixed boxes: which of many points they reach, in one
    numpy expression over every box and point (the slab test of :meth:`Box3.blocks`).

    A box the origin lies in (the fixture a scanner is mounted in) blocks a line that runs more than ``mount_depth``
    (m) inside it: a scanner in a pedestal's corner sees out past the corner's faces, not through the pedestal."""

    def __init__(self, origin, boxes: list[Box3], mount_depth: float = 0.0):
        self.origin = np.asarray(origin, float)
        self.mounts = [box for box in boxes if box.contains(self.origin)]
        self.boxes = [box for box in boxes if not box.contains(self.origin)]
        self.mount_depth = float(mount_depth)
        every = self.boxes + self.mounts
        rotations = [np.array([[math.cos(b.yaw), math.sin(b.yaw), 0.0], [-math.sin(b.yaw), math.cos(b.yaw), 0.0],
                               [0.0, 0.0, 1.0]]) for b in every]
        self._rotation = np.array(rotations).reshape(-1, 3, 3)  # into each box's frame
        self._centre = np.array([r @ b.center for r, b in zip(rotations, every)]).reshape(-1, 3)
        self._half = np.array([b.half for b in every], float).reshape(-1, 3)
        self._start = np.array([r @ self.origin for r in rotations]).reshape(-1, 3) - self._centre

    def reaches(self, point) -> bool:
        """:meth:`reach` of one point, in plain floats: a scanner looks at one point (the nearest of a body region) as
        often as at a limb's many, where numpy's set-up costs more than the test."""
        origin = self.origin
        if any(box.blocks(origin, point) for box in self.boxes):
            return False
        if not self.mounts:
            return True
        length = math.dist(origin, point)
        return all(box.leaves_at(origin, point) * length <= self.mount_depth for box in self.mounts)

    def reach(self, points: np.ndarray) -> np.ndarray:
        """Whether the segment from the origin to each of ``points`` (an (n, 3) array) passes through no box (and
        runs no deeper than ``mount_depth`` through the one the origin lies in)."""
        points = np.asarray(points, float).reshape(-1, 3)
        if not len(self._half) or not len(points):
            return np.ones(len(points), bool)
        end = np.einsum("wij,nj->wni", self._rotation, points) - self._centre[:, None, :]
        start, half = self._start[:, None, :], self._half[:, None, :]
        step = end - start
        flat = np.abs(step) < _EPS
        inside = (-half < start) & (start < half)
        safe = np.where(flat, 1.0, step)
        u, v = (-half - start) / safe, (half - start) / safe
        low = np.where(flat, np.where(inside, -np.inf, np.inf), np.minimum(u, v))
        high = np.where(flat, np.where(inside, np.inf, -np.inf), np.maximum(u, v))
        enter = np.maximum(low.max(axis=2), 0.0)
        leave = np.minimum(high.min(axis=2), 1.0)
        walls = len(self.boxes)
        reached = ~((leave[:walls] - enter[:walls]) > _EPS).any(axis=0)
        if self.mounts:  # the length of each line inside each mount: from the origin to where it leaves
            length = np.linalg.norm(points - self.origin, axis=1)
            reached &= ~((leave[walls:] * length) > self.mount_depth).any(axis=0)
        return reached


# -- polygons ----------------------------------------------------------------------
def signed_area(polygon) -> float:
    """The polygon's signed area (m²), positive when counter-clockwise."""
    p = np.asarray(polygon, float)
    return 0.5 * float(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))


def _cross(o, a, b) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def segments_cross(a, b, c, d) -> bool:
    """Whether segments a-b and c-d meet at a point inside both (touching at an end does not count)."""
    d1, d2 = _cross(c, d, a), _cross(c, d, b)
    d3, d4 = _cross(a, b, c), _cross(a, b, d)
    return ((d1 > _EPS and d2 < -_EPS) or (d1 < -_EPS and d2 > _EPS)) and (
        (d3 > _EPS and d4 < -_EPS) or (d3 < -_EPS and d4 > _EPS)
    )


def is_simple(polygon) -> bool:
    """No two edges that are not neighbours meet, and no vertex repeats."""
    p = [tuple(v) for v in polygon]
    n = len(p)
    if len(set(p)) != n:
        return False
    for i in range(n):
        for j in range(i + 1, n):
            if j == i + 1 or (i == 0 and j == n - 1):
                continue
            if segments_cross(p[i], p[(i + 1) % n], p[j], p[(j + 1) % n]):
                return False
    return True


def is_convex(polygon) -> bool:
    p = np.asarray(polygon, float)
    n = len(p)
    turns = [_cross(p[i], p[(i + 1) % n], p[(i + 2) % n]) for i in range(n)]
    return all(t >= -_EPS for t in turns) or all(t <= _EPS for t in turns)


def point_in_triangle(q, a, b, c) -> bool:
    return _cross(a, b, q) >= -_EPS and _cross(b, c, q) >= -_EPS and _cross(c, a, q) >= -_EPS


def triangulate(polygon) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Ear clipping of a simple polygon into counter-clockwise triangles."""
    p = [np.asarray(v, float) for v in polygon]
    if signed_area(p) < 0:
        p.reverse()
    triangles, left = [], list(range(len(p)))
    while len(left) > 3:
        for k in range(len(left)):
            i, j, m = left[k - 1], left[k], left[(k + 1) % len(left)]
            a, b, c = p[i], p[j], p[m]
            if _cross(a, b, c) <= _EPS:
                continue  # a reflex (or flat) corner is not an ear
            if any(point_in_triangle(p[o], a, b, c) for o in left if o not in (i, j, m)):
                continue
            triangles.append((a, b, c))
            left.pop(k)
            break
        else:  # numerically degenerate: what is left is flat
            break
    if len(left) == 3 and _cross(p[left[0]], p[left[1]], p[left[2]]) > _EPS:
        triangles.append(tuple(p[i] for i in left))
    return triangles


def points_in_polygon(points, polygon):
    """:func:`point_in_polygon` of many points at once (an (n, 2) array): a boolean array, the same rule and the
    same arithmetic, so a point on an edge gets the same answer either way."""
    import numpy as np

    q = np.asarray(points, float).reshape(-1, 2)
    inside = np.zeros(len(q), bool)
    for i in range(len(polygon)):
        a, b = polygon[i], polygon[(i + 1) % len(polygon)]
        crosses = (a[1] > q[:, 1]) != (b[1] > q[:, 1])
        if not crosses.any():
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            x = a[0] + (q[:, 1] - a[1]) * (b[0] - a[0]) / (b[1] - a[1])
        inside ^= crosses & (q[:, 0] < x)
    return inside


def point_in_polygon(q, polygon) -> bool:
    inside, p, n = False, polygon, len(polygon)
    for i in range(n):
        a, b = p[i], p[(i + 1) % n]
        if (a[1] > q[1]) != (b[1] > q[1]):
            x = a[0] + (q[1] - a[1]) * (b[0] - a[0]) / (b[1] - a[1])
            if q[0] < x:
                inside = not inside
    return inside


# -- walking ----------------------------------------------------------------------
def _inside_any(q, obstacles) -> int | None:
    for index, outline in enumerate(obstacles):
        if point_in_polygon(q, outline) and not _on_boundary(q, outline):
            return index
    return None


def _on_boundary(q, outline) -> bool:
    n = len(outline)
    for i in range(n):
        a, b = outline[i], outline[(i + 1) % n]
        ab = b - a
        t = float(np.clip(np.dot(q - a, ab) / max(np.dot(ab, ab), _EPS), 0.0, 1.0))
        if np.linalg.norm(a + t * ab - q) < 1e-7:
            return True
    return False


def _clear(a, b, obstacles) -> bool:
    """Whether walking straight from a to b stays out of every outline's inside."""
    for outline in obstacles:
        n = len(outline)
        for i in range(n):
            if segments_cross(a, b, outline[i], outline[(i + 1) % n]):
                return False
        mid = (a + b) / 2.0
        if point_in_polygon(mid, outline) and not _on_boundary(mid, outline):
            return False
        # a segment along a diagonal from corner to corner crosses no edge: test quarter points too
        for f in (0.25, 0.75):
            q = a + f * (b - a)
            if point_in_polygon(q, outline) and not _on_boundary(q, outline):
                return False
    return True


def shortest_path(start, goal, obstacles: list[list[np.ndarray]]) -> list[np.ndarray] | None:
    """The shortest walk from start to goal around convex outlines, through their corners.

    Returns the points after ``start`` (ending with ``goal``), or None when no
    walk exists. Corners inside another outline are not used.
    """
    start, goal = np.asarray(start, float), np.asarray(goal, float)
    if _clear(start, goal, obstacles):
        return [goal]
    corners = [c for outline in obstacles for c in outline if _inside_any(c, obstacles) is None]
    nodes = [start, goal, *corners]
    best = {0: 0.0}
    previous: dict[int, int] = {}
    queue = [(0.0, 0)]
    done = set()
    while queue:
        cost, i = heapq.heappop(queue)
        if i in done:
            continue
        done.add(i)
        if i == 1:
            break
        for j in range(1, len(nodes)):
            if j in done or not _clear(nodes[i], nodes[j], obstacles):
                continue
            c = cost + float(np.linalg.norm(nodes[j] - nodes[i]))
            if c < best.get(j, math.inf) - 1e-12:
                best[j], previous[j] = c, i
                heapq.heappush(queue, (c, j))
    if 1 not in done:
        return None
    path, i = [], 1
    while i != 0:
        path.append(nodes[i])
        i = previous[i]
    return path[::-1]
