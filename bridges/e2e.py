"""End-to-end protection of safety-relevant CAN frames, and the black-channel checks on them.

The bus is a *black channel* (IEC 61784-3): nothing it delivers is trusted until
checked. Every safety-relevant frame of a cell's DBC follows AUTOSAR E2E
profile 2, as ``cantools.autosar.end_to_end`` computes it:

* byte 0, signal ``Crc``: CRC-8 (SAE J1850, polynomial 0x2F) over bytes 1.. of
  the frame followed by the frame's *data ID* for the current counter;
* byte 1, low nibble, signal ``Counter``: an alive counter, 0..15, one up per frame;
* the data ID for counter c is ``(frame id + c) mod 256`` (profile 2's DataIDList,
  here derived from the frame id so that a frame of one message never checks as
  another's).

:func:`protect` builds a frame; :class:`DeviceChecker` judges the frames of one
device: length, CRC, counter continuity (a repeated counter, or one that jumps
further than ``max_delta`` ahead, is a replay or lost frames), value ranges
(every signal within its DBC range and, for an enumeration, one of its values),
and a watchdog (no good frame within ``timeout``). After any failure the device
is trusted again only after ``recover_after`` good frames in a row.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

from cantools.autosar.end_to_end import compute_profile2_crc

COUNTER_MODULO = 16


def data_id(frame_id: int, counter: int) -> int:
    """Profile 2's data ID for a frame of ``frame_id`` carrying ``counter``."""
    return (frame_id + counter) % 256


def protect(message, values: dict, counter: int) -> bytes:
    """The frame of ``message`` (a cantools Message) with ``values``, ``counter`` and its CRC."""
    counter %= COUNTER_MODULO
    payload = bytearray(message.encode({**values, "Crc": 0, "Counter": counter}, strict=True))
    payload[0] = compute_profile2_crc(bytes(payload), data_id(message.frame_id, counter))
    return bytes(payload)


class Fault(str, Enum):
    """Why a frame, or a device, is not trusted."""

    LENGTH = "length"
    CRC = "crc"
    COUNTER = "counter"
    RANGE = "range"
    TIMEOUT = "timeout"
    CORRUPT = "corrupt"
    """A message that does not decode (a Zenoh link's counterpart of a bad CRC)."""
    LATE = "late"
    """A message older than the watchdog when it arrived (a link with time stamps)."""


@dataclass
class Verdict:
    """The outcome of checking one frame: the decoded signals when trusted, else why not."""

    trusted: bool
    values: dict | None = None
    fault: Fault | None = None
    recovering: bool = False
    """A good frame, not yet ``recover_after`` of them in a row since the last fault."""


@dataclass
class LinkTrust:
    """Whether a link's data is trusted: failed by any fault, trusted again after
    ``recover_after`` good messages in a row, failed by its watchdog when good ones stop.

    The checks of one kind of link (CAN frames, a robot controller's state) subclass it.
    """

    timeout: float
    """Watchdog (s): with no good message for this long the link is failed."""
    recover_after: int = 3
    faults: tuple = ()
    """The faults this kind of link can have (its diagnostics count each)."""
    counts: dict = field(default_factory=dict)
    good_in_a_row: int = 0
    last_good: float | None = None
    """When the last good message came (s)."""
    timed_out_at: float | None = None
    failed: bool = True
    """Untrusted until ``recover_after`` good messages came (also at start)."""

    def __post_init__(self):
        self.counts = {f.value: 0 for f in self.faults}

    def watchdog(self, now: float) -> Verdict | None:
        """The timeout verdict when no good message came within ``timeout`` (call it periodically)."""
        if self.last_good is None:
            return None
        since = max(self.last_good, self.timed_out_at if self.timed_out_at is not None else self.last_good)
        if now - since <= self.timeout:
            return None
        self.timed_out_at = now  # counted once per timeout period
        return self._fail(Fault.TIMEOUT)

    def _good(self, now: float, values: dict) -> Verdict:
        self.last_good = now
        self.good_in_a_row += 1
        if self.failed and self.good_in_a_row < self.recover_after:
            return Verdict(False, None, None, recovering=True)
        self.failed = False
        return Verdict(True, values)

    def _fail(self, fault: Fault) -> Verdict:
        self.counts[fault.value] = self.counts.get(fault.value, 0) + 1
        self.good_in_a_row = 0
        self.failed = True
        return Verdict(False, None, fault)


CAN_FAULTS = (Fault.LENGTH, Fault.CRC, Fault.COUNTER, Fault.RANGE, Fault.TIMEOUT)


@dataclass
class DeviceChecker(LinkTrust):
    """The black-channel checks of one device's frames (one DBC message)."""

    message: object = None
    max_delta: int = 2
    """How far ahead the counter may jump (1: no frame lost; 2: one lost frame tolerated)."""
    faults: tuple = CAN_FAULTS
    last_counter: int | None = None

    def check(self, data: bytes, now: float) -> Verdict:
        """Judge one frame received at ``now`` (s, any monotonic clock)."""
        message = self.message
        if len(data) != message.length:
            return self._fail(Fault.LENGTH)
        if compute_profile2_crc(data, data_id(message.frame_id, data[1] & 0x0F)) != data[0]:
            return self._fail(Fault.CRC)
        counter = data[1] & 0x0F
        if self.last_counter is not None:
            delta = (counter - self.last_counter) % COUNTER_MODULO
            if not 1 <= delta <= self.max_delta:
                self.last_counter = counter  # resynchronise on it, but do not trust this frame
                return self._fail(Fault.COUNTER)
        self.last_counter = counter
        try:
            values = message.decode(data, decode_choices=False, scaling=True)
        except Exception:  # noqa: BLE001 - cantools raises several kinds on a bad payload
            return self._fail(Fault.RANGE)
        if not self._in_range(values):
            return self._fail(Fault.RANGE)
        return self._good(now, {k: v for k, v in values.items() if k not in ("Crc", "Counter")})

    def _in_range(self, values: dict) -> bool:
        for signal in self.message.signals:
            value = values[signal.name]
            if signal.choices is not None and signal.name not in ("Crc", "Counter"):
                if int(value) not in signal.choices:
                    return False
            lo, hi = signal.minimum, signal.maximum
            if (lo is not None and value < lo - 1e-9) or (hi is not None and value > hi + 1e-9):
                return False
        return True
