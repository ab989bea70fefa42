"""The robot kind: a six-axis arm (URDF) moving between named poses, with ISO 10218 safety modes.

Its build adds the arm to the cell's plant (``prepare``), checks the model against the scenario (its
tool frame, its joints, each named pose within the limits, tool targets solved by inverse kinematics)
and adds the controller side (``build``).
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import MultibodyPlant

from cellsim.entity import TWIN_CHANNELS
from cellsim.kinds.robot.config import RobotConfig, ToolTarget
from cellsim.kinds.robot.geometry import add_arm_geometry, collision_shapes, model_without_collision
from cellsim.kinds.robot.system import HOLD, KD, KI, KP, Robot, robot_base_pose
from cellsim.kinematics import solve_tool_target
from cellsim.channels import enum_type, number_type
from cellsim.kind import Comparison, Figure, Glance, ModuleKind, Protocol
from cellsim.vocabulary import SafetyMode, value_set


class RobotKind(ModuleKind):
    name = "robot"
    section = "entities"
    config = RobotConfig
    summary = "A six-axis collaborative arm (URDF) moving between named poses (joint angles or tool targets), with ISO 10218 safety modes."
    sample_fields = tuple(f"q{i}" for i in range(6)) + ("safety_mode", "activity", "reached_pose")
    command_fields = ("safety_mode_request", "activity", "target_pose", "speed_limit")
    channels = (
        ("safety_mode", "enum", "current safety mode (safmod); unknown when shadowing with no valid sample"),
        ("activity", "enum", "one of its activities, or unknown (ract)"),
        ("location", "enum", "the layout.robot_regions region holding the tool, else layout.robot_elsewhere (rloc)"),
        ("reached_pose", "enum", "the named pose the arm rests at, or moving"),
        ("joint_positions", "vector, rad", "measured joint positions, at every update"),
        ("tool_speed", "number, m/s", "measured tool speed, at every update"),
        *TWIN_CHANNELS,
    )
    inputs = (
        ("safety_mode_request", "enum", "the safety mode a safety controller requests (it takes the most restrictive)"),
        ("activity", "enum", "the activity its process carries out (ract follows it)"),
        ("speed_limit", "number, m/s", "the tool speed an ssm module allows now; followed in ssmon, below its cap "
         "(sent to the physical twin as that cap when no ssm drives it)"),
        ("speed_scaling", "number, 0..1", "its controller's speed slider (a UR's): scales every motion; 1 unless "
         "an emulated controller drives it"),
    )
    files = {"model": "robot model"}
    glance = (
        Glance("cell", "{name} safety mode", "safety_mode"),
        Glance("robot", "{name} location", "location"),
        Glance("robot", "{name} activity", "activity"),
        Glance("robot", "{name} tool speed", "tool_speed", "m/s"),
    )
    comparison = Comparison("joint_positions", tuple(f"q{i}" for i in range(6)), tolerance=math.radians(20.0),
                            scale=180.0 / math.pi, unit="deg")
    """A physical joint further than 20 degrees from the twin's differs: beyond what the 0.1 s between two of the
    twin's joint-position messages explains at a cobot's joint speeds."""

    def protocol(self, name, cfg):
        modes, number = enum_type(SafetyMode), number_type(None)
        activities = enum_type(value_set(f"{name}_activity", [*cfg.activities, "unknown"]))
        poses = enum_type(value_set(f"{name}_pose", ["moving", *cfg.named_poses]))
        return Protocol(
            (*((f"q{i}", number) for i in range(6)), ("safety_mode", modes), ("activity", activities),
             ("reached_pose", poses)),
            (("safety_mode_request", modes), ("activity", activities), ("target_pose", number),
             ("speed_limit", number_type("m/s"))),
            # its supervisor lost: stopped, its first activity, holding where it is, no speed allowed
            {"safety_mode_request": SafetyMode.STOPPED.value, "activity": cfg.activities[0], "target_pose": HOLD,
             "speed_limit": 0.0},
        )

    def prepare(self, cell, name, cfg):
        _add_arm(cell, name, cfg)

    def build(self, cell, name, cfg):
        return build_robot(cell, name, cfg)

    def check(self, sf, name, cfg):
        _check(sf, name, cfg)

    def figures(self, name, cfg):
        return [Figure(name, "final_safety_mode", "final safety mode", f"{name}.safety_mode")]

    def abstraction(self, abstract, name, cfg):
        from cellsim.kinds.robot.abstraction import RobotAbstraction

        return RobotAbstraction(abstract, name, cfg)


def _model_path(sf, name: str, cfg: RobotConfig):
    return sf.resolve_path(f"entities.{name}.model", cfg.model)


def _add_arm(cell, name: str, cfg: RobotConfig) -> None:
    """Add the arm's model to the plant, welded at its base pose; every problem is a ConfigError.

    The model is read in full (strictly) to check it and to take its collision
    shapes, then added to the plant without them (see ``arm_geometry``).
    """
    instance, shapes = _parse_arm(cell.sf, name, cfg, cell.plant)
    cell.plant.WeldFrames(cell.plant.world_frame(), cell.plant.GetBodyByName("base_link", instance).body_frame(),
                          robot_base_pose(cfg))
    cell.robots[name] = instance
    cell.prepared[name] = shapes


def _parse_arm(sf, name: str, cfg: RobotConfig, plant):
    """The arm's model added to ``plant`` without its collision shapes, checked: one model, Drake can read it, a
    ``base_link``, the tool frame, six joint positions; returns (its model instance, its collision shapes). Every
    problem is a ConfigError at the key at fault (``model`` or ``tool_frame``)."""
    key = f"entities.{name}"
    model = _model_path(sf, name, cfg)
    try:
        shapes, instances = collision_shapes(model, name, strict=True)
    except Exception as e:  # noqa: BLE001 - Drake's parser raises RuntimeError with a long text
        raise sf.error(f"{key}.model", f"not a robot model Drake can read: {_first_line(e)}") from None
    if instances != 1:
        raise sf.error(f"{key}.model", f"expected one robot model in {cfg.model}, found {instances}")
    text, file_type = model_without_collision(model)
    (instance,) = Parser(plant, name).AddModelsFromString(text, file_type)
    if not plant.HasBodyNamed("base_link", instance):
        raise sf.error(f"{key}.model", f"{cfg.model} has no link named 'base_link' (where the arm is fixed to the cell)")
    if not plant.HasFrameNamed(cfg.tool_frame, instance):
        raise sf.error(f"{key}.tool_frame", f"{cfg.model} has no frame named '{cfg.tool_frame}'")
    joints = sum(plant.get_joint(j).num_positions() for j in plant.GetJointIndices(instance))
    if joints != 6:
        raise sf.error(f"{key}.model", f"{cfg.model} has {joints} joint positions; a robot entity needs 6")
    return instance, shapes


def _check_against_model(cell, name: str, cfg: RobotConfig) -> None:
    """Each named pose within the model's joint limits; each joint able to move (the plant finalised)."""
    plant, instance = cell.plant, cell.robots[name]
    joints = sorted(
        (plant.get_joint(j) for j in plant.GetJointIndices(instance) if plant.get_joint(j).num_positions() == 1),
        key=lambda joint: joint.position_start(),
    )
    for joint in joints:
        if not joint.velocity_upper_limits()[0] > 0:
            raise cell.sf.error(
                f"entities.{name}.model",
                f"joint '{joint.name()}' of {cfg.model} has velocity limit {joint.velocity_upper_limits()[0]:g}: it could never move",
            )
    for pose, q in cfg.named_poses.items():
        if isinstance(q, ToolTarget):
            continue  # solved within the joint limits
        for i, (x, joint) in enumerate(zip(q, joints)):
            lo, hi = joint.position_lower_limits()[0], joint.position_upper_limits()[0]
            if not lo <= x <= hi:
                raise cell.sf.error(
                    f"entities.{name}.named_poses.{pose}.{i}",
                    f"{x:g} rad is outside the limits of joint '{joint.name()}' in {cfg.model}: [{lo:g}, {hi:g}] rad",
                )


