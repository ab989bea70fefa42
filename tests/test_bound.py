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
    assert block["excluded_failed_runs"] == 1 and block["sampling"].startswith("uniform waits; ")
    # a failed run's configuration is not covered: the statement says the sample is of the runs that complete
    assert "only those that complete (1 of 4 did not" in block["sampling"]
    assert campaign_bounds(runs[:3], ["A"], "uniform waits")["sampling"] == "uniform waits"
    assert block["conditions"]["A"]["failures"] == 1 and block["conditions"]["A"]["runs"] == 3
    assert block["conditions"]["B"]["failures"] == 1 and block["conditions"]["C"]["failures"] == 0
    assert block["overall"]["failures"] == 2
    assert block["conditions"]["C"]["upper_bound"] == pytest.approx(upper_bound(0, 3))


def test_the_binomial_cdf_at_its_edges():
    assert binomial_cdf(-1, 10, 0.3) == 0.0
    assert binomial_cdf(10, 10, 0.3) == 1.0 and binomial_cdf(11, 10, 0.3) == 1.0
    assert binomial_cdf(0, 10, 0.0) == 1.0 and binomial_cdf(3, 10, -0.1) == 1.0
    assert binomial_cdf(9, 10, 1.0) == 0.0 and binomial_cdf(0, 10, 1.5) == 0.0
    assert binomial_cdf(0, 10, math.nextafter(1.0, 0.0)) < 1e-100  # just below 1: a sum, not the edge
    assert binomial_cdf(2, 4, 0.5) == pytest.approx(11 / 16, abs=1e-15)
    assert binomial_cdf(9, 10, 0.5) == pytest.approx(1 - 1 / 1024, abs=1e-14)  # never above 1


def test_the_bound_refuses_what_is_not_a_count_or_a_confidence_with_its_reason():
    for failures, runs in ((-1, 5), (6, 5)):
        with pytest.raises(ValueError, match=rf"failures must be in \[0, runs\], got {failures} of {runs}"):
            upper_bound(failures, runs)
    for confidence in (0.0, 1.0, 1.5):
        with pytest.raises(ValueError, match=rf"confidence must be in \(0, 1\), got {confidence}"):
            upper_bound(1, 10, confidence)
    assert upper_bound(1, 10, math.nextafter(0.0, 1.0)) > 0.1  # any confidence strictly inside is taken
    for target in (0.0, 1.0, 2.0):
        with pytest.raises(ValueError, match=rf"the target probability must be in \(0, 1\), got {target}"):
            runs_needed(target)


def test_the_bound_is_one_only_with_no_runs_or_every_run_failing():
    assert upper_bound(0, 0) == 1.0 and upper_bound(7, 7) == 1.0
    assert upper_bound(0, 1) == pytest.approx(0.95) and upper_bound(6, 7) < 1.0


def test_the_bisection_converges_to_machine_precision_on_both_sides_of_the_equation():
    for k, n in ((1, 10), (5, 100), (37, 1000), (999, 1000)):
        p = upper_bound(k, n)
        assert binomial_cdf(k, n, p) <= 0.05 + 1e-12  # the bound itself: at or past the 5 % point
        assert binomial_cdf(k, n, p * (1 - 1e-12)) > 0.05 - 1e-9  # a hair below: still plausible
    assert upper_bound(999, 1000) < 1.0


@pytest.mark.parametrize("target, runs", [(0.5, 5), (0.1, 29), (0.05, 59), (1e-2, 299), (1e-3, 2995), (0.95, 2), (0.96, 1),
                                          (0.9, 2)])
def test_runs_needed_is_the_fewest_clean_runs_whose_bound_is_below_the_target(target, runs):
    assert runs_needed(target) == runs
    assert upper_bound(0, runs) < target and (runs == 1 or upper_bound(0, runs - 1) >= target)
    assert runs_needed(target, 0.99) >= runs  # more confidence, more runs


def test_the_campaign_block_names_what_it_states():
    from cellsim.validation.bound import COUNTING, METHOD, Bound

    runs = [{"status": "completed", "violations": ["A"]}, {"status": "completed"}, {"status": "completed", "undecided": ["A"]}]
    block = campaign_bounds(runs, ["A", "B"], "waits uniform", confidence=0.9)
    assert block["confidence"] == 0.9 and block["method"] == METHOD and block["counted"] == COUNTING
    assert block["overall"] == {"failures": 2, "runs": 3, "rate": 2 / 3, "upper_bound": upper_bound(2, 3, 0.9)}
    assert block["conditions"]["A"] == Bound(2, 3, 0.9).to_json() and block["conditions"]["B"]["failures"] == 0
    assert block["conditions"]["B"]["upper_bound"] == upper_bound(0, 3, 0.9)  # at the block's confidence
    assert Bound(0, 0).to_json() == {"failures": 0, "runs": 0, "rate": None, "upper_bound": 1.0}


