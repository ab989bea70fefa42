"""A process controller for any cell: the robot's moves and dwells, and the machines' cycles.

Each step does one thing and names the robot activity it is:

* ``move_to: POSE``: the robot moves to one of its named poses;
* ``dwell: SECONDS``: the robot stays put (picking, placing);
* ``start: MACHINE``: starts a machine's cycle (its command stays on until the
  machine says it is busy) and goes on, so the machine works in parallel with
  the robot;
* ``wait_for: MACHINE``: waits until that machine is no longer busy: its cycle
  ended, or was abandoned when the machine stopped (at once if it is idle);
* ``wait_until: CONDITION``: waits until a condition over the cell's channels
  holds, written in the condition language without temporal operators
  (docs/condition-language.md), e.g. ``loader.reached_pose == clear``: how one
  robot hands a part over to another, or waits for any machine, sensor or step
  of another process (at once if it already holds);
* ``operate: {machine: MACHINE, seconds: S}``: keeps a machine without a cycle
  working (its command on) until it has worked S seconds, counting only while
  it reports its working activity (the welding cell's weld: the robot holds the
  work-piece while the welder welds).

The steps repeat; completing the last counts one cycle. It advances only
while the robot's safety mode lets it move (not srmst, stopped, or unknown), and it obeys the safety controller's activity
requests: a new request listed in ``restart_on_request`` restarts the steps from
the one it names; any other request pauses them, and the robot reports it.
No machine is mandatory.

A cell may run several processes, one per robot. Each machine is driven (started
or operated) by one process at most; any other may ``wait_for`` its cycle. Two
processes moving one robot, or driving one machine, are a load-time error
naming both steps.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from cellsim.channels import NO_VALUE, enum_type, number_type
from cellsim.config.typed_yaml import FieldError
from cellsim.entities.robot import HOLD
from cellsim.registry import ModuleKind, deferred
from cellsim.scenario import Period, PositiveSeconds, Seconds, check_steps
from cellsim.systems import CellSystem, write_changed
from cellsim.vocabulary import CodedEnum, SafetyMode, value_set

_STANDSTILL = {SafetyMode.MONITORED_STOP.code, SafetyMode.STOPPED.code, SafetyMode.UNKNOWN.code}


@dataclass
class Operation:
    """A machine kept working for a time."""

    machine: str
    """The machine (one without a cycle_time: it works while commanded)."""
    seconds: PositiveSeconds
    """How long it must work (s): counted while it reports its working activity."""


@dataclass
class ProcessStep:
    """One step: exactly one of move_to, dwell, start, wait_for, wait_until, operate; and the robot's activity."""

    name: str
    """The step's name: the controller's step channel reads it."""
    activity: str
    """The robot activity this step is (one of the robot's activities)."""
    move_to: str | None = None
    """A named pose of the robot to move to."""
    dwell: Seconds = 0.0
    """Seconds to stay put."""
    start: str | None = None
    """A machine whose cycle to start (the process goes on at once)."""
    wait_for: str | None = None
    """A machine whose cycle to wait for."""
    wait_until: str | None = None
    """A condition over the cell's channels (no temporal operators) to wait for, e.g.
    ``loader.reached_pose == clear``."""
    operate: Operation | None = None
    """A machine to keep working for some seconds ({machine, seconds})."""

    def __post_init__(self):
        given = [k for k in ("move_to", "start", "wait_for", "wait_until", "operate") if getattr(self, k) is not None]
        given += ["dwell"] if self.dwell else []
        if len(given) != 1:
            raise FieldError("name", f"step '{self.name}' must have exactly one of move_to, dwell, start, wait_for, "
                                     "wait_until, operate")

    @property
    def machine(self) -> str | None:
        """The machine this step starts, waits for or operates."""
        return self.start or self.wait_for or (self.operate.machine if self.operate else None)


