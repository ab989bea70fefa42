"""The one codec of live messages (cellsim.codec), at its exact limits: what it takes, what it
refuses, and how it says so. Every receiver of the twin's network decodes through it, so each limit
here is a check a forged or broken message meets."""

from __future__ import annotations

import json
import math

import pytest

from cellsim.channels import BOOL, NO_VALUE, enum_type, number_type
from cellsim import codec
from cellsim.codec import MAX_PAYLOAD, MAX_SEQ, MAX_STAMP, CodecError, FieldCodec
from cellsim.link import REFUSALS, Fault
from cellsim.vocabulary import Range, SafetyMode

SAMPLE = FieldCodec(("range", "distance", "broken"), (enum_type(Range), number_type("m"), BOOL))
COMMAND = FieldCodec(("safety_mode_request", "speed"), (enum_type(SafetyMode), number_type("m/s")), nullable=True)


def message(**over) -> bytes:
    return json.dumps({"t": 1_800_000_000.5, "seq": 7, "fields": {"range": "near", "distance": 1.25, "broken": False},
                       **over}).encode()


def refused(payload: bytes, codec_=SAMPLE) -> CodecError:
    with pytest.raises(CodecError) as e:
        codec_.decode(payload)
    assert "\n" not in str(e.value)
    return e.value


def test_a_sample_decodes_to_its_port_codes_and_back():
    decoded = SAMPLE.decode(message())
    assert (decoded.t, decoded.seq, decoded.failure) == (1_800_000_000.5, 7, None)
    assert decoded.codes == [float(Range.NEAR.code), 1.25, 0.0]
    assert SAMPLE.fields(decoded.codes) == {"range": "near", "distance": 1.25, "broken": False}
    assert json.loads(SAMPLE.encode_codes(1.0, 2, decoded.codes)) == {
        "t": 1.0, "seq": 2, "fields": {"range": "near", "distance": 1.25, "broken": False}}
    assert SAMPLE.decode(message(fields={"range": "far", "distance": 0, "broken": True, "extra": 1})).codes == [
        float(Range.FAR.code), 0.0, 1.0]  # fields it does not know are ignored


def test_the_size_limit_is_exact():
    filler = b" " * (MAX_PAYLOAD - len(message()))
    at_limit = message()[:-1] + filler + b"}"
    assert len(at_limit) == MAX_PAYLOAD and SAMPLE.decode(at_limit).seq == 7
    over = message()[:-1] + filler + b" }"
    error = refused(over)
    assert str(error) == f"{MAX_PAYLOAD + 1} bytes, more than the {MAX_PAYLOAD} a message may have"
    assert error.kind == "too large"


@pytest.mark.parametrize("payload, why, kind", [
    (b"[" * 30_000 + b"]" * 30_000, "nested too deeply", "nested too deeply"),
    (b"{\"t\": ", "not JSON: Expecting value: line 1 column 7 (char 6)", "not JSON"),
    (b"\xff\xfe", None, "not JSON"),
    (b"[1, 2]", "not a JSON object", "not a JSON object"),
    (b"\"text\"", "not a JSON object", "not a JSON object"),
])
def test_what_is_no_json_object_is_refused_with_its_kind(payload, why, kind):
    error = refused(payload)
    assert error.kind == kind and (why is None or str(error) == why)


@pytest.mark.parametrize("t, ok", [
    (MAX_STAMP, True), (math.nextafter(MAX_STAMP, math.inf), False), (-MAX_STAMP, True), (0, True),
    (float("inf"), False), (float("nan"), False), (True, False), ("1.0", False), (None, False), (2**63, True),
    (2**63 + 1, False),
])
def test_the_time_stamp_is_a_finite_number_within_its_limit(t, ok):
    if ok and abs(t) <= MAX_STAMP:
        assert SAMPLE.decode(json.dumps({"t": t, "seq": 1, "fields": {"range": "far", "distance": 1, "broken": False}})
                             .encode()).t == float(t)
        return
    error = refused(json.dumps({"t": t, "seq": 1, "fields": {}}).encode())
    assert str(error) in ("'t' is not a number", "'t' is out of range")


