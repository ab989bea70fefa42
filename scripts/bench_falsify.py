"""How many runs a falsification search needs to find a violation, against random sampling.

For each seed, each method searches the scenario (``cellsim falsify``'s own code,
2 workers) until its first violation of the targeted conditions or its budget;
the figure per method is the median number of runs that took over the seeds.
The methods take turns seed by seed, so they share the machine's conditions (the
figure counts runs, not seconds, so it does not depend on them anyway). A seed
that found nothing within the budget counts as budget + 1, a lower bound: the
medians are then lower bounds too, and the script says so.

The random method draws from the campaign's own distribution, through the same
loop: its median is what a campaign would have needed.

    .venv/bin/python scripts/bench_falsify.py                         # two_operators, every condition
    .venv/bin/python scripts/bench_falsify.py --condition HRW:detected
    .venv/bin/python scripts/bench_falsify.py --scenario scenarios/palletising_fault.yaml --budget 150
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", type=Path, default=ROOT / "scenarios" / "two_operators.yaml")
    parser.add_argument("--condition", action="append", default=[], help="condition to falsify (repeatable; default all)")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--budget", type=int, default=120)
    parser.add_argument("--methods", default="cmaes,qd,random", help="comma-separated; the last is the baseline")
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()

    from cellsim.campaign.falsify import FalsifyPlan, run_falsify

    methods = args.methods.split(",")
    found: dict[str, list[int]] = {m: [] for m in methods}
    censored: dict[str, int] = {m: 0 for m in methods}
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="cellsim-bench-falsify-") as tmp:
        for seed in range(1, args.seeds + 1):
            for method in methods:
                plan = FalsifyPlan(str(args.scenario.resolve()), (), seed, args.budget, method,
                                   conditions=tuple(args.condition))
                outcome = run_falsify(plan, Path(tmp) / f"{method}-{seed}", jobs=args.jobs, overwrite=True)
                runs = outcome.results["search"]["runs_to_first_violation"]
                if runs is None:
                    censored[method] += 1
                    runs = args.budget + 1
                found[method].append(runs)
                print(f"seed {seed:2d}  {method:7s} {runs:4d} runs{'' if runs <= args.budget else ' (none found)'}",
                      flush=True)
    target = ", ".join(args.condition) or "any condition"
    print(f"\n{args.scenario.name}, first violation of {target}; {args.seeds} seeds, budget {args.budget} runs; "
          f"{time.perf_counter() - started:.0f} s in all")
    baseline = methods[-1]
    base_median = statistics.median(found[baseline])
    for method in methods:
        median = statistics.median(found[method])
        ratio = "" if method == baseline else f"  ratio to {baseline} {median / base_median:.2f}"
        note = f"  ({censored[method]} of {args.seeds} found none: median is a lower bound)" if censored[method] else ""
        print(f"{method:7s} median {median:6.1f} runs  found by {args.seeds - censored[method]}/{args.seeds} seeds"
              f"{ratio}{note}")


if __name__ == "__main__":
    main()
