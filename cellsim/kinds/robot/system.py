"""The collaborative robot arm: joint-space motion between named poses, its safety
state machine, and where its tool is.

The arm itself is a MultibodyPlant model driven by an InverseDynamicsController
(both in Drake's C++, stepping every ``time_step``). This module is the arm's
*controller side*: every ``period`` (20 ms) it turns the process controller's target pose and
the safety controller's mode request into a desired joint state, and reports
the robot's safety mode, activity, location and tool speed measured on the plant.

Motion: a straight line in joint space from the current desired position to the
target pose, timed by a path parameter s in [0, 1]. Its rate ds/dt is capped by
the joint velocity limits and by the tool speed cap of the current safety mode
(``speed_limits``: pflim 0.25 m/s) less ``TRACKING_ALLOWANCE``, so the measured
speed stays under the cap, using the largest tool displacement per unit
of s along the segment; it changes at most at the rate that brings the robot
from full speed to standstill within ``braking_time`` (s), which is how srmst
and stopped bring it to rest.
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import MultibodyPlant
from pydrake.geometry import Rgba
from pydrake.math import RigidTransform, RollPitchYaw

from cellsim.channels import enum_type, number_type, vector_type
from cellsim.entity import EntitySystem, valid_code
from cellsim.kinds.robot.config import RobotConfig
from cellsim.config.layout import Layout
from cellsim.systems import read_scalar, write_changed, write_scalar
from cellsim.vocabulary import SafetyMode, TwinMode, value_set

KP, KI, KD = 400.0, 1.0, 40.0
"""Joint controller gains: 20 rad/s bandwidth, critically damped."""

HOLD = -1.0
"""Target-pose code meaning "stay where you are"."""

STANDSTILL_MODES = frozenset({SafetyMode.MONITORED_STOP, SafetyMode.STOPPED})
_MODES = tuple(SafetyMode)


def requested_mode(code: float) -> SafetyMode:
    """The safety mode a request's ``code`` asks of the arm: a request with no value (NaN, -1), with no mode's code,
    or asking for ``unknown`` (no mode an arm can be put in) is a stop."""
    if not (math.isfinite(code) and 0 <= code < len(_MODES)):
        return SafetyMode.STOPPED
    mode = _MODES[int(code)]
    return SafetyMode.STOPPED if mode is SafetyMode.UNKNOWN else mode
_SEGMENT_SAMPLES = 24
TRACKING_ALLOWANCE = 0.04
"""The arm plans its tool speed this far below a mode's speed cap (m/s): the joint controller
overshoots a planned speed by up to about that much as an acceleration ends, and the measured
speed must never exceed the cap (a safety-rated reduced speed is a limit, not a target)."""
PATH_MARGIN = 1.05
"""A segment's tool metres per unit of its path (``tool_per_s``) are its sampled points' fastest stretch times this,
for the tool's speed between two samples."""


def braking_deceleration(cfg) -> float:
    """The tool's braking deceleration (m/s^2) the arm delivers at its path's fastest point on a segment its normal
    cap limits: it plans that segment at ``speed_limits.normal`` less ``TRACKING_ALLOWANCE``, over ``PATH_MARGIN``, and
    brakes from there to standstill in ``braking_time``. A segment its joints limit (planned slower) brakes slower."""
    return (cfg.speed_limits.normal - TRACKING_ALLOWANCE) / (PATH_MARGIN * cfg.braking_time)


def _shell(r: float, g: float, b: float) -> Rgba:
    return Rgba(r, g, b, 0.85)


SAFETY_MODE_COLORS = {
    SafetyMode.HAND_GUIDED.value: _shell(0.2, 0.5, 1.0),  # blue
    SafetyMode.SPEED_SEPARATION.value: _shell(1.0, 0.85, 0.1),  # yellow
    SafetyMode.POWER_FORCE_LIMITING.value: _shell(1.0, 0.55, 0.0),  # orange
    SafetyMode.MONITORED_STOP.value: _shell(0.95, 0.25, 0.1),  # red-orange
    SafetyMode.STOPPED.value: _shell(0.8, 0.0, 0.0),  # red
    SafetyMode.UNKNOWN.value: _shell(0.7, 0.0, 0.8),  # magenta: no valid sample, assume the worst
}
"""The shell the arm wears in Meshcat per safety mode (normal: none, the arm's own colours)."""


