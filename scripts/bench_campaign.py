#!/usr/bin/env python3
"""Benchmark: a test campaign of the welding cell, end to end, and the condition check alone.

Runs ``cellsim campaign`` (the library call behind it) for --runs runs of 30
simulated seconds with --jobs workers into a temporary folder: simulation, trace
reconstruction, the 14 safety conditions, use cases, coverage and the HTML report.
Prints the time per stage (summed over the workers for the per-run stages) and
the wall time, then the time to evaluate the 14 conditions, use cases and
coverage on one recorded 30-s trace.

Then the same on a violating run (the operator never leaves the cell: three conditions
violated, each explained in a sentence and with its evidence for the timeline).

Targets (issue 3, tightened by issue 9): 100 runs in at most 55 s wall with --jobs 2; the 14
conditions on one 30-s trace in at most 10 ms; with explanations (issue 13) too.

    .venv/bin/python scripts/bench_campaign.py [--runs 100] [--jobs 2] [--seed 1]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cellsim.campaign.runner import CampaignPlan, run_campaign  # noqa: E402
from cellsim.config.typed_yaml import ConfigError  # noqa: E402
from cellsim.logic.mtl import TraceEvaluator  # noqa: E402
from cellsim.logic.trace import Trace  # noqa: E402
from cellsim.scenario import load_scenario  # noqa: E402
from cellsim.simulation import simulate  # noqa: E402
from cellsim.validation.check import check  # noqa: E402

SCENARIO = ROOT / "scenarios" / "welding_cell.yaml"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--scenario", type=Path, default=SCENARIO)
    parser.add_argument("--set", action="append", default=[], metavar="PATH=VALUE", help="scenario override (repeatable)")
    args = parser.parse_args()
    try:  # bad input: one line and exit code 2, as the CLI does
        load_scenario(args.scenario, args.set)
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)

    with tempfile.TemporaryDirectory() as tmp:
        plan = CampaignPlan(str(args.scenario.resolve()), tuple(args.set), args.seed, args.runs)
        started = time.perf_counter()
        outcome = run_campaign(plan, Path(tmp) / "campaign", jobs=args.jobs)
        wall = time.perf_counter() - started
        timing = outcome.timing
        totals = outcome.results["totals"]
        print(f"campaign: {args.runs} runs x 30 s, --jobs {args.jobs}, {args.scenario.name} {' '.join(args.set)}")
        for stage in ("simulate", "trace", "check"):
            print(f"  {stage:<10} {timing[stage]:7.2f} s  (summed over workers, {timing[stage] / args.runs * 1e3:6.1f} ms per run)")
        for stage in ("coverage", "report"):
            print(f"  {stage:<10} {timing[stage]:7.2f} s")
        print(f"  wall       {wall:7.2f} s  (target <= 55 s for 100 runs)")
        print(
            f"  violating runs {totals['violating_runs']}, failed {totals['failed']}, "
            f"coverage {totals['coverage']['overall']['fraction']:.0%}"
        )

        # The check alone, on one recorded run, and on a violating one (explanations).
        print(check_timing(Path(tmp) / "campaign" / outcome.results["runs"][0]["out"], "one 30-s trace"))
        violating = Path(tmp) / "violating"
        simulate(load_scenario(args.scenario, [*args.set, "operator.waypoints.cell.wait=100"]), violating)
        print(check_timing(violating, "a violating 30-s trace"))


def check_timing(run: Path, what: str) -> str:
    """Median time to check the run's recorded trace: the conditions alone, then with use cases and coverage."""
    checked = check(run)
    recorded, case = checked.trace.trace, checked.case
    conditions, everything = [], []
    for _ in range(50):
        # a fresh trace each time: nothing cached from the previous round
        trace = Trace(dict(recorded.signals), recorded.start, recorded.end)
        t0 = time.perf_counter()
        evaluator = TraceEvaluator(trace)
        for formula in case.conditions.values():
            evaluator.evaluate(formula)
        conditions.append(time.perf_counter() - t0)
        trace = Trace(dict(recorded.signals), recorded.start, recorded.end)
        t0 = time.perf_counter()
        result = case.check(trace)
        everything.append(time.perf_counter() - t0)
    explained = sum(1 for v in result.verdicts.values() if v.explanation)
    return (f"check of {what} ({len(case.conditions)} conditions, {explained} violations explained): "
            f"{statistics.median(conditions) * 1e3:.2f} ms evaluating; "
            f"the whole check with explanations, use cases and coverage: {statistics.median(everything) * 1e3:.2f} ms "
            "(target <= 10 ms)")


if __name__ == "__main__":
    main()
