"""Benchmark: `cellsim verify` on a scenario, model built and checked, with its figures per stage.

Prints the abstract model's size (the cell, and the largest model with one monitor)
and the seconds of each stage: building the cell's diagram, declaring and cutting
the floor into places, writing the model, Storm's parse, build and check. The
target (issue 20): the welding cell within 10 s in total on this machine.

    .venv/bin/python scripts/bench_verify.py [SCENARIO] [--runs N] [--timed]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario", nargs="?", default=str(ROOT / "scenarios" / "welding_cell.yaml"))
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--timed", action="store_true", help="bound the cell's durations below (more states)")
    args = parser.parse_args()
    start = time.perf_counter()
    from cellsim.scenario import load_scenario
    from cellsim.verify.run import verify

    imported = time.perf_counter() - start
    totals, last = [], None
    for _ in range(args.runs):
        sf = load_scenario(args.scenario)
        began = time.perf_counter()
        last = verify(sf, timed=args.timed)
        totals.append(time.perf_counter() - began)
    stats, largest = last.stats, last.largest or last.stats
    engine = "decision diagrams, every monitor in one model" if stats.symbolic else "state by state"
    print(f"scenario: {Path(args.scenario).name}{' (timed)' if args.timed else ''}; Storm built it {engine}")
    print(f"states: {stats.states:,} (the cell), {largest.states:,} (largest, with a monitor); "
          f"transitions: {stats.transitions:,} / {largest.transitions:,}")
    people = last.model.cell.places.people
    print("places: " + ", ".join(f"{p.role.module} {len(p.places)}" for p in people)
          + f" ({last.model.cell.places.poses_measured:,} poses measured)")
    for stage, seconds in last.times.items():
        print(f"  {stage:<12} {seconds:8.3f} s")
    print(f"import: {imported:.2f} s; verify total: median {statistics.median(totals):.2f} s "
          f"(min {min(totals):.2f}, max {max(totals):.2f}) over {len(totals)} runs; target <= 10 s")
    results = ", ".join(f"{r.prop.name}={r.value:g}" for r in last.results if isinstance(r.value, float))
    print(f"values: {results}")


if __name__ == "__main__":
    main()
