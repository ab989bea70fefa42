"""The tests marked ONE_AT_A_TIME share one pytest-xdist worker: live cells on fixed ports (ur-rtde's 30004) and
real-time pacing depend on it. pytest 9 with pytest-xdist 3.8 silently stopped grouping them (pyproject pins
pytest below 9); this fails if the grouping stops again."""

from __future__ import annotations

import pytest
from conftest import ONE_AT_A_TIME

pytestmark = [ONE_AT_A_TIME]


def test_a_one_at_a_time_test_is_scheduled_in_its_group(request):
    assert request.node.get_closest_marker("xdist_group").args == ("cores",)
    if getattr(request.config, "workerinput", None) is not None:  # under pytest-xdist: its id carries the group
        assert request.config.option.loadgroup, "the suite must run with --dist loadgroup (pyproject's addopts)"
        assert request.node.nodeid.endswith("@cores"), request.node.nodeid
