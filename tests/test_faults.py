"""The emulator's fault grammar (cellsim.live.faults): ``--fault ENTITY=KIND[@T0[-T1]]``, ``--rate ENTITY=HZ``
and which fault applies where. The messages as the user sees them (exit 2, one line) are
the CLI tests' (tests/test_live.py, tests/test_bridge.py); here, the grammar itself."""

from __future__ import annotations

import math

import pytest
from conftest import ROOT

from cellsim.cell_io import Fault
from cellsim.live.faults import (ALL_FAULTS, BUS_FAULTS, ZENOH_FAULTS, FaultError, check_entities, check_faults, parse_fault,
                                 parse_rate)

ENTITIES = ("robot", "welder", "light_barrier", "range_detector", "operator")
"""The welding cell's entities, in the scenario's order."""

EXPECTED = ("expected ENTITY=KIND[@T0[-T1]] (seconds, T0 < T1) with KIND one of "
            "silence, freeze, corrupt, delay, replay, drop, crc, length, flood")


def can_devices() -> set[str]:
    from cellsim.bridges.config import load_bridge

    return set(load_bridge(ROOT / "bridges" / "welding_cell.yaml").config.devices)


def test_every_kind_of_every_outlet_is_a_fault_zenoh_s_first():
    assert ALL_FAULTS == ("silence", "freeze", "corrupt", "delay", "replay", "drop", "crc", "length", "flood")
    assert set(ALL_FAULTS) == set(ZENOH_FAULTS) | set(BUS_FAULTS)


@pytest.mark.parametrize("text, fault", [
    ("robot=silence", Fault("robot", "silence", 0.0, math.inf)),
    ("robot=freeze@2", Fault("robot", "freeze", 2.0, math.inf)),
    ("robot=freeze@2-", Fault("robot", "freeze", 2.0, math.inf)),
    ("welder=crc@3-5", Fault("welder", "crc", 3.0, 5.0)),
    ("light_barrier=corrupt@0.5-1.25", Fault("light_barrier", "corrupt", 0.5, 1.25)),
    ("robot=delay@0-0.001", Fault("robot", "delay", 0.0, 0.001)),
    ("welder=flood", Fault("welder", "flood", 0.0, math.inf)),  # a bus fault parses: whether it applies is checked later
])
def test_a_fault_is_an_entity_a_kind_and_a_window_of_simulated_time(text, fault):
    assert parse_fault(text) == fault


@pytest.mark.parametrize("text", [
    "robot=melt",             # no such kind
    "robot=Silence",          # kinds are lower case
    "robot",                  # no kind
    "robot=",                 # an empty kind
    "=silence",               # no entity
    "robot=silence@5-2",      # T0 after T1
    "robot=silence@1-1",      # an empty window
    "robot=silence@x",        # not a number
    "robot=silence@1-x",
    "robot=silence@1-2-3",
    "robot=silence@nan",
    "robot=silence@inf",
    "robot=silence@1e-3",     # '-' separates T0 from T1: no exponents
])
def test_a_malformed_fault_is_one_line_naming_it_and_the_grammar(text):
    with pytest.raises(FaultError) as caught:
        parse_fault(text)
    assert str(caught.value) == f"--fault {text!r}: {EXPECTED}"
    assert isinstance(caught.value, ValueError)


@pytest.mark.parametrize("text, rate", [
    ("robot=500", ("robot", 500.0)), ("robot=0.1", ("robot", 0.1)), ("light_barrier=1000", ("light_barrier", 1000.0)),
])
def test_a_rate_is_an_entity_and_samples_per_second(text, rate):
    assert parse_rate(text) == rate


@pytest.mark.parametrize("text", ["robot=0", "robot=0.09", "robot=1000.5", "robot=-5", "robot=x", "robot=", "robot",
                                  "=500", "robot=nan", "robot=inf"])
def test_a_malformed_rate_is_one_line_naming_it_and_the_range(text):
    with pytest.raises(FaultError) as caught:
        parse_rate(text)
    assert str(caught.value) == f"--rate {text!r}: expected ENTITY=HZ with HZ from 0.1 to 1000"


def _mode_lags(sf, out) -> list[float]:
    """Simulated 15 s of the cell: for each change of the controller's safety-mode request, how long the robot took
    to be in that mode (s), read from the black box with plain SQL."""
    import sqlite3

    import cellsim

    cellsim.simulate(sf, out, duration=15.0, check=False)
    db = sqlite3.connect(out / "blackbox.sqlite")
    try:
        rows = db.execute("SELECT t, channel, payload FROM messages WHERE channel IN "
                          "('safety_controller.safmod', 'robot.safety_mode') AND t > 0 ORDER BY t, rowid").fetchall()
    finally:
        db.close()
    asked = [(t, p) for t, c, p in rows if c == "safety_controller.safmod"]
    taken = [(t, p) for t, c, p in rows if c == "robot.safety_mode"]
    assert len(asked) == len(taken) >= 2
    return [round(t1 - t0, 6) for (t0, p0), (t1, p1) in zip(asked, taken) if p0 == p1]


