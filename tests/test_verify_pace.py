"""A person's pace in the abstract cell (issue 36): how many periods crossing a place takes, by hand, and the
witness check that finds a crossing faster than that (cellsim.verify.floor)."""

from __future__ import annotations

import pytest

from cellsim.verify.floor import ENTERED_AT_START, PersonPlaces, Place, crossing_periods, pace_departure
from cellsim.verify.model import PersonRole, Pose

PERIOD, SPEED = 0.02, 1.0  # s, m/s: 0.02 m per period


def _corridor() -> PersonPlaces:
    """A corridor along x, a pose every 0.1 m: place 0 from 0 to 0.2 m, place 1 from 0.3 to 0.7 m, place 2 from
    0.8 to 1.0 m; the person starts at x = 0."""
    poses = [Pose(round(0.1 * i, 6), 0.0, 0.0) for i in range(11)]
    role = PersonRole("p", poses, poses[0], lambda *a: None, step=0.1)
    places = [Place(0, (0,), poses[0:3]), Place(1, (1,), poses[3:8]), Place(2, (2,), poses[8:11])]
    return PersonPlaces(role, places, {0: {1}, 1: {0, 2}, 2: {1}}, 0, "p_place", [])


def test_a_crossing_takes_the_periods_its_least_walk_takes_by_hand():
    need = crossing_periods(_corridor(), PERIOD, SPEED)
    # place 1 from place 0 to place 2: enters at 0.3 m, leaves at 0.7 m, less a grid step at either end: 0.2 m,
    # 10 periods at 0.02 m a period; it may have entered just after the sample before its first one there, so it is
    # seen there at 9 samples at least
    assert need[(0, 1, 2)] == 9 and need[(2, 1, 0)] == 9
    # place 0 from the start (x = 0, there at sample 0) to place 1 (left at 0.2 m), less a step: 0.1 m, 5 periods
    assert need[(ENTERED_AT_START, 0, 1)] == 5
    # stepping back where one came from costs nothing (the person may stand on the border)
    assert (0, 1, 0) not in need and (1, 2, 1) not in need
    # twice as fast: half the periods (5, seen at 4 samples)
    assert crossing_periods(_corridor(), PERIOD, 2 * SPEED)[(0, 1, 2)] == 4
    # a crossing that is no whole number of periods rounds up, then gives the sample it may have entered before
    assert crossing_periods(_corridor(), PERIOD, 0.21 / 0.2 * SPEED)[(0, 1, 2)] == 9  # 9.52 periods: 10, seen at 9
    assert crossing_periods(_corridor(), PERIOD, 0.19 / 0.2 * SPEED)[(0, 1, 2)] == 10  # 10.5 periods: 11, seen at 10


def test_the_bound_is_sound_a_continuous_walk_at_full_speed_meets_it():
    """A walk along the corridor at exactly the speed, sampled every period from any phase, is never seen crossing a
    place faster than the bound allows: the bound never forbids what the person can do."""
    person = _corridor()
    for speed in (0.5, 1.0, 1.32, 2.0):
        for phase in (0.0, 0.13, 0.5, 0.99):
            xs = [max(0.0, (k + phase) * PERIOD * speed) for k in range(200)]
            # the place a point belongs to: the nearest pose's (the border is halfway between two poses)
            places = [0 if x < 0.25 else 1 if x < 0.75 else 2 for x in xs if x <= 1.0]
            walk = [{"p_place": p} for p in places]
            assert pace_departure(person, walk, PERIOD, speed) is None, (speed, phase)


def test_a_witness_crossing_a_place_too_fast_is_found_with_its_variable_period_and_reason():
    person = _corridor()

    def witness(at_start: int, in_the_middle: int) -> list[dict]:
        return [{"p_place": 0}] * at_start + [{"p_place": 1}] * in_the_middle + [{"p_place": 2}] * 3

    assert pace_departure(person, witness(5, 9), PERIOD, SPEED) is None  # exactly as fast as it can
    why, step = pace_departure(person, witness(5, 8), PERIOD, SPEED)
    assert why == ("p_place crosses place 1 (from place 0 to place 2) in 8 period(s) at 0.1-0.26 s; at 1 m/s that "
                   "takes at least 9 (0.18 s)")
    assert step == 13  # the first state the person cannot be in: out of place 1 too soon
    why, _ = pace_departure(person, witness(4, 9), PERIOD, SPEED)
    assert why.startswith("p_place crosses place 0 (from its start to place 1) in 4 period(s)")
    assert pace_departure(person, [{"other": 1}], PERIOD, SPEED) is None  # a witness without this person


@pytest.mark.parametrize("speed", [0.5, 1.0, 1.32, 3.0])
def test_a_witness_at_exactly_the_bound_passes_and_one_period_less_fails(speed):
    person = _corridor()
    need = crossing_periods(person, PERIOD, speed)
    first, middle = need.get((ENTERED_AT_START, 0, 1), 1), need.get((0, 1, 2), 1)
    walk = [{"p_place": 0}] * first + [{"p_place": 1}] * middle + [{"p_place": 2}]
    assert pace_departure(person, walk, PERIOD, speed) is None
    if middle > 1:
        hurried = [{"p_place": 0}] * first + [{"p_place": 1}] * (middle - 1) + [{"p_place": 2}]
        assert pace_departure(person, hurried, PERIOD, speed) is not None


def test_without_the_grid_slack_a_crossing_the_bound_allows_is_found():
    """``exact``: the crossing measured between the grid's points, without the two steps a place's border may lie
    from them. Where it asks more than the bound, only a finer grid can tell whether the walk is possible: a walk
    at the bound (5 periods from the start, 9 across place 1) is found crossing place 0 in fewer periods than the
    0.2 m from the start to its border point take (10), and place 1 needs 19 (0.4 m between its border points)."""
    person = _corridor()
    assert crossing_periods(person, PERIOD, SPEED, exact=True)[(0, 1, 2)] == 19
    walk = [{"p_place": 0}] * 5 + [{"p_place": 1}] * 9 + [{"p_place": 2}] * 3
    assert pace_departure(person, walk, PERIOD, SPEED) is None
    why, _ = pace_departure(person, walk, PERIOD, SPEED, exact=True)
    assert why.startswith("p_place crosses place 0 (from its start to place 1) in 5 period(s)")
