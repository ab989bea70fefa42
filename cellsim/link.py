"""The one rule for trusting a link to a physical twin: watchdog, sequence, recover-after.

Whoever *receives* a physical twin's data judges it with :class:`LinkTrust`: the
twin's sample sources (an entity's physical samples, in the diagram), the bridge
daemon (a CAN device's frames, a robot controller's states), the emulated devices
(the twin's command frames) and the emulator's command sources. The rule:

* a message that does not decode, fails its integrity check (CRC, length) or
  carries a value out of range is a fault (the link is *corrupt*);
* a sender's sequence number must follow the last one taken: a repeat or a step
  back is refused and counted (``repeated``: a frozen or replayed stream then goes
  stale), a jump further ahead than ``max_gap`` is a fault (``counter``);
* a message stamped more than ``future_skew`` seconds ahead of the receiver's
  clock is refused and counted (``future``); one that arrives older than the
  watchdog is a fault (``late``: the link is *stale*);
* with no good message for ``timeout`` seconds of the receiver's clock the link
  is *stale* (``timeout``); a corrupt link stays corrupt while faulty messages keep
  arriving, and goes stale when they stop too;
* after any fault, ``recover_after`` good messages in a row are needed before the
  link is trusted again (*recovering* until then). At start the link is stale;
* a sequence that shows two senders (``masquerade_after`` anomalies within
  ``masquerade_window`` s: jumps back or far ahead, repeats carrying other content)
  is a *masquerade*: it latches the link corrupt, every message failing, until
  ``clear_after`` messages in strict order (one sender's stable run) clear it.
  End-to-end protection (a CRC and a counter) is no authentication: a forger who
  computes them passes the frame checks, but not this one for long.

Freshness is judged by the receiver's clock: arrival times decide stale, the
sender's stamp only decides late and future. A sender that restarts (its
sequence counting from 1 again) is heard once its old stream has gone stale.

Every receiver applies the rule in one order (:meth:`LinkTrust.receive`): the
message's integrity first (it decodes; its CRC, length or MAC: the receiver's
own checks), then its stamp (when it carries one), then its sequence, then its
values' range, and only then is it good.

One fault vocabulary (:class:`Fault`) runs from the frame to the black box: the
bridge forwards the fault it found by its name (``{"failed": "crc"}``,
``cellsim.codec``), and the twin fails its link by that same fault
(:func:`failed_link`: ``timeout`` and ``late`` make a link stale, every other
failure corrupt).

The debounce is applied once, by the receiver that acts on the data: the bridge
forwards every frame's outcome at once (a good frame as a sample, a bad one as a
failure message), and the twin's sample source gates it.

A ``LinkTrust`` is a plain object; a Drake system keeps its state in its context
(:meth:`LinkTrust.state` and :meth:`LinkTrust.restore`), so the same code runs in
a discrete update.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from cellsim.vocabulary import PhysicalLink


class Fault(str, Enum):
    """Why a message, or a link, is not trusted."""

    LENGTH = "length"
    CRC = "crc"
    COUNTER = "counter"
    """The sequence (an alive counter, a ``seq``) jumped further ahead than allowed."""
    RANGE = "range"
    TIMEOUT = "timeout"
    CORRUPT = "corrupt"
    """A message that does not decode (a Zenoh link's counterpart of a bad CRC)."""
    LATE = "late"
    """A message older than the watchdog when it arrived."""
    REPEATED = "repeated"
    """A sequence number not after the last one taken: a repeat or a replay (refused, not a failure)."""
    FUTURE = "future"
    """Stamped further ahead of the receiver's clock than the allowed skew (refused, not a failure)."""
    MASQUERADE = "masquerade"
    """The sequence shows two senders (it jumps back and forth, or repeats with other content): every
    message fails until one sender's stable run clears it."""
    AUTH = "auth"
    """An authenticated frame whose MAC does not verify (``cellsim.bridges.secoc``): forged, tampered with, made with
    another key, or too old to place."""


STALE_FAULTS = frozenset({Fault.TIMEOUT, Fault.LATE})
"""Faults that make a link stale; every other failure makes it corrupt."""
REFUSALS = frozenset({Fault.REPEATED, Fault.FUTURE})
"""Faults that refuse one message without failing the link."""
LINK_FAILURES = tuple(f for f in Fault if f not in REFUSALS)
"""Faults that fail a link: what a failure message may name."""


def failed_link(fault: Fault) -> PhysicalLink:
    """The state a link fails into by ``fault`` (not a refusal): stale on a timeout or a late message, else corrupt."""
    return PhysicalLink.STALE if fault in STALE_FAULTS else PhysicalLink.CORRUPT


@dataclass
class Judgement:
    """The outcome of one message: its values when trusted, else why not."""

    trusted: bool
    values: object = None
    fault: Fault | None = None
    recovering: bool = False
    """A good message, not yet ``recover_after`` of them in a row since the last fault."""

    @property
    def good(self) -> bool:
        """The message itself was good (trusted, or recovering)."""
        return self.fault is None


@dataclass
class LinkTrust:
    """Whether a link's data is trusted (see the module docstring).

    Times are seconds on the receiver's clock (any monotonic clock: the twin's
    simulation clock paced to the wall, or ``time.monotonic()``); stamps are the
    sender's, compared with the receiver's wall clock.
    """

    timeout: float
    """Watchdog (s): with no good message for this long the link is stale."""
    recover_after: int = 3
    max_gap: int = 2
    """How far ahead a sequence number may jump (messages lost on the way) before it is a fault."""
    future_skew: float = 0.5
    """How far ahead of the receiver's clock a sender's stamp may be (s): clocks of one cell differ."""
    modulo: int | None = None
    """Sequence numbers wrap at this (a CAN alive counter: 16); None: they only grow."""
    faults: tuple = ()
    """The faults this kind of link can have (counted from zero, for its diagnostics)."""
    counts: dict = field(default_factory=dict)
    link: PhysicalLink = PhysicalLink.STALE
    good_in_a_row: int = 0
    last_good: float | None = None
    """When the last good message came (s, the receiver's clock)."""
    last_seq: int | None = None
    timed_out_at: float | None = None
    last_heard: float | None = None
    """When the last message came that failed the link (s): a corrupt link is not stale while they come."""
    masquerade_after: int = 3
    masquerade_window: float = 1.0
    clear_after: int = 16
    anomaly_times: tuple = ()
    """When the latest anomalies came (s), those within ``masquerade_window`` of the last, at most
    ``masquerade_after``: the window slides with each anomaly."""
    masquerade: bool = False
    clean_run: int = 0
    last_content: float | None = None

    def __post_init__(self):
        self.counts = {f.value: 0 for f in self.faults}

    # -- the rule ----------------------------------------------------------------
    @property
    def failed(self) -> bool:
        """Untrusted: failed by a fault or the watchdog, or still recovering (also at start)."""
        return self.link is not PhysicalLink.OK

    def stamp(self, stamp: float, now_wall: float) -> Fault | None:
        """Judge a sender's time stamp against the receiver's wall clock at arrival: None, or the fault
        (a refusal or a failure) to give :meth:`fail`, which counts it."""
        if not math.isfinite(stamp) or stamp > now_wall + self.future_skew:
            return Fault.FUTURE
        if now_wall - stamp > self.timeout:
            return Fault.LATE
        return None

    def sequence(self, seq: int, now: float, content: float | None = None) -> Fault | None:
        """Judge a sequence number (and, for a repeat, whether ``content`` differs: a hash of the message):
        None when it follows, else the fault (a refusal or a failure) to give :meth:`fail`, which counts it.

        After the link went stale any number starts the sequence afresh (a restarted sender), but the very
        message last heard, again (its number and content), is still a repeat: a frozen stream stays refused, stale,
        however long it repeats. A masquerade (see the module docstring) fails every message until it is cleared.
        """
        last, last_content = self.last_seq, self.last_content
        self.last_content = content
        if last is None or self.link is PhysicalLink.STALE and self._silent(now) and not self.masquerade:
            if last is not None and seq == last and content is not None and content == last_content:
                return Fault.REPEATED  # the same message: a frozen sender, not a restarted one
            self.last_seq = seq
            return None
        delta = (seq - last) % self.modulo if self.modulo else seq - last
        repeated = delta == 0 if self.modulo else delta <= 0
        if repeated and not (content is not None and last_content is not None and content != last_content):
            if self.masquerade:
                self.clean_run = 0
            return Fault.REPEATED  # a retransmission, a frozen or replayed stream: refused
        if repeated or delta > self.max_gap:  # a step back with other content, or a jump: two senders?
            self._anomaly(now)
        self.clean_run = self.clean_run + 1 if delta == 1 else 0
        if self.masquerade and self.clean_run >= self.clear_after:
            self.masquerade, self.anomaly_times = False, ()  # one sender's stable run
        self.last_seq = seq  # resynchronise on it, whether it is taken or not
        if self.masquerade:
            return Fault.MASQUERADE
        if repeated or delta > self.max_gap:
            return Fault.COUNTER
        return None

    @property
    def anomalies(self) -> int:
        """How many anomalies came within ``masquerade_window`` up to the latest (that one included)."""
        return len(self.anomaly_times)

    @property
    def anomaly_since(self) -> float | None:
        """When the earliest of :attr:`anomalies` came (s); None without one."""
        return self.anomaly_times[0] if self.anomaly_times else None

    def _anomaly(self, now: float) -> None:
        """An anomaly at ``now``: ``masquerade_after`` of them within any ``masquerade_window`` (both ends included)
        latch the masquerade, wherever the window starts (it slides: no edge to time bursts across)."""
        recent = [t for t in self.anomaly_times if now - t <= self.masquerade_window]
        self.anomaly_times = tuple([*recent, now][-self.masquerade_after:])
        if len(self.anomaly_times) >= self.masquerade_after:
            self.masquerade = True  # (the message that made the anomaly also restarts the clean run)

    def receive(self, now: float, seq: int, content: float | None = None, *, stamp: float | None = None,
                wall: float | None = None, values=None, in_range=None) -> Judgement:
        """Judge a message that passed its integrity checks, in the rule's one order: its ``stamp`` (the
        sender's wall clock, against the receiver's ``wall``; when it carries one), its sequence ``seq``
        (``content``: a hash, telling a repeat from another sender), then ``in_range(values)`` (a fault for
        values it may not carry, or None); fails (or refuses) it on the first fault, else it is good. A silence
        longer than ``timeout`` before it is judged first (:meth:`watchdog`): the link went stale in it, whenever
        the caller's own watchdog call comes, so this message starts the recovery rather than being trusted."""
        self.watchdog(now)
        fault = self.stamp(stamp, wall) if stamp is not None else None
        fault = fault or self.sequence(seq, now, content)
        if fault is None and in_range is not None:
            fault = in_range(values)
        return self.fail(fault, now) if fault is not None else self.good(now, values)

    def good(self, now: float, values=None) -> Judgement:
        """A good message arrived at ``now`` (after a silence longer than ``timeout``: one of the recovery's)."""
        self.watchdog(now)
        self.last_good = now
        self.timed_out_at = None
        self.good_in_a_row += 1
        if self.link is not PhysicalLink.OK and self.good_in_a_row < self.recover_after:
            self.link = PhysicalLink.RECOVERING
            return Judgement(False, values, None, recovering=True)
        self.link = PhysicalLink.OK
        return Judgement(True, values)

    def fail(self, fault: Fault, now: float | None = None) -> Judgement:
        """A fault (of a message that arrived at ``now``): counted, and the link fails (stale or corrupt)
        until it recovers."""
        if fault in REFUSALS:  # one message refused: counted, the link as it was
            self._count(fault)
            return Judgement(False, None, fault)
        self._count(fault)
        self.good_in_a_row = 0
        self.link = failed_link(fault)
        if now is not None and self.link is PhysicalLink.CORRUPT:
            self.last_heard = now
        return Judgement(False, None, fault)

    def watchdog(self, now: float) -> Judgement | None:
        """The timeout judgement when no good message came within ``timeout`` (call it periodically);
        counted once per timeout period."""
        if self.last_good is None:
            return None
        since = self.last_good if self.timed_out_at is None else self.timed_out_at
        if self.link is PhysicalLink.CORRUPT and self.last_heard is not None:
            since = max(since, self.last_heard)  # faulty messages still come: corrupt, not stale
        if now - since <= self.timeout:
            return None
        self.timed_out_at = now
        return self.fail(Fault.TIMEOUT)

    def _silent(self, now: float) -> bool:
        return self.last_good is None or now - self.last_good > self.timeout

    def _count(self, fault: Fault) -> None:
        self.counts[fault.value] = self.counts.get(fault.value, 0) + 1

    # -- state in a Drake context ---------------------------------------------------
    def state(self) -> np.ndarray:
        """The rule's state as numbers: [link code, good in a row, last good, last seq, timed out at, last heard,
        masquerade, clean run, last content, then ``masquerade_after`` anomaly times (-inf: none)]."""
        times = [*self.anomaly_times, *[-np.inf] * (self.masquerade_after - len(self.anomaly_times))]
        return np.array([
            float(self.link.code), float(self.good_in_a_row),
            -np.inf if self.last_good is None else self.last_good,
            -1.0 if self.last_seq is None else float(self.last_seq),
            -np.inf if self.timed_out_at is None else self.timed_out_at,
            -np.inf if self.last_heard is None else self.last_heard,
            1.0 if self.masquerade else 0.0, float(self.clean_run),
            np.nan if self.last_content is None else self.last_content,
            *times,
        ])

    def restore(self, state) -> "LinkTrust":
        values = [float(x) for x in state]
        (code, good, last_good, last_seq, timed_out_at, last_heard, masquerade, clean_run, last_content) = values[:9]
        self.anomaly_times = tuple(t for t in values[9:] if t != -np.inf)
        self.link = PhysicalLink.from_code(code)
        self.good_in_a_row = int(good)
        self.last_good = None if last_good == -np.inf else last_good
        self.last_seq = None if last_seq < 0 else int(last_seq)
        self.timed_out_at = None if timed_out_at == -np.inf else timed_out_at
        self.last_heard = None if last_heard == -np.inf else last_heard
        self.clean_run, self.masquerade = int(clean_run), masquerade > 0.5
        self.last_content = None if math.isnan(last_content) else last_content
        return self
