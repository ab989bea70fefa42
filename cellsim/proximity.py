"""Nearest pairs of two sets of SceneGraph geometries, by one broadphase query.

The cell's collision filters let a broadphase query (``ComputeSignedDistancePairwiseClosestPoints``) return
only the pairs the modules measure (``CellBuild.measure_between``): robot parts and body regions, a
sensor's volumes and body regions. A module asks for the pairs within a distance and keeps its own.

A separation moves continuously: between two looks ``dt`` apart it changes by at most
``MAX_CLOSING_SPEED * dt``. So the nearest pair now lies within the last separation plus that much,
and a query of that thin shell returns a few pairs instead of all of them (:func:`nearest_since`).
"""

from __future__ import annotations

MAX_CLOSING_SPEED = 5.0
"""m/s: the fastest a robot part and a body region close on (or part from) each other: an arm's link at
3 m/s, a person at 2 m/s."""


def nearest(query, these, those, within: float):
    """The nearest pair of one of ``these`` and one of ``those`` (sets of GeometryIds) within ``within`` (m),
    or None."""
    best = None
    for pair in query.ComputeSignedDistancePairwiseClosestPoints(within):
        if (best is None or pair.distance < best.distance) and (
                (pair.id_A in these and pair.id_B in those) or (pair.id_B in these and pair.id_A in those)):
            best = pair
    return best


def nearest_since(query, these, those, last: float, dt: float, limit: float):
    """The nearest pair now (within ``limit``, else None), knowing it was ``last`` (m) apart ``dt`` seconds ago:
    first from the shell within ``last + MAX_CLOSING_SPEED dt``, where it must lie unless something moved
    faster (a person's sample jumping): then from everything within ``limit``."""
    shell = max(last, 0.0) + MAX_CLOSING_SPEED * dt
    if shell < limit:
        found = nearest(query, these, those, shell)
        if found is not None:
            return found
    return nearest(query, these, those, limit)
