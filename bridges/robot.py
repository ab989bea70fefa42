"""The robot over Zenoh: its controller's state in, the twin's requests out.

The robot controller's side (an RTDE adapter beside a UR controller on a real
cell; ``cellsim emulate --can`` here) publishes its state on
``cellsim/<cell>/controller/<robot>/state`` at its own rate (500 Hz for a UR
e-Series), one JSON object per state::

    {"t": 1795000000.002, "seq": 17, "position": [6 x rad], "velocity": [6 x rad/s],
     "safety_mode": "normal", "activity": "moving", "reached_pose": "home"}

``t`` is the controller's wall-clock time of the state, ``seq`` counts its
states, ``position``/``velocity`` follow the configured joint order, the rest
are the robot entity's sample fields (``cellsim modules robot``).

The daemon checks every state as it checks a CAN frame (``RobotStateChecker``):
it must decode (else *corrupt*), its ``seq`` must follow the last one (a repeat
or a jump back is a replay, *counter*), it must not be older than the watchdog
on arrival (*late*), its joints must be finite and within the configured limits
and its safety mode one of the vocabulary's (*range*), and a good one must come
within the watchdog (*timeout*). A trusted state becomes the robot's physical
sample (``q0``..``q5`` from ``position``) and a CDR ``sensor_msgs/JointState``
on the key zenoh-bridge-ros2dds maps to the configured ROS 2 topic. Anything
else publishes a failure message (``cellsim.live.codec``) at once: the twin's
robot fails safe without waiting for its ``stale_after``, and trusts the link
again only after ``recover_after`` good states in a row.

Requests go back on ``cellsim/<cell>/controller/<robot>/request`` in the live
command format, only while the robot is in twin mode: the twin's latest
command, or a stop (``safety_mode_request: stopped``, no activity, no target)
when the twin is lost.
"""

from __future__ import annotations

import json
import math
import threading
from dataclasses import dataclass, field

from bridges.e2e import Fault, LinkTrust, Verdict
from cellsim.live import keys
from cellsim.live.codec import encode_failure, encode_fields
from cellsim.vocabulary import SafetyMode

ROBOT_FAULTS = (Fault.CORRUPT, Fault.COUNTER, Fault.LATE, Fault.RANGE, Fault.TIMEOUT)
SAFE_REQUEST = {"safety_mode_request": SafetyMode.STOPPED.value, "activity": None, "target_pose": None}
"""What a robot is asked when its supervisor is lost: stop."""
_MODES = {m.value for m in SafetyMode}


@dataclass
class RobotStateChecker(LinkTrust):
    """The checks of one robot controller's state stream (see the module docstring)."""

    joints: int = 6
    joint_limit: float = 2 * math.pi
    max_joint_speed: float = 2 * math.pi
    max_delta: int = 5
    """How far ahead ``seq`` may jump (states lost on the way), before it counts as a counter fault."""
    faults: tuple = ROBOT_FAULTS
    last_seq: int | None = None

    def check(self, payload: bytes, now: float) -> Verdict:
        """Judge one state received at ``now`` (UNIX s, the clock the controller stamps with)."""
        try:
            state = json.loads(payload)
            t, seq = state["t"], state["seq"]
            position, velocity = state["position"], state["velocity"]
            if not (isinstance(t, (int, float)) and isinstance(seq, int) and isinstance(position, list)
                    and isinstance(velocity, list) and isinstance(state["safety_mode"], str)):
                raise TypeError
            position = [float(q) for q in position]
            velocity = [float(v) for v in velocity]
        except (ValueError, TypeError, KeyError, UnicodeDecodeError):
            return self._fail(Fault.CORRUPT)
        if self.last_seq is not None and not 1 <= seq - self.last_seq <= self.max_delta:
            self.last_seq = seq  # resynchronise on it, but do not trust this state
            return self._fail(Fault.COUNTER)
        self.last_seq = seq
        if now - t > self.timeout:
            return self._fail(Fault.LATE)
        if (len(position) != self.joints or len(velocity) != self.joints
                or not all(math.isfinite(q) and abs(q) <= self.joint_limit for q in position)
                or not all(math.isfinite(v) and abs(v) <= self.max_joint_speed for v in velocity)
                or state["safety_mode"] not in _MODES):
            return self._fail(Fault.RANGE)
        return self._good(now, {**state, "position": position, "velocity": velocity})


