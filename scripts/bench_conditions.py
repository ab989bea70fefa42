#!/usr/bin/env python3
"""Benchmark of the offline MTL evaluation of welding-cell safety conditions.

Builds a synthetic but realistically shaped recorded run (30 s, 11 enum/bool
signals, ~100 value changes each on the 20 ms control grid, seeded RNG) and the 14
conditions of the welding cell's risk model:

* for each hazard X in HS, HC, HRW (with a macro Xe for its enabling situation):
  detected  ``G((Xe and X == inact) -> (Xe U[0, 0.5s] X == act))``,
  mitigated ``G(X == act -> F X == mit)``,
  handled   ``G(X == mit -> F X == inact)``,
  not_mis   ``G(not X == mis)``;
* ``F(not otab)`` and ``F(oloc == none)``.

Prints the parse time, the evaluation time of each condition on its own (median
of repeats, fresh trace and evaluator each time: nothing cached), their total
against the 10 ms target, and the total when the 14 conditions share one
evaluator (common sub-formulas computed once).

    .venv/bin/python scripts/bench_conditions.py [--repeats 200] [--seed 1] [--changes 100]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cellsim.logic import (  # noqa: E402
    BoolDomain,
    EnumDomain,
    Signal,
    Trace,
    TraceEvaluator,
    evaluate,
    parse,
)

TARGET_MS = 10.0
DURATION = 30.0
TICK = 0.02  # control period: all changes happen on the 50 Hz grid

HAZARD = ("inact", "act", "mit", "mis")
VOCABULARY = {
    "safmod": EnumDomain(("normal", "hguid", "ssmon", "pflim", "srmst", "stopped")),
    "ract": EnumDomain(("idle", "moving", "exchWrkp", "welding")),
    "wact": EnumDomain(("idle", "welding")),
    "rngDet": EnumDomain(("none", "far", "near", "close")),
    "oloc": EnumDomain(("none", "table", "door", "cell")),
    "otab": BoolDomain(),
    "lgtBar": BoolDomain(),
    "HS": EnumDomain(HAZARD),
    "HC": EnumDomain(HAZARD),
    "HRW": EnumDomain(HAZARD),
    "welder.on": BoolDomain(),
}
MACROS = {
    "HS_e": "safmod in {normal, hguid, ssmon, pflim} and (ract in {exchWrkp, welding} "
    "or wact == welding) and rngDet in {near, close}",
    "HC_e": "safmod in {normal, hguid, ssmon, pflim} and ract in {moving, exchWrkp} "
    "and oloc == table and not lgtBar",
    "HRW_e": "safmod in {normal, hguid, ssmon} and (wact == welding or welder.on) "
    "and oloc in {table, cell}",
}


def conditions() -> dict[str, str]:
    conds: dict[str, str] = {}
    for x in ("HS", "HC", "HRW"):
        conds[f"{x}_detected"] = f"G(({x}_e and {x} == inact) -> ({x}_e U[0, 0.5s] {x} == act))"
        conds[f"{x}_mitigated"] = f"G({x} == act -> F {x} == mit)"
        conds[f"{x}_handled"] = f"G({x} == mit -> F {x} == inact)"
        conds[f"{x}_not_mis"] = f"G(not {x} == mis)"
    conds["operator_leaves_table"] = "F(not otab)"
    conds["operator_leaves_cell"] = "F(oloc == none)"
    return conds


def _change_times(rng: np.random.Generator, changes: int) -> np.ndarray:
    ticks = rng.choice(np.arange(1, int(DURATION / TICK)), size=changes, replace=False)
    return np.concatenate([[0.0], np.sort(ticks) * TICK])


def synthetic_trace(seed: int, changes: int) -> dict[str, Signal]:
    """~``changes`` value changes per signal; hazards follow inact->act->mit->inact."""
    rng = np.random.default_rng(seed)
    signals: dict[str, Signal] = {}
    for name, domain in VOCABULARY.items():
        times = _change_times(rng, changes)
        if name in ("HS", "HC", "HRW"):
            values, state = [], "inact"
            for _ in times:
                values.append(state)
                if state == "inact":
                    state = "act"
                elif state == "act":
                    state = "mis" if rng.random() < 0.05 else "mit"
                else:
                    state = "inact"
        elif isinstance(domain, BoolDomain):
            first = bool(rng.integers(2))
            values = [first ^ (i % 2 == 1) for i in range(len(times))]
        else:
            values, prev = [], None
            for _ in times:
                choices = [v for v in domain.values if v != prev]
                prev = choices[rng.integers(len(choices))]
                values.append(prev)
        signals[name] = Signal(times, values)
    return signals


def median_ms(fn, repeats: int) -> float:
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter_ns()
        fn()
        samples.append(time.perf_counter_ns() - t0)
    return statistics.median(samples) / 1e6


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=200)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--changes", type=int, default=100, help="value changes per signal")
    args = ap.parse_args(argv)

    signals = synthetic_trace(args.seed, args.changes)
    texts = conditions()
    n_breaks = sum(len(s) for s in signals.values())

    def parse_all():
        return {name: parse(text, VOCABULARY, MACROS) for name, text in texts.items()}

    formulas = parse_all()
    parse_ms = median_ms(parse_all, args.repeats)

    print(
        f"trace: {DURATION:.0f} s, {len(signals)} signals, {n_breaks} samples "
        f"(~{args.changes} changes per signal), seed {args.seed}"
    )
    print(f"{len(formulas)} conditions; median of {args.repeats} repeats\n")
    print(f"parse (all {len(formulas)}, with macros): {parse_ms:8.3f} ms\n")
    print(f"{'condition':24} {'verdict':>22} {'eval ms':>9}")

    total = 0.0
    for name, f in formulas.items():
        # a fresh Trace each time so that not even the per-signal clipping is cached
        traces = [Trace(signals, 0.0, DURATION) for _ in range(args.repeats)]
        it = iter(traces)
        ms = median_ms(lambda: evaluate(f, next(it)), args.repeats)
        verdict = evaluate(f, Trace(signals, 0.0, DURATION))
        shown = "holds" if verdict.holds else f"violated at {verdict.violated_at:.2f} s"
        print(f"{name:24} {shown:>22} {ms:9.3f}")
        total += ms

    traces = [Trace(signals, 0.0, DURATION) for _ in range(args.repeats)]
    it = iter(traces)

    def shared():
        ev = TraceEvaluator(next(it))
        for f in formulas.values():
            ev.evaluate(f)

    shared_ms = median_ms(shared, args.repeats)
    ok = total <= TARGET_MS
    print(f"\n{'total (independent)':24} {'':>22} {total:9.3f}   target {TARGET_MS:.0f} ms: "
          f"{'OK' if ok else 'MISSED'}")
    print(f"{'total (shared evaluator)':24} {'':>22} {shared_ms:9.3f}")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
