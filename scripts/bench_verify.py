"""Benchmark: `cellsim verify` on every shipped cell, model built and checked, with its figures per stage.

Each cell runs in a process of its own (its peak memory is the larger of that
process's and its Storm child's, read when it ends: ``verify`` runs Storm in a
forked process, which shares the parent's pages until it writes them): the
abstract model's size, how Storm built it, the
seconds of each stage (building the cell's diagram, declaring and cutting the
floor into places, writing the model, Storm's parse, build and check) and the
median of ``--runs`` runs. Witnesses are not replayed on the twin (``cellsim
verify`` does that, end to end). The targets (issue 36), model build and check:
the welding cell at most 2 s, the palletising cell at most 10 s, the assembly
bench at most 20 s and 1 GB.

``--end-to-end`` also times ``cellsim verify`` itself on each cell, as a whole
process (start-up, refinement and the twin's replays included), and prints its
ratio to the model figure measured just before (target: at most 3x), with the
endings and the refinements it took.

    .venv/bin/python scripts/bench_verify.py [SCENARIO ...] [--runs N] [--timed] [--end-to-end]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGETS = {"welding_cell": (2.0, None), "palletising_cell": (10.0, None), "assembly_bench": (20.0, 1024.0)}
"""Cell -> (seconds, MB) its model build and check should take at most (issue 36); None: no target."""


def shipped() -> list[Path]:
    """The shipped scenarios (not the risk models and validation files they include)."""
    return sorted(p for p in (ROOT / "scenarios").glob("*.yaml")
                  if not p.stem.endswith(("_risk_model", "_validation")))


def measure(scenario: str, runs: int, timed: bool) -> dict:
    """In this process: verify ``scenario`` ``runs`` times; its figures (the last run's stages)."""
    from cellsim.scenario import load_scenario
    from cellsim.verify.run import verify

    totals, last = [], None
    for _ in range(runs):
        sf = load_scenario(scenario)
        began = time.perf_counter()
        last = verify(sf, timed=timed)
        totals.append(time.perf_counter() - began)
    stats, largest = last.stats, last.largest or last.stats
    engine = ("decision diagrams" if stats.symbolic else "decision diagrams, made sparse for witnesses"
              if getattr(stats, "made_sparse", False) else "state by state for witnesses")  # (getattr: older trees)
    return {"states": stats.states, "transitions": stats.transitions, "largest_states": largest.states,
            "largest_transitions": largest.transitions, "engine": engine,
            "places": {p.role.module: len(p.places) for p in last.model.cell.places.people},
            "stages": last.times, "median": statistics.median(totals), "min": min(totals), "max": max(totals),
            "runs": len(totals), "violated": [r.prop.name for r in last.results if r.holds is False and not r.fair]}


def in_child(scenario: Path, runs: int, timed: bool) -> dict:
    """``measure`` in a child process, with its peak resident memory (MB)."""
    args = [sys.executable, __file__, "--child", str(scenario), "--runs", str(runs), *(["--timed"] if timed else [])]
    child = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    out = child.stdout.read()
    _, status, usage = os.wait4(child.pid, 0)
    if os.waitstatus_to_exitcode(status) != 0:
        return {"error": f"exit {os.waitstatus_to_exitcode(status)}"}
    return {**json.loads(out), "peak_mb": usage.ru_maxrss / 1024}


def end_to_end(scenario: Path, timed: bool) -> dict:
    """``cellsim verify`` on ``scenario`` as a whole process, witnesses replayed and refined: its wall seconds,
    exit code, endings and refinements."""
    import tempfile

    with tempfile.TemporaryDirectory(prefix="bench-verify-") as out:
        args = [sys.executable, "-m", "cellsim", "verify", str(scenario), "--json", "--out", out,
                *(["--timed"] if timed else [])]
        began = time.perf_counter()
        done = subprocess.run(args, capture_output=True, text=True, cwd=ROOT)
        seconds = time.perf_counter() - began
    try:
        result = json.loads(done.stdout)
    except json.JSONDecodeError:
        return {"error": f"exit {done.returncode}: {done.stderr.strip().splitlines()[-1:]}"}
    endings: dict[str, int] = {}
    for prop in result["properties"]:
        if prop.get("ending"):
            endings[prop["ending"]] = endings.get(prop["ending"], 0) + 1
    return {"seconds": seconds, "exit": done.returncode, "endings": endings,
            "refinements": [r["refinement"] for r in result.get("refinements", [])]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenarios", nargs="*", help="scenario files (default: every shipped cell)")
    parser.add_argument("--runs", type=int, default=1, help="runs per cell (the median is quoted; default 1)")
    parser.add_argument("--timed", action="store_true", help="bound the cell's durations below (more states)")
    parser.add_argument("--end-to-end", action="store_true",
                        help="also time `cellsim verify` itself (replays and refinement included) against the model")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(measure(args.child, args.runs, args.timed)))
        return
    for path in [Path(s) for s in args.scenarios] or shipped():
        print(f"{path.stem}{' (timed)' if args.timed else ''}:", flush=True)
        f = in_child(path, args.runs, args.timed)
        if "error" in f:
            print(f"  failed ({f['error']})")
            continue
        print(f"  states {f['states']:,}, transitions {f['transitions']:,} (largest model built: "
              f"{f['largest_states']:,} / {f['largest_transitions']:,}); {f['engine']}; places "
              + ", ".join(f"{who} {n}" for who, n in f["places"].items()))
        print("  " + ", ".join(f"{stage} {seconds:.2f}" for stage, seconds in f["stages"].items()) + " (s)")
        seconds, mb = TARGETS.get(path.stem, (None, None))
        target = "".join([f"; target <= {seconds:g} s" if seconds else "", f", <= {mb:g} MB" if mb else ""])
        print(f"  model build and check: median {f['median']:.2f} s (min {f['min']:.2f}, max {f['max']:.2f}, "
              f"{f['runs']} runs); peak memory {f['peak_mb']:.0f} MB (largest process){target}")
        if f["violated"]:
            print(f"  violated in the model: {', '.join(f['violated'])}")
        if args.end_to_end:
            e = end_to_end(path, args.timed)
            if "error" in e:
                print(f"  end to end: failed ({e['error']})")
                continue
            print(f"  end to end: {e['seconds']:.2f} s, {e['seconds'] / f['median']:.1f}x the model (target <= 3x); "
                  f"exit {e['exit']}; " + ", ".join(f"{n} {ending}" for ending, n in sorted(e["endings"].items()))
                  + (f"; refined: {', '.join(e['refinements'])}" if e["refinements"] else ""))


if __name__ == "__main__":
    main()