@dataclass
class ProcessConfig:
    """The cell's process: steps of the robot and its machines, repeated."""

    kind: Literal["process"]
    steps: list[ProcessStep]
    """The steps, in order."""
    robot: str = "robot"
    """The robot entity the process moves."""
    restart_on_request: dict[str, str] = field(default_factory=dict)
    """Robot activity requested by the safety controller -> step the process restarts from.
    Any other activity requested pauses the process, and the robot reports it."""
    period: Period = 0.04
    """Update period (s)."""

    def __post_init__(self):
        check_steps([s.name for s in self.steps], self.restart_on_request)

    @property
    def machines(self) -> list[str]:
        """The machines the steps start, wait for or operate, in order of first mention."""
        return list(dict.fromkeys(step.machine for step in self.steps if step.machine is not None))

    @property
    def driven(self) -> list[str]:
        """The machines the steps start or operate: the process drives their command input (one process
        per machine; others may wait_for it)."""
        return list(dict.fromkeys(s.machine for s in self.steps if s.start or s.operate))

    @property
    def cycled(self) -> list[str]:
        """The machines whose cycles the steps start or wait for (whose busy they read)."""
        return list(dict.fromkeys(s.machine for s in self.steps if s.start or s.wait_for))

    @property
    def operated(self) -> list[str]:
        """The machines the steps operate (whose activity they read)."""
        return list(dict.fromkeys(s.machine for s in self.steps if s.operate))


class Process(CellSystem):
    """The process controller.

    Ports:
      activity_request (input): code of a robot activity requested by the safety controller, -1 for none.
      robot_safety_mode (input): the robot's SafetyMode code.
      robot_reached_pose (input): the robot's reached-pose code (0 moving, i + 1 for named pose i).
      <machine>_busy (input), per machine started or waited for: the machine's busy channel.
      <machine>_activity (input), per machine operated: the machine's activity code.
      reads <module>.<channel> (input), per channel a wait_until condition reads: that channel
        (declared and wired once every module is built: ``wire_conditions``).
      target_pose (output): index of the robot's named pose to move to, -1 to hold.
      robot_activity (output): code of the robot activity being carried out.
      <machine>_command (output), per machine: 1 from a start step until the machine is busy.
      step (channel): the current step's name.
      cycles_completed (channel): process cycles completed so far.
    """

    def __init__(
        self, module: str, cfg: ProcessConfig, pose_names: list[str], activities: type[CodedEnum], working: dict[str, float]
    ):
        """``working``: the code of each operated machine's working activity."""
        super().__init__(module, cfg.period)
        self.working = working
        self.steps = cfg.steps
        self.machines = cfg.machines
        self.targets = [HOLD if s.move_to is None else float(pose_names.index(s.move_to)) for s in self.steps]
        self.activity_codes = [float(activities(s.activity).code) for s in self.steps]
        self.restart = {activities(a).code: [s.name for s in self.steps].index(step) for a, step in cfg.restart_on_request.items()}
        self.step_names = value_set(f"{module}_step", [s.name for s in self.steps])

        self.activity_request_port = self.declare_input("activity_request", ctype=enum_type(activities), default=NO_VALUE)
        self.robot_mode_port = self.declare_input("robot_safety_mode")
        self.reached_pose_port = self.declare_input("robot_reached_pose")
        self.busy_ports = {m: self.declare_input(f"{m}_busy") for m in cfg.cycled}
        self.activity_ports = {m: self.declare_input(f"{m}_activity") for m in cfg.operated}
        # [step progress (s dwelled), last request]
        self._state = self.declare_state("state", [0.0, NO_VALUE])
        self._target = self.declare_state("target_pose", [self.targets[0]])
        self._activity = self.declare_state("robot_activity", [self.activity_codes[0]])
        self._commands = [self.declare_state(f"{m}_command", [0.0]) for m in self.machines]
        self.target_pose_port = self.DeclareStateOutputPort("target_pose", self._target)
        self.robot_activity_port = self.DeclareStateOutputPort("robot_activity", self._activity)
        self.command_ports = [self.DeclareStateOutputPort(f"{m}_command", g) for m, g in zip(self.machines, self._commands)]
        self._step = self.declare_channel("step", enum_type(self.step_names), self.steps[0].name)
        self._cycles = self.declare_channel("cycles_completed", number_type(None), 0.0)
        self._outputs = [self._target, self._activity, self._step, self._cycles, *self._commands]
        self.conditions: list = [None] * len(self.steps)
        """Per step: its wait_until condition compiled (``wire_conditions``), else None."""
        self.condition_reads: dict[str, tuple] = {}
        """Channel a condition reads -> (its input port, its type)."""

    def wire_conditions(self, cell, name: str) -> None:
        """Parse each wait_until against every channel of the built cell, declare an input per channel
        read and wire it: a bad condition is a ConfigError at its key (file, line, column)."""
        from cellsim.logic.predicates import compile_predicate
        from cellsim.logic.syntax import FormulaError, parse
        from cellsim.validation.traces import channel_domains

        channels = cell.channels()
        vocabulary = channel_domains(spec for spec, _ in channels.values())
        for i, step in enumerate(self.steps):
            if step.wait_until is None:
                continue
            try:
                formula = parse(step.wait_until, vocabulary, allow_temporal=False)
            except FormulaError as e:
                where = f"column {e.column} of the condition: " if e.column is not None else ""
                raise cell.sf.error(f"behaviours.{name}.steps.{i}.wait_until", where + e.message) from None
            self.conditions[i] = compile_predicate(formula, vocabulary)
            for channel in sorted(self.conditions[i].variables):
                if channel not in self.condition_reads:
                    spec, source = channels[channel]
                    port = self.declare_input(f"reads {channel}")
                    cell.builder.Connect(source, port)
                    self.condition_reads[channel] = (port, spec.type)

    def _condition_holds(self, context, index: int) -> bool:
        values = {}
        for channel in self.conditions[index].variables:
            port, ctype = self.condition_reads[channel]
            code = port.Eval(context)[0]
            if ctype.kind == "number":
                values[channel] = code  # NaN (no value) makes every comparison false
            elif ctype.kind == "bool":
                values[channel] = code > 0.5
            else:
                values[channel] = ctype.decode([code])
        return self.conditions[index](values)

    def update(self, context, xd):
        request = self.activity_request_port.Eval(context)[0]
        state = context.get_discrete_state(self._state).get_value().tolist()
        progress, last_request = state
        published = [context.get_discrete_state(g)[0] for g in self._outputs]
        index, cycles = int(published[2]), published[3]
        if request != last_request and request in self.restart:
            index, progress = self.restart[request], 0.0
        step = self.steps[index]
        target, activity = self.targets[index], self.activity_codes[index]
        commands = [0.0] * len(self.machines)

        if request != NO_VALUE and request not in self.restart:  # any other request pauses the process
            target, activity = HOLD, request
        elif self.robot_mode_port.Eval(context)[0] not in _STANDSTILL:
            if step.move_to is not None:
                done = self.reached_pose_port.Eval(context)[0] == target + 1.0
            elif step.dwell > 0:
                progress += self.period
                done = progress >= step.dwell - 1e-9
            elif step.start is not None:  # held until the machine acknowledges by being busy
                done = self.busy_ports[step.start].Eval(context)[0] > 0.5
                commands[self.machines.index(step.start)] = 0.0 if done else 1.0
            elif step.wait_for is not None:
                done = self.busy_ports[step.wait_for].Eval(context)[0] < 0.5
            elif step.wait_until is not None:
                done = self._condition_holds(context, index)
            else:  # operate: commanded on, its working time counted while it works
                machine = step.operate.machine
                if self.activity_ports[machine].Eval(context)[0] == self.working[machine]:
                    progress += self.period
                done = progress >= step.operate.seconds - 1e-9
                commands[self.machines.index(machine)] = 0.0 if done else 1.0
            if done:
                progress = 0.0
                index = (index + 1) % len(self.steps)
                if index == 0:
                    cycles += 1
                target, activity = self.targets[index], self.activity_codes[index]
        outputs = [float(target), float(activity), float(index), float(cycles), *commands]
        write_changed(xd, self._outputs, outputs, published)
        new_state = [progress, float(request)]
        if new_state != state:
            xd.get_mutable_vector(self._state).SetFromVector(np.array(new_state))


