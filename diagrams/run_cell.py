"""What every cell built in code does when run as a script: simulate it and print its verdicts."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Callable

import cellsim

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
"""Where the files the cells name are found (the arm's model, the welding cell's risk model and validation)."""


def main(scenario: Callable[[], cellsim.Scenario], description: str) -> None:
    """Simulate ``scenario()`` (``--seed``, ``--duration``, ``--out``, ``--overwrite``) and print its verdicts."""
    name = scenario().name
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--duration", type=float, default=None)
    parser.add_argument("--out", type=Path, default=Path("runs") / name)
    parser.add_argument("--overwrite", action="store_true")
    args = parser.parse_args()
    sf = cellsim.scenario_in_code(scenario(), base_dir=SCENARIOS)
    run = cellsim.simulate(sf, args.out, seed=args.seed, duration=args.duration, overwrite=args.overwrite)
    print(f"{run.summary.status}: {run.out / 'blackbox.sqlite'}")
    for condition, verdict in run.verdicts.items():
        print(f"  {condition}: {verdict}")
