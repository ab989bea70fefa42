"""ROS 2 messages as zenoh-bridge-ros2dds carries them: CDR with its 4-byte encapsulation header.

zenoh-bridge-ros2dds maps a ROS 2 topic to a Zenoh key (the topic name without
its leading ``/``, after the bridge's namespace) and carries the message's raw
CDR serialisation. ``rosbags`` serialises standard message types in pure Python,
so the daemon needs no ROS installation to speak to ROS 2 tools.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

JOINT_STATE = "sensor_msgs/msg/JointState"


@lru_cache(maxsize=1)
def typestore():
    """The ROS 2 (Humble) type store of rosbags: standard messages and their CDR (de)serialisers."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


class JointStateEncoder:
    """Joint states as CDR ``sensor_msgs/msg/JointState`` messages, for fixed joint names.

    With the names fixed, every field of the message sits at a fixed offset: rosbags
    serialises one template message, and each state is packed into a copy of it at the
    offsets found there (a state at 500 Hz costs microseconds, not rosbags' tenth of a
    millisecond). Little-endian CDR, as the template's encapsulation header says.
    """

    def __init__(self, joints: list[str]):
        import struct

        store = typestore()
        self.joints = list(joints)
        n = len(self.joints)
        JointState, Header, Time = (store.types[t] for t in (JOINT_STATE, "std_msgs/msg/Header", "builtin_interfaces/msg/Time"))
        # sentinels: values that appear nowhere else in the serialised template
        position = np.array([1e300 / (k + 2) for k in range(n)])
        velocity = np.array([-1e300 / (k + 2) for k in range(n)])
        template = bytes(store.serialize_cdr(
            JointState(header=Header(stamp=Time(sec=0x5A5A5A5A, nanosec=0x3C3C3C3C), frame_id=""), name=self.joints,
                       position=position, velocity=velocity, effort=np.array([], dtype=np.float64)), JOINT_STATE))
        assert template[:4] == b"\x00\x01\x00\x00", "rosbags no longer writes little-endian CDR"
        self._template = bytearray(template)
        self._stamp_at = template.index(struct.pack("<iI", 0x5A5A5A5A, 0x3C3C3C3C))
        self._position_at = template.index(position.astype("<f8").tobytes())
        self._velocity_at = template.index(velocity.astype("<f8").tobytes())
        self._stamp = struct.Struct("<iI")
        self._doubles = struct.Struct(f"<{n}d")

    def encode(self, t: float, position, velocity) -> bytes:
        """The CDR bytes of the state at UNIX time ``t`` (s): positions in rad, velocities in rad/s."""
        sec = math.floor(t)
        message = self._template
        self._stamp.pack_into(message, self._stamp_at, int(sec), min(int(round((t - sec) * 1e9)), 999_999_999))
        self._doubles.pack_into(message, self._position_at, *position)
        self._doubles.pack_into(message, self._velocity_at, *velocity)
        return bytes(message)


def decode_joint_state(payload: bytes):
    """A CDR ``sensor_msgs/msg/JointState`` back as its rosbags message (for tests and tools)."""
    return typestore().deserialize_cdr(payload, JOINT_STATE)
