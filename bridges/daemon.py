"""The bridge daemon's CAN side: device frames in, the twin's physical samples out.

Every frame of a configured device passes the black-channel checks of
``bridges.e2e``; a trusted frame becomes the entity's physical sample on
``cellsim/<cell>/physical/<entity>`` in the live format (``docs/live.md``). Any
failure (length, CRC, counter, range, watchdog), and every frame while the device
recovers, publishes the device's fail-safe sample at once instead: the twin sees
the state it must assume. Frames of unknown identifiers are counted and
dropped; nothing a frame holds stops the daemon.

Still to come (issue "The bridge daemon"): commands to the bus, the robot over
Zenoh, diagnostics, the daemon's command line.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from bridges.config import LoadedBridge
from bridges.e2e import DeviceChecker, Verdict
from cellsim.live import keys
from cellsim.live.codec import encode_fields


@dataclass
class Device:
    entity: str
    mapping: object
    message: object
    checker: DeviceChecker
    publisher: object
    seq: int = 0
    published: int = 0
    fail_safe_published: int = 0


@dataclass
class Bridge:
    """Maps one cell's CAN devices to its twin's physical samples."""

    loaded: LoadedBridge
    session: object
    clock: object = time.time
    devices: dict = field(default_factory=dict)
    unknown_frames: int = 0

    def __post_init__(self):
        cfg, database = self.loaded.config, self.loaded.database
        for entity, mapping in cfg.devices.items():
            message = database.get_message_by_name(mapping.message)
            checker = DeviceChecker(message, mapping.watchdog, recover_after=cfg.recover_after)
            publisher = self.session.declare_publisher(keys.physical(cfg.cell, entity))
            self.devices[message.frame_id] = Device(entity, mapping, message, checker, publisher)

    def handle(self, frame_id: int, data: bytes, now: float | None = None) -> Verdict | None:
        """Check one received frame and publish what it means for the twin."""
        now = self.clock() if now is None else now
        device = self.devices.get(frame_id)
        if device is None:
            self.unknown_frames += 1
            return None
        verdict = device.checker.check(bytes(data), now)
        if verdict.trusted:
            self._publish(device, self._fields(device, verdict.values), now)
        else:
            self._publish_fail_safe(device, now)
        return verdict

    def check_watchdogs(self, now: float | None = None) -> None:
        """Fail every device whose frames stopped (call it at least every cycle time)."""
        now = self.clock() if now is None else now
        for device in self.devices.values():
            if device.checker.watchdog(now) is not None:
                self._publish_fail_safe(device, now)

    def _fields(self, device: Device, values: dict) -> dict:
        fields = {}
        for name, signal_name in device.mapping.fields.items():
            signal = device.message.get_signal_by_name(signal_name)
            value = values[signal_name]
            if signal.choices is not None:
                fields[name] = str(signal.choices[int(value)])
            elif signal.length == 1:
                fields[name] = bool(value)
            else:
                fields[name] = float(value)
        return fields

    def _publish_fail_safe(self, device: Device, now: float) -> None:
        device.fail_safe_published += 1
        self._publish(device, dict(device.mapping.fail_safe), now)

    def _publish(self, device: Device, fields: dict, now: float) -> None:
        device.seq += 1
        device.published += 1
        device.publisher.put(encode_fields(now, device.seq, fields))