def _first_line(error: Exception) -> str:
    text = " ".join(line.strip() for line in str(error).splitlines() if line.strip())
    return text[:300]


def effective_mass(plant, instance, payload: float) -> float:
    """m_R of ISO/TS 15066 Annex A (kg): M/2 + m_L, half the mass of the arm's moving links (its bodies not welded
    to the world) plus the whole mass of its tooling (bodies welded to a moving link, as a tool is to the flange:
    they move with the contact point as the payload does) and of the payload."""
    from pydrake.multibody.tree import JointIndex

    welds = [plant.get_joint(JointIndex(j)) for j in range(plant.num_joints())]
    welds = [joint for joint in welds if joint.num_velocities() == 0]
    welded, grown = {plant.world_body().index()}, True
    while grown:  # follow weld joints out from the world
        grown = False
        for joint in welds:
            if joint.parent_body().index() in welded and joint.child_body().index() not in welded:
                welded.add(joint.child_body().index())
                grown = True
    tooling = {joint.child_body().index() for joint in welds if joint.child_body().index() not in welded}
    moving = [b for b in plant.GetBodyIndices(instance) if b not in welded]
    links = sum(plant.get_body(b).default_mass() for b in moving if b not in tooling)
    tools = sum(plant.get_body(b).default_mass() for b in moving if b in tooling)
    return 0.5 * links + tools + payload


