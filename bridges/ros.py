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
    """Joint states as CDR ``sensor_msgs/msg/JointState`` messages, for fixed joint names."""

    def __init__(self, joints: list[str]):
        store = typestore()
        self.joints = list(joints)
        self._store = store
        self._JointState = store.types[JOINT_STATE]
        self._Header = store.types["std_msgs/msg/Header"]
        self._Time = store.types["builtin_interfaces/msg/Time"]
        self._no_effort = np.array([], dtype=np.float64)

    def encode(self, t: float, position, velocity) -> bytes:
        """The CDR bytes of the state at UNIX time ``t`` (s): positions in rad, velocities in rad/s."""
        sec = math.floor(t)
        stamp = self._Time(sec=int(sec), nanosec=min(int(round((t - sec) * 1e9)), 999_999_999))
        message = self._JointState(
            header=self._Header(stamp=stamp, frame_id=""), name=self.joints,
            position=np.asarray(position, dtype=np.float64), velocity=np.asarray(velocity, dtype=np.float64),
            effort=self._no_effort,
        )
        return bytes(self._store.serialize_cdr(message, JOINT_STATE))


def decode_joint_state(payload: bytes):
    """A CDR ``sensor_msgs/msg/JointState`` back as its rosbags message (for tests and tools)."""
    return typestore().deserialize_cdr(payload, JOINT_STATE)