def robot_base_pose(cfg: RobotConfig) -> RigidTransform:
    return RigidTransform(RollPitchYaw(0.0, 0.0, np.radians(cfg.base_yaw_deg)), list(cfg.base_position))


class ArmKinematics:
    """A private, continuous copy of the arm for forward kinematics of the tool."""

    def __init__(self, model_path: str, cfg: RobotConfig):
        self.model_path = str(model_path)
        self.plant = MultibodyPlant(0.0)
        (instance,) = Parser(self.plant).AddModels(str(model_path))
        base = self.plant.GetBodyByName("base_link", instance).body_frame()
        self.plant.WeldFrames(self.plant.world_frame(), base, robot_base_pose(cfg))
        self.plant.Finalize()
        self.context = self.plant.CreateDefaultContext()
        self.tool = self.plant.GetFrameByName(cfg.tool_frame, instance)
        self.velocity_limits = self.plant.GetVelocityUpperLimits()
        self.num_joints = self.plant.num_positions()

    def tool_position(self, q) -> np.ndarray:
        self.plant.SetPositions(self.context, q)
        return self.tool.CalcPoseInWorld(self.context).translation()

    def tool_position_and_speed(self, x) -> tuple[np.ndarray, float]:
        """Tool position (m) and translational speed (m/s) for the state x = [q, v]."""
        self.plant.SetPositionsAndVelocities(self.context, x)
        position = self.tool.CalcPoseInWorld(self.context).translation()
        speed = float(np.linalg.norm(self.tool.CalcSpatialVelocityInWorld(self.context).translational()))
        return position, speed


