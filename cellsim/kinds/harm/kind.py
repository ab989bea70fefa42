"""The harm kind: every cell with a robot and a person judges contact with the person's body."""

from __future__ import annotations

from cellsim.kind import ModuleKind
from cellsim.kinds.harm.config import HarmConfig


class HarmKind(ModuleKind):
    """Contact between the robots and each person's body regions, judged against a limits table."""

    name = "harm"
    section = "services"
    config = HarmConfig
    summary = ("What the robots do to each person's body: contact per body region, transient or clamping, and its "
               "severity against a biomechanical limits table (ISO/TS 15066 Annex A's model); in every cell by default.")
    stage = 10
    default_module = "harm"
    files = {"limits": "biomechanical limits table"}
    channels = (
        ("severity", "number", "the worst contact's severity now: v_rel / v_max (0: no contact; above 1: harm)"),
        ("clamping", "number", "the worst quasi-static (clamping) contact's severity now (0: none)"),
        ("contact_region", "enum", "body region of the worst contact (none: no contact)"),
        ("contact_person", "enum", "person of the worst contact (none: no contact)"),
        ("contact_part", "enum", "robot part of the worst contact, <robot>_<link> (none: no contact)"),
        ("contact_kind", "enum", "transient or quasi_static (clamping) (none: no contact)"),
        ("contact_speed", "number, m/s", "the worst contact's relative speed along its push (docs/harm.md)"),
        ("nearest_region", "enum", "body region nearest to a robot within cutoff (none: nobody that near)"),
        ("nearest_person", "enum", "the person whose region is nearest to a robot within cutoff (none: nobody that near)"),
        ("separation_<robot>", "number, m", "per robot: its least true distance to any body region, up to cutoff"),
        ("region_jump", "number, m", "the most a body region moved in one update near a robot beyond it and the thinnest "
         "robot part's thickness (the largest yet; above 0: it may have passed through a part unseen)"),
        ("unwatched_part_speed", "number, m/s",
         "the fastest a robot part's point moved at a look ending an interval watched only at looks (the largest yet)"),
    )

    def build(self, cell, name, cfg):
        return build_harm(cell, name, cfg)

    def check(self, sf, name, cfg):
        _limits(sf, name, cfg)

    def conditions(self, name, cfg):
        from cellsim.config.validation import Described

        return {
            "NoHarm": Described(f"G({name}.severity <= 1)",
                                "No robot touches a person harder than the body region's limit (severity above 1)."),
            "NoClamping": Described(f"G({name}.clamping <= 1)",
                                    "No robot pins a person's body region against something beyond its quasi-static limit."),
        }

    def findings(self, name, cfg, blackbox):
        from cellsim.kinds.harm.findings import harm_findings

        return harm_findings(name, blackbox, cfg.max_part_speed)

    def abstraction(self, abstract, name, cfg):
        """Contact, where a condition reads the severity or the clamping: possible wherever an arm's bound distance to a
        body may be at most 0 (:mod:`cellsim.kinds.harm.abstraction`); nothing else of it."""
        from cellsim.kinds.harm.abstraction import HarmAbstraction

        return HarmAbstraction(abstract, name, cfg)


def _limits(sf, name: str, cfg: HarmConfig):
    from cellsim.kinds.harm.limits import SHIPPED, load_limits
    from cellsim.body import REGIONS

    path = sf.resolve_path(f"services.{name}.limits", cfg.limits) if cfg.limits else SHIPPED
    return load_limits(path, REGIONS).value


def build_harm(cell, name: str, cfg: HarmConfig):
    """The harm service, when the cell has a robot and a person (else nothing)."""
    from cellsim.kinds.harm.system import HarmMonitor, Part

    if not cell.bodies or not cell.arm_geometry:
        return None
    plant = cell.plant
    parts, names = {}, []
    for robot, geometries in cell.arm_geometry.items():
        instance = cell.robots[robot]
        for geometry, body in geometries.items():
            part = f"{robot}_{body}"
            link = plant.GetBodyByName(body, instance)
            rigid = min(int(b.index()) for b in plant.GetBodiesWeldedTo(link))
            parts[geometry] = Part(robot, link.index(), cell.arm_mass[robot], part, rigid)
            if part not in names:
                names.append(part)
    people = list(cell.bodies)
    system = cell.add(name, HarmMonitor(name, cfg, cell.scenario.time_step, _limits(cell.sf, name, cfg),
                                        {robot: cell.arm_mass[robot] for robot in cell.arm_geometry}, people, names, plant))
    cell.connect_query(system.query_port)
    cell.builder.Connect(plant.get_body_poses_output_port(), system.body_poses_port)
    cell.builder.Connect(plant.get_body_spatial_velocities_output_port(), system.body_velocities_port)
    bodies = {}
    for index, (person, body) in enumerate(cell.bodies.items()):
        pose, previous = system.add_person(person, body)
        cell.builder.Connect(body.pose_port, pose)
        cell.builder.Connect(body.previous_pose_port, previous)
        bodies.update({g: (index, region) for g, region in body.regions.items()})
    try:
        system.set_geometries(cell.scene_graph.model_inspector(), parts, bodies, cell.fixture_geometry)
    except ValueError as e:  # a look schedule with no common multiple, an arm shape with no bound
        raise cell.sf.error(f"services.{name}.far_period" if "common multiple" in str(e) else f"services.{name}",
                            str(e).removeprefix(f"{name}: ")) from None
    return system
