"""verify's robot abstraction bounds the tool speed the controller reads after a change of safety
mode (``SpeedEnvelope``), and in ssmon after its monitor's speed limit falls (the limit is the
cap there); here the twin's robot is held to that bound, reading by reading.

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
MACHINE_TENDING = ROOT / "scenarios" / "machine_tending.yaml"
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
    # the operator laying out blanks beside the pedestal, 0.8 m from the scanner: in ssmon its monitor's limit falls
    # below the ssmon cap while the arm picks at the bench
    "machine_tending_limited": (MACHINE_TENDING, ["operator.waypoints.bench_south.position=[-0.45, -0.75]",
                                                  "operator.waypoints.bench_south.reach=null"]),
}


def _caps(sf) -> dict[str, float]:
    limits = sf.scenario.entities["robot"].speed_limits
    caps = {m.value: getattr(limits, m.value, 0.0) for m in SafetyMode}
    caps[SafetyMode.UNKNOWN.value] = limits.normal
    return caps


def _outside(bb, envelope: SpeedEnvelope, caps: dict[str, float], threshold: float, strict: bool) -> list:
    """The speed readings above (at or above, not ``strict``) ``threshold`` that the abstract model does
    not allow: its countdown replayed over the run's safety modes, one period at a time; in ssmon the cap
    is also the monitor's speed limit where there is one (the model's is never below it: the highest its
    formula gives in the separation's region)."""
    dt = envelope.period
    modes, speeds = bb.series("robot.safety_mode"), bb.series("robot.tool_speed")
    limits = bb.series("ssm.speed_limit") if "ssm.speed_limit" in bb.channels() else None

    def refresh(k: int) -> int:
        mode = modes.value_at(k * dt + 1e-9)
        cap = caps[mode]
        if limits is not None and mode == SafetyMode.SPEED_SEPARATION.value:
            limit = limits.value_at(k * dt + 1e-9)
            cap = min(cap, 0.0 if limit is None else limit)
        return envelope.periods(cap, threshold, strict)

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
    """The runs exercise what the envelope is about: a stop and a slow-down from nearly full speed, and in ssmon a
    limit falling below the cap while the arm moves near it."""
    assert max(_speeds_at_changes(runs["palletising_stop_at_full_speed"][1], {"srmst", "stopped"})) >= 0.85
    assert max(_speeds_at_changes(runs["welding"][1], {"ssmon", "pflim"})) >= 0.85
    bb = runs["machine_tending_limited"][1]
    limits, speeds, modes = bb.series("ssm.speed_limit"), bb.series("robot.tool_speed"), bb.series("robot.safety_mode")
    limited = [speeds.value_at(float(t)) for t, v in zip(limits.times, limits.values)
               if v is not None and v < 0.4 and modes.value_at(float(t)) == "ssmon"]
    assert limited and max(limited) > 0.3  # the arm was moving near the ssmon cap as the limit fell below it


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


def test_a_limit_below_the_monitor_s_would_not_cover_the_twin(runs):
    """The limit's check has teeth: a model that took the limit from the low end of the separation's region (here,
    0.1 m/s under the monitor's) would leave the twin's readings in ssmon outside it; the model takes the high end."""
    sf, bb = runs["machine_tending_limited"]
    robot = sf.scenario.entities["robot"]
    envelope = SpeedEnvelope(period=0.02, braking=robot.braking_time)
    limits = bb.series("ssm.speed_limit")
    lowered = type(limits)(limits.channel, limits.times, [None if v is None else max(v - 0.1, 0.0) for v in limits.values])

    class Lowered:
        def series(self, channel):
            return lowered if channel == "ssm.speed_limit" else bb.series(channel)

        def channels(self):
            return bb.channels()

    outside = [o for threshold in (0.2, 0.25, 0.3) for o in _outside(Lowered(), envelope, _caps(sf), threshold, True)]
    assert outside and all(mode == "ssmon" for _, _, mode in outside)
