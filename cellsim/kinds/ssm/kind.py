"""The ssm kind: a speed limit wired to its robot, separation from geometry or a sensor's channel."""

from __future__ import annotations

from cellsim.config.typed_yaml import suggest
from cellsim.kinds.ssm.config import GEOMETRY, SsmConfig
from cellsim.kinds.ssm.system import SpeedSeparationMonitor, parameters_of
from cellsim.kind import ModuleKind


class SsmKind(ModuleKind):
    """Speed and separation monitoring of one robot: the speed it may have now."""

    name = "ssm"
    section = "behaviours"
    config = SsmConfig
    summary = ("Speed and separation monitoring (ISO/TS 15066): protective separation distance, margin and the speed "
               "a robot may have now, which it follows in ssmon.")
    stage = 10
    channels = (
        ("separation", "number, m", "separation to the nearest person (from the arm's geometry, or the sensor)"),
        ("protective_distance", "number, m", "S_p for the robot's current speed towards the person"),
        ("margin", "number, m", "separation less S_p (negative: too fast for the separation)"),
        ("speed_limit", "number, m/s", "the speed the robot may have now; the robot follows it in ssmon"),
        ("true_margin", "number, m", "on the truth: true separation less S_p of the true speed, no allowances"),
        ("unwatched_margin_fall", "number, m/s",
         "the fastest the true margin fell in ssmon between two judgements not watched at every step"),
    )

    def build(self, cell, name, cfg):
        return build_ssm(cell, name, cfg)

    def check(self, sf, name, cfg):
        _check(sf, name, cfg)

    def conditions(self, name, cfg):
        from cellsim.config.validation import Described

        return {"TrueSSM": Described(
            f"G({cfg.robot}.safety_mode == ssmon -> {name}.true_margin >= 0)",
            "While a monitored arm is in speed and separation monitoring, its true separation from every person "
            "exceeds the protective distance of its true speed.")}

    def findings(self, name, cfg, blackbox):
        """A true margin seen falling faster than ``max_margin_fall`` between two judgements (a dip may be missed)."""
        from cellsim.kind import Finding

        channel = f"{name}.unwatched_margin_fall"
        if channel not in blackbox.channels():
            return []
        series = blackbox.series(channel)
        over = [(t, v) for t, v in zip(series.times.tolist(), series.values) if isinstance(v, (int, float))
                and v > cfg.max_margin_fall]
        if not over:
            return []
        fastest = max(v for _, v in over)
        return [Finding(name, "fast fall", over[0][0], None,
                        f"the true margin fell at {fastest:.3g} m/s between two of {name}'s judgements, faster than the "
                        f"{cfg.max_margin_fall:g} m/s it assumes there: a dip below 0 between them may have been missed "
                        f"(raise {name}.max_margin_fall)", {"speed": fastest, "max_margin_fall": cfg.max_margin_fall})]

    def abstraction(self, abstract, name, cfg):
        """Its true margin, where a property compares it with 0 (``TrueSSM``); nothing else of it."""
        from cellsim.kinds.ssm.abstraction import SsmAbstraction

        return SsmAbstraction(abstract, name, cfg)


def build_ssm(cell, name: str, cfg: SsmConfig) -> SpeedSeparationMonitor:
    """The monitor of ``cfg.robot``: its speed limit wired to the robot, its separation measured."""
    from cellsim.kinds.robot.system import ArmKinematics

    robot = cell.modules[cfg.robot]
    robot_cfg = cell.scenario.modules_of_kind("robot")[cfg.robot]
    kinematics = ArmKinematics(robot.kinematics.model_path, robot_cfg)
    system = cell.add(name, SpeedSeparationMonitor(name, cfg, parameters_of(cfg, robot_cfg), kinematics,
                                                   robot_cfg.base_position[:2], robot_cfg.speed_limits.ssmon))
    cell.builder.Connect(cell.plant.get_state_output_port(cell.robots[cfg.robot]), system.robot_state_port)
    cell.builder.Connect(system.GetOutputPort("speed_limit"), robot.speed_limit_port)
    cell.builder.Connect(robot.GetOutputPort("safety_mode"), system.robot_mode_port)
    cell.connect_query(system.query_port)  # the monitor's separation, or the truth beside a sensor's
    system.set_geometries(cell.scene_graph.model_inspector(), cell.arm_geometry[cfg.robot], cell.people)
    try:
        system.watch_truth(cell.scenario.time_step, [person.period for person in cell.bodies.values()], robot.period,
                           cfg.max_margin_fall)
    except ValueError as e:  # periods with no common multiple to judge the truth on: the scenario's to change
        raise cell.sf.error(f"behaviours.{name}.period", str(e).removeprefix(f"{name}: ")) from None
    if system.from_geometry:  # bodies the twin may have lost track of: the robot's and every person's links
        watched = [cfg.robot, *cell.bodies]
        for entity, port in zip(watched, system.watch_links(watched)):
            cell.builder.Connect(cell.modules[entity].GetOutputPort("physical_link"), port)
    else:  # a sensor's distance: every entity is built by now
        channels = cell.channels()
        where = f"behaviours.{name}.separation"
        if cfg.separation not in channels:
            raise cell.sf.error(where, f"no channel '{cfg.separation}'{suggest(cfg.separation, channels)}")
        spec, port = channels[cfg.separation]
        if spec.type.kind != "number" or spec.type.unit != "m":
            raise cell.sf.error(where, f"'{cfg.separation}' is not a distance in m ({spec.type.kind}, "
                                f"{spec.type.unit or 'no unit'})")
        cell.builder.Connect(port, system.separation_port)
        sensor = cfg.separation.partition(".")[0]
        if sensor in cell.entities:  # its reading has no value while its link is not ok (stale, corrupt, recovering)
            (link,) = system.watch_links([sensor])
            cell.builder.Connect(cell.modules[sensor].GetOutputPort("physical_link"), link)
    return system


def _check(sf, name: str, cfg: SsmConfig) -> None:
    """The robot exists and is monitored once; the reaction time covers this monitor's and the robot's periods; a
    sensor's separation is a channel in m."""
    key = f"behaviours.{name}"
    robots = sf.scenario.modules_of_kind("robot")
    if cfg.robot not in robots:
        raise sf.error(f"{key}.robot", f"no robot entity named '{cfg.robot}' ({', '.join(robots) or 'none'})")
    latency = cfg.period + robots[cfg.robot].period
    if cfg.reaction_time < latency - 1e-9:
        # the arm takes a new limit at its next update after this monitor's: a shorter T_r credits the formula, the
        # speed limit and the true margin with reaction time the arm does not have
        raise sf.error(f"{key}.reaction_time", f"{cfg.reaction_time:g} s is shorter than the periods of this monitor "
                       f"and of robot '{cfg.robot}' together ({latency:g} s): the arm acts on a limit that late at the "
                       "earliest; T_r must cover them (and the sensor's response)")
    for other, other_cfg in sf.scenario.modules_of_kind("ssm").items():
        if other == name:
            break
        if other_cfg.robot == cfg.robot:
            where = sf.locate(f"behaviours.{other}.robot")
            raise sf.error(f"{key}.robot", f"robot '{cfg.robot}' is already monitored by '{other}' ({where[0]}, "
                           f"line {where[1]}): one speed limit per robot")
    if cfg.separation != GEOMETRY:
        module, _, signal = cfg.separation.partition(".")
        if module not in sf.scenario.entities or not signal:
            raise sf.error(f"{key}.separation", f"'{cfg.separation}' is neither geometry nor a sensor's channel "
                           "(module.signal, e.g. scanner.distance)")
