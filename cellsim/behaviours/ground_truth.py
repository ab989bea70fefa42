"""Ground truth the sensors cannot give: the true operator-robot separation.

An analysis behaviour (paper, section 6: "capturing the distance between the
operator and the robot irrespective of the LIDAR blind spots").
"""

from __future__ import annotations

from pydrake.common.value import AbstractValue
from pydrake.geometry import QueryObject

from cellsim.channels import number_type
from cellsim.registry import ModuleKind, deferred
from cellsim.scenario import GroundTruthConfig
from cellsim.systems import CellSystem, write_scalar

FAR_AWAY = 10.0  # m, reported when there is no operator or no robot


class GroundTruth(CellSystem):
    """Ports:
    geometry_query (input): SceneGraph QueryObject.
    separation (channel, m): minimum signed distance between any robot geometry
      and any operator geometry (negative: they overlap).
    """

    def __init__(self, module: str, cfg: GroundTruthConfig):
        super().__init__(module, cfg.period)
        self.query_port = self.DeclareAbstractInputPort("geometry_query", AbstractValue.Make(QueryObject()))
        self.pairs: list = []
        self._separation = self.declare_channel(
            "separation", number_type("m"), FAR_AWAY, record="every_sample",
            description="True minimum operator-robot distance",
        )

    def set_geometries(self, robot_ids, operator_ids) -> None:
        self.pairs = [(r, o) for r in robot_ids for o in operator_ids]

    def update(self, context, xd):
        if not self.pairs:
            return
        query = self.query_port.Eval(context)
        nearest = min(query.ComputeSignedDistancePairClosestPoints(a, b).distance for a, b in self.pairs)
        write_scalar(xd, self._separation, min(nearest, FAR_AWAY))


def build_ground_truth(cell, name: str, cfg: GroundTruthConfig) -> GroundTruth:
    system = cell.add(name, GroundTruth(name, cfg))
    cell.connect_query(system.query_port)
    system.set_geometries(cell.robot_geometry, cell.people)  # every entity exists at this stage
    return system


KIND = ModuleKind(
    name="ground_truth",
    abstraction=deferred("cellsim.verify.model:observer"),
    section="behaviours",
    config=GroundTruthConfig,
    build=build_ground_truth,
    stage=10,
    summary="Measures what no sensor reports: the true minimum distance between every robot and every person.",
    channels=(("separation", "number, m", "true minimum person-robot distance (negative: overlap)"),),
)
