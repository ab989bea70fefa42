"""The robot kind's configuration: its model, named poses, speed limits and braking."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Literal

from cellsim.config.typed_yaml import FieldError, Range
from cellsim.config.layout import UNKNOWN
from cellsim.config.twin import TwinSettings
from cellsim.config.units import Degrees, JointAngle, Period, Speed, Vec3


@dataclass
class SpeedLimits:
    """Cap on the tool's speed (m/s) in each moving safety mode; srmst and stopped are standstill. A collaborative
    mode's cap is at most normal's."""

    normal: Speed = 1.0
    """Full speed: the highest cap (each collaborative mode's is at most this)."""
    hguid: Speed = 0.25
    """Hand-guided operation."""
    ssmon: Speed = 0.5
    """Speed and separation monitoring."""
    pflim: Speed = 0.25
    """Power and force limiting (ISO/TS 15066: collaborative speed)."""

    def __post_init__(self):
        # a collaborative mode reduces the speed: the arm's timing and braking (and verify's bounds of them) count
        # on none being faster than normal
        for mode in ("hguid", "ssmon", "pflim"):
            if getattr(self, mode) > self.normal:
                raise FieldError(mode, f"{getattr(self, mode):g} m/s is above normal ({self.normal:g} m/s): a "
                                 "collaborative mode cannot allow more than full speed")


@dataclass(frozen=True)
class ToolTarget:
    """A pose given by where the robot's tool should be; solved into joint angles at load time."""

    tool_at: Vec3
    """Where the tool frame's origin should be, in the cell (m)."""
    tool_rpy_deg: tuple[Degrees, Degrees, Degrees] | None = None
    """The tool frame's orientation in the cell, roll-pitch-yaw (degrees); omitted: any orientation."""


@dataclass
class RobotConfig:
    kind: Literal["robot"]
    model: str
    """URDF of the arm, relative to the scenario file."""
    named_poses: dict[str, list[JointAngle] | ToolTarget]
    """The poses the process moves between: joint positions (rad), or a tool target
    ``{tool_at: [x, y, z], tool_rpy_deg: [r, p, y]}`` solved by inverse kinematics at load time."""
    base_position: Vec3 = (0.0, 0.0, 0.0)
    """Where the arm's base_link is fixed in the cell (m)."""
    base_yaw_deg: Degrees = 0.0
    """Rotation of the base about the vertical axis (degrees)."""
    tool_frame: str = "tcp"
    """The frame of the model whose position gives the robot's location and tool speed."""
    activities: list[str] = field(default_factory=lambda: ["idle", "working", "off"])
    """Its activities in the cell's words (ract); the first is its activity before the process starts."""
    initial_pose: str = "home"
    """The named pose the arm starts in."""
    speed_limits: SpeedLimits = field(default_factory=SpeedLimits)
    """Tool speed cap per moving safety mode (m/s): a limit the tool (its tool_frame) keeps in that mode (the arm plans
    0.04 m/s below it), once braked to it: the mode reads the new one as soon as it is requested, while the arm brakes
    from its speed at its own rate (braking_time from full speed), so after a change to a slower mode the tool is above
    the new cap for up to braking_time x (old - new) / normal. Other points of the arm may move somewhat faster than
    the tool (the harm service and ssm measure every shape's own speed)."""
    payload: Annotated[float, Range(0.0, 1000.0, unit="kg")] = 0.0
    """Mass the tool carries (kg): with half the moving links' mass, the robot's effective mass in a contact
    (ISO/TS 15066 Annex A), which the harm service judges contacts by."""
    braking_time: Annotated[float, Range(0.0, 10.0, lo_open=True, unit="s")] = 0.5
    """Time to standstill from full speed on srmst or stopped (s)."""
    period: Period = 0.02
    """Update period of the controller side (s); a multiple of the plant step."""
    twin: TwinSettings = field(default_factory=TwinSettings)
    """Its twin mode (model, shadow, twin), scheduled changes and when samples go stale."""

    def __post_init__(self):
        if len(set(self.activities)) != len(self.activities) or not all(a.isidentifier() for a in self.activities):
            raise FieldError("activities", "activities must be distinct identifiers")
        if not self.activities or UNKNOWN in self.activities:
            raise FieldError("activities", f"list at least one activity; '{UNKNOWN}' is what a shadowed robot reports")
        if "moving" in self.named_poses:
            raise FieldError("named_poses.moving", "'moving' is what reached_pose reads between poses; name the pose otherwise")
        if self.initial_pose not in self.named_poses:
            raise FieldError("initial_pose", f"'{self.initial_pose}' is not one of the named_poses")
        for name, q in self.named_poses.items():
            if isinstance(q, list) and len(q) != 6:
                raise FieldError(f"named_poses.{name}", f"needs 6 joint positions, got {len(q)}")
