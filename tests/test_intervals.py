"""The exact interval algebra under the condition language (cellsim.logic.intervals), against a brute-force
reading of its definitions at every point that matters.

Sets here have whole-number ends in a domain [0, 12), and windows whole-number bounds, so every result
changes value only at whole numbers: checking each whole number and each half (the inside of every
piece) checks the sets entirely. Every result must also be canonical: sorted, non-empty, not adjacent."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellsim.logic.intervals import (
    IntervalSet,
    always_flat,
    complement_flat,
    eventually_flat,
    intersection_flat,
    until0_flat,
    union_flat,
)

START, END = 0.0, 12.0
POINTS = [k / 2 for k in range(int(2 * END))]  # every whole number and half in [0, 12)

pieces = st.lists(st.tuples(st.integers(0, 12), st.integers(0, 12)), max_size=6)


def make(raw) -> IntervalSet:
    return IntervalSet(START, END, [(a, b) for a, b in raw])


def canonical(flat) -> bool:
    return (len(flat) % 2 == 0 and all(START <= x <= END for x in flat)
            and all(flat[i] < flat[i + 1] for i in range(len(flat) - 1)))


def holds(s: IntervalSet, t: float) -> bool:
    return any(a <= t < b for a, b in s.intervals)


def equal_to(flat, predicate) -> None:
    assert canonical(flat), flat
    got = IntervalSet.from_flat(START, END, list(flat))
    assert [holds(got, t) for t in POINTS] == [predicate(t) for t in POINTS], (flat, got)


@settings(max_examples=300, deadline=None)
@given(pieces, pieces)
def test_union_intersection_and_complement_are_pointwise(x, y):
    a, b = make(x), make(y)
    equal_to(union_flat(list(a.flat), list(b.flat)), lambda t: holds(a, t) or holds(b, t))
    equal_to(intersection_flat(list(a.flat), list(b.flat)), lambda t: holds(a, t) and holds(b, t))
    equal_to(complement_flat(list(a.flat), START, END), lambda t: not holds(a, t))
    assert (a | b) == (b | a) and (a & b) == (b & a) and (a - b) == (a & ~b)
    assert (a | b).measure() + (a & b).measure() == pytest.approx(a.measure() + b.measure())


@settings(max_examples=300, deadline=None)
@given(pieces, st.integers(0, 4), st.integers(0, 4) | st.just(math.inf))
def test_eventually_and_always_are_their_windows(x, lo, width):
    a = make(x)
    hi = lo + width

    def meets(t):  # [t+lo, t+hi] meets a
        return any(t + lo < r and t + hi >= l for l, r in a.intervals)

    def within(t):  # a on all of [t+lo, t+hi] within the domain (vacuous past its end)
        top = min(t + hi, END)
        return all(holds(a, u) for u in POINTS + [math.floor(t + lo)] if t + lo <= u <= top and u < END) and (
            t + lo >= END or holds(a, t + lo) or t + lo > top)

    equal_to(eventually_flat(list(a.flat), lo, hi, START), meets)
    equal_to(always_flat(list(a.flat), lo, hi, START, END), within)


@settings(max_examples=300, deadline=None)
@given(pieces, pieces, st.integers(0, 5) | st.just(math.inf))
def test_until_has_a_witness_in_its_window_with_phi_up_to_it(x, y, hi):
    phi, psi = make(x), make(y)

    def until(t):  # some t' in [t, t+hi] with psi(t') and phi on [t, t')
        for c, d in psi.intervals:
            witness = max(t, c)
            if witness < d and witness <= t + hi:
                if all(holds(phi, u) for u in POINTS if t <= u < witness) and (witness == t or holds(phi, t)):
                    return True
        return False

    equal_to(until0_flat(list(phi.flat), list(psi.flat), hi), until)


def test_the_domain_is_a_finite_non_empty_span_and_sets_of_two_domains_do_not_mix():
    for start, end in ((1.0, 1.0), (2.0, 1.0), (0.0, math.inf), (-math.inf, 0.0), (math.nan, 1.0)):
        with pytest.raises(ValueError, match=r"bad domain \["):
            IntervalSet(start, end)
    with pytest.raises(ValueError, match=r"domains differ: \[0.0, 12.0\) vs \[0.0, 10.0\)"):
        make([(1, 2)]) | IntervalSet(0.0, 10.0)
    with pytest.raises(TypeError, match="expected an IntervalSet, got list"):
        make([(1, 2)]) & [(1, 2)]


def test_a_sets_measure_membership_and_hash():
    s = make([(1, 3), (5, 6), (8, 12)])
    assert s.measure() == 2 + 1 + 4 and s.first() == 1.0 and len(s) == 3
    assert 1.0 in s and 3.0 not in s and 11.5 in s and 12.0 not in s and -1.0 not in s
    assert s.is_full() is False and make([(0, 12)]).is_full() and make([]).is_empty()
    sets = {make([(a, a + 1)]) for a in range(10)}
    assert len(sets) == 10 and len({hash(x) for x in sets}) == 10  # distinct sets spread over distinct hashes
    assert make([(1, 2), (2, 3)]) == make([(1, 3)]) and hash(make([(1, 2), (2, 3)])) == hash(make([(1, 3)]))


# Every set of whole-number pieces of [0, 6): the 64 unions of its unit cells, so that every pattern of gaps
# and neighbours (two pieces that merge under a window while an earlier one does not, ...) is met.
SMALL_END = 6.0
SMALL_POINTS = [k / 2 for k in range(int(2 * SMALL_END))]
ALL_SETS = [IntervalSet(0.0, SMALL_END, [(k, k + 1) for k in range(6) if mask >> k & 1]) for mask in range(64)]


def _small(flat, predicate):
    assert canonical(flat) and all(x <= SMALL_END for x in flat), flat
    got = IntervalSet.from_flat(0.0, SMALL_END, list(flat))
    assert [holds(got, t) for t in SMALL_POINTS] == [predicate(t) for t in SMALL_POINTS], flat


def test_every_small_set_under_every_window_and_connective():
    for a in ALL_SETS:
        for lo in range(3):
            for hi in (lo, lo + 1, lo + 3, math.inf):
                _small(eventually_flat(list(a.flat), lo, hi, 0.0),
                       lambda t: any(t + lo < r and t + hi >= l for l, r in a.intervals))
        for b in ALL_SETS:
            _small(union_flat(list(a.flat), list(b.flat)), lambda t: holds(a, t) or holds(b, t))
            _small(intersection_flat(list(a.flat), list(b.flat)), lambda t: holds(a, t) and holds(b, t))


def test_every_small_pair_under_until():
    for phi in ALL_SETS:
        for psi in ALL_SETS:
            for hi in (0, 1, 2, math.inf):
                def until(t):
                    for c, d in psi.intervals:
                        witness = max(t, c)
                        if witness < d and witness <= t + hi and (witness == t or holds(phi, t)) and all(
                                holds(phi, u) for u in SMALL_POINTS if t <= u < witness):
                            return True
                    return False

                _small(until0_flat(list(phi.flat), list(psi.flat), hi), until)


def test_a_set_reads_back_as_the_expression_that_makes_it():
    s = make([(1, 3), (5, 6)])
    assert repr(s) == "IntervalSet(0.0, 12.0, [(1.0, 3.0), (5.0, 6.0)])"
    assert eval(repr(s), {"IntervalSet": IntervalSet}) == s
