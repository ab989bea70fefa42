"""The ssm kind in the abstract cell: its true margin, where a property reads it (``TrueSSM``).

The true margin is, at each instant, the least over the arm's shapes and a person's body regions
of their true distance less the protective distance S_p of the shape's true speed towards the
region (no allowances; :mod:`cellsim.kinds.ssm.system`). The model bounds it from below, per state:

* **the distance**, per place of the floor and per stretch of the arm's path (a region of a move, a
  pose it rests at; ``RobotAbstraction.stretches``), bounded from below by spheres covering both
  (:mod:`cellsim.verify.clearance`), measured at every pose of the floor as a sensor's reading is
  (so places are cut where the bound crosses a threshold below);
* **the speed**: on a straight joint-space move the arm's ds/dt is at most its cap-equivalent tool
  speed u over the move's ``tool_per_s`` (the twin plans it so), so any point of the arm moves at most
  u times the stretch's *rate* (its points' fastest metres per unit of s, over ``tool_per_s``); u is
  the robot's modelled tool speed (its speed envelope: the caps, and the braking after one ends),
  compared with 0 and each positive cap;
* **S_p** with the whole reaction time T_r (the twin's shrinks once a stop is ordered: a larger S_p).

So in each state the margin may be below 0 only if, for some person, the distance's bound at their
place is below S_p of u's largest possible value times the rate; the model's true margin reads
below 0 in every such state and above 0 elsewhere. A property that asks it to stay at or above 0
(``TrueSSM``) then holds in the model only where no state of a possible dip is reachable; a witness
goes to the twin, which judges the true margin itself. An arm on a path the model does not know
(re-targeted mid-move) may be anywhere within its reach: there, any motion near a person is a
possible dip. Only comparisons of the true margin with 0 are modelled, and only for a monitor fed
by a sensor's channel, whose limit the model takes from the sensor's reading: one that measures on
the geometry has its limit from the very distances the margin is judged on, which the model bounds
only from below, so its arm would move at its ssmon cap near a person in the model, a dip the twin
refutes everywhere (its true margin is left out, with that reason).
"""

from __future__ import annotations

import math

import numpy as np

from cellsim.verify.clearance import BODY_TOLERANCE, TOLERANCE, ArmGroup, ArmSweep, BodyCover, Clearance, arm_groups
from cellsim.verify.expressions import Thresholds
from cellsim.verify.prism import Command, Module, Var
from cellsim.verify.model import (AbstractCell, ModuleAbstraction, SensedSignal, SensorRole, context_of, lookup,
                                  prism_name, set_of)
from cellsim.kinds.robot.abstraction import TRACKING_TOLERANCE
from cellsim.kinds.ssm.system import FAR_AWAY
from cellsim.vocabulary import SafetyMode


