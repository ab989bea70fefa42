"""The bridge daemon's diagnostics: per device, how its link is doing, at ROS diagnostics levels.

Every ``diagnostics_period`` and at once when a level changes, each device's
status goes out on ``cellsim/<cell>/diagnostics/<entity>`` as JSON::

    {"t": 1795000000.0, "entity": "light_barrier", "device": "LightCurtainState",
     "level": "OK", "message": "trusted", "rate_hz": 50.0, "nominal_hz": 50.0,
     "age_s": 0.004, "received": 2500, "counts": {"crc": 0, "counter": 0, ...}}

Levels, as ROS diagnostics name them (a group shows its worst member):

* ``STALE``: no good message yet, or none within the device's watchdog;
* ``ERROR``: the device is failed (a check failed and it has not recovered):
  the twin was told its link failed;
* ``WARN``: trusted, but errors were counted since the last status, or its
  rate is below ``RATE_WARNING`` of nominal;
* ``OK``: trusted, at its rate, no new errors.

Every change of level is also logged (logger ``cellsim.bridge``).
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field

LEVELS = ("OK", "WARN", "ERROR", "STALE")
RATE_WARNING = 0.8
"""A rate below this fraction of nominal is a warning."""
log = logging.getLogger("cellsim.bridge")


def worst(levels) -> str:
    """The worst of some levels (OK for none)."""
    return max(levels, key=LEVELS.index, default="OK")


@dataclass
class DeviceDiagnostics:
    """The status of one device's link, from its checker (a ``LinkTrust``)."""

    entity: str
    device: str
    """What the device sends: its DBC message, or "robot controller"."""
    checker: object
    nominal_hz: float
    publisher: object = None
    level: str = "STALE"
    received: int = 0
    _window_start: float | None = None
    _window_received: int = 0
    _window_counts: dict = field(default_factory=dict)
    last: dict = field(default_factory=dict)

    def frame(self) -> None:
        """Count one message received (good or not)."""
        self.received += 1
        self._window_received += 1

    def status(self, now: float) -> dict:
        """The device's status now (the rate is over the time since the last status)."""
        checker = self.checker
        level, span, rate, age, new_errors = self._assess(now)
        if level == "STALE":
            message = "no good message yet" if age is None else f"no good message for {age:.3f} s"
        elif level == "ERROR":
            message = "failed: " + (", ".join(f"{k} {v}" for k, v in new_errors.items()) or "recovering")
        elif new_errors:
            message = "errors: " + ", ".join(f"{k} {v}" for k, v in new_errors.items())
        elif level == "WARN":
            message = f"rate {rate:.1f} Hz of {self.nominal_hz:g}"
        else:
            message = "trusted"
        return {"t": now, "entity": self.entity, "device": self.device, "level": level, "message": message,
                "rate_hz": round(rate, 2), "nominal_hz": self.nominal_hz,
                "age_s": None if age is None else round(age, 4), "received": self.received, "counts": dict(checker.counts)}

    def _assess(self, now: float) -> tuple[str, float, float, float | None, dict]:
        """(level, span of the window (s), rate (Hz), age of the last good message (s), errors in the window)."""
        checker = self.checker
        if self._window_start is None:
            self._window_start = now
        span = now - self._window_start
        rate = self._window_received / span if span > 0 else 0.0
        counted = self._window_counts
        new_errors = {k: v - counted.get(k, 0) for k, v in checker.counts.items() if v > counted.get(k, 0)}
        age = None if checker.last_good is None else max(0.0, now - checker.last_good)
        if age is None or age > checker.timeout:
            level = "STALE"
        elif checker.failed:
            level = "ERROR"
        elif new_errors or (span >= 0.5 and rate < RATE_WARNING * self.nominal_hz):
            level = "WARN"
        else:
            level = "OK"
        return level, span, rate, age, new_errors

    def publish(self, now: float, every: float) -> None:
        """Publish the status if ``every`` s passed since the last one, or at once if its level changed."""
        due = self._window_start is not None and now - self._window_start >= every
        if not due and self.last and self._assess(now)[0] == self.level:
            return
        status = {**self.status(now), "every_s": every}  # (a reader takes it as stale after a few missed)
        if status["level"] != self.level:
            log.log(logging.INFO if status["level"] == "OK" else logging.WARNING, "%s (%s): %s -> %s, %s",
                    self.entity, self.device, self.level, status["level"], status["message"])
        self.level, self.last = status["level"], status
        if self.publisher is not None:
            self.publisher.put(json.dumps(status, separators=(",", ":")))
        self._window_start, self._window_received = now, 0
        self._window_counts = dict(self.checker.counts)
