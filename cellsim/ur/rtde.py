"""RTDE, the Real-Time Data Exchange of Universal Robots controllers, on the wire (protocol version 2).

One codec for both ends: the bridge daemon's client (``cellsim.bridges.ur``) and
the emulated controller's server (``cellsim.ur.controller``). ``ur-rtde``'s
clients (a library nobody here wrote) are what the server is tested against.

A package is ``uint16 size`` (the whole package, header included), ``uint8 type``,
then its payload; everything big-endian. The types a session uses:

======== ===== ======================================================================
type     byte  payload (client -> controller; controller's reply)
======== ===== ======================================================================
``V``    86    uint16 protocol version; reply uint8 accepted
``v``    118   nothing; reply uint32 major, minor, bugfix, build
``O``    79    double frequency (Hz), the variables' names joined by commas; reply uint8
               recipe id, their types joined by commas (``NOT_FOUND`` for an unknown name)
``I``    73    the variables' names; reply uint8 recipe id, their types (``IN_USE`` for a
               name another client writes, ``NOT_FOUND``); recipe id 0: refused
``S``    83    nothing; reply uint8 accepted (outputs stream from now on)
``P``    80    nothing; reply uint8 accepted
``U``    85    uint8 recipe id, then the recipe's values in order (both ways)
``M``    77    uint8 length, message, uint8 length, source, uint8 warning level
======== ===== ======================================================================

Field types: ``BOOL``/``UINT8`` one byte, ``UINT32``, ``INT32``, ``UINT64``,
``DOUBLE``, and the vectors ``VECTOR3D``, ``VECTOR6D``, ``VECTOR6INT32``,
``VECTOR6UINT32``. The variables' names and types are the controller's
(:data:`OUTPUTS`, :data:`INPUTS`, with the register families).

RTDE has no authentication or integrity check of its own (TCP's checksum
aside): on a real cell it runs on the cell's own network, and the daemon judges
each state by the link rule (``cellsim.link``) as it does any physical twin's data.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass

PORT = 30004
"""The controller's RTDE port."""
PROTOCOL_VERSION = 2

REQUEST_PROTOCOL_VERSION = ord("V")
GET_URCONTROL_VERSION = ord("v")
TEXT_MESSAGE = ord("M")
DATA_PACKAGE = ord("U")
SETUP_OUTPUTS = ord("O")
SETUP_INPUTS = ord("I")
START = ord("S")
PAUSE = ord("P")

HEADER = struct.Struct(">HB")
MAX_PACKAGE = 0xFFFF

NOT_FOUND = "NOT_FOUND"
IN_USE = "IN_USE"

FORMATS = {
    "BOOL": "?", "UINT8": "B", "UINT32": "I", "INT32": "i", "UINT64": "Q", "DOUBLE": "d",
    "VECTOR3D": "3d", "VECTOR6D": "6d", "VECTOR6INT32": "6i", "VECTOR6UINT32": "6I",
}
"""Each RTDE field type's ``struct`` format (big-endian in a package)."""

_V6 = "VECTOR6D"
OUTPUTS = {
    "timestamp": "DOUBLE", "target_q": _V6, "target_qd": _V6, "target_qdd": _V6, "target_current": _V6,
    "target_moment": _V6, "actual_q": _V6, "actual_qd": _V6, "actual_current": _V6, "joint_control_output": _V6,
    "actual_TCP_pose": _V6, "actual_TCP_speed": _V6, "actual_TCP_force": _V6, "target_TCP_pose": _V6,
    "target_TCP_speed": _V6, "actual_digital_input_bits": "UINT64", "joint_temperatures": _V6,
    "actual_execution_time": "DOUBLE", "robot_mode": "INT32", "joint_mode": "VECTOR6INT32", "safety_mode": "INT32",
    "safety_status": "INT32", "actual_tool_accelerometer": "VECTOR3D", "speed_scaling": "DOUBLE",
    "target_speed_fraction": "DOUBLE", "actual_momentum": "DOUBLE", "actual_main_voltage": "DOUBLE",
    "actual_robot_voltage": "DOUBLE", "actual_robot_current": "DOUBLE", "actual_joint_voltage": _V6,
    "actual_digital_output_bits": "UINT64", "runtime_state": "UINT32", "elbow_position": "VECTOR3D",
    "elbow_velocity": "VECTOR3D", "robot_status_bits": "UINT32", "safety_status_bits": "UINT32",
    "analog_io_types": "UINT32", "standard_analog_input0": "DOUBLE", "standard_analog_input1": "DOUBLE",
    "standard_analog_output0": "DOUBLE", "standard_analog_output1": "DOUBLE", "io_current": "DOUBLE",
    "euromap67_input_bits": "UINT32", "euromap67_output_bits": "UINT32", "euromap67_24V_voltage": "DOUBLE",
    "euromap67_24V_current": "DOUBLE", "tool_mode": "UINT32", "tool_analog_input_types": "UINT32",
    "tool_analog_input0": "DOUBLE", "tool_analog_input1": "DOUBLE", "tool_output_voltage": "INT32",
    "tool_output_current": "DOUBLE", "tool_temperature": "DOUBLE", "tcp_force_scalar": "DOUBLE",
    "output_bit_registers0_to_31": "UINT32", "output_bit_registers32_to_63": "UINT32",
    "input_bit_registers0_to_31": "UINT32", "input_bit_registers32_to_63": "UINT32",
    "payload": "DOUBLE", "payload_cog": "VECTOR3D", "payload_inertia": _V6, "script_control_line": "UINT32",
    "ft_raw_wrench": _V6, "tcp_offset": _V6, "actual_robot_energy_consumed": "DOUBLE",
    "actual_robot_braking_energy_dissipated": "DOUBLE",
}
"""The controller's output variables a client may ask for, and their types."""

