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


import numpy as np

from cellsim.channels import NO_VALUE, enum_type, number_type
from cellsim.kinds.robot.system import HOLD
from cellsim.kinds.process.config import ProcessConfig
from cellsim.systems import CellSystem, write_changed
from cellsim.vocabulary import CodedEnum, SafetyMode, value_set

STANDSTILL = {SafetyMode.MONITORED_STOP.code, SafetyMode.STOPPED.code, SafetyMode.UNKNOWN.code}
"""Safety-mode codes in which the robot stands still, so the steps wait."""


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
        from cellsim.channels import channel_domains

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
        elif self.robot_mode_port.Eval(context)[0] not in STANDSTILL:
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
