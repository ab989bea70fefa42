#!/usr/bin/env python3
"""The mutation report: every mutant of the safety modules killed, or explained.

Reads what ``mutmut run`` left in ``mutants/`` (one ``<module>.py.meta`` JSON file per
mutated module, each mutant's exit code) and ``tests/mutation_equivalents.yaml`` (the
mutants that survive because they change nothing a caller can see, each with its reason),
and prints, per module, the mutants made, killed, explained and left unexplained, then
every unexplained one with the line it changes (``mutmut show``).

    .venv/bin/mutmut run --max-children 2
    .venv/bin/python scripts/mutation_report.py

Exit 0 when every mutant is killed (its tests failed, hung or crashed) or explained; 1 when one
survives unexplained, found no test or was never run; 2 when there is no mutmut run to read. An explanation of
a mutant that no longer survives (or no longer exists) is listed as stale, to be removed.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from collections import Counter
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
EQUIVALENTS = ROOT / "tests" / "mutation_equivalents.yaml"
KILLED = {1, 3}
"""mutmut's exit codes of a run that failed: a test caught the mutant."""
DETECTED = {"timeout", "segfault"}
"""Outcomes that are detections too: the tests never finished (a loop that no longer ends, a crash)."""
SURVIVED = 0


def outcome(code) -> str:
    """mutmut's exit code of a mutant's tests, as a word (mutmut.stats.status_by_exit_code's)."""
    from mutmut.stats import status_by_exit_code

    return status_by_exit_code[code]


def read_runs(folder: Path) -> dict[str, dict[str, object]]:
    """module path -> {mutant name: exit code}, from mutmut's .meta files."""
    found = {}
    for meta in sorted(folder.rglob("*.py.meta")):
        module = meta.relative_to(folder).as_posix().removesuffix(".meta")
        found[module] = json.loads(meta.read_text())["exit_code_by_key"]
    return found


def read_equivalents(path: Path) -> dict[str, str]:
    """mutant name -> why it is equivalent (the file's ``equivalent`` list)."""
    if not path.is_file():
        return {}
    data = yaml.safe_load(path.read_text()) or {}
    return {entry["mutant"]: entry["why"] for entry in data.get("equivalent", [])}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mutants", type=Path, default=ROOT / "mutants", help="mutmut's folder (default: mutants/)")
    parser.add_argument("--no-show", action="store_true", help="do not print each unexplained mutant's change")
    args = parser.parse_args()
    runs = read_runs(args.mutants)
    if not runs:
        print(f"no mutmut run in {args.mutants}: run `.venv/bin/mutmut run` first", file=sys.stderr)
        return 2
    equivalents = read_equivalents(EQUIVALENTS)
    unexplained, stale = [], []
    print(f"{'module':<42} {'mutants':>8} {'killed':>8} {'equivalent':>10} {'unexplained':>11}")
    totals = Counter()
    for module, codes in runs.items():
        counts = Counter()
        for name, code in codes.items():
            word = outcome(code)
            if code in KILLED or word in DETECTED:
                counts["killed"] += 1
                if name in equivalents:
                    stale.append((name, "killed now"))
            elif code == SURVIVED and name in equivalents:
                counts["equivalent"] += 1
            else:
                counts["unexplained"] += 1
                unexplained.append((name, word))
        counts["mutants"] = len(codes)
        totals.update(counts)
        print(f"{module:<42} {counts['mutants']:>8} {counts['killed']:>8} {counts['equivalent']:>10} {counts['unexplained']:>11}")
    print(f"{'all':<42} {totals['mutants']:>8} {totals['killed']:>8} {totals['equivalent']:>10} {totals['unexplained']:>11}")
    known = {name for codes in runs.values() for name in codes}
    stale += [(name, "no such mutant") for name in equivalents if name not in known]
    for name, why in stale:
        print(f"stale explanation in {EQUIVALENTS.name}: {name} ({why})")
    if unexplained:
        print(f"\n{len(unexplained)} mutant(s) neither killed nor explained:")
        for name, word in unexplained:
            print(f"- {name}: {word}")
            if not args.no_show:
                shown = subprocess.run([sys.executable, "-m", "mutmut", "show", name], capture_output=True, text=True,
                                       cwd=ROOT)
                print("\n".join("    " + line for line in shown.stdout.splitlines() if line.startswith(("+", "-"))
                                and not line.startswith(("+++", "---"))))
        return 1
    print("every mutant killed or explained")
    return 0


if __name__ == "__main__":
    sys.exit(main())
