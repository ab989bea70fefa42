"""The live twin's Zenoh key space (docs/live.md): the contract between the twin,
the emulator, the bridge daemon and the dashboard.

Every key starts ``cellsim/<cell>/`` (the scenario's name). Segments are lower-case
identifiers, so a key is also a valid ROS 2 topic name: zenoh-bridge-ros2dds maps
the ROS topic ``/cellsim/welding_cell/physical/robot`` to this very key.
"""

from __future__ import annotations

ROOT = "cellsim"


def cell_prefix(cell: str) -> str:
    return f"{ROOT}/{cell}"


def channel(cell: str, module: str, signal: str) -> str:
    """A twin channel's value: on change, and every HEARTBEAT seconds."""
    return f"{ROOT}/{cell}/twin/{module}/{signal}"


def physical(cell: str, entity: str) -> str:
    """A physical twin's samples (the emulator or the bridge daemon publishes them)."""
    return f"{ROOT}/{cell}/physical/{entity}"


def command(cell: str, entity: str) -> str:
    """Commands to a physical twin (the twin publishes them for entities in twin mode)."""
    return f"{ROOT}/{cell}/command/{entity}"


def twin_mode_control(cell: str) -> str:
    """Queryable of the running twin: a request to switch an entity's twin mode."""
    return f"{ROOT}/{cell}/control/twin_mode"


def status(cell: str, process: str) -> str:
    """A process's status (pacing lag, sample ages), every second."""
    return f"{ROOT}/{cell}/status/{process}"


def alive(cell: str, process: str) -> str:
    """A process's liveliness token: present while it runs."""
    return f"{ROOT}/{cell}/alive/{process}"


def fault_control(cell: str) -> str:
    """Queryable of the emulator: inject a fault at run time."""
    return f"{ROOT}/{cell}/control/fault"


def controller_state(cell: str, robot: str) -> str:
    """A robot controller's state stream (joint state at its own rate: 500 Hz for a UR e-Series);
    the bridge daemon turns it into the robot's physical samples."""
    return f"{ROOT}/{cell}/controller/{robot}/state"


def controller_request(cell: str, robot: str) -> str:
    """Requests to a robot controller (safety mode, activity, target pose), from the bridge daemon."""
    return f"{ROOT}/{cell}/controller/{robot}/request"


def diagnostics(cell: str, device: str) -> str:
    """The bridge daemon's diagnostics of one device (level OK/WARN/ERROR/STALE, rates, error counts)."""
    return f"{ROOT}/{cell}/diagnostics/{device}"


def describe(cell: str) -> str:
    """Queryable of the running twin: what it runs (the resolved scenario, its channels and hazards),
    for a dashboard that has only the network."""
    return f"{ROOT}/{cell}/describe"