INPUTS = {
    "speed_slider_mask": "UINT32", "speed_slider_fraction": "DOUBLE",
    "standard_digital_output_mask": "UINT8", "standard_digital_output": "UINT8",
    "configurable_digital_output_mask": "UINT8", "configurable_digital_output": "UINT8",
    "tool_digital_output_mask": "UINT8", "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8", "standard_analog_output_type": "UINT8",
    "standard_analog_output_0": "DOUBLE", "standard_analog_output_1": "DOUBLE",
    "input_bit_registers0_to_31": "UINT32", "input_bit_registers32_to_63": "UINT32",
    "external_force_torque": _V6,
}
"""The controller's input variables a client may write, and their types."""

REGISTERS = 48
"""Registers per family (``input_int_register_0`` .. ``_47``; 0-23 the lower range, 24-47 the upper)."""
_REGISTER = re.compile(r"(input|output)_(int|double|bit)_register_(\d+)$")


def output_type(name: str) -> str:
    """The type of output variable ``name`` (``NOT_FOUND`` for one the controller does not have)."""
    return OUTPUTS.get(name) or _register_type(name, ("output", "input")) or NOT_FOUND


def input_type(name: str) -> str:
    """The type of input variable ``name`` (``NOT_FOUND`` for one the controller does not have)."""
    return INPUTS.get(name) or _register_type(name, ("input",)) or NOT_FOUND


def _register_type(name: str, directions: tuple[str, ...]) -> str | None:
    match = _REGISTER.match(name)
    number = int(match[3]) if match else -1
    valid = range(64, 128) if match and match[2] == "bit" else range(REGISTERS)  # bits 0-63: the 32-bit groups
    if match is None or match[1] not in directions or number not in valid:
        return None
    return {"int": "INT32", "double": "DOUBLE", "bit": "BOOL"}[match[2]]


def int_register(direction: str, number: int) -> str:
    """The name of integer register ``number``: ``input_int_register_18``, ``output_int_register_18``."""
    return f"{direction}_int_register_{number}"


# -- safety and robot modes, as the controller reports them ------------------------------
SAFETY_MODES = {
    1: "NORMAL", 2: "REDUCED", 3: "PROTECTIVE_STOP", 4: "RECOVERY", 5: "SAFEGUARD_STOP",
    6: "SYSTEM_EMERGENCY_STOP", 7: "ROBOT_EMERGENCY_STOP", 8: "VIOLATION", 9: "FAULT",
    10: "VALIDATE_JOINT_ID", 11: "UNDEFINED_SAFETY_MODE", 12: "AUTOMATIC_MODE_SAFEGUARD_STOP",
    13: "SYSTEM_THREE_POSITION_ENABLING_STOP",
}
"""``safety_mode``: the controller's safety mode codes."""
SAFETY_NORMAL, SAFETY_REDUCED, SAFETY_PROTECTIVE_STOP, SAFETY_UNDEFINED = 1, 2, 3, 11
ROBOT_MODES = {
    -1: "NO_CONTROLLER", 0: "DISCONNECTED", 1: "CONFIRM_SAFETY", 2: "BOOTING", 3: "POWER_OFF", 4: "POWER_ON",
    5: "IDLE", 6: "BACKDRIVE", 7: "RUNNING", 8: "UPDATING_FIRMWARE",
}
"""``robot_mode``: the arm's power and brake state."""
ROBOT_RUNNING = 7
RUNTIME_STATES = {0: "STOPPING", 1: "STOPPED", 2: "PLAYING", 3: "PAUSING", 4: "PAUSED", 5: "RESUMING"}
"""``runtime_state``: the program's."""
RUNTIME_PLAYING = 2

