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

Its safety mode is the one requested, from the next period on; at first, the one it takes
at its update at t = 0, which reads the request then (a controller's default command). The tool's speed,
as read, is any value its ``SpeedEnvelope`` allows: up to the cap in force, and
after a cap ends, falling to zero within the braking time (read late by the
telemetry period and the controller's tracking). The model keeps, per threshold
the guards compare the speed with, a countdown of the periods a speed above it
(and, where a cap equals it, at it) may still be read; the tool makes progress
only while some speed may be.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cellsim.verify.model import ModuleAbstraction, AbstractCell, lookup, runs_of, set_of, updates_in
from cellsim.verify.prism import Command, Enum, Module, Var
from cellsim.kinds.robot.system import requested_mode
from cellsim.vocabulary import SafetyMode

SAMPLES = 200
"""Points sampled along each move to find the regions it passes through."""
TRACKING_LAG = 0.06
"""How far (s) the arm's measured speed may lag its planned speed (the joint controller's tracking)."""
TRACKING_TOLERANCE = 0.05
"""How far (m/s) the measured speed may stay above the planned braking line while the arm settles."""
SETTLE_TIME = 0.1
"""How long (s) after its planned speed reaches zero the arm may still be read moving."""
_MODES = tuple(SafetyMode)


class RobotAbstraction(ModuleAbstraction):
    def declare(self, cell: AbstractCell) -> None:
        """Reads its mode request and target pose (in ``build``)."""

    def _samples(self, a: int, b: int) -> tuple[np.ndarray, list[int]]:
        """The move from pose a to pose b at SAMPLES + 1 evenly spaced points of its straight joint-space line: (joint
        positions (SAMPLES + 1, joints), the location code of the tool at each)."""
        robot = self.system
        start, goal = robot.poses[a], robot.poses[b]
        configs = start + np.linspace(0.0, 1.0, SAMPLES + 1)[:, None] * (goal - start)
        return configs, [robot.locate(robot.kinematics.tool_position(q)).code for q in configs]

    def _runs(self, a: int, b: int) -> list[tuple[int, int, int]]:
        """The move from pose a to pose b as the regions its tool passes through, in order: (location code, first
        sample, last sample)."""
        runs: list[list[int]] = []
        for i, code in enumerate(self._samples(a, b)[1]):
            if runs and runs[-1][0] == code:
                runs[-1][2] = i
            else:
                runs.append([code, i, i])
        return [tuple(run) for run in runs]

    def _moves(self, period: float, timed: bool) -> dict[tuple[int, int], list[tuple[int, int]]]:
        """(a, b) -> [(location code, least periods there)] along the move from pose a to pose b: timed, the periods
        the tool surely spends in the region at its fastest (its joint limits and normal cap, no acceleration), less
        one for the phase of the robot's updates against the crossing; else 0."""
        moves = {}
        for a, b in self._pairs():
            rate = self._pace(a, b)[1]
            # a crossing of T s shows in as few as floor(T / period) of the robot's updates (their phase against
            # it), and the model asks for one more than the least (the update that leaves): one less
            moves[(a, b)] = [(code, max(0, math.floor((last - first) / SAMPLES / rate / period) - 1) if timed else 0)
                             for code, first, last in self._runs(a, b)]
        return moves

    def _pace(self, a: int, b: int) -> tuple[float, float]:
        """The move from pose a to pose b as the twin plans it (``start_segment``): (the tool's metres per unit of the
        line's parameter s at most, the fastest ds/dt: its joint limits and the normal cap)."""
        robot = self.system
        motion = robot.start_segment(robot.poses[a], b)
        tool_per_s, joint_rate = float(motion[3]), float(motion[4])
        return tool_per_s, min(joint_rate, robot.normal_cap / tool_per_s)

    def _pairs(self) -> list[tuple[int, int]]:
        """Every move (a, b) between two named poses, in the order the model numbers them (after the poses)."""
        n = len(self.system.poses)
        return [(a, b) for a in range(n) for b in range(n) if a != b]

    def stretches(self) -> list["ArmStretch"]:
        """Where the arm may be in each state of its abstraction: on each region of each move, the samples in it, the
        one before, and as far on as the arm can go in one of its periods at its fastest (the model's region is
        where the measured tool was at the robot's last update); at rest at each pose, there and on the end of
        every move to it that the arm may still be settling along (``TRACKING_LAG`` at its fastest); and on a path
        not modelled (anywhere)."""
        r, robot = self.name, self.system
        poses, pairs = len(robot.poses), self._pairs()
        seg, k = f"{r}_segment", f"{r}_region"
        spacing = 1.0 / SAMPLES
        moves, settling = [], {p: [robot.poses[p][None, :]] for p in range(poses)}
        for i, (a, b) in enumerate(pairs):
            configs = self._samples(a, b)[0]
            tool_per_s, fastest = self._pace(a, b)
            ahead = math.ceil(fastest * robot.period / spacing - 1e-9)
            for region, (code, first, last) in enumerate(self._runs(a, b)):
                moves.append(ArmStretch(f"{seg}={poses + i} & {k}={region}",
                                        [configs[max(first - 1, 0):last + 2 + ahead]], tool_per_s, spacing,
                                        f"on {robot.pose_names[a]} -> {robot.pose_names[b]}, "
                                        f"{robot.locations.from_code(code).value}", code))
            behind = math.ceil(fastest * TRACKING_LAG / spacing - 1e-9)
            settling[b].append(configs[-1 - behind:])
        out = [ArmStretch(f"{seg}={p}", settling[p], 0.0, spacing, f"at rest at {robot.pose_names[p]}",
                          robot.locate(robot.kinematics.tool_position(robot.poses[p])).code) for p in range(poses)]
        out += moves
        out.append(ArmStretch(f"{seg}>={poses + len(pairs)}", None, 0.0, 0.0, "on a path not modelled", None))
        return out

    def build(self, cell: AbstractCell) -> None:
        r, robot, cfg = self.name, self.system, self.cfg
        period = cell.period * cell.every(r)  # (its own: its counters advance at its updates)
        poses = len(robot.poses)
        moves = self._moves(period, self.timed(cell))
        pairs = list(moves)
        segment = {pair: poses + i for i, pair in enumerate(pairs)}
        havoc = {b: poses + len(pairs) + b for b in range(poses)}
        locations = [loc for loc in robot.locations if loc is not robot.unknown_location]
        seg, k, t, hloc = f"{r}_segment", f"{r}_region", f"{r}_periods", f"{r}_wherever"
        longest = max((len(v) for v in moves.values()), default=1)
        most = max((n for v in moves.values() for _, n in v), default=0)
        target = cell.input(r, "target_pose")
        initial = robot.pose_names.index(cfg.initial_pose)
        # with its tool's speed read, the robot moves only while a cap above zero is in force; without, the
        # cap is not modelled and it may move at any time (more behaviours, and no braking countdown in the state)
        go = self.motion_allowed(cell) if self._enveloped(cell) else "true"
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
        self._activity(cell)
        cell.assume(f"{r}'s tool is located on the commanded path (tracking error neglected), the regions it "
                    f"passes through found at {SAMPLES + 1} points of each move (a region crossed between two is "
                    "missed); its moves take "
                    + ("at least their time at full speed without acceleration" if self.timed(cell)
                       else "any time from one period on"))

    def refinement(self, cell: AbstractCell, witness: list[dict]) -> tuple[str, str, int] | None:
        """A witness in which the tool passes through a region of its move in fewer of the robot's updates than it
        takes at full speed (its moves' durations not modelled): bound them below (``<robot>:timed``)."""
        r, key = self.name, f"{self.name}:timed"
        if self.timed(cell):
            return None
        every = cell.every(r)
        moves = self._moves(cell.period * every, True)
        poses, pairs = len(self.system.poses), list(moves)
        seg, k = f"{r}_segment", f"{r}_region"
        if any(seg not in state or k not in state for state in witness):
            return None
        runs = runs_of([{"at": (state[seg], state[k])} for state in witness], "at")
        for ((segment, region), first, last), ((then, then_region), _, _) in zip(runs, runs[1:]):
            if not poses <= segment < poses + len(pairs):
                continue  # at rest, or on a path not modelled
            a, b = pairs[segment - poses]
            least = moves[(a, b)][region][1]
            onwards = (then == segment and then_region == region + 1) or then == b
            took = updates_in(first, last, every)
            if onwards and took < least + 1:
                names = self.system.pose_names
                return (key, f"{seg} passes region {region} of its move {names[a]} -> {names[b]} in {took} update(s) "
                             f"at {first * cell.period:g}-{(last + 1) * cell.period:g} s; at full speed it takes at "
                             f"least {least + 1}", last + 1)
        return None

    def _activity(self, cell: AbstractCell) -> None:
        """The activity it publishes: the one its input asked for at its last update (as the twin's robot takes it
        then), kept as its own state where someone reads it; else the input itself (nobody sees the difference)."""
        r, request = self.name, cell.input(self.name, "activity")
        signal = f"{r}.activity"
        if signal not in cell.reads:
            cell.define(signal, request)
            return
        encoding, var = cell.encoding(signal), f"{r}_activity"
        high = len(encoding.values) - 1 if isinstance(encoding, Enum) else max(encoding.regions - 1, 1)
        cell.add(Module(f"{r}_activity", [Var(var, -1, high, cell.initial_code(signal))],
                        [Command("true", (("1", {var: request}),))],
                        comment=f"robot {r}: the activity asked of it at its last update (-1: none it knows)"))
        cell.define(signal, var)

    def _initial_mode(self, cell: AbstractCell) -> int:
        """The safety mode it first publishes: its update at t = 0 takes the request it reads then."""
        built = cell.cell
        context = built.diagram.CreateDefaultContext()
        built.set_initial_state(context)
        code = self.system.mode_request_port.Eval(self.system.GetMyContextFromRoot(context))[0]
        return requested_mode(code).code

    def _safety(self, cell: AbstractCell, period: float) -> None:
        r, robot = self.name, self.system
        request = cell.input(r, "safety_mode_request")
        mode = f"{r}_mode"
        # as the twin reads a request (requested_mode): no value, or 'unknown', is a stop
        new_mode = f"({request} >= 0 & {request} != {SafetyMode.UNKNOWN.code} ? {request} : {SafetyMode.STOPPED.code})"
        initial = self._initial_mode(cell)
        cell.define(f"{r}.safety_mode", mode)
        if not self._enveloped(cell):
            cell.add(Module(f"{r}_safety", [Var(mode, 0, len(_MODES) - 1, initial)],
                            [Command("true", (("1", {mode: new_mode}),))], comment=f"robot {r}: the requested safety mode"))
            cell.assume(f"{r} takes a requested safety mode in one period (its speed is read by nobody: not modelled)")
            return
        envelope, caps = SpeedEnvelope.of(robot, period), self._caps()
        encoding = cell.encoding(f"{r}.tool_speed")
        limit = self._limit(cell)
        ssmon = SafetyMode.SPEED_SEPARATION
        # one countdown per speed threshold: the periods a speed above it may still be read; one for a speed
        # at it where a cap equals it (a speed may sit at its cap, never above); one for motion itself
        countdowns = {"moving": (None, False)}
        for i, value in enumerate(encoding.values):
            if value > 0:
                countdowns[f"over{i}"] = (value, True)
                if value in caps.values():
                    countdowns[f"at{i}"] = (value, False)
        variables, update = [Var(mode, 0, len(_MODES) - 1, initial)], {mode: new_mode}
        possible = {}  # countdown -> its guard: a speed it counts may be read next period
        for suffix, (threshold, strict) in countdowns.items():
            var = f"{r}_{suffix}"
            refresh = {m.code: envelope.periods(caps[m], threshold, strict) for m in _MODES}
            refill, start = lookup(mode, refresh, 0), refresh[initial]
            can = [c for c, n in refresh.items() if n > 0]
            if limit is not None:  # in ssmon its cap is also the monitor's limit (the region of its bound)
                expr = limit
                by_limit = {region: envelope.periods(min(caps[ssmon], _region_cap(encoding, region)), threshold, strict)
                            for region in range(encoding.regions)}
                refill = f"({mode}={ssmon.code} ? {lookup(expr, by_limit, 0)} : {refill})"
                if initial == ssmon.code:
                    start = max(by_limit.values())
                can = [c for c in can if c != ssmon.code]
                limited = f" | ({mode}={ssmon.code} & {set_of(expr, [g for g, n in by_limit.items() if n > 0])})"
            else:
                limited = ""
            variables.append(Var(var, 0, max(max(refresh.values()), start), start))
            update[var] = f"max({var} - 1, {refill})"
            possible[suffix] = f"({var} > 0 | {set_of(mode, can)}{limited})"
        cell.add(Module(f"{r}_safety", variables, [Command("true", (("1", update),))],
                        comment=f"robot {r}: the requested safety mode, and how many periods more its tool may be "
                                "read moving above (at) each speed threshold"))
        var = f"{r}_speed"
        guards = []
        for region in range(encoding.regions):
            i = (region - 1) // 2
            if region == 0 or encoding.values[i] <= 0:
                guard = "true"
            elif region % 2 and f"at{i}" in countdowns:
                guard = f"{possible[f'at{i}']} | {possible[f'over{i}']}"
            else:
                guard = possible[f"over{i}"]
            guards.append(guard)
        if f"{r}.tool_speed_bound" in cell.reads:  # the fastest region its envelope allows now: no choice made
            bound = "0"
            for region, guard in enumerate(guards[1:], start=1):
                bound = f"(({guard}) ? {region} : {bound})"
            # firm: the cap in force, braking from an earlier one not counted (the speed it keeps while it moves)
            steady = lookup(mode, {m.code: encoding.region_of(caps[m]) for m in _MODES}, 0)
            if limit is not None:
                steady = f"({mode}={ssmon.code} ? min({encoding.region_of(caps[ssmon])}, {limit}) : {steady})"
            cell.define(f"{r}.tool_speed_bound", bound, encoding, firm=steady)
        if f"{r}.tool_speed" in cell.reads:
            cell.add(Module(f"{r}_tool_speed", [Var(var, 0, encoding.regions - 1, 0)],
                            [Command(guard, (("1", {var: str(region)}),)) for region, guard in enumerate(guards)],
                            comment=f"robot {r}: its tool's speed (m/s) as read, any value its speed envelope allows"))
            cell.define(f"{r}.tool_speed", var, encoding)
        cell.assume(f"{r} takes a requested safety mode in one period; its tool's speed never exceeds the cap of its "
                    f"mode, and after a cap C ends it falls no slower than from C to zero within the braking time "
                    f"({self.cfg.braking_time:g} s), read up to {envelope.lag:g} s late (telemetry and tracking) and "
                    f"up to {envelope.tolerance:g} m/s above that line until it has settled")

    def _enveloped(self, cell: AbstractCell) -> bool:
        """Whether its speed envelope is modelled: somebody reads its tool's speed, or the fastest it may be now
        (``<robot>.tool_speed_bound``, in the tool speed's regions: a formula of the state, no choice)."""
        return f"{self.name}.tool_speed" in cell.reads or f"{self.name}.tool_speed_bound" in cell.reads

    def _caps(self) -> dict[SafetyMode, float]:
        """Each safety mode's tool speed cap (m/s); unknown: the normal one."""
        caps = {m: self.system.speed_caps.get(m, 0.0) for m in _MODES}
        caps[SafetyMode.UNKNOWN] = self.system.normal_cap
        return caps

    def motion_allowed(self, cell: AbstractCell) -> str:
        """The guard under which the tool may make progress along its move: it may still be moving."""
        moving = [m.code for m, cap in self._caps().items() if cap > 0]
        limit, ssmon, mode = self._limit(cell), SafetyMode.SPEED_SEPARATION.code, f"{self.name}_mode"
        if limit is None or ssmon not in moving:
            return f"({self.name}_moving > 0 | {set_of(mode, moving)})"
        encoding = cell.encoding(f"{self.name}.tool_speed")
        free = [g for g in range(encoding.regions) if _region_cap(encoding, g) > 0]
        return (f"({self.name}_moving > 0 | {set_of(mode, [c for c in moving if c != ssmon])} | "
                f"({mode}={ssmon} & {set_of(limit, free)}))")

    def _limit(self, cell: AbstractCell) -> str | None:
        """The bound its speed-limit input's monitor gives of the limit (``<monitor>.speed_limit_bound``: a formula in
        the regions of its tool speed, the limit at most the upper end of its region), where the monitor models it;
        None: the limit is not modelled (in ssmon, its cap alone: more speed than the twin's, never less)."""
        source = cell.connections.get((self.name, "speed_limit"))
        if source is None or f"{source}_bound" not in cell.reads:
            return None
        return cell.read(f"{source}_bound", self.name)


def _region_cap(encoding, region: int) -> float:
    """The upper end (m/s) of a region of the tool speed's encoding: its threshold, or the next one up (inf above
    the last)."""
    i = region // 2
    return encoding.values[i] if i < len(encoding.values) else math.inf


@dataclass(frozen=True)
class ArmStretch:
    """Where the arm may be while the abstract robot is in the states ``guard`` (a PRISM expression)."""

    guard: str
    lines: list[np.ndarray] | None
    """Joint positions (rad) it passes through there, as lines of consecutive samples of a straight joint-space move
    (on a move: one; at rest: the pose, then the end of each move to it); None: anywhere (a path not modelled)."""
    tool_per_s: float
    """Metres the tool moves per unit of the line's parameter s at most (the twin's ``start_segment``): the arm's
    ds/dt is at most its cap-equivalent speed over this (0: at rest)."""
    spacing: float
    """A move's parameter s from one sample of a line to the next."""
    words: str
    location: int | None
    """The code of the layout's region the tool is in there (None: not known)."""


@dataclass(frozen=True)
class SpeedEnvelope:
    """What the tool's speed, as read by the controller, can be after a change of safety mode.

    The arm decelerates at a constant rate that brings it from its full speed to
    rest within ``braking`` (s) (``cellsim.kinds.robot.system``), so from the moment a cap C
    ends, its planned speed is at most C (1 - t / braking) and never below the
    cap that follows. The speed read lags it by ``lag`` (the controller's period and
    the joint controller's tracking) and the arm settles onto that line within
    ``tolerance`` m/s, and within ``settle`` s after it reaches zero. While a cap
    is in force the speed stays at or below it: the arm plans its speed below the
    cap (``TRACKING_ALLOWANCE``) by its controller's overshoot. A test holds the
    twin's readings to this envelope.
    """

    period: float
    braking: float
    lag: float = TRACKING_LAG
    tolerance: float = TRACKING_TOLERANCE
    settle: float = SETTLE_TIME

    @classmethod
    def of(cls, robot, period: float) -> "SpeedEnvelope":
        return cls(period, robot.cfg.braking_time, lag=robot.period + TRACKING_LAG)

    def periods(self, cap: float, threshold: float | None, strict: bool = True) -> int:
        """Periods, counted from the last period a cap ``cap`` was in force, for which a speed above
        ``threshold`` (at or above it if not ``strict``; None: any speed) may still be read; 0 when no
        such speed can be read under that cap at all."""
        if cap <= 0.0 or (threshold is not None and (cap <= threshold if strict else cap < threshold)):
            return 0
        lag = math.ceil(self.lag / self.period - 1e-9)
        braking = self.braking / self.period
        longest = lag + math.ceil((self.braking + self.settle) / self.period - 1e-9)
        if threshold is None or threshold <= self.tolerance:
            return longest
        return min(longest, lag + math.ceil(braking * (1.0 - (threshold - self.tolerance) / cap) - 1e-9))

