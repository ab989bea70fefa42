"""verify's robot abstraction bounds the tool speed the controller reads after a change of safety
mode (``SpeedEnvelope``); here the twin's robot is held to that bound, reading by reading.

The abstract model keeps, per speed threshold, a countdown of the periods a speed above it may still
be read. This test replays that countdown over a twin run's safety modes, period by period, and
checks that every speed the run's telemetry reports above a threshold is one the model allows. Were
the envelope too tight (a braking the twin does not achieve, a lag too short, a cap the arm
overshoots), some reading would fall outside it and verify's "holds" would no longer cover the twin.
"""

from __future__ import annotations

import pytest

from cellsim.kinds.robot.abstraction import SpeedEnvelope
from cellsim.scenario import load_scenario
from cellsim.vocabulary import SafetyMode

from conftest import ROOT, run

PALLETISING_CELL = ROOT / "scenarios" / "palletising_cell.yaml"
WELDING_CELL = ROOT / "scenarios" / "welding_cell.yaml"
THRESHOLDS = (0.05, 0.1, 0.2, 0.25, 0.3, 0.4, 0.5, 0.75, 0.9, 1.0)

# Runs whose robot changes mode at speed: the palletising cell as shipped (a stop while stacking, a slow
# down near the press), a walk that trips the pallet curtain while the arm crosses the cell at nearly
# full speed, and the welding cell's own walk (collaborative speed at the shared table, a stop).
RUNS = {
    "palletising": (PALLETISING_CELL, []),
    "palletising_stop_at_full_speed": (PALLETISING_CELL, [
        "operator.start_delay=12.74", "operator.waypoints.pallet_bay.wait=5.72",
        "operator.waypoints.reset_panel.wait=0.6", "operator.waypoints.press_approach.wait=0.51",
        "operator.waypoints.press_front.wait=3.32", "operator.waypoints.leave.wait=8.85",
        "operator.waypoints.press_front.position.1=1.55",
    ]),
    "welding": (WELDING_CELL, []),
}


def _caps(sf) -> dict[str, float]:
    limits = sf.scenario.entities["robot"].speed_limits
    caps = {m.value: getattr(limits, m.value, 0.0) for m in SafetyMode}
    caps[SafetyMode.UNKNOWN.value] = limits.normal
    return caps


def _outside(bb, envelope: SpeedEnvelope, caps: dict[str, float], threshold: float, strict: bool) -> list:
    """The speed readings above (at or above, not ``strict``) ``threshold`` that the abstract model does
    not allow: its countdown replayed over the run's safety modes, one period at a time."""
    dt = envelope.period
    modes, speeds = bb.series("robot.safety_mode"), bb.series("robot.tool_speed")

    def refresh(k: int) -> int:
        return envelope.periods(caps[modes.value_at(k * dt + 1e-9)], threshold, strict)

    last = round(float(speeds.times[-1]) / dt)
    countdown = [envelope.periods(caps[SafetyMode.NORMAL.value], threshold, strict)]
    for k in range(last):
        countdown.append(max(countdown[k] - 1, refresh(k)))
    outside = []
    for t, v in zip(speeds.times, speeds.values):
        k = round(float(t) / dt)
        if v is None or k == 0 or not (v > threshold if strict else v >= threshold):
            continue
        if not (countdown[k - 1] > 0 or refresh(k - 1) > 0):  # the model's guard on reading it at period k
            outside.append((float(t), v, modes.value_at(float(t))))
    return outside


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    out = {}
    for name, (path, overrides) in RUNS.items():
        sf = load_scenario(path, overrides)
        bb = run(sf, tmp_path_factory.mktemp(name) / "run", duration=sf.scenario.duration, seed=sf.scenario.seed)
        out[name] = (sf, bb)
    return out


def _speeds_at_changes(bb, to: set[str]) -> list[float]:
    """The highest speed read in the 0.1 s before each change of safety mode into one of ``to``."""
    modes, speeds = bb.series("robot.safety_mode"), bb.series("robot.tool_speed")
    return [max((v for u, v in zip(speeds.times, speeds.values) if t - 0.1 <= u <= t and v is not None), default=0.0)
            for t, m in zip(modes.times, modes.values) if m in to]


def test_the_runs_brake_and_slow_from_speed(runs):
    """The runs exercise what the envelope is about: a stop and a slow-down from nearly full speed."""
    assert max(_speeds_at_changes(runs["palletising_stop_at_full_speed"][1], {"srmst", "stopped"})) >= 0.85
    assert max(_speeds_at_changes(runs["welding"][1], {"ssmon", "pflim"})) >= 0.85


@pytest.mark.parametrize("name", list(RUNS))
def test_every_speed_the_twin_reads_is_one_the_abstract_model_allows(runs, name):
    sf, bb = runs[name]
    caps = _caps(sf)
    robot = sf.scenario.entities["robot"]
    envelope = SpeedEnvelope(period=0.02, braking=robot.braking_time)
    checked = 0
    for threshold in THRESHOLDS:
        for strict in (True, False):
            assert _outside(bb, envelope, caps, threshold, strict) == [], (threshold, strict)
            checked += 1
    speeds = bb.series("robot.tool_speed").values
    assert checked and max(v for v in speeds if v is not None) > 0.5  # the arm did move fast


def test_an_envelope_without_braking_would_not_cover_the_twin(runs):
    """The check has teeth: a model in which the speed falls to the new cap at once, read without lag,
    leaves the twin's readings after a stop outside it."""
    sf, bb = runs["palletising_stop_at_full_speed"]
    instant = SpeedEnvelope(period=0.02, braking=1e-6, lag=0.0, tolerance=0.0, settle=0.0)
    outside = _outside(bb, instant, _caps(sf), 0.3, True)
    assert outside and all(mode in ("srmst", "stopped") for _, _, mode in outside)
