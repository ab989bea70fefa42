"""End-to-end protection of safety-relevant CAN frames, and the black-channel checks on them.

The bus is a *black channel* (IEC 61784-3): nothing it delivers is trusted until
checked. Every safety-relevant frame of a cell's DBC follows AUTOSAR E2E
profile 2, as ``cantools.autosar.end_to_end`` computes it:

* byte 0, signal ``Crc``: CRC-8 (SAE J1850, polynomial 0x2F) over bytes 1.. of
  the frame followed by the frame's *data ID* for the current counter;
* byte 1, low nibble, signal ``Counter``: an alive counter, 0..15, one up per frame;
* the data ID for counter c is ``(base + c) mod 256`` (profile 2's DataIDList),
  its base the same CRC-8 over the frame id's two bytes: every bit of the 11-bit
  id counts (the id alone mod 256 made 0x110 and 0x210 one list). Two protected
  messages of one length with one base would check as each other: the bridge's
  loader refuses such a DBC (:func:`sharing_data_ids`).

:func:`protect` builds a frame; :class:`DeviceChecker` judges the frames of one
device: length, CRC, counter continuity (a repeated counter, or one that jumps
further than ``max_delta`` ahead, is a replay or lost frames), value ranges
(every signal within its DBC range and, for an enumeration, one of its values),
and the link rule of ``cellsim.link`` (the alive counter as a sequence: a repeated
counter is refused, one that jumps further than ``max_gap`` is a fault; a watchdog,
no good frame within ``timeout``; trusted again only after ``recover_after`` good
frames in a row). The daemon forwards each frame's outcome at once; the twin,
which receives it, applies the recover-after (the debounce is applied once).

E2E protection is not authentication: a message with ``Freshness`` and ``Mac``
signals is also authenticated (:mod:`cellsim.bridges.secoc`), checked after the CRC and
before the counter, so a forgery never moves the sequence.
"""

from __future__ import annotations

import functools
import zlib
from dataclasses import dataclass

from cantools.autosar.end_to_end import compute_profile2_crc

from cellsim.link import Fault, Judgement, LinkTrust

COUNTER_MODULO = 16
MAX_GAP = 2
"""How far a device's alive counter may jump (one lost frame tolerated): its frames' checks' default."""


@functools.lru_cache(maxsize=4096)
def data_id_base(frame_id: int) -> int:
    """The base of a message's data IDs: CRC-8 (profile 2's polynomial) over its frame id's two bytes (four for an
    extended, 29-bit id)."""
    return compute_profile2_crc(b"\x00" + frame_id.to_bytes(2 if frame_id <= 0xFFFF else 4, "big"), 0)


def data_id(frame_id: int, counter: int) -> int:
    """Profile 2's data ID for a frame of ``frame_id`` carrying ``counter``."""
    return (data_id_base(frame_id) + counter) % 256


def sharing_data_ids(messages) -> tuple | None:
    """Two protected messages (cantools Messages) of one length whose data IDs are the same for every counter, so
    that a frame of one checks as the other's; None when there are none."""
    seen: dict[tuple[int, int], object] = {}
    for message in messages:
        key = (message.length, data_id_base(message.frame_id))
        if key in seen:
            return seen[key], message
        seen[key] = message
    return None


def protect(message, values: dict, counter: int, authenticator=None) -> bytes:
    """The frame of ``message`` (a cantools Message) with ``values``, ``counter`` and its CRC; with an
    ``authenticator`` (``cellsim.bridges.secoc``), also its freshness value and MAC, before the CRC."""
    counter %= COUNTER_MODULO
    signals = {**values, "Crc": 0, "Counter": counter}
    if authenticator is not None:
        freshness = authenticator.next_freshness()
        signals.update(Freshness=freshness % authenticator.modulo, Mac=0)
        signals["Mac"] = authenticator.mac(message.encode(signals, strict=True), freshness)
    payload = bytearray(message.encode(signals, strict=True))
    payload[0] = compute_profile2_crc(bytes(payload), data_id(message.frame_id, counter))
    return bytes(payload)


E2E_FAULTS = (Fault.LENGTH, Fault.CRC, Fault.COUNTER, Fault.REPEATED, Fault.MASQUERADE, Fault.RANGE, Fault.TIMEOUT)
AUTHENTICATED_FAULTS = (*E2E_FAULTS, Fault.AUTH, Fault.LATE, Fault.FUTURE)
"""An authenticated message's frames can also fail their MAC or freshness (``cellsim.bridges.secoc``)."""
PROTECTION = ("Crc", "Counter", "Freshness", "Mac")
"""The signals that protect a frame rather than carry the device's values."""


@dataclass
class DeviceChecker(LinkTrust):
    """The black-channel checks of one device's frames (one DBC message), then the link rule
    (``cellsim.link``: its alive counter as a sequence modulo 16, the watchdog, recover-after)."""

    message: object = None
    max_gap: int = MAX_GAP
    """How far the counter may jump (1: no frame lost; 2: one lost frame tolerated)."""
    modulo: int = COUNTER_MODULO
    faults: tuple = E2E_FAULTS
    authenticator: object = None
    """For an authenticated message, its ``cellsim.bridges.secoc.Authenticator`` (the receiver's)."""

    def __post_init__(self):
        if self.authenticator is not None and self.faults == E2E_FAULTS:
            self.faults = AUTHENTICATED_FAULTS
        super().__post_init__()

    def check(self, data: bytes, now: float) -> Judgement:
        """Judge one frame received at ``now`` (s, any monotonic clock)."""
        message = self.message
        if len(data) != message.length:
            return self.fail(Fault.LENGTH, now)
        if compute_profile2_crc(data, data_id(message.frame_id, data[1] & 0x0F)) != data[0]:
            return self.fail(Fault.CRC, now)
        try:
            values = message.decode(data, decode_choices=False, scaling=True)
        except Exception:  # noqa: BLE001 - cantools raises several kinds on a bad payload
            return self.fail(Fault.RANGE, now)
        if self.authenticator is not None:  # before the counter: a forgery must not move its sequence
            fault = self.authenticator.verify(data, int(values["Freshness"]), int(values["Mac"]), self)
            if fault is not None:
                return self.fail(fault, now)
        carried = {k: v for k, v in values.items() if k not in PROTECTION}
        return self.receive(now, data[1] & 0x0F, zlib.crc32(data), values=carried,
                            in_range=lambda _: self._in_range(values))

    def _in_range(self, values: dict) -> Fault | None:
        """RANGE for a signal beyond its DBC range or an enumeration's code it does not name."""
        for signal in self.message.signals:
            value = values[signal.name]
            if signal.choices is not None and signal.name not in PROTECTION:
                if int(value) not in signal.choices:
                    return Fault.RANGE
            lo, hi = signal.minimum, signal.maximum
            if (lo is not None and value < lo - 1e-9) or (hi is not None and value > hi + 1e-9):
                return Fault.RANGE
        return None
