"""The one conversion between an entity's fields and a DBC message's signals (cellsim.bridges.signals),
on the welding cell's own DBC, decoded back with cantools (the library the frames are read with)."""

from __future__ import annotations

import math
from pathlib import Path

import cantools
import pytest

from cellsim.bridges.config import load_bridge
from cellsim.bridges.e2e import protect
from cellsim.bridges.signals import NONE, SignalMap, Unsendable
from cellsim.channels import BOOL, enum_type, number_type

ROOT = Path(__file__).resolve().parents[1]
DBC = cantools.database.load_file(str(ROOT / "bridges" / "welding_cell.dbc"))


def _scanner():
    return SignalMap.of_device(DBC.get_message_by_name("ScannerState"), {"range": "Range", "distance": "Distance"},
                               {"range": enum_type(["far", "near", "close"]), "distance": number_type("m")})


def _round_trip(signals: SignalMap, fields: dict) -> dict:
    message = signals.message
    data = protect(message, signals.signals(fields), 0)
    return signals.fields(message.decode(data, decode_choices=False))


def test_a_sample_frame_carries_its_fields_and_gives_them_back_typed():
    scanner = _scanner()
    back = _round_trip(scanner, {"range": "near", "distance": 1.234})
    assert back == {"range": "near", "distance": pytest.approx(1.234, abs=1e-3)}
    assert isinstance(back["distance"], float)


def test_a_sample_beyond_its_signal_is_sent_as_the_range_end_and_no_number_is_not_sent():
    scanner = _scanner()
    assert scanner.signals({"range": "far", "distance": math.inf})["Distance"] == 60.0
    assert scanner.signals({"range": "far", "distance": 75.0})["Distance"] == 60.0
    assert scanner.signals({"range": "far", "distance": -1.0})["Distance"] == 0.0
    with pytest.raises(Unsendable, match="Distance"):
        scanner.signals({"range": "far", "distance": math.nan})
    with pytest.raises(Unsendable, match="Range"):
        scanner.signals({"range": "nowhere", "distance": 1.0})
    with pytest.raises(ValueError, match="no safe command"):
        scanner.safe_signals()


def test_a_boolean_field_is_a_bit_and_comes_back_a_bool():
    curtain = SignalMap.of_device(DBC.get_message_by_name("LightCurtainState"), {"broken": "Broken"}, {"broken": BOOL})
    assert curtain.signals({"broken": True}) == {"Broken": 1}
    assert _round_trip(curtain, {"broken": True}) == {"broken": True}
    assert _round_trip(curtain, {"broken": False}) == {"broken": False}


def test_a_command_the_frame_cannot_carry_is_sent_as_the_safe_command_never_bent_into_another():
    message = DBC.get_message_by_name("WelderCommand")
    safe = {"activity_request": "off", "command": 0.0}
    command = SignalMap.of_command(message, {"ActivityRequest": "activity_request", "Weld": "command"}, safe)
    assert command.safe_signals() == {"ActivityRequest": "off", "Weld": 0.0}
    assert command.signals({"activity_request": "welding", "command": 1.0}) == {"ActivityRequest": "welding", "Weld": 1.0}
    assert command.signals({}) == command.safe_signals()  # nothing commanded yet
    assert command.signals({"activity_request": "melting", "command": 7.0}) == command.safe_signals()
    assert command.signals({"activity_request": "welding", "command": math.nan})["Weld"] == 0.0
    assert command.signals({"activity_request": None, "command": 1.0})["ActivityRequest"] == NONE


def test_a_null_command_field_travels_as_none_where_the_signal_can_say_it_else_as_the_safe_command():
    welder = SignalMap.of_command(DBC.get_message_by_name("WelderCommand"),
                                  {"ActivityRequest": "activity_request", "Weld": "command"},
                                  {"activity_request": "off", "command": 0.0})
    assert _round_trip(welder, {"activity_request": None, "command": 1.0}) == {"activity_request": None, "command": 1.0}
    request = SignalMap.of_command(DBC.get_message_by_name("SafetyModeRequest"), {"SafetyMode": "safety_mode_request"},
                                   {"safety_mode_request": "stopped"})
    assert _round_trip(request, {"safety_mode_request": None}) == {"safety_mode_request": "stopped"}
    assert _round_trip(request, {"safety_mode_request": "normal"}) == {"safety_mode_request": "normal"}