# -- the module kind ----------------------------------------------------------------
def build_process(cell, name: str, cfg: ProcessConfig) -> Process:
    """The process, wired to the robot it moves and to each machine it starts or waits for."""
    robot = cell.modules[cfg.robot]
    working = {m: float(cell.modules[m].working) for m in cfg.operated}
    system = cell.add(name, Process(name, cfg, robot.pose_names, robot.activity_type, working))
    connect = cell.builder.Connect
    connect(system.target_pose_port, robot.target_port)
    connect(system.robot_activity_port, robot.activity_port)
    connect(robot.GetOutputPort("safety_mode"), system.robot_mode_port)
    connect(robot.GetOutputPort("reached_pose"), system.reached_pose_port)
    for machine, command in zip(cfg.machines, system.command_ports):
        if machine in cfg.driven:  # a machine only waited for is driven by another process, or by none
            connect(command, cell.modules[machine].GetInputPort("command"))
    for machine, busy in system.busy_ports.items():
        connect(cell.modules[machine].GetOutputPort("busy"), busy)
    for machine, activity in system.activity_ports.items():
        connect(cell.modules[machine].GetOutputPort("activity"), activity)
    if any(step.wait_until is not None for step in cfg.steps):  # it may read any module's channel
        cell.after_all(lambda: system.wire_conditions(cell, name))
    return system


