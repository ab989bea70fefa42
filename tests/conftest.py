"""Shared helpers: load the welding cell, run it, read its black box."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cellsim.kinds.operator.config import Waypoint
from cellsim.scenario import load_scenario
from cellsim.blackbox import BlackBox
from cellsim.simulation import BLACKBOX, simulate

ROOT = Path(__file__).resolve().parents[1]

ONE_AT_A_TIME = pytest.mark.xdist_group("cores")
"""Tests that need the cores in real time (a live twin's pacing, a bridge's latency) or take both (a
campaign's two workers, Storm's decision-diagram engine) run one after another on one pytest-xdist
worker (``--dist loadgroup``, in pyproject's addopts), never beside each other: on the two cores of
CI, a live twin beside a two-worker campaign loses its pacing."""
WELDING_CELL = ROOT / "scenarios" / "welding_cell.yaml"


def welding_cell(*overrides: str):
    return load_scenario(WELDING_CELL, list(overrides))


def place_operator(sf, start, waypoints: dict[str, Waypoint] | None = None, start_delay: float = 0.0):
    """Give the operator a scripted walk (no speed jitter, so timings are exact)."""
    op = sf.scenario.entities["operator"]
    op.start = tuple(start)
    op.waypoints = waypoints if waypoints is not None else {"stay": Waypoint(tuple(start), 1000.0)}
    op.start_delay = start_delay
    op.speed_jitter = 0.0
    return sf


def run(sf, out: Path, duration: float = 30.0, seed: int = 1, **kwargs) -> BlackBox:
    simulate(sf, out, seed=seed, duration=duration, **kwargs)
    return BlackBox(out / BLACKBOX)


def first_time(series, predicate, after: float = -1.0):
    """The first message time at or after ``after`` whose value satisfies ``predicate``."""
    for t, v in zip(series.times, series.values):
        if t >= after and predicate(v):
            return float(t)
    return None


def values_between(series, t0: float, t1: float) -> list:
    """Values holding at any time in [t0, t1]."""
    out = [series.value_at(t0)]
    out += [v for t, v in zip(series.times, series.values) if t0 < t <= t1]
    return out


@pytest.fixture(scope="session", autouse=True)
def cell_keys(tmp_path_factory):
    """The cell's keys for every Zenoh session of the tests, theirs and their processes' (which inherit
    ``CELLSIM_KEYS``): made once per test process, never the user's own ~/.config/cellsim/keys."""
    import os

    from cellsim.live.pki import ENVIRONMENT, init_keys

    folder = tmp_path_factory.mktemp("cell") / "keys"
    init_keys(folder)
    previous = os.environ.get(ENVIRONMENT)
    os.environ[ENVIRONMENT] = str(folder)
    yield folder
    if previous is None:
        os.environ.pop(ENVIRONMENT, None)
    else:
        os.environ[ENVIRONMENT] = previous


@pytest.fixture
def tmp_run(tmp_path):
    return tmp_path / "run"


def legs_distance(point, xy, yaw: float = 0.0, body_radius: float = 0.2, height: float = 1.75) -> float:
    """Hand computation: the distance (m) from ``point`` (at leg height, below the knees) to the nearer lower leg of a
    person standing at ``xy`` facing ``yaw``: each a vertical capsule of radius ``LIMB_RADIUS['lower_leg']`` (scaled
    by the height) 0.45 body_radius to either side of the body's middle (cellsim.body)."""
    from cellsim.body import LIMB_RADIUS

    side = np.array([-np.sin(yaw), np.cos(yaw)]) * 0.45 * body_radius
    radius = LIMB_RADIUS["lower_leg"] * height / 1.75
    return min(float(np.hypot(*(np.asarray(point[:2]) - (np.asarray(xy) + s * side)))) - radius for s in (1, -1))