class SsmAbstraction(ModuleAbstraction):
    """A monitor fed by a sensor's channel: its true margin where a condition compares it with 0, and its speed limit
    (the robot's cap in ssmon). Its sensed separation and margin are not modelled; a monitor measuring on the
    geometry is an observer (the robot in ssmon at its mode's fixed cap, which the limit only lowers)."""

    def __init__(self, cell: AbstractCell, name: str, cfg):
        super().__init__(cell, name, cfg)
        self.groups = None
        """[(a group of the arm's stretches, its clearance's thresholds (m))] once the true margin is modelled."""
        self.speeds: list[float] = []

    def declare_for_readers(self, cell: AbstractCell) -> None:
        """Where a condition compares the true margin with 0 (and nothing else): measure each group of stretches'
        clearance at every pose of the floor, read the robot's speed bound against 0 and the caps, and model the
        limit from the sensor's separation."""
        signal = f"{self.name}.true_margin"
        if signal not in cell.reads:
            return
        if cell.thresholds.get(signal, set()) != {0.0}:
            cell.unmodelled[signal] = "only its comparison with 0 is modelled"
            return
        if self.system.from_geometry:
            # its limit comes from the very distances the true margin is judged on, which the model bounds only from
            # below: an arm held to its mode's cap would make every motion near a person a dip the twin refutes
            cell.unmodelled[signal] = (f"{self.name} measures the separation on the geometry, and its speed limit, which "
                                       "keeps that margin, is not in the model (an arm at its ssmon cap near a person "
                                       "would be a dip the twin refutes)")
            return
        from cellsim.kinds.robot.abstraction import RobotAbstraction
        from cellsim.verify.expressions import VerifyError

        system, robot_name = self.system, self.cfg.robot
        robot = RobotAbstraction(cell, robot_name, cell.sf.scenario.modules_of_kind("robot")[robot_name])
        inspector = cell.cell.scene_graph.model_inspector()
        kin = system.kinematics
        try:
            sweep = ArmSweep(kin.plant, kin.context, [(body, inspector.GetShape(g), inspector.GetPoseInFrame(g))
                                                       for g, body in system.bodies.items()])
            bodies = BodyCover(inspector, system.pairs.b.ids)
            reach = sweep.reach(robot.system.poses[0])
        except ValueError as e:
            raise VerifyError(f"{self.name}: its true margin cannot be bounded: {e}") from None
        # u is compared with 0 and the caps it may have in ssmon: its own, and the normal one it may still be braking
        # from (above that: no cap, never read)
        caps = robot.system.speed_caps
        self.speeds = sorted({0.0, caps[SafetyMode.SPEED_SEPARATION], caps[SafetyMode.NORMAL]})
        groups, self.members = arm_groups(sweep, robot.stretches(), reach)
        modelled = [(group, [self._sp(group, 0.0)] if group.rate is None else sorted({self._sp(group, u)
                                                                                     for u in self.speeds}))
                    for group in groups]
        clouds = [group.spheres for group in groups]
        self.groups = modelled
        clearance = Clearance(clouds, [ts for _, ts in modelled], max(t for _, ts in modelled for t in ts) + 0.05)
        # (kept for the tests that hold the bounds to SceneGraph's: the stretches by location, their spheres)
        self.clearance, self.bodies, self.sweep, self.clouds = clearance, bodies, sweep, clouds
        of = context_of(system)
        signals = {}
        for k, (_, thresholds) in enumerate(modelled):
            port = f"clearance{k}"
            cell.internal[f"{self.name}.{port}"] = Thresholds(tuple(thresholds))
            signals[port] = SensedSignal(lambda distances, k=k: distances[k], None)
            cell.read(f"{self.name}.{port}", self.name, required=False)  # (its .of_<person> formulas are read)
        cell.add_sensor(SensorRole(self.name, signals, measure=lambda root: clearance.of(
            bodies.at(system.query_port.Eval(of(root))))))
        cell.read(f"{robot_name}.tool_speed_bound", self.name)
        cell.compares(f"{robot_name}.tool_speed", self.speeds)  # (the bound is in the tool speed's regions)
        # its limit from the sensor's reading, which the model has: the robot's cap in ssmon too
        cell.read(f"{self.name}.speed_limit_bound", robot_name)
        cell.read(self.cfg.separation, self.name)
        cell.compares(self.cfg.separation, [system.parameters.separation_for(u) for u in self.speeds])

    def build(self, cell: AbstractCell) -> None:
        if self.groups is None:  # (its limit is modelled with its true margin)
            return
        self._limit(cell)
        speed = cell.read(f"{self.cfg.robot}.tool_speed_bound", self.name)
        steady = cell.signals[f"{self.cfg.robot}.tool_speed_bound"].firm
        firm_dips = []
        speed_regions = cell.encoding(f"{self.cfg.robot}.tool_speed")
        dips = []
        for k, (stretch, thresholds) in enumerate(self.groups):
            encoding = cell.encoding(f"{self.name}.clearance{k}")
            # a clearance region -> the fastest speed region with no dip there: at most the fastest u whose S_p fits
            table = {}
            for region in range(encoding.regions):
                low = encoding.values[(region - 1) // 2] if region else -np.inf  # (region 0: below every threshold)
                fits = [u for u in self.speeds if self._sp(stretch, u) <= low]
                table[region] = speed_regions.region_of(max(fits)) if fits else -1
            clearances = [prism_name(f'{self.name}.clearance{k}.of_{p.module}') for p in cell.people]
            allowed = [lookup(c, table, -1) for c in clearances]
            if allowed:
                dips.append(f"({stretch.guard}) & ({' | '.join(f'{speed} > {a}' for a in allowed)})")
            if allowed and stretch.rate is not None:
                # firm: a dip whatever the arm's speed (the bound below even a still arm's S_p), the arm on a move of
                # its own at a cap above 0 (not braking from one, nor settling at a pose): the likeliest for the twin
                deep = [r for r, a in table.items() if a == -1]
                moving = f"{steady} > {speed_regions.region_of(0.0)}"
                if stretch.at_rest:
                    moving += " & !(" + " | ".join(f"({g})" for g in stretch.at_rest) + ")"
                firm_dips.append(f"({stretch.guard}) & {moving} & ({' | '.join(set_of(c, deep) for c in clearances)})")
        dip = " | ".join(f"({d})" for d in dips) or "false"
        firm_dip = " | ".join(f"({d})" for d in firm_dips) or "false"
        cell.define(f"{self.name}.true_margin", f"(({dip}) ? 0 : 2)", Thresholds((0.0,)), firm=f"(({firm_dip}) ? 0 : 2)")
        body, arm = BODY_TOLERANCE, TOLERANCE
        cell.assume(
            f"{self.name}'s true margin is bounded from below: the arm's shapes and each body region covered by "
            f"spheres (reaching at most {arm:g} m and {body:g} m beyond them), the arm anywhere between the samples of "
            "its moves; its points' speed at most its cap-equivalent tool speed times each stretch's fastest point "
            "per metre of tool path (the speed its envelope allows, compared with 0 and each cap); S_p with the "
            "whole reaction time; an arm on a path not modelled anywhere within its reach. The margin reads below "
            "0 wherever it may be (only a comparison with 0 is modelled). The distance is measured at the floor's "
            "grid poses, as every sensor's reading is: a person between two of them, or turned between two of its "
            "four headings, or partly reached out, may stand nearer (by up to half the grid's diagonal, and up to "
            "0.77 times a body part's distance from the body's axis for a turn)")

    def _limit(self, cell: AbstractCell) -> None:
        """``<ssm>.speed_limit_bound``: the limit it took at its last update from the separation it read, as the
        region of the robot's tool speed holding the highest limit the separation's region allows (the limit grows
        with the separation)."""
        sensed = cell.read(self.cfg.separation, self.name)
        separation = cell.encoding(self.cfg.separation)
        speeds = cell.encoding(f"{self.cfg.robot}.tool_speed")
        limit = self.system.parameters.speed_limit
        table = {}
        for region in range(separation.regions):
            i = region // 2  # the region's upper end: its threshold, or the next one up
            if i < len(separation.values):
                value = limit(separation.values[i])
                # (a separation placed where the limit is a speed told apart gives that speed, not a rounding above)
                value = next((u for u in speeds.values if abs(u - value) <= 1e-9 * max(1.0, u)), value)
                table[region] = speeds.region_of(value)
            else:
                table[region] = speeds.regions - 1
        var = f"{self.name}_limit"
        start = speeds.region_of(limit(FAR_AWAY))
        cell.add(Module(f"{self.name}_limit", [Var(var, 0, speeds.regions - 1, start)],
                        [Command("true", (("1", {var: lookup(sensed, table, speeds.regions - 1)}),))],
                        comment=f"{self.name}: the speed limit it took from the separation it read (the highest that "
                                "separation's region allows, as a region of the robot's tool speed)"))
        cell.define(f"{self.name}.speed_limit_bound", var, speeds)
        cell.assume(f"{self.name}'s speed limit is the highest its formula gives in the separation's region read "
                    f"({self.cfg.separation}, compared with the separations whose limit is 0 and each speed the model "
                    "tells apart); in ssmon the robot's cap is also that limit, braking to it as from a mode's cap")

    def _sp(self, group: ArmGroup, u: float) -> float:
        """S_p (m, whole reaction time) of the fastest point of ``group``'s stretches at tool speed ``u`` (m/s, a speed
        the model tells apart): at most ``u`` and the envelope's tolerance over it (a speed above 0 may sit up to that
        above its line while the arm settles), times its rate; a path not modelled: known only standing still."""
        sp = self.system.parameters.true_protective_distance
        if group.rate is None:
            return sp(0.0) if u == 0.0 else math.inf
        tool = u + TRACKING_TOLERANCE if u > 0.0 else 0.0  # the tool's speed: the robot's stopping time is its
        return sp(group.rate * tool, stopping_speed=tool)
