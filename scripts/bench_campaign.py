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

With ``--scheduler`` it times, in the same run, the same campaign on a Dask cluster
beside the local pool: ``--scheduler auto`` starts a scheduler and --jobs workers
(one thread each, no nanny) on loopback for it and stops them by PID after;
``--scheduler tcp://HOST:PORT`` uses a running one. Local and cluster take turns
(local, cluster, local, cluster for --rounds 2) and the ratio of the medians is printed.
Target (issue 21): the cluster within 1.15x of the local pool on 2 workers of this machine.
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
    parser.add_argument("--scheduler", help="also time the campaign on this Dask scheduler ('auto': start one on loopback)")
    parser.add_argument("--rounds", type=int, default=2, help="with --scheduler: local/cluster pairs to time")
    args = parser.parse_args()
    if args.scheduler:
        compare_with_cluster(args)
        return
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


def compare_with_cluster(args) -> None:
    """The same campaign on the local pool and on a Dask cluster, taking turns; the ratio of the medians."""
    import contextlib
    import socket
    import subprocess

    @contextlib.contextmanager
    def loopback_cluster(tmp: Path):
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        address = f"tcp://127.0.0.1:{port}"
        started = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
                                     "--port", str(port), "--no-dashboard"], cwd=tmp, stdout=subprocess.DEVNULL,
                                    stderr=subprocess.DEVNULL)]
        try:
            for i in range(args.jobs):
                folder = tmp / f"worker{i}"
                folder.mkdir()
                started.append(subprocess.Popen(
                    [sys.executable, "-m", "distributed.cli.dask_worker", address, "--host", "127.0.0.1", "--nthreads",
                     "1", "--no-nanny", "--no-dashboard", "--local-directory", str(folder)],
                    cwd=folder, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            from distributed import Client

            with Client(address, timeout=60) as client:
                client.wait_for_workers(args.jobs, timeout=120)
            yield address
        finally:
            for process in started:
                process.kill()
                process.wait()

    with tempfile.TemporaryDirectory() as tmp, contextlib.ExitStack() as stack:
        tmp = Path(tmp)
        address = args.scheduler if args.scheduler != "auto" else stack.enter_context(loopback_cluster(tmp))
        plan = CampaignPlan(str(args.scenario.resolve()), tuple(args.set), args.seed, args.runs)
        times: dict[str, list[float]] = {"local": [], "cluster": []}
        for round_ in range(args.rounds):
            for where in ("local", "cluster"):
                started = time.perf_counter()
                outcome = run_campaign(plan, tmp / f"{where}{round_}", jobs=args.jobs,
                                       scheduler=address if where == "cluster" else None)
                times[where].append(time.perf_counter() - started)
                extra = f", {outcome.results['cluster']['retries']} retried" if where == "cluster" else ""
                print(f"  round {round_ + 1} {where:<8} {times[where][-1]:7.2f} s{extra}", flush=True)
        local, cluster = statistics.median(times["local"]), statistics.median(times["cluster"])
        print(f"campaign: {args.runs} runs, {args.jobs} local workers vs {args.jobs} Dask workers at {address}")
        print(f"  local pool  median {local:7.2f} s  (min {min(times['local']):.2f}, max {max(times['local']):.2f})")
        print(f"  cluster     median {cluster:7.2f} s  (min {min(times['cluster']):.2f}, max {max(times['cluster']):.2f})")
        print(f"  ratio cluster / local {cluster / local:.3f}  (target <= 1.15)")


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
