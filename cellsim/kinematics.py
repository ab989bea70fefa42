"""Cartesian tool targets, solved into joint poses once, at load time.

A robot's named pose may be given as joint angles or as where its tool should
be (``tool_at``, optionally ``tool_rpy_deg``). :func:`solve_tool_target` turns
such a target into joint angles with Drake's ``InverseKinematics`` (SNOPT or
IPOPT, whichever the wheel has) on a private copy of the arm: the tool frame's
origin within ``POSITION_TOLERANCE`` of the point, its orientation within
``ORIENTATION_TOLERANCE`` when one is given, every joint within its limits.

The solve is deterministic: it starts from each of the given seed poses in turn
(then from the arm bent with its first joint turned towards the target, and
round from it) and keeps the first feasible solution, the one nearest its seed (a quadratic
cost on the distance to it), so a target near the previous pose of a sequence
is reached without the arm flipping over. Results are cached, so the check at
load time and the build share one solve.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

POSITION_TOLERANCE = 1e-3
"""How far (m) the solved tool may be from the target point."""
ORIENTATION_TOLERANCE = math.radians(1.0)
"""How far (rad) the solved tool may be turned from the target orientation."""


@dataclass(frozen=True)
class Solution:
    """A solved target: joint angles (rad), or why there are none."""

    q: tuple[float, ...] | None
    miss: float = 0.0
    """With no solution: the least distance (m) from the tool to the point among the attempts."""


@functools.lru_cache(maxsize=256)
def _arm(model_path: str, base: tuple[float, ...], tool_frame: str):
    """A continuous plant of the arm welded at ``base`` = (x, y, z, yaw_deg), and its tool frame."""
    from pydrake.math import RigidTransform, RollPitchYaw
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import MultibodyPlant

    plant = MultibodyPlant(0.0)
    (instance,) = Parser(plant).AddModels(model_path)
    pose = RigidTransform(RollPitchYaw(0.0, 0.0, math.radians(base[3])), list(base[:3]))
    plant.WeldFrames(plant.world_frame(), plant.GetBodyByName("base_link", instance).body_frame(), pose)
    plant.Finalize()
    return plant, plant.GetFrameByName(tool_frame, instance)


def _facing_seeds(base, target, n: int) -> tuple[tuple[float, ...], ...]:
    """Extra starting poses: the arm bent, its first joint turned towards the target (and round from it)."""
    pan = math.atan2(target[1] - base[1], target[0] - base[0]) - math.radians(base[3])
    bent = (-math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0)[: n - 1]
    return tuple((pan + k * math.pi / 2, *bent) for k in (0, 1, -1, 2))


@functools.lru_cache(maxsize=1024)
def solve_tool_target(
    model_path: str,
    base: tuple[float, ...],
    tool_frame: str,
    position: tuple[float, float, float],
    rpy_deg: tuple[float, float, float] | None,
    seeds: tuple[tuple[float, ...], ...],
) -> Solution:
    """Joint angles putting ``tool_frame`` at ``position`` (world, m), turned ``rpy_deg`` if given."""
    from pydrake.math import RollPitchYaw, RotationMatrix
    from pydrake.multibody.inverse_kinematics import InverseKinematics
    from pydrake.solvers import Solve

    plant, tool = _arm(model_path, base, tool_frame)
    target = np.array(position, float)
    context = plant.CreateDefaultContext()
    best_miss = math.inf
    for seed in seeds + _facing_seeds(base, target, len(seeds[0]) if seeds else 6):
        ik = InverseKinematics(plant, with_joint_limits=True)
        slack = np.full(3, POSITION_TOLERANCE)
        ik.AddPositionConstraint(tool, np.zeros(3), plant.world_frame(), target - slack, target + slack)
        if rpy_deg is not None:
            wanted = RotationMatrix(RollPitchYaw(np.radians(rpy_deg)))
            ik.AddOrientationConstraint(plant.world_frame(), wanted, tool, RotationMatrix(), ORIENTATION_TOLERANCE)
        q = ik.q()
        ik.get_mutable_prog().AddQuadraticErrorCost(np.eye(len(seed)), np.array(seed), q)
        ik.get_mutable_prog().SetInitialGuess(q, np.array(seed))
        result = Solve(ik.prog())
        solved = result.GetSolution(q)
        plant.SetPositions(context, solved)
        miss = float(np.linalg.norm(tool.CalcPoseInWorld(context).translation() - target))
        if result.is_success():
            return Solution(tuple(float(x) for x in solved))
        best_miss = min(best_miss, miss)
    return Solution(None, best_miss)