@dataclass
class RobotLink:
    """The daemon's side of one robot controller (states in, requests out)."""

    cell: str
    entity: str
    config: object
    """Its ``RobotLinkConfig``."""
    session: object
    recover_after: int = 3
    checker: RobotStateChecker = None
    published: int = 0
    failures_published: int = 0
    requests_sent: int = 0
    safe_requests_sent: int = 0
    received: int = 0
    diagnostics: object = None
    """Its DeviceDiagnostics (counted under the link's lock)."""
    _seq: int = 0
    _request_seq: int = 0
    _last_t: float = 0.0
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def __post_init__(self):
        cfg = self.config
        self.checker = RobotStateChecker(timeout=cfg.watchdog, recover_after=self.recover_after,
                                         joint_limit=cfg.joint_limit, max_joint_speed=cfg.max_joint_speed)
        self._sample = self.session.declare_publisher(keys.physical(self.cell, self.entity))
        self._request = self.session.declare_publisher(keys.controller_request(self.cell, self.entity))
        self._joint_state = None
        if cfg.ros_key:
            import zenoh

            from bridges.ros import JointStateEncoder

            self._encoder = JointStateEncoder(cfg.joints)
            self._joint_state = self.session.declare_publisher(cfg.ros_key, encoding=zenoh.Encoding.APPLICATION_CDR)

    def handle(self, payload: bytes, now: float | None = None) -> Verdict:
        import time

        now = time.time() if now is None else now
        with self._lock:
            self.received += 1
            if self.diagnostics is not None:
                self.diagnostics.frame()
            verdict = self.checker.check(payload, now)
            if verdict.trusted:
                state = verdict.values
                fields = {f"q{i}": q for i, q in enumerate(state["position"])}
                fields.update({name: state.get(name) for name in ("safety_mode", "activity", "reached_pose")})
                self._publish(encode_fields(self._stamp(float(state["t"])), self._next(), fields))
                if self._joint_state is not None:
                    self._joint_state.put(self._encoder.encode(state["t"], state["position"], state["velocity"]))
            else:
                self._fail(now, verdict.fault)
            return verdict

    def check_watchdog(self, now: float) -> None:
        with self._lock:
            verdict = self.checker.watchdog(now)
            if verdict is not None:
                self._fail(now, verdict.fault)

    def publish_diagnostics(self, now: float, every: float) -> None:
        with self._lock:
            self.diagnostics.publish(now, every)

    def send(self, fields: dict | None, now: float) -> None:
        """Send a request: the twin's command ``fields``, or the stop when None (the supervisor is lost)."""
        self._request_seq += 1
        self.requests_sent += 1
        if fields is None:
            self.safe_requests_sent += 1
            fields = SAFE_REQUEST
        self._request.put(encode_fields(now, self._request_seq, {**SAFE_REQUEST, **fields}))

    def _fail(self, now: float, fault: Fault | None) -> None:
        # a timeout or a late state: the controller's data is stale; anything else: corrupt
        failure = "stale" if fault in (Fault.TIMEOUT, Fault.LATE) else "corrupt"
        self.failures_published += 1
        self._publish(encode_failure(self._stamp(now), self._next(), failure))

    def _stamp(self, t: float) -> float:
        # the twin drops a message not newer than the last: keep the stamps increasing
        self._last_t = max(t, self._last_t + 1e-6)
        return self._last_t

    def _next(self) -> int:
        self._seq += 1
        return self._seq

    def _publish(self, payload: bytes) -> None:
        self.published += 1
        self._sample.put(payload)
