"""The one encoding of every live message: UTF-8 JSON objects.

A physical sample or a command::

    {"t": 1795000000.125, "seq": 42, "fields": {"safety_mode": "normal", "q0": 1.3576, ...}}

``t`` is the sender's wall-clock time (UNIX seconds) when the sample was taken,
``seq`` counts the sender's messages on that key (a repeat or an older message
is dropped), ``fields`` names each field as ``cellsim modules KIND`` lists it
(physical-sample fields, command fields), enums by name, booleans as true/false,
numbers in SI units; a command field with no request is null.

A physical link that failed (the bridge daemon's checks refused its physical twin's
data, or its watchdog expired) is said with a failure in place of the fields, so the
entity fails safe at once instead of after its ``stale_after``::

    {"t": 1795000000.125, "seq": 43, "failed": "stale"}     # or "corrupt"

A twin channel's value: ``{"t": ..., "sim_time": ..., "value": ...}``, the value as
the black box writes it.
"""

from __future__ import annotations

import json
import math

from cellsim.channels import ChannelType, number_type


class CodecError(ValueError):
    """A message that is not what its key carries (the reason is one line)."""


def field_types(entity) -> list[ChannelType]:
    """The type of each physical-sample field of an entity: its channel of that name, else a number."""
    by_signal = {spec.signal: spec.type for spec, _ in getattr(entity, "channels", [])}
    return [
        by_signal[name] if name in by_signal and by_signal[name].kind in ("enum", "bool") else number_type(None)
        for name in entity.sample_fields
    ]


def encode_fields(t: float, seq: int, fields: dict) -> bytes:
    return json.dumps({"t": t, "seq": seq, "fields": fields}, separators=(",", ":")).encode()


FAILURES = ("stale", "corrupt")
"""What a failure message may say of a physical link (``PhysicalLink`` values)."""


def encode_failure(t: float, seq: int, failure: str) -> bytes:
    """The message saying the physical link failed (``failure``: one of FAILURES)."""
    assert failure in FAILURES
    return json.dumps({"t": t, "seq": seq, "failed": failure}, separators=(",", ":")).encode()


def decode_sample(payload: bytes, names: tuple[str, ...], types: list[ChannelType]) -> tuple[float, int, str | None, list[float]]:
    """(wall time, sequence number, failure or None, the fields as port codes) of a sample or a
    failure message (whose codes are NaN), or CodecError."""
    message = _object(payload)
    failure = message.get("failed")
    if failure is None:
        t, seq, codes = decode_fields(payload, names, types, message)
        return t, seq, None, codes
    if failure not in FAILURES:
        raise CodecError(f"'failed' is not one of {', '.join(FAILURES)}")
    t, seq = _stamp(message)
    return t, seq, failure, [math.nan] * len(names)


def _object(payload: bytes) -> dict:
    try:
        message = json.loads(payload)
    except (ValueError, UnicodeDecodeError) as e:
        raise CodecError(f"not JSON: {e}") from None
    if not isinstance(message, dict):
        raise CodecError("not a JSON object")
    return message


def _stamp(message: dict) -> tuple[float, int]:
    t, seq = message.get("t"), message.get("seq")
    if not isinstance(t, (int, float)) or isinstance(t, bool) or not math.isfinite(t):
        raise CodecError("'t' is not a time")
    if not isinstance(seq, int) or isinstance(seq, bool) or seq < 0:
        raise CodecError("'seq' is not a count")
    return float(t), seq


def decode_fields(payload: bytes, names: tuple[str, ...], types: list[ChannelType],
                  message: dict | None = None) -> tuple[float, int, list[float]]:
    """(wall time, sequence number, the fields as port codes) of a sample message, or CodecError."""
    if message is None:
        message = _object(payload)
    t, seq = _stamp(message)
    fields = message.get("fields")
    if not isinstance(fields, dict):
        raise CodecError("'fields' is not an object")
    codes = []
    for name, ctype in zip(names, types):
        if name not in fields:
            raise CodecError(f"field '{name}' is missing")
        value = fields[name]
        try:
            if ctype.kind == "bool":
                if not isinstance(value, bool):
                    raise ValueError
                codes.append(1.0 if value else 0.0)
            elif ctype.kind == "enum":
                codes.append(float(ctype.encode(value)[0]))
            else:
                if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
                    raise ValueError
                codes.append(float(value))
        except (ValueError, KeyError, TypeError):
            raise CodecError(f"field '{name}': {value!r} is not {ctype.domain() if ctype.kind == 'enum' else ctype.kind}") from None
    return float(t), seq, codes


def fields_of(names: tuple[str, ...], types: list[ChannelType], codes) -> dict:
    """The JSON fields of port codes (inverse of ``decode_fields``)."""
    return {name: ctype.decode([code]) for name, ctype, code in zip(names, types, codes)}


def decode_command(payload: bytes, names: list[str], types: list[ChannelType]) -> tuple[float, list[float]]:
    """(wall time, the named command fields as input codes) of a command message; a null
    field is "no request" (-1). Fields a receiver does not take are ignored."""
    from cellsim.channels import NO_VALUE

    try:
        message = json.loads(payload)
    except (ValueError, UnicodeDecodeError) as e:
        raise CodecError(f"not JSON: {e}") from None
    if not isinstance(message, dict) or not isinstance(message.get("fields"), dict):
        raise CodecError("not a command object")
    t = message.get("t")
    if not isinstance(t, (int, float)) or isinstance(t, bool) or not math.isfinite(t):
        raise CodecError("'t' is not a time")
    codes = []
    for name, ctype in zip(names, types):
        if name not in message["fields"]:
            raise CodecError(f"field '{name}' is missing")
        value = message["fields"][name]
        try:
            if value is None:
                codes.append(NO_VALUE)
            elif ctype.kind == "enum":
                codes.append(float(ctype.encode(value)[0]))
            elif ctype.kind == "bool":
                codes.append(1.0 if value is True else 0.0 if value is False else float("nan"))
            else:
                codes.append(float(value))
        except (ValueError, KeyError, TypeError):
            raise CodecError(f"field '{name}': {value!r} is not {ctype.domain()}") from None
        if not math.isfinite(codes[-1]):
            raise CodecError(f"field '{name}': {value!r} is not {ctype.domain()}")
    return float(t), codes
