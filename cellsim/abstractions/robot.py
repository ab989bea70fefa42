"""The robot arm in the abstract cell: where its tool goes on each move, how fast, in which mode.

A move from one named pose to another is a straight line in joint space (as the
arm's controller drives it); sampling it through the arm's kinematics at load time
gives the regions of the layout its tool passes through, in order, and a lower
bound on the periods it spends in each (at the fastest rate the joint limits and
the normal speed cap allow, ignoring acceleration). In the abstract model the
tool is in one region of its move and each period it stays (any slower pace:
safety modes, braking, acceleration) or, once it has been there that long,
goes on to the next. A move re-targeted before it ends follows a path the
abstraction does not know: until it arrives, the tool may be in any region.

Its safety mode is the one requested, from the next period on. The tool's speed
is any value up to the highest speed cap in force over the last braking time
(plus the telemetry period its speed is published at): the modes it was in
then; it makes progress only while that cap is above zero.
"""

from __future__ import annotations

import math

import numpy as np

from cellsim.entities.robot import TELEMETRY_PERIOD
from cellsim.verify.expressions import Thresholds
from cellsim.verify.model import ModuleAbstraction, AbstractCell, lookup, set_of
from cellsim.verify.prism import Command, Module, Var
from cellsim.vocabulary import SafetyMode

SAMPLES = 200
"""Points sampled along each move to find the regions it passes through."""
_MODES = tuple(SafetyMode)


