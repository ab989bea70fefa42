"""The process kind: its build (wired to the robot and the machines it drives) and load-time checks."""

from __future__ import annotations

from cellsim.kinds.process.config import ProcessConfig
from cellsim.kinds.process.system import Process
from cellsim.kind import Figure, Glance, ModuleKind


class ProcessKind(ModuleKind):
    """A process controller moving one robot and driving machines through repeated steps."""

    name = "process"
    section = "behaviours"
    config = ProcessConfig
    summary = "A process controller for any cell: the robot's moves and dwells, machines' cycles started and awaited, machines operated."
    stage = 10
    glance = (Glance("cell", "process step", "step"), Glance("cell", "cycles completed", "cycles_completed"))
    channels = (
        ("step", "enum", "the current step's name"),
        ("cycles_completed", "number", "process cycles completed so far"),
    )
    inputs = (
        ("activity_request", "enum", "a robot activity a safety controller requests: restarts or pauses the steps"),
    )

    def build(self, cell, name, cfg):
        return build_process(cell, name, cfg)

    def check(self, sf, name, cfg):
        _check(sf, name, cfg)

    def figures(self, name, cfg):
        """Cycles completed are the robot's it moves."""
        return [Figure(cfg.robot, "cycles_completed", "work cycles completed", f"{name}.cycles_completed")]

    def abstraction(self, abstract, name, cfg):
        from cellsim.kinds.process.abstraction import ProcessAbstraction

        return ProcessAbstraction(abstract, name, cfg)


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