SAFETY_STATUS_BITS = ("normal", "reduced", "protective_stopped", "recovery", "safeguard_stopped",
                      "system_emergency_stopped", "robot_emergency_stopped", "emergency_stopped", "violation",
                      "fault", "stopped_due_to_safety")
"""``safety_status_bits``: bit i set is this name."""


class RtdeError(ValueError):
    """A package that does not follow the protocol (the message says what is wrong)."""


# -- packages ------------------------------------------------------------------------
def package(kind: int, payload: bytes = b"") -> bytes:
    """One package: its header and ``payload``."""
    size = HEADER.size + len(payload)
    if size > MAX_PACKAGE:
        raise RtdeError(f"a package of {size} bytes is longer than RTDE allows ({MAX_PACKAGE})")
    return HEADER.pack(size, kind) + payload


def text(value: str) -> bytes:
    return value.encode("ascii", "replace")


def names_payload(names: list[str]) -> bytes:
    return text(",".join(names))


def names_of(payload: bytes) -> list[str]:
    """The comma-separated names or types of a setup package or its reply (``ur-rtde`` ends its list
    with a comma: an empty name is no name)."""
    try:
        value = payload.decode("ascii")
    except UnicodeDecodeError:
        raise RtdeError("a list of names that is not ASCII") from None
    return [n.strip() for n in value.split(",") if n.strip()]


def text_message(message: str, source: str = "cellsim", level: int = 1) -> bytes:
    """A text message package (protocol version 2): ``level`` 0 exception, 1 error, 2 warning, 3 info."""
    m, s = text(message)[:255], text(source)[:255]
    return package(TEXT_MESSAGE, bytes([len(m)]) + m + bytes([len(s)]) + s + bytes([level]))


class PackageReader:
    """Packages out of a byte stream: ``feed`` bytes as they come, iterate the whole packages."""

    def __init__(self):
        self._buffer = bytearray()

    def feed(self, data: bytes) -> list[tuple[int, bytes]]:
        """The (type, payload) of every package completed by ``data``; RtdeError on a size no package has."""
        buffer = self._buffer
        buffer += data
        done = []
        while len(buffer) >= HEADER.size:
            size, kind = HEADER.unpack_from(buffer)
            if size < HEADER.size:
                raise RtdeError(f"a package header giving {size} bytes, less than the header itself")
            if len(buffer) < size:
                break
            done.append((kind, bytes(buffer[HEADER.size:size])))
            del buffer[:size]
        return done


@dataclass(frozen=True)
class Recipe:
    """A recipe: the variables one data package carries, in order, and their types."""

    id: int
    names: tuple[str, ...]
    types: tuple[str, ...]

    def __post_init__(self):
        unknown = [t for t in self.types if t not in FORMATS]
        if unknown:
            raise RtdeError(f"recipe {self.id}: no such type {', '.join(unknown)}")
        object.__setattr__(self, "_struct", struct.Struct(">" + "".join(FORMATS[t] for t in self.types)))

    @property
    def size(self) -> int:
        """The bytes of a data package's values (after the recipe id)."""
        return self._struct.size

    def pack(self, values: dict) -> bytes:
        """A data package of this recipe: each variable's value from ``values`` (vectors as sequences)."""
        flat = []
        for name, kind in zip(self.names, self.types):
            value = values[name]
            if kind.startswith("VECTOR"):
                flat.extend(value)
            elif kind == "BOOL":
                flat.append(bool(value))
            elif kind == "DOUBLE":
                flat.append(float(value))
            else:
                flat.append(int(value))
        return package(DATA_PACKAGE, bytes([self.id]) + self._struct.pack(*flat))

    def unpack(self, payload: bytes) -> dict:
        """The values of a data package's payload (recipe id first); RtdeError if it is not this recipe's."""
        if not payload or payload[0] != self.id:
            raise RtdeError(f"a data package of recipe {payload[0] if payload else '?'}, expected {self.id}")
        if len(payload) - 1 != self.size:
            raise RtdeError(f"a data package of recipe {self.id} with {len(payload) - 1} bytes of values, "
                            f"expected {self.size}")
        flat = self._struct.unpack_from(payload, 1)
        values, i = {}, 0
        for name, kind in zip(self.names, self.types):
            width = 6 if kind.startswith("VECTOR6") else 3 if kind == "VECTOR3D" else 1
            values[name] = flat[i] if width == 1 else flat[i:i + width]
            i += width
        return values