def test_a_device_given_a_faster_rate_is_emulated_at_it_and_takes_a_command_at_its_next_cycle(tmp_path):
    """``emulate --rate robot=500``: the emulated robot works at its controller's 2 ms cycle as well as publishing at
    it, so it takes a safety-mode request one plant step after it is made, where the scenario's robot (20 ms) takes it
    at its next update; a rate slower than an entity's period changes only how often it publishes."""
    from cellsim.cli.emulate import _devices_at_their_rates
    from cellsim.scenario import load_scenario

    welding = ROOT / "scenarios" / "welding_cell.yaml"
    scenario = load_scenario(welding, [])
    curtain = scenario.scenario.entities["light_barrier"].period
    assert set(_mode_lags(scenario, tmp_path / "scenario")) == {0.02}
    emulated = load_scenario(welding, [])
    _devices_at_their_rates(emulated, {"robot": 500.0, "light_barrier": 1.0})
    assert emulated.scenario.entities["robot"].period == pytest.approx(0.002)
    assert emulated.scenario.entities["light_barrier"].period == curtain
    assert set(_mode_lags(emulated, tmp_path / "emulated")) == {0.002}


def test_zenoh_faults_apply_to_every_entity_without_a_bus():
    check_faults([parse_fault(f"{e}={k}") for e in ENTITIES for k in ZENOH_FAULTS], ENTITIES, None)


def test_a_bus_fault_without_can_is_refused():
    faults = [parse_fault("robot=silence"), parse_fault("welder=flood"), parse_fault("robot=drop")]
    with pytest.raises(FaultError) as caught:
        check_faults(faults, ENTITIES, None)
    assert str(caught.value) == "--fault welder=flood: a bus fault needs --can; on Zenoh: silence, freeze, corrupt, delay, replay"


def test_with_can_a_device_has_the_bus_faults_and_the_others_the_zenoh_faults():
    devices = can_devices()
    faults = [parse_fault(f"{e}={k}") for e in ENTITIES for k in (BUS_FAULTS if e in devices else ZENOH_FAULTS)]
    check_faults(faults, ENTITIES, devices)


def test_with_can_a_zenoh_fault_on_a_can_device_is_refused():
    with pytest.raises(FaultError) as caught:
        check_faults([parse_fault("welder=freeze")], ENTITIES, can_devices())
    assert str(caught.value) == "--fault welder=freeze: welder is a CAN device; its faults: drop, crc, replay, length, flood, delay"


def test_with_can_a_bus_fault_on_an_entity_on_zenoh_is_refused():
    with pytest.raises(FaultError) as caught:
        check_faults([parse_fault("robot=silence"), parse_fault("robot=crc")], ENTITIES, can_devices())
    assert str(caught.value) == "--fault robot=crc: robot is on Zenoh; its faults: silence, freeze, corrupt, delay, replay"


def test_a_fault_on_an_unknown_entity_is_refused_naming_the_entities():
    with pytest.raises(FaultError) as caught:
        check_faults([parse_fault("robto=drop")], ENTITIES, can_devices())  # the entity first, then its kinds
    assert str(caught.value) == ("--fault/--rate: no entity named 'robto' "
                                 "(entities: robot, welder, light_barrier, range_detector, operator)")


def test_faults_name_an_unknown_entity_before_rates_do():
    with pytest.raises(FaultError, match="no entity named 'rob' "):
        check_entities([parse_fault("rob=silence")], {"robto": 5.0}, ENTITIES)
    with pytest.raises(FaultError, match="no entity named 'robto' "):
        check_entities([parse_fault("robot=silence")], {"robto": 5.0}, ENTITIES)
    check_entities([parse_fault("robot=silence")], {"robot": 500.0}, ENTITIES)


def test_a_freeze_or_a_replay_sends_an_old_message_or_none_never_a_fresh_one():
    """An audit found the emulator's replay fault sent good, new samples until 50 had been sent (a fault early in a
    run was no fault at all), and a freeze before any sample did the same."""
    from cellsim.live.emulator import REPLAYED, ZenohOutlet

    sent = []
    outlet = ZenohOutlet(type("P", (), {"put": lambda self, payload: sent.append(payload)})())
    assert outlet.send({"broken": False}, "replay", 0.0) == 0 and outlet.send({"broken": False}, "freeze", 0.0) == 0
    for k in range(3):
        outlet.send({"broken": k % 2 == 1}, None, 0.04 * k)
    fresh = list(sent)
    assert outlet.send({"broken": True}, "replay", 0.2) == 1 and sent[-1] == fresh[0]  # the oldest kept: fewer than 50
    assert outlet.send({"broken": True}, "freeze", 0.24) == 1 and sent[-1] == fresh[-1]
    for k in range(60):
        outlet.send({"broken": False}, None, 0.3 + 0.04 * k)
    outlet.send({"broken": True}, "replay", 3.0)
    assert sent[-1] == outlet.history[-REPLAYED] and outlet.seq == 63  # (no fault made a new message)
