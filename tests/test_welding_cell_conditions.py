"""The welding cell's 14 safety conditions and 3 use-case classifiers on hand-made traces.

Every trace describes a 30 s run of the cell in the short variable names of
``scenarios/welding_cell_validation.yaml``. A trace starts from the cell working
normally with nobody around (``BACKGROUND``) and each test states only what
differs: the sensor readings of an operator's interference and the controller's
reaction (hazard phases, safety mode, activities), at the controller's 20 ms step.

Semantics (docs/condition-language.md): right-continuous piecewise-constant
signals on ``[0, 30)``; unbounded ``F``/``U`` are strong, bounded windows cut by
the end of the trace are not judged; ``violated_at`` of ``G p`` is the first
instant where ``p`` is false.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from cellsim.logic.mtl import TraceEvaluator
from cellsim.logic.trace import Signal, Trace
from cellsim.scenario import load_scenario
from cellsim.validation.check import scenario_safety_case

ROOT = Path(__file__).resolve().parents[1]
DURATION = 30.0
STEP = 0.02  # the safety controller's period

# The cell working normally, nobody around.
BACKGROUND = dict(
    safmod="normal",
    rloc="atTable",
    ract="exchWrkp",
    wact="idle",
    rngDet="far",
    lgtBar=False,
    notif="ok",
    notif_leaveWrkb=False,
    HRW="inact",
    HS="inact",
    HC="inact",
    oloc="none",
    otab=False,
)


@pytest.fixture(scope="module")
def case():
    return scenario_safety_case(load_scenario(ROOT / "scenarios" / "welding_cell.yaml"))


def make_trace(duration: float = DURATION, **changes: list[tuple[float, object]]) -> Trace:
    """A trace over ``[0, duration)``: the background values, changed as given.

    ``changes[var]`` is a list of ``(time, value)`` in time order; the background
    value holds before its first entry. ``None`` makes the variable undefined.
    """
    unknown = set(changes) - set(BACKGROUND)
    assert not unknown, f"not a trace variable: {unknown}"
    signals = {}
    for name, default in BACKGROUND.items():
        points = list(changes.get(name, []))
        if not points or points[0][0] > 0.0:
            points.insert(0, (0.0, default))
        signals[name] = Signal([t for t, _ in points], [v for _, v in points])
    return Trace(signals, 0.0, duration)


def merge(*parts: dict) -> dict:
    """Combine change descriptions; lists of the same variable are merged in time order."""
    out: dict[str, list] = {}
    for part in parts:
        for name, points in part.items():
            out[name] = sorted(out.get(name, []) + list(points), key=lambda p: p[0])
    return out


def verdict(case, condition: str, changes: dict):
    return TraceEvaluator(make_trace(**changes)).evaluate(case.conditions[condition])


def exercises(case, use_case: str, changes: dict) -> bool:
    return TraceEvaluator(make_trace(**changes)).evaluate(case.use_cases[use_case]).holds


# ---------------------------------------------------------------------------
# Interference episodes: what the sensors see while an operator interferes from
# t0 to t1, with the machines in the state in which the hazard can arise.


def episode(hazard: str, t0: float, t1: float) -> dict:
    if hazard == "HRW":  # robot at the shared table, operator reaching across it
        return dict(
            rloc=[(t0 - 1.0, "sharedTbl"), (t1 + 1.0, "inCell")],
            otab=[(t0 - 0.5, True), (t1 + 0.5, False)],
            lgtBar=[(t0, True), (t1, False)],
        )
    if hazard == "HS":  # operator walks into the cell while the robot exchanges a work-piece
        return dict(oloc=[(t0 - 0.5, "inCell"), (t1 + 0.5, "none")], rngDet=[(t0, "near"), (t1, "far")])
    if hazard == "HC":  # operator walks up to the welder during a weld
        return dict(
            rloc=[(t0 - 3.0, "atWeldSpot")],
            ract=[(t0 - 3.0, "welding")],
            wact=[(t0 - 3.0, "welding")],
            oloc=[(t0 - 1.5, "inCell"), (t1 + 1.5, "none")],
            rngDet=[(t0 - 1.0, "near"), (t0, "close"), (t1, "near"), (t1 + 1.0, "far")],
        )
    raise ValueError(hazard)


def phases(hazard: str, *points: tuple[float, str]) -> dict:
    return {hazard: list(points)}


def handled(hazard: str, t0: float, t1: float) -> dict:
    """The controller's textbook reaction to ``episode(hazard, t0, t1)``: detect, mitigate, resume."""
    act, mit, res, back = t0 + STEP, t0 + 2 * STEP, t1 + STEP, t1 + 2 * STEP
    mode = {"HRW": "pflim", "HS": "ssmon", "HC": "stopped"}[hazard]
    out = merge(
        phases(hazard, (act, "act"), (mit, "mit"), (res, "res"), (back, "inact")),
        dict(safmod=[(mit, mode), (back, "normal")]),
    )
    if hazard == "HRW":
        out = merge(out, dict(notif_leaveWrkb=[(mit, True), (back, False)]))
    else:
        out = merge(out, dict(notif=[(mit, "leaveArea"), (back, "ok")]))
    if hazard == "HC":  # stop the cell, start over by exchanging the work-piece
        out = merge(out, dict(ract=[(mit, "off"), (back, "exchWrkp")], wact=[(mit, "off"), (back, "idle")]))
    return out