@pytest.mark.parametrize("seq, ok", [(0, True), (MAX_SEQ, True), (MAX_SEQ + 1, False), (-1, False), (True, False),
                                     (1.0, False), ("1", False), (None, False)])
def test_the_sequence_is_a_count_up_to_its_limit(seq, ok):
    payload = message(seq=seq)
    if ok:
        assert SAMPLE.decode(payload).seq == seq
    else:
        assert str(refused(payload)) == "'seq' is not a count"


@pytest.mark.parametrize("fields, why", [
    ({"range": "nearby", "distance": 1.0, "broken": False}, "field 'range': 'nearby' is not ['far', 'near', 'close']"),
    ({"range": 1, "distance": 1.0, "broken": False}, "field 'range': 1 is not ['far', 'near', 'close']"),
    ({"range": "far", "distance": "1.0", "broken": False}, "field 'distance': '1.0' is not number"),
    ({"range": "far", "distance": True, "broken": False}, "field 'distance': True is not number"),
    ({"range": "far", "distance": 1e9 + 1, "broken": False}, "field 'distance': 1000000001.0 is not number"),
    ({"range": "far", "distance": 1.0, "broken": 1}, "field 'broken': 1 is not bool"),
    ({"range": "far", "distance": 1.0, "broken": None}, "field 'broken': None is not bool"),
    ({"range": "far", "broken": False}, "field 'distance' is missing"),
    ([], "'fields' is not an object"),
])
def test_a_field_of_the_wrong_kind_is_refused_naming_the_field(fields, why):
    error = refused(message(fields=fields))
    assert str(error) == why
    if str(error).startswith("field '") and "missing" not in why:
        assert error.kind.endswith("of the wrong kind")  # one kind per field, whatever value it carried


def test_numbers_are_taken_up_to_their_limit_of_a_billion():
    at = SAMPLE.decode(message(fields={"range": "far", "distance": 1e9, "broken": False}))
    assert at.codes[1] == 1e9
    assert SAMPLE.decode(message(fields={"range": "far", "distance": -1e9, "broken": False})).codes[1] == -1e9


def test_a_null_field_is_no_request_only_where_fields_may_be_null():
    command = COMMAND.decode(json.dumps({"t": 1.0, "seq": 1, "fields": {"safety_mode_request": None, "speed": None}}).encode())
    assert command.codes == [NO_VALUE, NO_VALUE]
    # an enumeration's no-request reads back as null; a number's stays its code (a pose index of -1: none)
    assert COMMAND.fields(command.codes) == {"safety_mode_request": None, "speed": NO_VALUE}
    assert COMMAND.fields([float(SafetyMode.SPEED_SEPARATION.code), 0.5]) == {"safety_mode_request": "ssmon", "speed": 0.5}
    assert str(refused(message(fields={"range": None, "distance": 1.0, "broken": False}))) == (
        "field 'range': None is not ['far', 'near', 'close']")


def test_a_failure_message_names_the_fault_that_failed_the_link_and_nothing_else():
    for fault in Fault:
        if fault in REFUSALS:  # a refused message fails no link: no failure message says it
            with pytest.raises(ValueError, match="not a link failure"):
                codec.encode_failure(1.0, 1, fault)
            continue
        decoded = SAMPLE.decode(codec.encode_failure(5.0, 3, fault))
        assert (decoded.t, decoded.seq, decoded.failure, decoded.codes) == (5.0, 3, fault, None)
        assert json.loads(codec.encode_failure(5.0, 3, fault))["failed"] == fault.value
    assert str(refused(json.dumps({"t": 1.0, "seq": 1, "failed": "stale"}).encode())) == (
        "'failed' is not one of " + ", ".join(f.value for f in Fault if f not in REFUSALS))
    with pytest.raises(ValueError, match="not a link failure"):
        codec.encode_failure(1.0, 1, "ok")