class RobotAbstraction(ModuleAbstraction):
    def declare(self, cell: AbstractCell) -> None:
        """Reads its mode request and target pose (in ``build``)."""

    def _moves(self, period: float, timed: bool) -> dict[tuple[int, int], list[tuple[int, int]]]:
        """(a, b) -> [(location code, least periods there)] along the move from pose a to pose b."""
        robot = self.system
        moves = {}
        for a in range(len(robot.poses)):
            for b in range(len(robot.poses)):
                if a == b:
                    continue
                start, goal = robot.poses[a], robot.poses[b]
                motion = robot._start_segment(start, b)
                tool_per_s, joint_rate = float(motion[3]), float(motion[4])
                rate = min(joint_rate, robot._normal_cap / tool_per_s)  # ds/dt at most
                codes = [robot.locate(robot.kinematics.tool_position(start + s * (goal - start))).code
                         for s in np.linspace(0.0, 1.0, SAMPLES + 1)]
                runs: list[list[int]] = []
                for code in codes:
                    if runs and runs[-1][0] == code:
                        runs[-1][1] += 1
                    else:
                        runs.append([code, 1])
                moves[(a, b)] = [(code, max(0, math.floor((count - 1) / SAMPLES / rate / period)) if timed else 0)
                                 for code, count in runs]
        return moves

    def build(self, cell: AbstractCell) -> None:
        r, robot, cfg = self.name, self.system, self.cfg
        period = cell.period
        poses = len(robot.poses)
        moves = self._moves(period, cell.timed)
        pairs = list(moves)
        segment = {pair: poses + i for i, pair in enumerate(pairs)}
        havoc = {b: poses + len(pairs) + b for b in range(poses)}
        locations = [loc for loc in robot.locations if loc is not robot.unknown_location]
        seg, k, t, hloc = f"{r}_segment", f"{r}_region", f"{r}_periods", f"{r}_wherever"
        longest = max((len(v) for v in moves.values()), default=1)
        most = max((n for v in moves.values() for _, n in v), default=0)
        target = cell.input(r, "target_pose")
        initial = robot.pose_names.index(cfg.initial_pose)
        vmax = f"{r}_cap"
        # with its tool's speed read, the robot moves only while a cap above zero is in force; without, the
        # cap is not modelled and it may move at any time (more behaviours, and no braking countdown in the state)
        go = f"{vmax} > 0" if f"{r}.tool_speed" in cell.reads else "true"
        commands: list[Command] = []

        def cmd(guard, update):
            commands.append(Command(guard, (("1", update),)))

        for p in range(poses):  # at rest at pose p
            here = f"{seg}={p}"
            cmd(f"{here} & ({target}=-1 | {target}={p})", {})
            for q in range(poses):
                if q != p:
                    cmd(f"{here} & {target}={q}", {seg: str(segment[(p, q)]), k: "0", t: "0"})
        for (a, b), regions in moves.items():
            moving = f"{seg}={segment[(a, b)]}"
            retarget = f"({target}!=-1 & {target}!={b})"
            for i, (_, n) in enumerate(regions):
                at = f"{moving} & {k}={i}"
                cmd(at, {t: f"min({t}+1, {n})"})  # stays (any slower pace)
                if i + 1 < len(regions):
                    cmd(f"{at} & {t}>={n} & {go}", {k: str(i + 1), t: "0"})
                else:
                    cmd(f"{at} & {t}>={n} & {go}", {seg: str(b), k: "0", t: "0"})
                for code in range(len(locations)):  # re-targeted: an unknown path
                    cmd(f"{at} & {retarget}", {seg: f"{poses + len(pairs)} + {target}", k: "0", t: "0", hloc: str(code)})
        for b in range(poses):
            lost = f"{seg}={havoc[b]}"
            for code in range(len(locations)):
                cmd(f"{lost} & ({target}=-1 | {target}={b})", {hloc: str(code)})
                cmd(f"{lost} & {target}!=-1 & {target}!={b}", {seg: f"{poses + len(pairs)} + {target}", hloc: str(code)})
            cmd(f"{lost} & {go}", {seg: str(b), hloc: "0"})  # arrived: where it was lost no longer matters
        n_segments = poses + len(pairs) + poses
        cell.add(Module(f"{r}_motion", [
            Var(seg, 0, n_segments - 1, initial), Var(k, 0, max(longest - 1, 0), 0), Var(t, 0, max(most, 0), 0),
            Var(hloc, 0, len(locations) - 1, 0),
        ], commands, comment=f"robot {r}: at rest at a pose, on a move from pose to pose (a region at a time), "
                             "or re-targeted on a path not modelled"))

        # where the tool is, and which pose it rests at
        location = {p: robot.locate(robot.kinematics.tool_position(robot.poses[p])).code for p in range(poses)}
        expr = f"{hloc}"
        for (a, b), regions in reversed(list(moves.items())):
            table = {i: code for i, (code, _) in enumerate(regions)}
            expr = f"({seg}={segment[(a, b)]} ? {lookup(k, table, -1)} : {expr})"
        expr = f"({seg}<{poses} ? {lookup(seg, location, -1)} : {expr})"
        cell.define(f"{r}.location", expr)
        cell.define(f"{r}.reached_pose", f"({seg}<{poses} ? {seg}+1 : 0)")

        # its safety mode, and the speed cap over the last braking time
        self._safety(cell, period)
        cell.define(f"{r}.activity", cell.input(r, "activity"))
        cell.assume(f"{r}'s tool is located on the commanded path (tracking error neglected); its moves take "
                    + ("at least their time at full speed without acceleration" if cell.timed else "any time from one period on"))

    def _safety(self, cell: AbstractCell, period: float) -> None:
        r, robot = self.name, self.system
        request = cell.input(r, "safety_mode_request")
        mode, vmax, countdown = f"{r}_mode", f"{r}_cap", f"{r}_cap_held"
        new_mode = f"({request} >= 0 ? {request} : {SafetyMode.UNKNOWN.code})"
        cell.define(f"{r}.safety_mode", mode)
        if f"{r}.tool_speed" not in cell.reads:
            cell.add(Module(f"{r}_safety", [Var(mode, 0, len(_MODES) - 1, SafetyMode.NORMAL.code)],
                            [Command("true", (("1", {mode: new_mode}),))], comment=f"robot {r}: the requested safety mode"))
            cell.assume(f"{r} takes a requested safety mode in one period (its speed is read by nobody: not modelled)")
            return
        caps = {m: robot.speed_caps.get(m, 0.0) for m in _MODES}
        caps[SafetyMode.UNKNOWN] = robot._normal_cap
        levels = sorted({0.0, *caps.values()})
        cap_of = lookup(mode, {m.code: levels.index(caps[m]) for m in _MODES}, 0)
        hold = math.ceil(self.cfg.braking_time / period - 1e-9) + math.ceil(TELEMETRY_PERIOD / period - 1e-9) + 1
        update = {
            mode: new_mode,
            vmax: f"({cap_of} >= {vmax} ? {cap_of} : ({countdown} > 0 ? {vmax} : {cap_of}))",
            countdown: f"({cap_of} >= {vmax} ? {hold} : ({countdown} > 0 ? {countdown} - 1 : {hold}))",
        }
        cell.add(Module(f"{r}_safety", [
            Var(mode, 0, len(_MODES) - 1, SafetyMode.NORMAL.code),
            Var(vmax, 0, len(levels) - 1, levels.index(robot._normal_cap)),
            Var(countdown, 0, hold, hold),
        ], [Command("true", (("1", update),))],
            comment=f"robot {r}: the requested safety mode, and the highest speed cap of the last {hold} periods"))
        speed = f"{r}.tool_speed"
        if speed in cell.reads:
            encoding = cell.encoding(speed)
            var = f"{r}_speed"
            commands = []
            for region in range(encoding.regions):
                low = _low(encoding, region)
                allowed = [i for i, level in enumerate(levels) if low <= level + 1e-12 and (region % 2 or low < level or region == 0)]
                commands.append(Command(set_of(vmax, allowed) if allowed else "false", (("1", {var: str(region)}),)))
            cell.add(Module(f"{r}_tool_speed", [Var(var, 0, encoding.regions - 1, 0)], commands,
                            comment=f"robot {r}: its tool's speed (m/s), any value up to the cap in force"))
            cell.define(speed, var, encoding)
        cell.assume(f"{r} takes a requested safety mode in one period and slows to its cap within its braking time "
                    f"({self.cfg.braking_time:g} s)")


def _low(encoding: Thresholds, region: int) -> float:
    """The least value of a region (its threshold, or just above the threshold below; 0 for the first)."""
    if region % 2:
        return encoding.values[region // 2]
    return encoding.values[region // 2 - 1] if region else 0.0


def robot(cell, name, cfg):
    return RobotAbstraction(cell, name, cfg)