# ---------------------------------------------------------------------------
# X:detected  G((X_e and X == inact) -> (X_e U[0, 0.5s] X == act))

HRW_REACH = episode("HRW", 5.0, 7.0)
HS_APPROACH = episode("HS", 10.0, 15.0)
HC_APPROACH = merge(
    episode("HC", 13.0, 16.0),  # near at 12.0, close at 13.0
    # HS is handled first: speed and separation monitoring, a permissive mode
    phases("HS", (12.02, "act"), (12.04, "mit")),
    dict(safmod=[(12.04, "ssmon")], notif=[(12.04, "leaveArea")]),
)


def hc_stop(at: float) -> dict:
    """HC detected at ``at``, mitigated one step later by stopping the cell."""
    return merge(
        phases("HC", (at, "act"), (at + STEP, "mit")),
        dict(safmod=[(at + STEP, "stopped")], ract=[(at + STEP, "off")], wact=[(at + STEP, "off")]),
    )


DETECTED = [
    # --- HRW: the light barrier is broken at 5.0 while the robot is at the shared table
    pytest.param("HRW", merge(HRW_REACH, handled("HRW", 5.0, 7.0)), None, id="HRW-detected-next-step"),
    pytest.param(
        "HRW",
        merge(HRW_REACH, phases("HRW", (5.5, "act"), (5.52, "mit")), dict(safmod=[(5.52, "pflim")])),
        None,
        id="HRW-detected-at-the-0.5s-deadline",
    ),
    pytest.param(
        "HRW",
        merge(HRW_REACH, phases("HRW", (5.6, "act"), (5.62, "mit")), dict(safmod=[(5.62, "pflim")])),
        5.0,
        id="HRW-detected-0.6s-late",
    ),
    pytest.param(
        "HRW",
        dict(rloc=[(4.0, "sharedTbl"), (6.0, "inCell")], otab=[(4.5, True), (6.5, False)], lgtBar=[(5.0, True), (5.2, False)]),
        5.0,
        id="HRW-brief-reach-never-detected",
    ),
    pytest.param(
        "HRW",
        dict(otab=[(4.5, True), (7.5, False)], lgtBar=[(5.0, True), (7.0, False)]),
        None,
        id="HRW-reach-while-robot-at-its-own-table",
    ),
    pytest.param(
        "HRW",
        merge(HRW_REACH, dict(safmod=[(3.0, "stopped")], ract=[(3.0, "off")])),
        None,
        id="HRW-reach-while-cell-stopped",
    ),
    pytest.param(
        "HRW",
        merge(HRW_REACH, dict(ract=[(2.0, "idle")])),
        None,
        id="HRW-reach-while-cell-idle",
    ),
    pytest.param(
        "HRW",
        merge(
            HRW_REACH,  # still reaching until 7.0, but the controller resumes at 6.0
            phases("HRW", (5.02, "act"), (5.04, "mit"), (6.0, "res"), (6.02, "inact")),
            dict(safmod=[(5.04, "pflim"), (6.02, "normal")]),
        ),
        6.02,
        id="HRW-resumed-while-still-reaching-not-redetected",
    ),
    pytest.param(
        "HRW",
        dict(rloc=[(28.0, "sharedTbl")], otab=[(29.5, True)], lgtBar=[(29.8, True)]),
        None,
        id="HRW-reach-0.2s-before-end-not-judged",
    ),
    # --- HS: the operator comes near at 10.0 while the robot exchanges a work-piece
    pytest.param("HS", merge(HS_APPROACH, handled("HS", 10.0, 15.0)), None, id="HS-detected-next-step"),
    pytest.param(
        "HS",
        merge(HS_APPROACH, phases("HS", (10.5, "act"), (10.52, "mit")), dict(safmod=[(10.52, "ssmon")])),
        None,
        id="HS-detected-at-the-0.5s-deadline",
    ),
    pytest.param(
        "HS",
        merge(episode("HS", 10.0, 10.5), phases("HS", (10.5, "act"), (10.52, "res"), (10.54, "inact"))),
        None,
        id="HS-condition-ends-at-the-detection-instant",
    ),
    pytest.param(
        "HS",
        merge(HS_APPROACH, phases("HS", (10.6, "act"), (10.62, "mit")), dict(safmod=[(10.62, "ssmon")])),
        10.0,
        id="HS-detected-0.6s-late",
    ),
    pytest.param(
        "HS",
        merge(episode("HS", 10.0, 10.3), phases("HS", (10.5, "act"), (10.52, "res"), (10.54, "inact"))),
        10.0,
        id="HS-brief-approach-detected-at-0.5s-after-it-ended",
    ),
    pytest.param(
        "HS",
        merge(HS_APPROACH, dict(safmod=[(8.0, "stopped")], ract=[(8.0, "off")])),
        None,
        id="HS-near-while-cell-stopped",
    ),
    pytest.param(
        "HS",
        merge(HS_APPROACH, dict(ract=[(8.0, "idle")])),
        None,
        id="HS-near-while-cell-idle",
    ),
    pytest.param(
        "HS",
        merge(
            episode("HRW", 5.0, 13.0),  # operator 1 reaches across the bench until 13.0
            phases("HRW", (5.02, "act"), (5.04, "mit")),
            dict(safmod=[(5.04, "pflim")], notif_leaveWrkb=[(5.04, True)]),
            episode("HS", 6.0, 12.0),  # operator 2 walks up to the welder, HS stays inact
        ),
        6.0,
        id="HS-missed-while-busy-with-HRW-two-operators",
    ),
    pytest.param(
        "HS",
        merge(HS_APPROACH, handled("HS", 10.0, 15.0), dict(rngDet=[(11.0, "close"), (12.0, "near")])),
        None,
        id="HS-close-while-already-mitigated",
    ),
    pytest.param(
        "HS",
        dict(oloc=[(29.0, "inCell")], rngDet=[(29.8, "near")]),
        None,
        id="HS-near-0.2s-before-end-not-judged",
    ),
    # --- HC: the operator gets close to the welder at 13.0 during a weld (HS already in mit)
    pytest.param("HC", merge(HC_APPROACH, hc_stop(13.02)), None, id="HC-detected-next-step-in-ssmon"),
    pytest.param("HC", merge(HC_APPROACH, hc_stop(13.5)), None, id="HC-detected-at-the-0.5s-deadline"),
    pytest.param("HC", merge(HC_APPROACH, hc_stop(13.6)), 13.0, id="HC-detected-0.6s-late"),
    pytest.param("HC", HC_APPROACH, 13.0, id="HC-never-detected"),
    pytest.param(
        "HC",
        merge(episode("HS", 12.0, 16.0), dict(rngDet=[(13.0, "close"), (14.0, "near")])),
        None,
        id="HC-close-while-robot-exchanges",
    ),
    pytest.param(
        "HC",
        merge(HC_APPROACH, dict(wact=[(12.5, "idle")])),
        None,
        id="HC-close-while-welder-idle-between-spots",
    ),
    pytest.param(
        "HC",
        merge(HC_APPROACH, dict(safmod=[(12.5, "srmst")])),
        None,
        id="HC-close-in-monitored-stop",
    ),
]