def test_the_bridge_gives_every_mapped_frame_one_signal_map():
    loaded = load_bridge(ROOT / "bridges" / "welding_cell.yaml")
    cfg = loaded.config
    assert set(loaded.frames) == {m.message for _, m in loaded.mappings()}
    for mapping in cfg.devices.values():
        assert loaded.signals(mapping).safe is None
    for entity, mappings in cfg.commands.items():
        for mapping in mappings:
            assert set(loaded.signals(mapping).safe_signals()) == set(mapping.fields)


UNBOUNDED = cantools.database.load_string('''VERSION ""
BU_: Device Bridge
BO_ 100 Level: 4 Device
 SG_ Crc : 0|8@1+ (1,0) [0|255] "" Bridge
 SG_ Counter : 8|4@1+ (1,0) [0|15] "" Bridge
 SG_ Level : 16|16@1- (0.01,0) [0|0] "m" Bridge
''', database_format="dbc").get_message_by_name("Level")
"""A message whose signal has no range ([0|0]: cantools gives it no minimum and no maximum)."""


def test_types_decide_what_comes_back_a_boolean_is_a_bool_not_a_number():
    curtain = SignalMap.of_device(DBC.get_message_by_name("LightCurtainState"), {"broken": "Broken"}, {"broken": BOOL})
    back = _round_trip(curtain, {"broken": True})["broken"]
    assert back is True  # (1.0 == True: compare identity)
    untyped = SignalMap.of_device(DBC.get_message_by_name("LightCurtainState"), {"broken": "Broken"})
    assert type(_round_trip(untyped, {"broken": True})["broken"]) is float  # no type given: a number
    reset = SignalMap.of_command(DBC.get_message_by_name("LightCurtainState"), {"Broken": "reset"}, {"reset": False},
                                 {"reset": BOOL})
    assert _round_trip(reset, {"reset": True})["reset"] is True


def test_a_safe_command_with_no_request_is_the_signals_none():
    welder = SignalMap.of_command(DBC.get_message_by_name("WelderCommand"),
                                  {"ActivityRequest": "activity_request", "Weld": "command"},
                                  {"activity_request": None, "command": 0.0})
    assert welder.safe_signals() == {"ActivityRequest": NONE, "Weld": 0.0}


def test_a_value_that_is_no_number_is_refused_for_a_sample_and_replaced_by_the_safe_value_for_a_command():
    scanner = _scanner()
    with pytest.raises(Unsendable, match="is not a number"):
        scanner.signals({"range": "far", "distance": "near"})
    with pytest.raises(Unsendable, match=r"\(far, near, close\)"):  # the values it may take, named
        scanner.signals({"range": "nowhere", "distance": 1.0})
    distance = SignalMap.of_command(DBC.get_message_by_name("ScannerState"), {"Distance": "limit"}, {"limit": 30.0})
    assert distance.signals({"limit": "far"}) == {"Distance": 30.0}
    assert distance.signals({"limit": None}) == {"Distance": 30.0}
    # the ends of the signal's range are commands it can carry
    assert distance.signals({"limit": 0.0}) == {"Distance": 0.0}
    assert distance.signals({"limit": 60.0}) == {"Distance": 60.0}
    assert distance.signals({"limit": 60.001}) == {"Distance": 30.0}


def test_a_signal_without_a_range_takes_any_finite_number_and_no_infinity():
    level = SignalMap.of_device(UNBOUNDED, {"level": "Level"})
    assert level.signals({"level": -250.0}) == {"Level": -250.0}
    assert level.signals({"level": 250.0}) == {"Level": 250.0}
    for endless in (math.inf, -math.inf):  # no range end to send it as
        with pytest.raises(Unsendable, match="Level"):
            level.signals({"level": endless})
    command = SignalMap.of_command(UNBOUNDED, {"Level": "level"}, {"level": 0.5})
    assert command.signals({"level": -250.0}) == {"Level": -250.0}
    assert command.signals({"level": 250.0}) == {"Level": 250.0}
    assert command.signals({"level": math.inf}) == {"Level": 0.5} and command.signals({"level": -math.inf}) == {"Level": 0.5}