class Robot(EntitySystem):
    """The robot arm's controller side.

    Ports:
      safety_mode_request (input): SafetyMode code from the safety controller.
      target_pose (input): index of the named pose to move to, or -1 to hold.
      activity (input): code of the robot activity the process controller is carrying out.
      speed_limit (input, m/s): the tool speed allowed now in ssmon (speed and separation
        monitoring, ``cellsim.kinds.ssm``), below the mode's fixed cap; none: the cap alone.
      speed_scaling (input, 0..1): the controller's speed slider (a UR's): every motion's planned speed
        times it, 0 stops it; 1 unless an emulated controller drives it (``cellsim.ur``).
      measured_state (input): the plant's joint state [q (rad), v (rad/s)].
      physical_sample (input): [t, link, q (6, rad), safety_mode code, activity code, reached_pose code].
      desired_state (output): [q (rad), v (rad/s)] for the joint controller.
      safety_mode (channel): the robot's current safety mode (safmod).
      activity (channel): one of the robot's ``activities`` (ract; the welding cell:
        idle / exchWrkp / welding / off).
      location (channel): the name of the layout's robot region holding the tool, else
        layout.robot_elsewhere (rloc; the welding cell: atTable / sharedTbl / atWeldSpot / inCell).
      reached_pose (channel): the named pose the arm rests at, or ``moving``.
      joint_positions (channel, rad): measured q, at every update (recorded as it changes).
      tool_speed (channel, m/s): measured tool speed, at every update (recorded as it changes).

    In shadow or twin mode with no valid physical sample (stale or corrupt), it
    fails safe: safety mode, activity and location read ``unknown``, the pose
    ``moving``, joint positions and tool speed no value (null).
    """

    def __init__(self, module: str, cfg: RobotConfig, model_path: str, layout: Layout, poses: dict[str, np.ndarray]):
        n = 6
        super().__init__(
            module,
            cfg.period,
            cfg.twin,
            tuple(f"q{i}" for i in range(n)) + ("safety_mode", "activity", "reached_pose"),
            ("safety_mode_request", "activity", "target_pose", "speed_limit"),
        )
        self.cfg = cfg
        self.kinematics = ArmKinematics(model_path, cfg)
        if self.kinematics.num_joints != n:
            raise ValueError(f"{module}: the arm model has {self.kinematics.num_joints} joints, expected {n}")
        self.pose_names = list(poses)
        self.poses = np.array([poses[p] for p in self.pose_names], float)
        # the cell's own words for where the tool is: its regions, elsewhere, unknown
        self.locations = value_set(f"{module}_location", layout.robot_locations())
        self.regions = [(self.locations(name), r.min, r.max) for name, r in layout.robot_regions.items()]
        self.elsewhere = self.locations(layout.robot_elsewhere)
        self.unknown_location = self.locations("unknown")
        self.speed_caps = {
            SafetyMode.NORMAL: cfg.speed_limits.normal,
            SafetyMode.HAND_GUIDED: cfg.speed_limits.hguid,
            SafetyMode.SPEED_SEPARATION: cfg.speed_limits.ssmon,
            SafetyMode.POWER_FORCE_LIMITING: cfg.speed_limits.pflim,
        }
        self.normal_cap = self.speed_caps[SafetyMode.NORMAL]
        self._planned_caps = {mode: max(cap - TRACKING_ALLOWANCE, 0.5 * cap) for mode, cap in self.speed_caps.items()}
        initial = self.pose_names.index(cfg.initial_pose)
        q0 = self.poses[initial]
        self.initial_positions = q0

        self.mode_request_port = self.declare_input("safety_mode_request", ctype=enum_type(SafetyMode), default=SafetyMode.NORMAL.code)
        self.target_port = self.declare_input("target_pose", default=HOLD)
        # the cell's own words for what it does, and unknown (shadowed with no valid sample)
        self.activity_type = value_set(f"{module}_activity", [*cfg.activities, "unknown"])
        self.activity_port = self.declare_input("activity", ctype=enum_type(self.activity_type), default=0.0)
        self.speed_limit_port = self.declare_input("speed_limit", ctype=number_type("m/s"), default=math.inf)
        self.speed_scaling_port = self.declare_input("speed_scaling", ctype=number_type("1"), default=1.0)
        self.measured_state_port = self.declare_input("measured_state", 2 * n)
        self._desired = self.declare_state("desired_state", np.concatenate([q0, np.zeros(n)]))
        self.desired_state_port = self.DeclareStateOutputPort("desired_state", self._desired)

        location = self.locate(self.kinematics.tool_position(q0))
        self.reached_poses = value_set(f"{module}_pose", ["moving", *self.pose_names])
        published = [SafetyMode.NORMAL, self.activity_type(cfg.activities[0]), location, self.reached_poses(cfg.initial_pose)]
        # [the four codes below as last published, motion (see _advance)]: one read per update
        self._state = self.declare_state(
            "state", np.concatenate([[float(v.code) for v in published], [initial, 1.0, 0.0, 0.0, 0.0], q0, q0])
        )
        self._published = [
            self.declare_channel("safety_mode", enum_type(SafetyMode), published[0], description="Safety mode"),
            self.declare_channel("activity", enum_type(self.activity_type), published[1], description="What the robot is doing"),
            self.declare_channel("location", enum_type(self.locations), published[2], description="Where the tool is: a region of the layout, or elsewhere"),
            self.declare_channel("reached_pose", enum_type(self.reached_poses), published[3]),
        ]
        # measured at every update, recorded as they change: what a reader at the controller's rate could act on
        self._q = self.declare_channel("joint_positions", vector_type(n, "rad"), q0)
        self._tool_speed = self.declare_channel("tool_speed", number_type("m/s"), 0.0)

    # -- in Meshcat (cellsim.visual.cues) ------------------------------------------------
    def visual_cues(self, view) -> list:
        """The arm wears a shell coloured by its safety mode (none in normal)."""
        from cellsim.visual.cues import Cue

        frames = [f for f in getattr(self, "body_frames", []) if f is not None]
        channel = f"{self.module}.safety_mode"
        looks = {
            mode: view.shells(frames, color, f"safety_mode_{mode}")
            for mode, color in SAFETY_MODE_COLORS.items()
        }
        return [Cue(f"{self.module}/safety_mode", (channel,), looks, lambda values: values.get(channel))]

    replay_channels = ("joint_positions",)

    def show_recorded(self, cell, root_context, values: dict) -> None:
        """Put the arm at its recorded joint positions (rad)."""
        q = values.get(f"{self.module}.joint_positions")
        if q is not None and all(x is not None for x in q):
            plant_context = cell.plant.GetMyMutableContextFromRoot(root_context)
            cell.plant.SetPositions(plant_context, cell.robots[self.module], np.asarray(q, float))

    def recorded_as(self, field: str) -> tuple[str, int]:
        """q0..q5 are the elements of ``joint_positions``."""
        if field.startswith("q") and field[1:].isdigit():
            return f"{self.module}.joint_positions", int(field[1:])
        return super().recorded_as(field)

    def physical_state(self, context) -> list[float]:
        """q (rad, measured), safety mode, activity and reached pose codes."""
        q = self.measured_state_port.Eval(context)[:6]
        return [*q.tolist(), *(read_scalar(context, g) for g in self._published[:2]), read_scalar(context, self._published[3])]

    # -- helpers ------------------------------------------------------------------
    def locate(self, tool_position):
        """The location (a member of ``self.locations``) of the tool at ``tool_position``."""
        x, y, z = tool_position
        for location, (x0, y0, z0), (x1, y1, z1) in self.regions:
            if x0 <= x <= x1 and y0 <= y <= y1 and z0 <= z <= z1:
                return location
        return self.elsewhere

    def safe_command(self) -> dict[str, float]:
        """Its supervisor lost: stopped, its first activity, holding where it is, no speed allowed."""
        return {**super().safe_command(), "speed_limit": 0.0}

    def command_value(self, name: str, value: float) -> float:
        """``speed_limit`` goes out as the tool speed allowed in ssmon: its input, at most the mode's cap (with
        no ssm module, the cap itself: an unlimited speed is no number a message carries); no value stays no
        value, which the robot takes as a stop."""
        if name == "speed_limit" and not math.isnan(value):
            return min(value, self.speed_caps[SafetyMode.SPEED_SEPARATION])
        return value

    def sample_is_valid(self, sample) -> bool:
        return (
            valid_code(sample[6], SafetyMode)
            and valid_code(sample[7], self.activity_type)
            and valid_code(sample[8], self.reached_poses)
        )

    # -- update ---------------------------------------------------------------------
    def update(self, context, xd):
        view = self.consult_physical(context, xd)
        mode = requested_mode(self.mode_request_port.Eval(context)[0])
        target = self.target_port.Eval(context)[0]
        activity = self.activity_port.Eval(context)[0]
        state = context.get_discrete_state(self._state).get_value()
        published, motion = state[:4].tolist(), state[4:]

        if view.mode is TwinMode.MODEL:
            segment = motion[0]
            if motion[1] >= 1.0 and target in (HOLD, segment):
                # standing at the goal with nothing new to do: the motion state stays
                motion, desired = None, None
                reached = segment + 1.0 if segment != HOLD else 0.0
            else:
                motion, desired, reached = self._advance(motion, mode, target, self.speed_limit_port.Eval(context)[0],
                                                         self.speed_scaling_port.Eval(context)[0])
        elif view.sample is not None:
            q = view.sample[:6]
            motion = self._rest_at(q)
            desired = np.concatenate([q, np.zeros(6)])
            mode = SafetyMode.from_code(view.sample[6])
            activity, reached = view.sample[7], view.sample[8]
        else:  # stale or corrupt: the arm stands still in the twin, its real state is unknown
            self._report_unknown(xd, published, state, context)
            return

        measured = self.measured_state_port.Eval(context)
        kin = self.kinematics
        kin.plant.SetPositionsAndVelocities(kin.context, measured)
        location = self.locate(kin.tool.CalcPoseInWorld(kin.context).translation())
        codes = [float(mode.code), float(activity), float(location.code), float(reached)]
        write_changed(xd, self._published, codes, published)
        if motion is not None or codes != published:
            kept = state[4:] if motion is None else motion
            xd.get_mutable_vector(self._state).SetFromVector(np.concatenate((codes, kept)))
        if desired is not None:
            xd.get_mutable_vector(self._desired).SetFromVector(desired)
        vx, vy, vz = kin.tool.CalcSpatialVelocityInWorld(kin.context).translational()
        xd.get_mutable_vector(self._q).SetFromVector(measured[:6])
        write_scalar(xd, self._tool_speed, math.sqrt(vx * vx + vy * vy + vz * vz))

    def _report_unknown(self, xd, published: list, state: np.ndarray, context) -> None:
        """Fail safe in shadow or twin mode with no valid sample: report what must be assumed.

        Safety mode, activity and location read ``unknown`` (it may be moving at
        full speed, working, anywhere), the pose ``moving`` and the telemetry no
        value; the digital arm holds where it was, but nothing it shows is
        presented as the physical robot's current state.
        """
        codes = [float(SafetyMode.UNKNOWN.code), float(self.activity_type("unknown").code), float(self.unknown_location.code), 0.0]
        write_changed(xd, self._published, codes, published)
        if codes != published:
            xd.get_mutable_vector(self._state).SetFromVector(np.concatenate((codes, state[4:])))
        xd.get_mutable_vector(self._q).SetFromVector(np.full(6, np.nan))
        write_scalar(xd, self._tool_speed, np.nan)

    def _rest_at(self, q) -> np.ndarray:
        """Motion state of an arm standing at q (no segment)."""
        return np.concatenate([[HOLD, 1.0, 0.0, 0.0, 0.0], q, q])

    def start_segment(self, start: np.ndarray, target: int) -> np.ndarray:
        """Motion state at the start of a segment to named pose ``target``, with its rate limits."""
        goal = self.poses[target]
        delta = goal - start
        if not np.any(delta):
            return np.concatenate([[target, 1.0, 0.0, 0.0, 0.0], start, goal])
        joint_rate = float(np.min(self.kinematics.velocity_limits / np.maximum(np.abs(delta), 1e-12)))
        points = [self.kinematics.tool_position(start + k / _SEGMENT_SAMPLES * delta) for k in range(_SEGMENT_SAMPLES + 1)]
        tool_per_s = PATH_MARGIN * float(np.linalg.norm(np.diff(points, axis=0), axis=1).max()) * _SEGMENT_SAMPLES
        return np.concatenate([[target, 0.0, 0.0, max(tool_per_s, 1e-9), joint_rate], start, goal])

    def _advance(self, motion: np.ndarray, mode: SafetyMode, target: float, speed_limit: float = math.inf,
                 scaling: float = 1.0):
        """One period of the joint-space motion: (motion state, desired state, reached-pose code).

        In ssmon the tool's cap is also ``speed_limit`` (m/s), planned ``TRACKING_ALLOWANCE`` below it
        as a mode's cap is (at most halved); a limit with no value (NaN) is 0. The controller's speed
        slider ``scaling`` (0..1; no value: 0) scales the planned speed.

        Motion state: [segment target, s, ds/dt, tool metres per unit s, joint-limited
        max ds/dt, start (6), goal (6)].
        """
        dt = self.period
        segment, s, rate, tool_per_s, joint_rate = motion[:5].tolist()
        if target != HOLD and target != segment and rate == 0.0:
            # standing: a new segment from where the arm is commanded to be
            start, goal = motion[5:11], motion[11:17]
            motion = self.start_segment(start + s * (goal - start), int(target))
            segment, s, rate, tool_per_s, joint_rate = motion[:5].tolist()
        if s < 1.0:
            full = min(joint_rate, self._planned_caps[SafetyMode.NORMAL] / tool_per_s)
            accel = full / self.cfg.braking_time
            if mode in STANDSTILL_MODES or target != segment:
                cap = 0.0  # brake: a mode that stands still, or a new target to replan for
            else:
                planned = self._planned_caps[mode]
                if mode is SafetyMode.SPEED_SEPARATION and not speed_limit >= self.speed_caps[mode]:
                    limit = speed_limit if speed_limit > 0.0 else 0.0  # no value (NaN) stops it: fail safe
                    planned = max(limit - TRACKING_ALLOWANCE, 0.5 * limit)
                scale = min(scaling, 1.0) if scaling > 0.0 else 0.0
                cap = min(scale * min(joint_rate, planned / tool_per_s), math.sqrt(2.0 * accel * (1.0 - s)))
            rate = min(cap, rate + accel * dt) if rate < cap else max(cap, rate - accel * dt)
            s = min(1.0, s + rate * dt)
            if s >= 1.0:
                rate = 0.0
            motion = motion.copy()
            motion[1], motion[2] = s, rate
        delta = motion[11:17] - motion[5:11]
        desired = np.empty(12)
        np.multiply(delta, s, out=desired[:6])
        desired[:6] += motion[5:11]
        np.multiply(delta, rate, out=desired[6:])
        reached = segment + 1.0 if s >= 1.0 and segment != HOLD else 0.0
        return motion, desired, reached


# -- the module kind ----------------------------------------------------------------