@pytest.mark.parametrize("hazard, changes, violated_at", DETECTED)
def test_detected(case, hazard, changes, violated_at):
    v = verdict(case, f"{hazard}:detected", changes)
    assert v.holds is (violated_at is None)
    assert v.violated_at == violated_at


# ---------------------------------------------------------------------------
# X:mitigated  G(X == act -> F X in {mit, mit1, mit2})
# X:handled    G(X in {mit, mit1, mit2} -> F X == inact)
# X:not_mis    G(not X == mis)
# Each on an interference episode from 10.0 to 15.0 (or late in the run).

HAZARDS = ("HRW", "HS", "HC")


def run_with(hazard: str, *points: tuple[float, str], t0: float = 10.0, t1: float = 15.0) -> dict:
    return merge(episode(hazard, t0, t1), phases(hazard, *points))


PHASE_CASES = {
    # condition: [(id, phase points, other episodes, violated_at)]
    "mitigated": [
        ("act-then-mit", None, None),
        ("mit1-mit2-steps", [(10.02, "act"), (10.04, "mit1"), (10.5, "mit2"), (15.02, "res"), (15.04, "inact")], None),
        ("act-at-end-of-trace", [(29.92, "act")], 29.92),
        ("act-dropped-without-mitigation", [(10.02, "act"), (10.5, "res"), (10.52, "inact")], 10.02),
        (
            "second-episode-unmitigated",
            [(10.02, "act"), (10.04, "mit"), (15.02, "res"), (15.04, "inact"), (20.02, "act"), (20.5, "inact")],
            20.02,
        ),
    ],
    "handled": [
        ("mit-res-inact", None, None),
        ("mit1-mit2-res-inact", [(10.02, "act"), (10.04, "mit1"), (10.5, "mit2"), (15.02, "res"), (15.04, "inact")], None),
        ("operator-returns-during-res", [(10.02, "act"), (10.04, "mit"), (15.02, "res"), (15.5, "mit"), (20.0, "res"), (20.02, "inact")], None),
        ("mit-until-end", [(10.02, "act"), (10.04, "mit")], 10.04),
        ("stuck-resuming", [(10.02, "act"), (10.04, "mit"), (15.02, "res")], 10.04),
        ("stuck-in-mit2", [(10.02, "act"), (10.04, "mit1"), (10.5, "mit2")], 10.04),
        (
            "second-episode-not-resumed",
            [(10.02, "act"), (10.04, "mit"), (15.02, "res"), (15.04, "inact"), (20.02, "act"), (20.04, "mit")],
            20.04,
        ),
    ],
    "not_mis": [
        ("handled-episode", None, None),
        ("phase-recorded-from-1s", [(0.0, None), (1.0, "inact"), (10.02, "act"), (10.04, "mit"), (15.02, "res"), (15.04, "inact")], None),
        ("mishap-during-act", [(10.02, "act"), (10.3, "mis")], 10.3),
        ("mishap-after-mitigation", [(10.02, "act"), (10.04, "mit"), (12.0, "mis"), (12.5, "mit"), (15.02, "res"), (15.04, "inact")], 12.0),
        ("mishap-at-last-step", [(29.98, "mis")], 29.98),
    ],
}


