"""The fenceless machine-tending cell: what the default conditions find that the integrator's own miss.

Its own conditions (on what the scanner reports) hold; with no condition written on the ground
truth, `TrueSSM` fails while the sensed margin held, and the scanner's blind spot behind the bench
is named in the run's summary. The black box is read with sqlite3, the summary from the CLI run as
a process.
"""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import sys

import pytest
from conftest import ROOT

CELL = ROOT / "scenarios" / "machine_tending.yaml"
WIDE = {**os.environ, "COLUMNS": "250"}  # a wide terminal: the tables' lines are not wrapped


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("tending") / "run"
    done = subprocess.run([sys.executable, "-m", "cellsim", "simulate", str(CELL), "--out", str(out)],
                          capture_output=True, text=True, timeout=600, cwd=ROOT, env=WIDE)
    return out, done


def series(out, channel):
    db = sqlite3.connect(out / "blackbox.sqlite")
    rows = [(t, json.loads(p)["value"]) for t, p in
            db.execute("SELECT t, payload FROM messages WHERE channel = ? ORDER BY rowid", (channel,))]
    db.close()
    return rows


def value_at(rows, t):
    found = None
    for when, value in rows:
        if when > t + 1e-9:
            break
        found = value
    return found


def test_the_run_is_a_safety_finding_named_by_the_default_conditions(run):
    out, done = run
    assert done.returncode == 1, done.stderr
    assert "TrueSSM" in done.stdout and "1 of 5 conditions violated" in done.stdout
    assert "blind spot" in done.stdout and "protective field, which it reported free" in done.stdout
    checked = subprocess.run([sys.executable, "-m", "cellsim", "check", str(out)], capture_output=True, text=True,
                             timeout=300, cwd=ROOT, env=WIDE)
    verdicts = {line.split()[1]: line for line in checked.stdout.splitlines() if line.startswith("│")}
    assert "holds" in verdicts["SensedMargin"] and "holds" in verdicts["SlowsNearPeople"]
    assert "VIOLATED" in verdicts["TrueSSM"]


def test_the_true_margin_fails_while_the_sensed_margin_holds(run):
    """At some instant in ssmon the monitor's margin (from the scanner's distance) is positive and the true one
    (from the arm to the body) negative: the scanner measures from the pedestal, not the arm."""
    out, _ = run
    modes, sensed, true = (series(out, c) for c in ("robot.safety_mode", "ssm.margin", "ssm.true_margin"))
    found = [t for t, v in true if v < 0 and value_at(modes, t) == "ssmon" and value_at(sensed, t) >= 0]
    assert found, "no instant with the sensed margin held and the true one failed"
    separation, distance = series(out, "harm.separation_robot"), series(out, "scanner.distance")
    t = found[0]
    assert value_at(separation, t) < value_at(distance, t) - 0.3  # the arm is far nearer than the scanner says


def test_the_blind_spot_is_where_the_bench_hides_the_person(run):
    """While the person stands at the bench's west side (behind it, seen from the scanner), in the protective field,
    the scanner reads clear and the arm runs in normal mode."""
    out, _ = run
    unseen, field, modes = (series(out, c) for c in ("scanner.unseen", "scanner.field", "robot.safety_mode"))
    waypoint = series(out, "operator.waypoint")
    hidden = [t for t, v in unseen if v == "protective" and value_at(waypoint, t) == "bench_west"]
    assert hidden
    t = hidden[0] + 1.0
    assert value_at(unseen, t) == "protective" and value_at(field, t) == "clear" and value_at(modes, t) == "normal"