def build_robot(cell, name: str, cfg: RobotConfig) -> Robot:
    """The arm's controller side, its joint controller, and its geometry for ground truth."""
    from pydrake.systems.controllers import InverseDynamicsController

    _check_against_model(cell, name, cfg)
    poses = resolve_poses(cell.sf, name, cfg)
    robot = cell.add(name, Robot(name, cfg, str(_model_path(cell.sf, name, cfg)), cell.scenario.layout, poses))
    instance, plant, builder = cell.robots[name], cell.plant, cell.builder
    robot.body_frames = [plant.GetBodyFrameIdIfExists(b) for b in plant.GetBodyIndices(instance)]
    controller = builder.AddNamedSystem(
        f"{name}.joint_controller",
        InverseDynamicsController(robot.kinematics.plant, [KP] * 6, [KI] * 6, [KD] * 6, False),
    )
    builder.Connect(plant.get_state_output_port(instance), controller.get_input_port_estimated_state())
    builder.Connect(plant.get_state_output_port(instance), robot.measured_state_port)
    builder.Connect(robot.desired_state_port, controller.get_input_port_desired_state())
    builder.Connect(controller.get_output_port_control(), plant.get_actuation_input_port(instance))
    ids = add_arm_geometry(cell, name, instance, cell.prepared[name])
    cell.arm_geometry[name] = {g: shape.body for g, shape in zip(ids, cell.prepared[name])}
    cell.arm_mass[name] = effective_mass(cell.plant, instance, cfg.payload)
    cell.robot_geometry += ids
    cell.foreign_geometry += ids  # contact between them and anything is filtered out
    return robot


def resolve_poses(sf, name: str, cfg: RobotConfig) -> dict[str, np.ndarray]:
    """Every named pose as joint angles (rad): tool targets solved by inverse kinematics.

    A tool target is solved from the initial pose, then from the pose declared
    before it, then from the other joint poses: the arm stays in the initial
    pose's configuration (elbow up, say) where it can.
    An unreachable target is a ConfigError naming the pose and the steps moving to it.
    """
    model = str(_model_path(sf, name, cfg))
    base = (*cfg.base_position, cfg.base_yaw_deg)
    joint_poses = [tuple(q) for q in cfg.named_poses.values() if not isinstance(q, ToolTarget)]
    joint_poses.sort(key=lambda q: q != tuple(cfg.named_poses.get(cfg.initial_pose, ())))
    poses: dict[str, np.ndarray] = {}
    previous: tuple | None = None
    for pose, value in cfg.named_poses.items():
        if isinstance(value, ToolTarget):
            seeds = tuple(dict.fromkeys(joint_poses[:1] + ([previous] if previous else []) + joint_poses[1:]))
            try:
                solution = solve_tool_target(model, base, cfg.tool_frame, tuple(value.tool_at), value.tool_rpy_deg, seeds)
            except Exception as e:  # noqa: BLE001 - Drake's errors are long texts
                _parse_arm(sf, name, cfg, MultibodyPlant(0.0))  # a model or tool frame at fault is named as such
                raise sf.error(f"entities.{name}.named_poses.{pose}", f"inverse kinematics failed: {_first_line(e)}") from None
            if solution.q is None:
                turned = "" if value.tool_rpy_deg is None else f" turned {list(value.tool_rpy_deg)} deg"
                raise sf.error(
                    f"entities.{name}.named_poses.{pose}",
                    f"the tool of {name} cannot reach {list(value.tool_at)}{turned} within its joint limits "
                    f"(nearest {solution.miss:.3f} m away){_used_by(sf, pose)}",
                )
            value = solution.q
        poses[pose] = np.array(value, float)
        previous = tuple(value)
    return poses


def _used_by(sf, pose: str) -> str:
    """"; moved to by step 'x' of y" for the behaviours' steps naming ``pose``."""
    steps = [
        f"step '{getattr(step, 'name', i)}' of {module}"
        for module, cfg in sf.scenario.behaviours.items()
        for i, step in enumerate(getattr(cfg, "steps", []))
        if getattr(step, "move_to", None) == pose
    ]
    return f"; moved to by {', '.join(steps)}" if steps else ""


def _check(sf, name: str, cfg: RobotConfig) -> None:
    _model_path(sf, name, cfg)
    if any(isinstance(q, ToolTarget) for q in cfg.named_poses.values()):
        resolve_poses(sf, name, cfg)