def phase_params():
    for condition, cases in PHASE_CASES.items():
        for hazard in HAZARDS:
            for name, points, violated_at in cases:
                if points is None:
                    changes = merge(episode(hazard, 10.0, 15.0), handled(hazard, 10.0, 15.0))
                elif points[-1][0] > 29.0:  # an episode at the end of the run
                    changes = run_with(hazard, *points, t0=points[-1][0] - STEP, t1=DURATION + 1.0)
                else:
                    changes = run_with(hazard, *points)
                yield pytest.param(f"{hazard}:{condition}", changes, violated_at, id=f"{hazard}-{condition}-{name}")


@pytest.mark.parametrize("condition, changes, violated_at", list(phase_params()))
def test_phase_conditions(case, condition, changes, violated_at):
    v = verdict(case, condition, changes)
    assert v.holds is (violated_at is None)
    assert v.violated_at == violated_at


# ---------------------------------------------------------------------------
# Final:Tbl / Final:Cell: the operator *ends up* off the table and out of the
# cell (shared/welding-cell.md). A run that starts with the operator away and ends
# with them at the table / in the cell fails (the published F(not otab) would
# pass it, vacuously, at t = 0). Not G formulas: violated_at is the start.

FINAL = [
    pytest.param("Final:Tbl", dict(otab=[(8.0, True), (12.0, False)]), True, id="Tbl-reaches-bench-and-leaves"),
    pytest.param(
        "Final:Tbl",
        dict(otab=[(8.0, True), (12.0, False), (20.0, True), (25.0, False)]),
        True,
        id="Tbl-back-at-bench-then-leaves",
    ),
    pytest.param("Final:Tbl", dict(otab=[(0.0, True)]), False, id="Tbl-at-bench-all-run"),
    pytest.param("Final:Tbl", dict(otab=[(22.0, True)]), False, id="Tbl-walks-to-bench-and-stays-to-end"),
    pytest.param("Final:Cell", dict(oloc=[(10.0, "inCell"), (18.0, "none")]), True, id="Cell-enters-and-leaves"),
    pytest.param(
        "Final:Cell",
        dict(oloc=[(0.0, "inCell"), (3.0, "none")]),
        True,
        id="Cell-starts-inside-and-leaves",
    ),
    pytest.param("Final:Cell", dict(oloc=[(0.0, "inCell")]), False, id="Cell-inside-all-run"),
    pytest.param("Final:Cell", dict(oloc=[(22.0, "inCell")]), False, id="Cell-enters-and-stays-to-end"),
]


