"""The ground_truth kind: wired to SceneGraph's queries once every entity's geometry exists."""

from __future__ import annotations

from cellsim.kinds.ground_truth.config import GroundTruthConfig
from cellsim.kinds.ground_truth.system import GroundTruth
from cellsim.kind import Glance, ModuleKind


class GroundTruthKind(ModuleKind):
    """The true separations, measured on the geometry: what no sensor reports."""

    name = "ground_truth"
    section = "behaviours"
    config = GroundTruthConfig
    summary = ("Measures what no sensor reports: the true minimum distance between every robot and every person, and "
               "between every pair of robots.")
    stage = 10
    glance = (Glance("robot", "true separation", "separation", "m", far=1e3),)
    channels = (
        ("separation", "number, m", "true minimum person-robot distance (negative: overlap)"),
        ("clearance_<a>_<b>", "number, m", "per pair of robots a, b: the true minimum distance between them"),
    )

    def build(self, cell, name, cfg):
        return build_ground_truth(cell, name, cfg)

    def abstraction(self, abstract, name, cfg):
        """It only watches: nothing of it enters the abstract cell."""
        from cellsim.verify.model import Observer

        return Observer()


def build_ground_truth(cell, name: str, cfg: GroundTruthConfig) -> GroundTruth:
    system = cell.add(name, GroundTruth(name, cfg, list(cell.arm_geometry)))
    cell.connect_query(system.query_port)
    # every entity exists at this stage
    system.set_geometries(cell.scene_graph.model_inspector(), cell.robot_geometry, cell.people, cell.arm_geometry)
    return system
