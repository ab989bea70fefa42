"""The one encoding of every live message: UTF-8 JSON objects, typed by ``ChannelType``.

A physical sample or a command::

    {"t": 1795000000.125, "seq": 42, "fields": {"safety_mode": "normal", "q0": 1.3576, ...}}

``t`` is the sender's wall-clock time (UNIX seconds) when the sample was taken,
``seq`` counts the sender's messages on that key, ``fields`` names each field as
``cellsim modules KIND`` lists it (physical-sample fields, command fields), enums
by name, booleans as true/false, numbers in SI units; a command field with no
request is null. The receiver judges freshness and order (``cellsim.link``).

A physical link that failed (the bridge daemon's checks refused its physical twin's
data, or its watchdog expired) is said with a failure in place of the fields, so the
entity fails safe at once instead of after its ``stale_after``::

    {"t": 1795000000.125, "seq": 43, "failed": "crc"}     # the fault, as cellsim.link.Fault names it

A twin channel's value: ``{"t": ..., "sim_time": ..., "value": ...}``, the value as
the black box writes it (``ChannelType.decode``). A twin-mode request:
``{"entity": ..., "mode": ..., "by": ...}``, answered ``{"accepted": ..., "reason": ...}``.

:class:`FieldCodec` is the codec of one entity's sample or command fields: the
twin, the emulator, the bridge daemon and the dashboard all use it, so a value
crosses between its name (the network) and its port code (the diagram) here only.
Every message is checked before it touches state: at most ``MAX_PAYLOAD`` bytes,
an object, numbers finite and of sane size, enums among their values.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

from cellsim.channels import NO_VALUE, ChannelType, number_type
from cellsim.link import LINK_FAILURES, Fault

MAX_PAYLOAD = 64 * 1024
"""The largest message (bytes) any receiver decodes: a sample of a few dozen fields is well under 2 kB."""
MAX_STAMP = 1e12
"""Time stamps beyond this (s) are not times (UNIX time is about 1.8e9)."""
MAX_SEQ = 2**53
"""Sequence numbers beyond this are not counts a sender reaches."""
FAILURES = tuple(f.value for f in LINK_FAILURES)
"""What a failure message may say of a physical link: the fault that failed it (``cellsim.link.Fault``)."""


class CodecError(ValueError):
    """A message that is not what its key carries (the reason is one line; ``kind``, the reason without
    the message's own values, names the kind of refusal)."""

    def __init__(self, why: str, kind: str | None = None):
        super().__init__(why)
        self.kind = kind or why


@dataclass(frozen=True)
class Message:
    """A decoded sample, command or failure message."""

    t: float
    """The sender's wall-clock stamp (s)."""
    seq: int
    failure: Fault | None
    """The fault that failed the link, for a failure message; else None."""
    codes: list[float] | None
    """The fields as port codes (None for a failure)."""


def loads(payload: bytes, limit: int = MAX_PAYLOAD) -> dict:
    """A JSON object of at most ``limit`` bytes, or CodecError (never a crash on depth or size)."""
    if len(payload) > limit:
        raise CodecError(f"{len(payload)} bytes, more than the {limit} a message may have", "too large")
    try:
        message = json.loads(payload)
    except RecursionError:
        raise CodecError("nested too deeply") from None
    except (ValueError, UnicodeDecodeError) as e:
        raise CodecError(f"not JSON: {' '.join(str(e).split())[:80]}", "not JSON") from None
    if not isinstance(message, dict):
        raise CodecError("not a JSON object")
    return message


def dumps(message: dict) -> bytes:
    return json.dumps(message, separators=(",", ":")).encode()


def number(value, what: str, limit: float = math.inf) -> float:
    """A finite JSON number (not a boolean) within +/- ``limit``, as a float, or CodecError."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CodecError(f"{what} is not a number")
    if isinstance(value, int) and abs(value) > 2**63:
        raise CodecError(f"{what} is out of range")
    value = float(value)
    if not math.isfinite(value) or abs(value) > limit:
        raise CodecError(f"{what} is out of range")
    return value


@dataclass(frozen=True)
class FieldCodec:
    """The named, typed fields of one kind of message (an entity's samples, or its commands)."""

    names: tuple[str, ...]
    types: tuple[ChannelType, ...]
    nullable: bool = False
    """A null field means "no request" (commands)."""

    @classmethod
    def samples_of(cls, entity) -> "FieldCodec":
        """An entity's physical-sample fields: each typed as its channel of that name (enums and
        booleans), else a number."""
        by_signal = {spec.signal: spec.type for spec, _ in getattr(entity, "channels", [])}
        types = tuple(
            by_signal[name] if name in by_signal and by_signal[name].kind in ("enum", "bool") else number_type(None)
            for name in entity.sample_fields
        )
        return cls(tuple(entity.sample_fields), types)

    @classmethod
    def commands_of(cls, entity, names=None) -> "FieldCodec":
        """An entity's command fields (or the ``names`` among them), typed as its inputs of those names."""
        names = tuple(entity.command_fields if names is None else names)
        types = tuple(entity.input_types.get(name, number_type(None)) for name in names)
        return cls(names, types, nullable=True)

    # -- values <-> port codes ----------------------------------------------------------
    def code(self, name: str, ctype: ChannelType, value) -> float:
        """One field's port code, or CodecError naming the field."""
        try:
            if value is None:
                if self.nullable:
                    return NO_VALUE
                raise ValueError
            if ctype.kind == "bool":
                if not isinstance(value, bool):
                    raise ValueError
                return 1.0 if value else 0.0
            if ctype.kind == "enum":
                if not isinstance(value, str):
                    raise ValueError
                return float(ctype.encode(value)[0])
            return number(value, f"field '{name}'", 1e9)
        except (ValueError, KeyError, TypeError):
            expected = ctype.domain() if ctype.kind == "enum" else ctype.kind
            raise CodecError(f"field '{name}': {shown(value)} is not {expected}", f"field '{name}' of the wrong kind") from None

    def codes(self, fields: dict) -> list[float]:
        """The port codes of a message's ``fields`` (every field present; others ignored)."""
        if not isinstance(fields, dict):
            raise CodecError("'fields' is not an object")
        codes = []
        for name, ctype in zip(self.names, self.types):
            if name not in fields:
                raise CodecError(f"field '{name}' is missing")
            codes.append(self.code(name, ctype, fields[name]))
        return codes

    def fields(self, codes) -> dict:
        """The message fields of port codes (inverse of :meth:`codes`)."""
        out = {}
        for name, ctype, code in zip(self.names, self.types, codes):
            if self.nullable and code == NO_VALUE and ctype.kind != "number":
                out[name] = None
            else:
                out[name] = ctype.decode([code])
        return out

    # -- messages ------------------------------------------------------------------------
    def encode(self, t: float, seq: int, fields: dict) -> bytes:
        """A sample or command message of ``fields`` (as :meth:`fields` gives them)."""
        return encode_fields(t, seq, fields)

    def encode_codes(self, t: float, seq: int, codes) -> bytes:
        return self.encode(t, seq, self.fields(codes))

    def decode(self, payload: bytes) -> Message:
        """A sample, command or failure message, checked, or CodecError."""
        message = loads(payload)
        t, seq = stamp(message)
        failure = message.get("failed")
        if failure is not None:
            if failure not in FAILURES:
                raise CodecError(f"'failed' is not one of {', '.join(FAILURES)}")
            return Message(t, seq, Fault(failure), None)
        return Message(t, seq, None, self.codes(message.get("fields")))


def stamp(message: dict) -> tuple[float, int]:
    """(t, seq) of a message: a time and a count, or CodecError."""
    t = number(message.get("t"), "'t'", MAX_STAMP)
    seq = message.get("seq")
    if isinstance(seq, bool) or not isinstance(seq, int) or not 0 <= seq <= MAX_SEQ:
        raise CodecError("'seq' is not a count")
    return t, seq


def encode_fields(t: float, seq: int, fields: dict) -> bytes:
    """A sample or command message of ``fields`` (values as :meth:`FieldCodec.fields` gives them)."""
    return dumps({"t": t, "seq": seq, "fields": fields})


def encode_failure(t: float, seq: int, fault: Fault) -> bytes:
    """The message saying the physical link failed by ``fault`` (one of LINK_FAILURES)."""
    if fault not in LINK_FAILURES:
        raise ValueError(f"not a link failure: {fault!r}")
    return dumps({"t": t, "seq": seq, "failed": Fault(fault).value})


# -- twin channels ---------------------------------------------------------------------------
def encode_value(t: float, sim_time: float, value) -> bytes:
    """A twin channel's value (JSON-ready, as ``ChannelType.decode`` gives it) at ``sim_time``."""
    return dumps({"t": t, "sim_time": round(sim_time, 6), "value": value})


def decode_value(payload: bytes) -> tuple[float | None, object]:
    """(simulated time, value) of a twin channel's message, or CodecError."""
    message = loads(payload)
    sim_time = message.get("sim_time")
    return (None if sim_time is None else number(sim_time, "'sim_time'", MAX_STAMP)), message.get("value")


# -- twin-mode requests ------------------------------------------------------------------------
def encode_mode_request(entity: str, mode: str, by: str) -> bytes:
    return dumps({"entity": entity, "mode": mode, "by": by})


def decode_mode_request(payload: bytes | None) -> tuple[object, object, str]:
    """(entity, mode, who asks) of a twin-mode request (unchecked values; CodecError if no object)."""
    message = loads(payload) if payload is not None else {}
    return message.get("entity"), message.get("mode"), str(message.get("by", "unknown"))[:200]


def encode_answer(accepted: bool, reason: str) -> bytes:
    return dumps({"accepted": accepted, "reason": reason})


MAX_DESCRIPTION = 4 * 1024 * 1024
"""The largest ``describe`` answer (bytes): a resolved scenario and its channels."""


def encode_record(value) -> str:
    """A channel's value as the black box stores it (its ``payload``): ``{"value": ...}``."""
    return json.dumps({"value": value})


def decode_answer(payload: bytes) -> dict:
    try:
        answer = loads(payload)
    except CodecError:
        return {"accepted": False, "reason": "the answer was malformed"}
    return {"accepted": answer.get("accepted") is True, "reason": str(answer.get("reason", ""))}


def shown(value) -> str:
    """A received value as a refusal quotes it: its repr, cut to 40 characters (a payload is the sender's)."""
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."
