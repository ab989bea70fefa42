"""Ground truth the sensors cannot give: the true operator-robot separation, and the clearance
between every pair of robots.

An analysis behaviour (paper, section 6: "capturing the distance between the
operator and the robot irrespective of the LIDAR blind spots"). In a cell with
several arms, ``clearance_<a>_<b>`` is the least distance between arm a's and arm
b's collision shapes: two arms at one fixture that get out of step show it.
"""

from __future__ import annotations

from pydrake.common.value import AbstractValue
from pydrake.geometry import QueryObject

from cellsim.channels import number_type
from cellsim.kinds.ground_truth.config import GroundTruthConfig
from cellsim.proximity import NearestPair
from cellsim.systems import CellSystem, write_scalar

FAR_AWAY = 10.0  # m, reported when there is no operator or no robot


class GroundTruth(CellSystem):
    """Ports:
    geometry_query (input): SceneGraph QueryObject.
    separation (channel, m): minimum signed distance between any robot geometry
      and any operator geometry (negative: they overlap).
    clearance_<a>_<b> (channel, m), per pair of robots a, b (in the scenario's order): the minimum
      signed distance between their geometries.
    """

    def __init__(self, module: str, cfg: GroundTruthConfig, robots: list[str] = ()):
        self.robot_ids = self.person_ids = frozenset()
        """``robots``: the cell's robots, in order (a clearance channel per pair)."""
        super().__init__(module, cfg.period)
        self.query_port = self.DeclareAbstractInputPort("geometry_query", AbstractValue.Make(QueryObject()))
        self._separation = self.declare_channel(
            "separation", number_type("m"), FAR_AWAY, record="every_sample",
            description="True minimum operator-robot distance",
        )
        self.robot_pairs = [(a, b) for i, a in enumerate(robots) for b in robots[i + 1:]]
        self._clearances = [
            self.declare_channel(f"clearance_{a}_{b}", number_type("m"), FAR_AWAY, record="every_sample",
                                 description=f"True minimum distance between {a} and {b}")
            for a, b in self.robot_pairs
        ]
        self.separation_pair = None
        self.arm_pairs: list = [None for _ in self.robot_pairs]

    def set_geometries(self, inspector, robot_ids, operator_ids, arms: dict[str, list] | None = None) -> None:
        """``inspector``: SceneGraph's model inspector; ``arms``: each robot's GeometryIds, for the clearances."""
        self.robot_ids, self.person_ids = frozenset(robot_ids), frozenset(operator_ids)
        self.separation_pair = NearestPair(inspector, robot_ids, operator_ids)
        arms = arms or {}
        self.arm_pairs = [NearestPair(inspector, arms.get(a, ()), arms.get(b, ())) for a, b in self.robot_pairs]

    def update(self, context, xd):
        people_and_robots = bool(self.separation_pair)
        if not people_and_robots and not any(self.arm_pairs):
            return
        query = self.query_port.Eval(context)
        if people_and_robots:
            nearest = self.separation_pair(query, FAR_AWAY)
            write_scalar(xd, self._separation, FAR_AWAY if nearest is None else nearest.distance)
        for group, pairs in zip(self._clearances, self.arm_pairs):
            if pairs:
                nearest = pairs(query, FAR_AWAY)
                write_scalar(xd, group, FAR_AWAY if nearest is None else nearest.distance)
