"""The exact upper bound a campaign states: its defining equation, its coverage, its known values."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings, strategies as st

from cellsim.validation.bound import binomial_cdf, campaign_bounds, runs_needed, upper_bound


def _pmf(k: int, n: int, p: float) -> float:
    return math.comb(n, k) * p**k * (1 - p) ** (n - k)


def test_known_values():
    # no violation in 3,000 runs: about 1e-3 (the "about 3 000 clean runs for p < 1e-3 at 95 %")
    assert upper_bound(0, 3000) == pytest.approx(1 - 0.05 ** (1 / 3000), rel=1e-12)
    assert 9.9e-4 < upper_bound(0, 3000) < 1e-3
    assert runs_needed(1e-3) == 2995 and upper_bound(0, 2994) >= 1e-3 > upper_bound(0, 2995)
    # one of ten: 0.394 (tables of the one-sided 95 % Clopper-Pearson limit)
    assert upper_bound(1, 10) == pytest.approx(0.3942, abs=1e-4)
    assert upper_bound(10, 10) == 1.0 and upper_bound(0, 0) == 1.0
    assert upper_bound(5, 100) == pytest.approx(0.1023, abs=1e-4)


@settings(max_examples=200, deadline=None)
@given(n=st.integers(1, 5000), data=st.data())
def test_the_bound_solves_its_defining_equation(n, data):
    """P(X <= k | n, upper) = 5 %: the largest p under which k or fewer violations are still plausible."""
    k = data.draw(st.integers(0, n - 1))
    p = upper_bound(k, n)
    assert k / n < p < 1
    assert binomial_cdf(k, n, p) == pytest.approx(0.05, rel=1e-6)
    assert upper_bound(k + 1, n) > p and upper_bound(k, n + 1) < p  # more violations, higher; more runs, lower


@pytest.mark.parametrize("n", [10, 37, 100])
def test_its_coverage_is_at_least_95_percent_for_every_probability(n):
    """Exact, not asymptotic: for any true p, the chance the stated bound is at or above p is >= 95 %."""
    bounds = [upper_bound(k, n) for k in range(n + 1)]
    worst = 1.0
    for i in range(1, 400):
        p = i / 400
        coverage = math.fsum(_pmf(k, n, p) for k in range(n + 1) if bounds[k] >= p)
        assert coverage >= 0.95 - 1e-9, (n, p, coverage)
        worst = min(worst, coverage)
    assert worst < 0.97  # and not needlessly loose


def test_the_campaign_block_counts_undecided_runs_against_a_condition_and_leaves_failed_runs_out():
    runs = [
        {"status": "completed", "violations": ["A"]},
        {"status": "completed", "violations": [], "undecided": ["B"]},
        {"status": "completed", "violations": []},
        {"status": "failed"},
    ]
    block = campaign_bounds(runs, ["A", "B", "C"], "uniform waits")
    assert block["excluded_failed_runs"] == 1 and block["sampling"] == "uniform waits"
    assert block["conditions"]["A"]["failures"] == 1 and block["conditions"]["A"]["runs"] == 3
    assert block["conditions"]["B"]["failures"] == 1 and block["conditions"]["C"]["failures"] == 0
    assert block["overall"]["failures"] == 2
    assert block["conditions"]["C"]["upper_bound"] == pytest.approx(upper_bound(0, 3))