def test_twin_values_mode_requests_and_answers():
    assert codec.decode_value(codec.encode_value(1.0, 2.123456789, "ssmon")) == (2.123457, "ssmon")
    assert codec.decode_value(b'{"value": 3}') == (None, 3)
    with pytest.raises(CodecError, match="'sim_time' is out of range"):
        codec.decode_value(b'{"sim_time": 1e13, "value": 3}')
    assert codec.decode_mode_request(codec.encode_mode_request("robot", "shadow", "me")) == ("robot", "shadow", "me")
    assert codec.decode_mode_request(None) == (None, None, "unknown")
    assert codec.decode_mode_request(json.dumps({"by": "x" * 500}).encode())[2] == "x" * 200
    assert codec.decode_answer(codec.encode_answer(True, "done")) == {"accepted": True, "reason": "done"}
    assert codec.decode_answer(b'{"accepted": 1}') == {"accepted": False, "reason": ""}  # only true is true
    assert codec.decode_answer(b"[") == {"accepted": False, "reason": "the answer was malformed"}
    assert json.loads(codec.encode_record([1, None])) == {"value": [1, None]}


def test_a_refusal_quotes_at_most_forty_characters_of_what_it_received():
    assert codec.shown("x" * 38) == repr("x" * 38)  # 40 characters with its quotes: whole
    assert codec.shown("x" * 39) == repr("x" * 39)[:37] + "..."
    long = str(refused(message(fields={"range": "y" * 1000, "distance": 1.0, "broken": False})))
    assert long == "field 'range': '" + "y" * 36 + "... is not ['far', 'near', 'close']"


def test_the_codec_of_an_entity_follows_its_channels_and_inputs():
    from types import SimpleNamespace

    spec = SimpleNamespace(signal="range", type=enum_type(Range))
    entity = SimpleNamespace(sample_fields=("range", "distance"), channels=[(spec, None)],
                             command_fields=("speed",), input_types={})
    samples = FieldCodec.samples_of(entity)
    assert samples.names == ("range", "distance") and samples.types[0].kind == "enum"
    assert samples.types[1].kind == "number" and not samples.nullable
    commands = FieldCodec.commands_of(entity)
    assert commands.names == ("speed",) and commands.types[0].kind == "number" and commands.nullable


def test_a_json_error_is_quoted_to_eighty_characters():
    payload = b'{"' + b"a" * 60_000 + b'": 1,}'
    why = "Expecting property name enclosed in double quotes: line 1 column 60008 (char 60007)"
    assert len(why) > 80
    assert str(refused(payload)) == "not JSON: " + why[:80]


def test_messages_are_compact_json_with_their_documented_keys():
    assert codec.encode_fields(1.5, 2, {"a": 1}) == b'{"t":1.5,"seq":2,"fields":{"a":1}}'
    assert codec.encode_failure(1.5, 3, Fault.TIMEOUT) == b'{"t":1.5,"seq":3,"failed":"timeout"}'
    assert codec.encode_value(1.5, 2.25, True) == b'{"t":1.5,"sim_time":2.25,"value":true}'
    assert codec.encode_mode_request("robot", "twin", "me") == b'{"entity":"robot","mode":"twin","by":"me"}'
    assert codec.encode_answer(False, "no") == b'{"accepted":false,"reason":"no"}'


def test_whole_numbers_are_numbers_up_to_the_limits_and_huge_ones_are_refused_not_overflowed():
    fields = lambda d: {"range": "far", "distance": d, "broken": False}  # noqa: E731
    assert SAMPLE.decode(message(fields=fields(1000))).codes[1] == 1000.0
    assert SAMPLE.decode(message(fields=fields(-1_000_000_000))).codes[1] == -1e9
    for huge in (2**63, 10**400):  # a float() of 10**400 would overflow: refused before
        assert str(refused(message(fields=fields(huge)))).startswith("field 'distance':")
    assert str(refused(json.dumps({"t": 10**400, "seq": 1, "fields": {}}).encode())) == "'t' is out of range"


def test_an_entity_without_channels_has_number_fields_and_a_subset_of_commands_keeps_its_order():
    from types import SimpleNamespace

    bare = SimpleNamespace(sample_fields=("x", "y"))
    assert [t.kind for t in FieldCodec.samples_of(bare).types] == ["number", "number"]
    entity = SimpleNamespace(command_fields=("a", "b", "c"), input_types={"b": BOOL})
    some = FieldCodec.commands_of(entity, names=("c", "b"))
    assert some.names == ("c", "b") and [t.kind for t in some.types] == ["number", "bool"]
