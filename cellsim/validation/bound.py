"""How often a safety condition failed in a campaign, and the most it can fail at 95 % confidence.

A campaign's runs are independent draws from its samplers' distribution (the
configurations) and its seeds (the simulation's own randomness). Of ``n`` runs,
``k`` violated a condition; the true probability ``p`` that a run drawn the same
way violates it is bounded above by the exact one-sided Clopper-Pearson bound:
the largest ``p`` under which seeing ``k`` or fewer violations in ``n`` runs
still has probability at least ``1 - confidence``. It holds for every ``p``
(its coverage is at least the confidence, exactly, not asymptotically) and it
says nothing about configurations the samplers never draw.

With no violation, ``n`` runs bound ``p`` below ``1 - (1 - confidence)^(1/n)``:
2,995 runs for 1e-3 at 95 % (the "rule of three": about 3 / n).

The arithmetic is written here rather than taken from a statistics library: it
is the safety argument itself, and it is short (a binomial sum in log space and
a bisection), checked in the tests against its defining equation and its exact
coverage.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from cellsim.numbers import probability  # noqa: F401  (formatting, with the other numbers for people)

CONFIDENCE = 0.95
"""The confidence of every bound cellsim states."""
METHOD = "exact one-sided Clopper-Pearson bound"


def binomial_cdf(k: int, n: int, p: float) -> float:
    """P(X <= k) for X ~ Binomial(n, p), summed in log space (no underflow for large n)."""
    if k < 0:
        return 0.0
    if k >= n or p <= 0.0:
        return 1.0
    if p >= 1.0:
        return 0.0
    log_p, log_q = math.log(p), math.log1p(-p)
    terms = [math.lgamma(n + 1) - math.lgamma(i + 1) - math.lgamma(n - i + 1) + i * log_p + (n - i) * log_q
             for i in range(k + 1)]
    top = max(terms)
    return min(1.0, math.exp(top) * math.fsum(math.exp(t - top) for t in terms))


def upper_bound(failures: int, runs: int, confidence: float = CONFIDENCE) -> float:
    """The exact one-sided upper confidence bound on the failure probability, from ``failures`` of ``runs``."""
    if not 0 <= failures <= runs:
        raise ValueError(f"failures must be in [0, runs], got {failures} of {runs}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    alpha = 1.0 - confidence
    if runs == 0 or failures == runs:
        return 1.0
    if failures == 0:  # (1 - p)^n = alpha, solved exactly
        return -math.expm1(math.log(alpha) / runs)
    low, high = failures / runs, 1.0  # the CDF falls as p grows: bisect for CDF(p) = alpha
    for _ in range(200):
        middle = 0.5 * (low + high)
        if binomial_cdf(failures, runs, middle) > alpha:
            low = middle
        else:
            high = middle
        if high - low <= 1e-15 * high:
            break
    return high


def runs_needed(target: float, confidence: float = CONFIDENCE) -> int:
    """The fewest runs, none violating, whose upper bound is below ``target``."""
    if not 0.0 < target < 1.0:
        raise ValueError(f"the target probability must be in (0, 1), got {target}")
    n = max(1, math.floor(math.log(1.0 - confidence) / math.log1p(-target)))
    while upper_bound(0, n, confidence) >= target:
        n += 1
    while n > 1 and upper_bound(0, n - 1, confidence) < target:
        n -= 1
    return n


@dataclass(frozen=True)
class Bound:
    """A condition's violations in a campaign and the bound they give."""

    failures: int
    runs: int
    confidence: float = CONFIDENCE

    @property
    def rate(self) -> float | None:
        return self.failures / self.runs if self.runs else None

    @property
    def upper(self) -> float:
        return upper_bound(self.failures, self.runs, self.confidence)

    def to_json(self) -> dict:
        return {"failures": self.failures, "runs": self.runs, "rate": self.rate, "upper_bound": self.upper}


COUNTING = ("over the completed runs (a run that could not be simulated is left out and counted apart); "
            "a run where a condition could not be decided (missing data, inconclusive) counts as violating it")


def counts_against(run: dict, condition: str | None = None) -> bool:
    """Whether a completed run counts against ``condition`` (None: against any condition): it violated it
    or left it undecided. The one rule for the bound and for where ``--until-bound`` stops."""
    if condition is None:
        return bool(run.get("violations") or run.get("undecided"))
    return condition in run.get("violations", ()) or condition in run.get("undecided", ())


def campaign_bounds(runs: list[dict], conditions: list[str], sampling: str, confidence: float = CONFIDENCE) -> dict:
    """The ``bounds`` block of a campaign's results: per condition and for any condition, with what they
    are counted over and under which sampling distribution they hold."""
    completed = [r for r in runs if r.get("status") not in ("failed", "unfinished")]
    overall = Bound(sum(counts_against(r) for r in completed), len(completed), confidence)
    failed = sum(1 for r in runs if r.get("status") == "failed")
    drawn_from = sampling
    if failed:  # the completed runs are a sample of the runs that complete, not of every run drawn
        sampling = (f"{sampling}; of the runs drawn so, only those that complete ({failed} of {len(runs)} did not "
                    "complete or could not be read: a configuration that cannot be simulated is not covered)")
    return {
        "confidence": confidence,
        "method": METHOD,
        "sampling": sampling,
        "drawn_from": drawn_from,
        "counted": COUNTING,
        "excluded_failed_runs": failed,
        "excluded_unfinished_runs": sum(1 for r in runs if r.get("status") == "unfinished"),
        "overall": overall.to_json(),
        "conditions": {c: Bound(sum(counts_against(r, c) for r in completed), len(completed), confidence).to_json()
                       for c in conditions},
    }


