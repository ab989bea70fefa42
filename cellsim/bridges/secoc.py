"""Authenticated CAN frames, in the manner of AUTOSAR SecOC: a truncated AES-CMAC and a freshness value.

End-to-end protection (:mod:`cellsim.bridges.e2e`) finds frames that were corrupted, lost or
repeated on the way. It does not find forged ones: anyone on the bus who has the
DBC can compute a CRC and the next counter. A device that supports it
*authenticates* its frames instead, with a key a forger does not have. The
layout follows SecOC profile 1 for classic CAN, which uses a 24-bit MAC and an
8-bit freshness value:

* A DBC message that has the signals ``Freshness`` and ``Mac`` is authenticated.
  It keeps its ``Crc`` and ``Counter`` (E2E profile 2), because the CRC still
  finds corruption first, and a corrupted frame is reported as ``crc``, never as a
  forgery.
* **Key.** Each message has its own AES-128 key, derived from the cell's CAN key
  (``can.key``, written by ``cellsim keys init``). The derivation is NIST SP
  800-108 in counter mode with CMAC (``cryptography``'s ``KBKDFCMAC``): label
  ``cellsim SecOC``, context the frame id as 4 bytes big-endian. A real device is
  given only its own message's key.
* **Freshness.** The value is time-based: the count of ``tick``-second ticks of the
  wall clock since the Unix epoch. The sender's values only ever grow (one more than
  the last, if the clock has not moved on). The frame carries the value's low bits.
  The receiver rebuilds the full value from its own clock: it is the value with
  those low bits nearest its own count.
* **MAC.** The first ``Mac``-length bits of
  ``AES-CMAC(key, frame id (2 bytes big-endian) || the frame with its Crc, Freshness and Mac bits zeroed || full freshness value (8 bytes big-endian))``.
  The CRC is computed last, over the finished frame.

The receiver (:meth:`Authenticator.verify`) applies these rules:

* a MAC that does not verify is ``auth``. The frame was forged, tampered with and
  given a new CRC, made with another key, or is so old that its freshness was
  rebuilt wrong. The link fails (corrupt);
* a verified value not after the last one taken is ``repeated`` (a replay: refused);
* a value stamped further ahead of the receiver's clock than the link's skew is
  ``future`` (refused);
* a value older than the watchdog is ``late`` (the link goes stale).

The last two follow the stamp rule of :mod:`cellsim.link`. Sender's and receiver's
clocks must agree to well within the watchdog (PTP or NTP on a real cell). The
low bits must span the watchdog plus the skew both ways; the bridge configuration
checks this when it loads (:func:`window_problem`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable

from cellsim.link import Fault, LinkTrust

FRESHNESS, MAC = "Freshness", "Mac"
LABEL = b"cellsim SecOC"


def is_authenticated(message) -> bool:
    """Whether a DBC message (cantools) carries a freshness value and a MAC."""
    names = {s.name for s in message.signals}
    return FRESHNESS in names and MAC in names


def message_key(can_key: bytes, frame_id: int) -> bytes:
    """The AES-128 key of one message's frames, derived from the cell's CAN key (see the module)."""
    from cryptography.hazmat.primitives.ciphers import algorithms
    from cryptography.hazmat.primitives.kdf.kbkdf import KBKDFCMAC, CounterLocation, Mode

    kdf = KBKDFCMAC(algorithms.AES, Mode.CounterMode, 16, 4, 4, CounterLocation.BeforeFixed, LABEL,
                    frame_id.to_bytes(4, "big"), None)
    return kdf.derive(can_key)


def window_problem(message, tick: float, watchdog: float, skew: float) -> str | None:
    """Why the freshness value of ``message`` cannot span its window (None when it can): its low bits
    rebuild a value within half their range of the receiver's count, which must cover the watchdog
    (a frame that old is late) and the skew (a frame that far ahead is refused)."""
    bits = message.get_signal_by_name(FRESHNESS).length
    reach = (1 << bits) // 2 * tick
    if watchdog + skew >= reach:
        return (f"its {bits}-bit freshness value at {tick:g} s ticks rebuilds only within +-{reach:g} s, which must "
                f"exceed the watchdog ({watchdog:g} s) plus the clock skew allowed ({skew:g} s): widen the "
                "Freshness signal or lengthen freshness_tick")
    return None


@dataclass
class Authenticator:
    """Signs (sender) or verifies (receiver) the frames of one authenticated message."""

    message: object
    """The cantools message: its frame id, and its ``Freshness`` and ``Mac`` signals."""
    key: bytes
    """The message's key (:func:`message_key`)."""
    tick: float = 0.005
    """The freshness value's unit (s)."""
    clock: Callable[[], float] = time.time
    """The wall clock (s since the Unix epoch), kept in step with the other end's."""
    last: int | None = field(default=None, init=False)
    """The last freshness value sent, or taken."""

    def __post_init__(self):
        from cryptography.hazmat.primitives.ciphers import algorithms

        self._cipher = algorithms.AES(self.key)
        fv, mac = self.message.get_signal_by_name(FRESHNESS), self.message.get_signal_by_name(MAC)
        self.modulo, self.mac_bits = 1 << fv.length, mac.length
        # the bits the MAC covers: everything but Crc, Freshness and Mac
        ones = {s.name: 0 for s in self.message.signals}
        for name in ("Crc", FRESHNESS, MAC):
            ones[name] = (1 << self.message.get_signal_by_name(name).length) - 1
        hidden = self.message.encode(ones, scaling=False, strict=False)
        self._covered = bytes(~b & 0xFF for b in hidden)
        self._data_id = (self.message.frame_id & 0xFFFF).to_bytes(2, "big")

    # -- sender ---------------------------------------------------------------------
    def next_freshness(self) -> int:
        """The full freshness value of the next frame: the clock's tick count, after the last one sent."""
        value = math.floor(self.clock() / self.tick)
        if self.last is not None and value <= self.last:
            value = self.last + 1
        self.last = value
        return value

    def mac(self, frame: bytes, freshness: int) -> int:
        """The truncated MAC of ``frame`` (its Crc, Freshness and Mac bits are ignored) with the full
        ``freshness`` value."""
        from cryptography.hazmat.primitives.cmac import CMAC

        cmac = CMAC(self._cipher)
        cmac.update(self._data_id + bytes(a & b for a, b in zip(frame, self._covered)) + freshness.to_bytes(8, "big"))
        return int.from_bytes(cmac.finalize(), "big") >> (128 - self.mac_bits)

    # -- receiver -------------------------------------------------------------------
    def verify(self, frame: bytes, low_bits: int, mac: int, link: LinkTrust) -> Fault | None:
        """Judge one received frame (its ``Freshness`` and ``Mac`` signals as decoded) against the
        receiver's clock; ``link`` gives the watchdog and skew. None when it is authentic and fresh."""
        now = self.clock()
        count = math.floor(now / self.tick)
        freshness = count - ((count - low_bits) % self.modulo)
        if count - freshness > self.modulo // 2:
            freshness += self.modulo
        if self.mac(frame, freshness) != mac:
            return Fault.AUTH
        if self.last is not None and freshness <= self.last:
            return Fault.REPEATED
        fault = link.stamp(freshness * self.tick, now)
        if fault is None:
            self.last = freshness
        return fault
