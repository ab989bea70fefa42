"""The robot over Zenoh: its controller's state in, the twin's requests out.

A robot controller's side (an adapter of its own on a real cell; ``cellsim
emulate --can`` here; a UR controller is dialled over RTDE instead,
``cellsim.bridges.ur``) publishes its state on
``cellsim/<cell>/controller/<robot>/state`` at its own rate (500 Hz for a UR
e-Series), one JSON object per state::

    {"t": 1795000000.002, "seq": 17, "position": [6 x rad], "velocity": [6 x rad/s],
     "safety_mode": "normal", "activity": "moving", "reached_pose": "home"}

``t`` is the controller's wall-clock time of the state, ``seq`` counts its
states, ``position``/``velocity`` follow the configured joint order, the rest
are the robot entity's sample fields (``cellsim modules robot``).

The daemon checks every state as it checks a CAN frame (``RobotStateChecker``):
it must decode (else *corrupt*), then the link rule (``cellsim.link``): its
``seq`` must follow the last one (a repeat or a step back is refused, a jump of
more than 5 is *counter*), its stamp must not be ahead of the daemon's clock
(refused) nor older than the watchdog on arrival (*late*); its joints must be
finite and within the configured limits and its safety mode one of the
vocabulary's (*range*), and a good one must come within the watchdog (*timeout*). A trusted state becomes the robot's physical
sample (``q0``..``q5`` from ``position``) and a CDR ``sensor_msgs/JointState``
on the key zenoh-bridge-ros2dds maps to the configured ROS 2 topic. A good state
is forwarded at once; any fault publishes a failure message (``cellsim.codec``)
at once: the twin's robot fails safe without waiting for its ``stale_after``, and
trusts the link again only after ``recover_after`` good samples in a row.

Requests go back on ``cellsim/<cell>/controller/<robot>/request`` in the live
command format, only while the robot is in twin mode: the twin's latest
command, or a stop (``safety_mode_request: stopped``, no activity, no target)
when the twin is lost.
"""

from __future__ import annotations

import math
import threading
import zlib
from dataclasses import dataclass, field

from cellsim.link import Fault, Judgement, LinkTrust
from cellsim import codec
from cellsim.live import keys
from cellsim.vocabulary import SafetyMode

ROBOT_FAULTS = (Fault.CORRUPT, Fault.COUNTER, Fault.REPEATED, Fault.MASQUERADE, Fault.FUTURE, Fault.LATE, Fault.RANGE,
                Fault.TIMEOUT)
_MODES = {m.value for m in SafetyMode}


@dataclass
class JointStateChecker(LinkTrust):
    """The link rule of a robot controller's state stream, with the range every arm's joints must keep."""

    joint_limit: float = 2 * math.pi
    """Each joint's position at most this far from zero (rad)."""
    max_joint_speed: float = 2 * math.pi
    """Each joint's speed at most this (rad/s)."""
    max_gap: int = 5
    """How far ahead ``seq`` may jump (states lost on the way) before it counts as a counter fault."""
    faults: tuple = ROBOT_FAULTS

    def joints_in_range(self, position, velocity) -> bool:
        """Whether every joint is within its limit and its speed."""
        return (all(abs(q) <= self.joint_limit for q in position)
                and all(abs(v) <= self.max_joint_speed for v in velocity))


@dataclass
class RobotStateChecker(JointStateChecker):
    """The checks of one robot controller's state stream (see the module docstring), then the link rule."""

    joints: int = 6

    def check(self, payload: bytes, now: float, wall: float | None = None) -> Judgement:
        """Judge one state received at ``now`` (the daemon's clock) and ``wall`` (UNIX s, for the stamp)."""
        import time

        try:
            state = codec.loads(payload)
            t, seq = codec.stamp(state)
            position, velocity = state.get("position"), state.get("velocity")
            if not (isinstance(position, list) and isinstance(velocity, list)
                    and isinstance(state.get("safety_mode"), str)):
                raise codec.CodecError("not a robot state")
            position = [codec.number(q, "position", 1e6) for q in position]
            velocity = [codec.number(v, "velocity", 1e6) for v in velocity]
        except codec.CodecError:
            return self.fail(Fault.CORRUPT, now)
        return self.receive(now, seq, zlib.crc32(payload), stamp=t, wall=time.time() if wall is None else wall,
                            values={**state, "position": position, "velocity": velocity}, in_range=self._in_range)

    def _in_range(self, state: dict) -> Fault | None:
        """RANGE for a state with other than six joints, a joint beyond its limit or speed, an unknown mode."""
        position, velocity = state["position"], state["velocity"]
        if (len(position) != self.joints or len(velocity) != self.joints
                or not self.joints_in_range(position, velocity) or state["safety_mode"] not in _MODES):
            return Fault.RANGE
        return None


@dataclass
class RobotLink:
    """The daemon's side of one robot controller (states in, requests out)."""

    cell: str
    entity: str
    config: object
    """Its ``RobotLinkConfig``."""
    session: object
    safe: dict = field(default_factory=dict)
    """The robot kind's safe command, as command fields: what the controller is asked when the twin is lost."""
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

            from cellsim.bridges.ros import JointStateEncoder

            self._encoder = JointStateEncoder(cfg.joints)
            self._joint_state = self.session.declare_publisher(cfg.ros_key, encoding=zenoh.Encoding.APPLICATION_CDR)

    def handle(self, payload: bytes, now: float | None = None, wall: float | None = None) -> Judgement:
        """Judge one state that arrived at ``now`` (the daemon's clock) and ``wall`` (UNIX s), and publish what it
        means for the twin."""
        import time

        now = time.monotonic() if now is None else now
        with self._lock:
            self.received += 1
            if self.diagnostics is not None:
                self.diagnostics.frame()
            judgement = self.checker.check(payload, now, wall)
            if judgement.good:
                state = judgement.values
                fields = {f"q{i}": q for i, q in enumerate(state["position"])}
                fields.update({name: state.get(name) for name in ("safety_mode", "activity", "reached_pose")})
                self._publish(codec.encode_fields(float(state["t"]), self._next(), fields))
                if self._joint_state is not None:
                    self._joint_state.put(self._encoder.encode(state["t"], state["position"], state["velocity"]))
            elif judgement.fault not in (Fault.REPEATED, Fault.FUTURE):
                self._fail(judgement.fault)
            return judgement

    def check_watchdog(self, now: float) -> None:
        with self._lock:
            judgement = self.checker.watchdog(now)
            if judgement is not None:
                self._fail(judgement.fault)

    def publish_diagnostics(self, now: float, every: float) -> None:
        with self._lock:
            self.diagnostics.publish(now, every)

    def send(self, fields: dict | None, now: float) -> None:
        """Send a request: the twin's command ``fields``, or the kind's safe command when None (the twin is lost)."""
        import time

        self._request_seq += 1
        self.requests_sent += 1
        if fields is None:
            self.safe_requests_sent += 1
            fields = self.safe
        self._request.put(codec.encode_fields(time.time(), self._request_seq, {**self.safe, **fields}))

    def _fail(self, fault: Fault | None) -> None:
        import time

        # a timeout or a late state: the controller's data is stale; anything else: corrupt
        self.failures_published += 1
        self._publish(codec.encode_failure(time.time(), self._next(), fault))

    def _next(self) -> int:
        self._seq += 1
        return self._seq

    def _publish(self, payload: bytes) -> None:
        self.published += 1
        self._sample.put(payload)
