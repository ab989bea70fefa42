"""Where the twin and a UR cell's program meet: which RTDE variables carry what, and their values.

A UR controller knows joints, its own safety mode and a speed slider; it knows
nothing of the twin's safety modes, activities or named poses. Those live in the
integrator's program (URScript or PolyScope), which reads what the twin asks from
input integer registers and reports what it runs in output integer registers.
The register numbers are the bridge configuration's (``robots.<robot>.rtde.registers``);
a register's value is the value's *code*: its position in the field's list
(``cellsim modules robot``; safety modes: normal 0, hguid 1, ssmon 2, pflim 3,
srmst 4, stopped 5; activities in the kind's order; poses: ``moving`` 0, then
the named poses in order; a target pose is the named pose's index, -1 to hold).

**State, controller to twin** (:meth:`UrProgram.sample`): ``q0..q5`` are
``actual_q`` (rad). The safety mode is *stopped* whenever the controller is in
any safety stop (``safety_mode`` not NORMAL or REDUCED), the arm is not running
(``robot_mode`` not RUNNING) or the program is not (``runtime_state`` not
PLAYING: its registers are stale, and nothing acts on the twin's requests): what
the controller says of itself wins.
Otherwise it is the mode the program reports. A code outside a field's list is a
range fault, as is a joint beyond its limit.

**Commands, twin to controller** (:meth:`UrProgram.inputs`): the requested
safety mode's code, activity and target pose in their registers, and the speed
slider (``speed_slider_mask`` 1, ``speed_slider_fraction``) at the requested
mode's tool speed cap over the normal cap (0 in srmst and stopped; in ssmon at
most the SSM monitor's ``speed_limit`` over the normal cap, 0 without one), and a
heartbeat register counting the commands sent: the program stops the arm when it
stalls (the daemon lost, not only the twin). While the twin does not command the
robot (model or shadow mode) the daemon writes -1 in every request register and
leaves the slider alone (its mask 0), the heartbeat still counting: the program
runs on its own. The speed
slider scales every motion of the program; it is not a safety function: the
program must also act on the requested mode (a protective stop, a safety-rated
reduced mode), which docs/ur.md asks the integrator to check.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cellsim.ur import rtde
from cellsim.vocabulary import SafetyMode

STOP_MODES = (SafetyMode.MONITORED_STOP.value, SafetyMode.STOPPED.value)
RUNNING_SAFETY = (rtde.SAFETY_NORMAL, rtde.SAFETY_REDUCED)
STILL = 0.01
"""rad/s: the fastest any joint may turn for an arm that is not running (stopped, powered off, its program not
playing) to read as stopped; faster (braking after a stop, jogged from the pendant, backdriven), it reads unknown."""
MOVING_STATE = "moving"


class OutOfRange(ValueError):
    """A value the twin's field cannot take (a register's code outside its list, a joint beyond its limit)."""


@dataclass(frozen=True)
class UrProgram:
    """The registers of one robot's program, and the codecs of its entity's samples and commands."""

    registers: object
    """The configuration's ``UrRegisters``."""
    sample_types: dict
    """The robot entity's physical-sample fields -> their ChannelType."""
    command_types: dict
    """The robot entity's command fields -> their ChannelType."""
    speed_fractions: dict
    """Safety mode value -> the speed slider's fraction in it (its tool cap over the normal cap)."""
    normal_cap: float = 1.0
    """The tool's speed cap in normal mode (m/s): the speed the slider's 1 stands for."""

    # -- the variables ----------------------------------------------------------------
    def outputs(self) -> list[str]:
        """The output variables the daemon asks the controller for."""
        r = self.registers
        return ["timestamp", "actual_q", "actual_qd", "robot_mode", "safety_mode", "runtime_state",
                "safety_status_bits", "speed_scaling", "target_speed_fraction",
                *(rtde.int_register("output", n) for n in (r.safety_mode, r.activity, r.reached_pose))]

    def inputs(self) -> list[str]:
        """The input variables the daemon writes."""
        r = self.registers
        return ["speed_slider_mask", "speed_slider_fraction",
                *(rtde.int_register("input", n)
                  for n in (r.safety_mode_request, r.activity_request, r.target_pose, r.heartbeat))]

    # -- controller -> twin --------------------------------------------------------------
    def sample(self, values: dict) -> dict:
        """The robot's physical-sample fields of a state (``outputs()``'s values); OutOfRange if a register
        holds a code outside its field's list."""
        r = self.registers
        for name, known in (("safety_mode", rtde.SAFETY_MODES), ("robot_mode", rtde.ROBOT_MODES),
                            ("runtime_state", rtde.RUNTIME_STATES)):
            if values[name] not in known:
                raise OutOfRange(f"{name} {values[name]} is no code the controller documents")
        fields = {f"q{i}": float(q) for i, q in enumerate(values["actual_q"])}
        running = (values["safety_mode"] in RUNNING_SAFETY and values["robot_mode"] == rtde.ROBOT_RUNNING
                   and values["runtime_state"] == rtde.RUNTIME_PLAYING)
        reported = self._value("safety_mode", values[rtde.int_register("output", r.safety_mode)])
        if running:
            fields["safety_mode"] = reported
        elif values["safety_mode"] == rtde.SAFETY_UNDEFINED or max(abs(float(v)) for v in values["actual_qd"]) > STILL:
            fields["safety_mode"] = SafetyMode.UNKNOWN.value  # not running, yet moving (or its mode undefined)
        else:
            fields["safety_mode"] = SafetyMode.STOPPED.value
        fields["activity"] = self._value("activity", values[rtde.int_register("output", r.activity)])
        fields["reached_pose"] = self._value("reached_pose", values[rtde.int_register("output", r.reached_pose)])
        return fields

    def _value(self, name: str, code: int) -> str:
        ctype = self.sample_types[name]
        try:
            return ctype.enum.from_code(code).value
        except ValueError:
            raise OutOfRange(f"{name} code {code} is not one of {', '.join(ctype.domain())}") from None

    # -- twin -> controller --------------------------------------------------------------
    def input_values(self, command: dict | None, heartbeat: int) -> dict:
        """The input variables' values for a command of the twin (the entity's command fields; None: the twin
        does not command the robot, every request register -1 and the slider left as the program has it), the
        ``heartbeat`` count with it (wrapping within int32)."""
        r = self.registers
        if command is None:
            return {"speed_slider_mask": 0, "speed_slider_fraction": 1.0,
                    **{rtde.int_register("input", n): -1 for n in (r.safety_mode_request, r.activity_request, r.target_pose)},
                    rtde.int_register("input", r.heartbeat): heartbeat % 2**31}
        mode = command["safety_mode_request"]
        target = command.get("target_pose")
        target = -1 if target is None or not math.isfinite(target) or target < 0 else int(target)
        return {
            "speed_slider_mask": 1,
            "speed_slider_fraction": self.slider(mode, command.get("speed_limit")),
            rtde.int_register("input", r.safety_mode_request): self._code("safety_mode_request", mode),
            rtde.int_register("input", r.activity_request): self._code("activity", command.get("activity")),
            rtde.int_register("input", r.target_pose): target,
            rtde.int_register("input", r.heartbeat): heartbeat % 2**31,
        }

    def slider(self, mode: str, speed_limit) -> float:
        """The speed slider's fraction for a requested ``mode``: its cap over the normal cap; in ssmon, at most
        the SSM monitor's ``speed_limit`` (m/s) over the normal cap, and 0 when it has no value (a stop)."""
        fraction = self.speed_fractions.get(mode, 0.0)
        if mode == SafetyMode.SPEED_SEPARATION.value:
            valid = isinstance(speed_limit, (int, float)) and math.isfinite(speed_limit) and speed_limit >= 0.0
            fraction = min(fraction, speed_limit / self.normal_cap) if valid else 0.0
        return fraction

    def _code(self, name: str, value) -> int:
        ctype = self.command_types[name]
        if value is None:
            return -1
        return int(ctype.encode(value)[0])

    # -- the emulated controller's side -------------------------------------------------
    def command(self, inputs: dict) -> tuple[dict | None, float]:
        """What the twin asked, as the program reads it from the controller's inputs: (the entity's command
        fields, or None when the safety-mode request is -1: the twin does not command it; the speed slider's
        fraction). Any other code outside its list reads as the kind's stop (the request as stopped, no
        activity, hold)."""
        r = self.registers
        if inputs.get(rtde.int_register("input", r.safety_mode_request), -1) == -1:
            return None, float(np.clip(inputs.get("speed_slider_fraction", 1.0), 0.0, 1.0))

        def value(name: str, code: int):
            try:
                return self.command_types[name].enum.from_code(code).value
            except ValueError:
                return None

        mode = value("safety_mode_request", inputs.get(rtde.int_register("input", r.safety_mode_request), -1))
        target = int(inputs.get(rtde.int_register("input", r.target_pose), -1))
        fields = {"safety_mode_request": mode or SafetyMode.STOPPED.value,
                  "activity": value("activity", inputs.get(rtde.int_register("input", r.activity_request), -1)),
                  "target_pose": float(target) if target >= 0 else -1.0,
                  # the SSM's limit came as the slider, which scales the arm: no tighter cap than ssmon's here
                  "speed_limit": self.speed_fractions.get(SafetyMode.SPEED_SEPARATION.value, 0.0) * self.normal_cap}
        return fields, float(np.clip(inputs.get("speed_slider_fraction", 1.0), 0.0, 1.0))

    def state(self, fields: dict, velocity, t: float, slider: float) -> dict:
        """The controller's outputs for the emulated arm's sample ``fields`` (its joints, velocity in rad/s,
        time ``t`` in s since the controller started, the speed slider's fraction)."""
        r = self.registers
        mode = fields["safety_mode"]
        if mode == SafetyMode.STOPPED.value or mode == SafetyMode.UNKNOWN.value:
            safety = rtde.SAFETY_PROTECTIVE_STOP
        elif mode == SafetyMode.NORMAL.value or mode == SafetyMode.MONITORED_STOP.value:
            safety = rtde.SAFETY_NORMAL
        else:
            safety = rtde.SAFETY_REDUCED
        q = [float(fields[f"q{i}"]) for i in range(6)]
        return {
            "timestamp": t, "actual_q": q, "target_q": q, "actual_qd": list(velocity), "target_qd": list(velocity),
            "robot_mode": rtde.ROBOT_RUNNING, "safety_mode": safety, "safety_status": safety,
            "safety_status_bits": 1 << (safety - 1), "runtime_state": rtde.RUNTIME_PLAYING,
            "robot_status_bits": 0b11, "speed_scaling": slider, "target_speed_fraction": slider,
            rtde.int_register("output", r.safety_mode): int(self.sample_types["safety_mode"].encode(mode)[0]),
            rtde.int_register("output", r.activity): int(self.sample_types["activity"].encode(fields["activity"])[0]),
            rtde.int_register("output", r.reached_pose):
                int(self.sample_types["reached_pose"].encode(fields["reached_pose"])[0]),
        }