def check_robot_steps(sf, key: str, robot_name: str, steps, restart_on_request: dict[str, str]):
    """The robot a process moves exists, and its steps' poses and activities are the robot's.

    Returns the robot's config.
    """
    robots = sf.scenario.modules_of_kind("robot")
    if robot_name not in robots:
        raise sf.error(f"{key}.robot", f"no robot entity named '{robot_name}'")
    robot = robots[robot_name]
    for i, step in enumerate(steps):
        if step.move_to is not None and step.move_to not in robot.named_poses:
            raise sf.error(f"{key}.steps.{i}.move_to", f"'{step.move_to}' is not a named pose of {robot_name} ({', '.join(robot.named_poses)})")
        if step.activity not in robot.activities:
            raise sf.error(f"{key}.steps.{i}.activity", f"'{step.activity}' is not an activity of {robot_name} ({', '.join(robot.activities)})")
    for activity in restart_on_request:
        if activity not in robot.activities:
            raise sf.error(f"{key}.restart_on_request.{activity}", f"'{activity}' is not an activity of {robot_name} ({', '.join(robot.activities)})")
    return robot


def _driving_key(name: str, cfg: ProcessConfig, machine: str) -> str:
    """The key of the first step of process ``name`` that starts or operates ``machine``."""
    i, step = next((i, s) for i, s in enumerate(cfg.steps) if s.machine == machine and (s.start or s.operate))
    return f"behaviours.{name}.steps.{i}." + ("start" if step.start else "operate.machine")


def _check_one_driver(sf, name: str, cfg: ProcessConfig) -> None:
    """Each robot and each machine is driven by one process at most (its command inputs are wired once):
    an error at the later process, naming both places."""
    processes = sf.scenario.modules_of_kind("process")
    for other, other_cfg in processes.items():
        if other == name:
            return  # only the processes before this one: each pair is reported once, at the later
        if other_cfg.robot == cfg.robot:
            where = sf.locate(f"behaviours.{other}.robot")
            raise sf.error(f"behaviours.{name}.robot", f"robot '{cfg.robot}' is already moved by process '{other}' "
                           f"({where[0]}, line {where[1]}): one process moves a robot")
        for machine in cfg.driven:
            if machine in other_cfg.driven:
                where = sf.locate(_driving_key(other, other_cfg, machine))
                raise sf.error(_driving_key(name, cfg, machine),
                               f"machine '{machine}' is already driven by process '{other}' ({where[0]}, line {where[1]}, "
                               f"{where[2]}): one process starts or operates a machine; the others wait_for it")


def _check(sf, name: str, cfg: ProcessConfig) -> None:
    """The robot and machines it names exist; poses and activities are the robot's; no robot or machine
    is driven by two processes."""
    key = f"behaviours.{name}"
    _check_one_driver(sf, name, cfg)
    check_robot_steps(sf, key, cfg.robot, cfg.steps, cfg.restart_on_request)
    machines = sf.scenario.modules_of_kind("machine")
    for i, step in enumerate(cfg.steps):
        for field_name in ("start", "wait_for"):
            machine = getattr(step, field_name)
            if machine is not None and machine not in machines:
                raise sf.error(f"{key}.steps.{i}.{field_name}", f"no machine entity named '{machine}' ({', '.join(machines) or 'none'})")
            if machine is not None and machines[machine].cycle_time <= 0:
                raise sf.error(f"{key}.steps.{i}.{field_name}", f"machine '{machine}' has no cycle_time: it cannot run a cycle; operate it")
        if step.operate is not None:
            machine = step.operate.machine
            if machine not in machines:
                raise sf.error(f"{key}.steps.{i}.operate.machine", f"no machine entity named '{machine}' ({', '.join(machines) or 'none'})")
            if machines[machine].cycle_time > 0:
                raise sf.error(f"{key}.steps.{i}.operate.machine", f"machine '{machine}' runs cycles: start it and wait_for it")


KIND = ModuleKind(
    name="process",
    abstraction=deferred("cellsim.abstractions.process:process"),
    section="behaviours",
    config=ProcessConfig,
    build=build_process,
    stage=10,
    check=_check,
    summary="A process controller for any cell: the robot's moves and dwells, machines' cycles started and awaited, machines operated.",
    inputs=(
        ("activity_request", "enum", "a robot activity a safety controller requests: restarts or pauses the steps"),
    ),
    channels=(
        ("step", "enum", "the current step's name"),
        ("cycles_completed", "number", "process cycles completed so far"),
    ),
)
