"""The process controller: the cell's work cycle, as a list of steps.

Each step is a move to a named pose, a dwell, or a weld of a given duration,
and names the robot activity it represents. The cycle repeats; completing its
last step counts one work cycle.

It advances only while the robot's safety mode permits motion (not srmst or
stopped), and it obeys the safety controller's robot activity requests as the
robot's activity state machine (paper, Fig. 6): ``off`` and ``idle`` pause the
cycle and are what the robot reports; a *new* request listed in
``restart_on_request`` restarts the cycle from the step it names (``exchWrkp``:
bring the work-piece back; ``welding``: continue the unfinished weld).
"""

from __future__ import annotations

import numpy as np

from cellsim.channels import enum_type, number_type
from cellsim.entities.robot import HOLD
from cellsim.entities.welder import NO_REQUEST
from cellsim.registry import ModuleKind
from cellsim.scenario import WorkCycleConfig
from cellsim.systems import CellSystem, write_changed
from cellsim.vocabulary import CodedEnum, SafetyMode, value_set, WelderActivity

_STANDSTILL = {SafetyMode.MONITORED_STOP.code, SafetyMode.STOPPED.code, SafetyMode.UNKNOWN.code}
"""Modes in which the cycle waits: the robot stands still, or its state is unknown."""


class WorkCycle(CellSystem):
    """The robot's process controller.

    Ports:
      activity_request (input): code of a robot activity requested by the safety controller, -1 for none.
      robot_safety_mode (input): the robot's SafetyMode code.
      robot_reached_pose (input): the robot's reached-pose code (0 moving, i + 1 for named pose i).
      welder_activity (input): the welder's WelderActivity code.
      target_pose (output): index of the robot's named pose to move to, -1 to hold.
      robot_activity (output): code of the robot activity the robot is carrying out.
      weld_command (output): 1 while a weld is wanted.
      step (channel): the current step's name.
      cycles_completed (channel): work cycles completed so far.
    """

    def __init__(self, module: str, cfg: WorkCycleConfig, pose_names: list[str], activities: type[CodedEnum]):
        super().__init__(module, cfg.period)
        self.cfg = cfg
        self.steps = cfg.steps
        self.targets = [HOLD if s.move_to is None else float(pose_names.index(s.move_to)) for s in self.steps]
        self.activity_codes = [float(activities(s.activity).code) for s in self.steps]
        self.restart = {activities(a).code: [s.name for s in self.steps].index(step) for a, step in cfg.restart_on_request.items()}
        self.step_names = value_set(f"{module}_step", [s.name for s in self.steps])

        self.activity_request_port = self.declare_input("activity_request", ctype=enum_type(activities), default=NO_REQUEST)
        self.robot_mode_port = self.declare_input("robot_safety_mode")
        self.reached_pose_port = self.declare_input("robot_reached_pose")
        self.welder_activity_port = self.declare_input("welder_activity")
        first = self.steps[0]
        published = [self.targets[0], self.activity_codes[0], 0.0, 0.0, 0.0]
        # [step progress (s dwelled or welded), last activity request, the five outputs
        # below as last published]: one read per update, and unchanged outputs are not rewritten
        self._state = self.declare_state("state", [0.0, NO_REQUEST, *published])
        self._target = self.declare_state("target_pose", [published[0]])
        self._activity = self.declare_state("robot_activity", [published[1]])
        self._weld = self.declare_state("weld_command", [published[2]])
        self.target_pose_port = self.DeclareStateOutputPort("target_pose", self._target)
        self.robot_activity_port = self.DeclareStateOutputPort("robot_activity", self._activity)
        self.weld_command_port = self.DeclareStateOutputPort("weld_command", self._weld)
        self._step = self.declare_channel("step", enum_type(self.step_names), first.name)
        self._cycles = self.declare_channel("cycles_completed", number_type(None), 0.0)
        self._outputs = [self._target, self._activity, self._weld, self._step, self._cycles]

    def update(self, context, xd):
        request = self.activity_request_port.Eval(context)[0]
        state = context.get_discrete_state(self._state).get_value().tolist()
        progress, last_request, published = state[0], state[1], state[2:]
        index, cycles = int(published[3]), published[4]
        if request != last_request and request in self.restart:
            index, progress = self.restart[request], 0.0
        step = self.steps[index]
        target, weld, activity = self.targets[index], 0.0, self.activity_codes[index]

        if request != NO_REQUEST and request not in self.restart:  # any other request pauses the cycle
            target, activity = HOLD, request
        elif self.robot_mode_port.Eval(context)[0] not in _STANDSTILL:
            done = False
            if step.move_to is not None:
                done = self.reached_pose_port.Eval(context)[0] == target + 1.0
            elif step.dwell > 0:
                progress += self.period
                done = progress >= step.dwell - 1e-9
            else:
                weld = 1.0
                if self.welder_activity_port.Eval(context)[0] == WelderActivity.WELDING.code:
                    progress += self.period
                done = progress >= step.weld - 1e-9
            if done:
                weld, progress = 0.0, 0.0
                index = (index + 1) % len(self.steps)
                if index == 0:
                    cycles += 1
                step = self.steps[index]
                target, activity = self.targets[index], self.activity_codes[index]
        outputs = [float(target), float(activity), weld, float(index), float(cycles)]
        write_changed(xd, self._outputs, outputs, published)
        new_state = [progress, float(request), *outputs]
        if new_state != state:
            xd.get_mutable_vector(self._state).SetFromVector(np.array(new_state))


# -- the module kind ----------------------------------------------------------------
def build_work_cycle(cell, name: str, cfg: WorkCycleConfig) -> WorkCycle:
    """The process controller, wired to the robot it moves and the welder it starts."""
    robot, welder = cell.modules[cfg.robot], cell.modules[cfg.welder]
    system = cell.add(name, WorkCycle(name, cfg, robot.pose_names, robot.activity_type))
    connect = cell.builder.Connect
    connect(system.target_pose_port, robot.target_port)
    connect(system.robot_activity_port, robot.activity_port)
    connect(system.weld_command_port, welder.weld_command_port)
    connect(robot.GetOutputPort("safety_mode"), system.robot_mode_port)
    connect(robot.GetOutputPort("reached_pose"), system.reached_pose_port)
    connect(welder.GetOutputPort("activity"), system.welder_activity_port)
    return system


def _check(sf, name: str, cfg: WorkCycleConfig) -> None:
    """The robot and welder it names exist; poses and activities are the robot's."""
    from cellsim.behaviours.process import check_robot_steps

    key = f"behaviours.{name}"
    check_robot_steps(sf, key, cfg.robot, cfg.steps, cfg.restart_on_request)
    if cfg.welder not in sf.scenario.modules_of_kind("welder"):
        raise sf.error(f"{key}.welder", f"no welder entity named '{cfg.welder}'")


KIND = ModuleKind(
    name="work_cycle",
    section="behaviours",
    config=WorkCycleConfig,
    build=build_work_cycle,
    stage=10,
    check=_check,
    summary="The process controller: repeats moves to named poses, dwells and welds while the safety mode permits.",
    channels=(
        ("step", "enum", "the current step's name"),
        ("cycles_completed", "number", "work cycles completed so far"),
    ),
)