@pytest.mark.parametrize("condition, changes, holds", FINAL)
def test_final(case, condition, changes, holds):
    v = verdict(case, condition, changes)
    assert v.holds is holds
    assert v.violated_at == (None if holds else 0.0)


# ---------------------------------------------------------------------------
# Use cases

WALK_IN = merge(episode("HS", 10.5, 17.5), handled("HS", 10.5, 17.5))  # in the cell 10.0 .. 18.0

USE_CASES = [
    # U1: enters the cell once, not over the table, while the cell works, and leaves for good
    pytest.param("U1", WALK_IN, True, id="U1-walks-in-during-exchange-and-leaves"),
    pytest.param(
        "U1",
        merge(episode("HS", 10.5, 40.0), phases("HS", (10.52, "act"), (10.54, "mit")), dict(safmod=[(10.54, "ssmon")])),
        False,
        id="U1-walks-in-and-stays-to-end",
    ),
    pytest.param(
        "U1",
        merge(episode("HC", 13.0, 16.0), hc_stop(13.02), dict(ract=[(19.0, "exchWrkp")], wact=[(19.0, "idle")], safmod=[(19.0, "normal")])),
        True,
        id="U1-walks-to-welder-during-weld-and-leaves",
    ),
    pytest.param(
        "U1",
        merge(WALK_IN, dict(oloc=[(22.0, "inCell"), (24.0, "none")])),
        False,
        id="U1-enters-twice",
    ),
    pytest.param("U1", merge(dict(ract=[(0.0, "idle")]), episode("HS", 10.5, 17.5)), False, id="U1-enters-while-cell-idle"),
    pytest.param(
        "U1",
        merge(WALK_IN, dict(otab=[(9.0, True), (10.5, False)], lgtBar=[(9.5, True), (10.2, False)])),
        False,
        id="U1-climbs-in-over-the-table",
    ),
    pytest.param("U1", dict(otab=[(8.0, True), (12.0, False)]), False, id="U1-never-enters"),
    # U2: reaches across the workbench while the cell works
    pytest.param("U2", merge(HRW_REACH, handled("HRW", 5.0, 7.0)), True, id="U2-reaches-across-during-exchange"),
    pytest.param("U2", dict(otab=[(8.0, True), (12.0, False)]), False, id="U2-stands-at-bench-without-reaching"),
    pytest.param("U2", merge(HRW_REACH, dict(ract=[(0.0, "idle")])), False, id="U2-reaches-across-while-cell-idle"),
    pytest.param("U2", WALK_IN, False, id="U2-walks-into-cell-only"),
    # MU: inside the cell, behind the light curtain, out of the range detector's reach, >= 1 s.
    # A stint cut short by the end of the run has not lasted a second: not MU.
    pytest.param(
        "MU",
        dict(oloc=[(10.0, "inCell"), (14.5, "none")], rngDet=[(12.0, "near"), (14.0, "far")]),
        True,
        id="MU-in-cell-unseen-for-2s",
    ),
    pytest.param(
        "MU",
        dict(oloc=[(10.0, "inCell"), (14.5, "none")], rngDet=[(10.5, "near"), (14.0, "far")]),
        False,
        id="MU-in-cell-unseen-for-0.5s",
    ),
    pytest.param(
        "MU",
        dict(ract=[(0.0, "idle")], oloc=[(10.0, "inCell"), (14.5, "none")], rngDet=[(12.0, "near"), (14.0, "far")]),
        False,
        id="MU-in-cell-unseen-while-cell-idle",
    ),
    pytest.param("MU", WALK_IN, False, id="MU-walk-in-seen-by-range-detector"),
    pytest.param("MU", dict(oloc=[(29.5, "inCell")]), False, id="MU-in-cell-unseen-for-last-0.5s"),
]


@pytest.mark.parametrize("use_case, changes, expected", USE_CASES)
def test_use_cases(case, use_case, changes, expected):
    assert exercises(case, use_case, changes) is expected


def test_realistic_runs_satisfy_all_conditions(case):
    """The handled episodes used above violate none of the 14 conditions."""
    runs = {
        "HRW": merge(HRW_REACH, handled("HRW", 5.0, 7.0)),
        "HS": WALK_IN,
        "HC": merge(
            episode("HC", 13.0, 16.0),
            phases("HS", (12.02, "act"), (12.04, "mit"), (17.02, "res"), (17.04, "inact")),
            hc_stop(13.02),
            phases("HC", (16.02, "res"), (16.04, "inact")),
            dict(
                safmod=[(12.04, "ssmon"), (16.04, "ssmon"), (17.04, "normal")],  # stopped 13.04 .. 16.04
                ract=[(16.04, "exchWrkp")],
                wact=[(16.04, "idle")],
                rloc=[(17.0, "inCell")],
            ),
        ),
    }
    for name, changes in runs.items():
        result = case.check(make_trace(**changes))
        assert result.violations == [], name