def test_a_cdf_whose_terms_sum_past_one_by_rounding_is_one():
    """Near k = n, log-space terms can add up to a hair above 1 (1.0000000000000004 for k = 13, n = 14, p = 0.01):
    a probability is capped at 1."""
    assert binomial_cdf(13, 14, 0.01) == 1.0 and binomial_cdf(9, 10, 0.01) == 1.0


def test_runs_needed_at_another_confidence_uses_that_confidence_throughout():
    assert (runs_needed(0.1, 0.99), runs_needed(0.01, 0.99), runs_needed(0.5, 0.99)) == (44, 459, 7)


def test_a_probability_reads_as_people_write_it():
    from cellsim.validation.bound import probability

    assert [probability(p) for p in (None, 0.000998345, 0.0372, 0.5, 1.0)] == ["-", "0.000998", "0.0372", "0.5", "1"]


def test_the_sampling_in_words_names_what_every_run_has_in_common():
    """A bound holds for runs drawn as the campaign's: their duration and the campaign's --set overrides are part of
    that (an audit found 3 s runs stated as the scenario's 20 s of waits, with no word of the overrides)."""
    from cellsim.config.sampling import ChoiceSampler, describe_sampling

    words = describe_sampling({"mode": ChoiceSampler(kind="choice", values=["model", "shadow"])},
                              {"mode": ["light_barrier.twin.mode"]}, 3.0, ("duration=3", "robot.braking_time=0.4"))
    assert "each one of model, shadow, equally likely" in words
    assert "every run 3 s long with duration=3, robot.braking_time=0.4" in words


def test_a_campaign_s_size_is_said_to_follow_its_outcomes_only_where_it_did():
    """An --until-bound stop at a violation, or a plan grown after runs counted against it, chose the number of runs
    by their outcomes; resuming an interrupted campaign of the same size, or --until-bound that reached its runs
    clean, did not."""
    from cellsim.campaign.runner import chosen_as_they_came

    fixed = {"runs": 10, "until_bound": None, "finished_before": 0, "against_before": 0}
    resumed = {"runs": 10, "until_bound": None, "finished_before": 7, "against_before": 1}
    grown = {"runs": 20, "until_bound": None, "finished_before": 10, "against_before": 1}
    bounded = {"runs": 299, "until_bound": 0.01, "finished_before": 0, "against_before": 0}
    assert chosen_as_they_came([fixed, resumed], any_against=True) is None
    assert "extended after runs counted against it" in chosen_as_they_came([fixed, grown], any_against=True)
    assert chosen_as_they_came([bounded], any_against=False) is None  # 0 of 299: exact
    assert "--until-bound stops" in chosen_as_they_came([bounded], any_against=True)
    after_a_stop = {"runs": 6, "until_bound": None, "finished_before": 5, "against_before": 1}
    assert "extended after runs counted against it" in chosen_as_they_came([bounded, after_a_stop], any_against=True)


def test_until_bound_with_failed_runs_says_the_same_command_cannot_reach_it_and_what_would():
    """An audit found one failed run of 2995 left the bound at 0.00100008 (shown as "0.001") and the hint "run the
    same command to go on", which adds nothing: the failed run is kept and counted nowhere, and --runs cannot be
    given with --until-bound. The campaign's line says what would reach it."""
    from cellsim.cli.campaign import _until_bound_text

    one_failed = {"overall": {"failures": 0, "runs": 2994, "upper_bound": 0.0010000781698466697},
                  "excluded_failed_runs": 1}
    text = _until_bound_text(one_failed, 1e-3, 2995)
    assert "not reached: 0.00100008 after 2994 runs; 1 failed and count nowhere" in text
    assert "--runs 2996 instead of --until-bound" in text and "run the same command" not in text
    still_to_do = {"overall": {"failures": 0, "runs": 1000, "upper_bound": 0.003}, "excluded_failed_runs": 1}
    assert "run the same command to go on" in _until_bound_text(still_to_do, 1e-3, 2995)
    assert "reached: 0.000999" in _until_bound_text(
        {"overall": {"failures": 0, "runs": 2995, "upper_bound": 0.000999}, "excluded_failed_runs": 0}, 1e-3, 2995)
