"""A person in the abstract cell: anywhere on the floor it can walk, reaching where it reaches.

The abstraction is wider than the scenario's walk on purpose: the person may
stand at any point of the floor not taken by a fixture (the grid of
``PersonRole.poses``, at four headings), walk from there to a neighbouring point
each period (in any order, any number of times: ``verify`` asks what *any* walk
can do), reach towards every point its waypoints reach for, from wherever that
point is within arm's length and a step, and press each button its waypoints
press while standing where that waypoint is. A witness walk is written back as
this kind's own config: waypoints with waits and reaches.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from cellsim.kinds.operator.system import REACH_TIME, obstacles, plan_walk, route
from cellsim.floorplan import point_in_polygon, points_in_polygon
from cellsim.verify.model import ModuleAbstraction, AbstractCell, PersonRole, Pose
from cellsim.vocabulary import TwinMode

GRID = 0.1
"""The floor grid's step (m); refined (``<person>:fine``), half that."""
HEADINGS = (0.0, math.pi / 2, math.pi, 3 * math.pi / 2)
MARGIN = 0.6
"""How far (m) round the cell's fixtures, zones and walk the floor is sampled."""


class PersonAbstraction(ModuleAbstraction):
    def __init__(self, cell: AbstractCell, name: str, cfg):
        super().__init__(cell, name, cfg)
        self.layout = cell.sf.scenario.layout
        self.sf = cell.sf

    def declare(self, cell: AbstractCell) -> None:
        cfg, layout = self.cfg, self.layout
        self.step = GRID / 2 if f"{self.name}:fine" in cell.refinements else GRID
        found = obstacles(cfg, layout) if cfg.avoid_fixtures else []
        self.outlines = tuple(outline for _, outline in found)
        points = self._grid()
        poses = [Pose(x, y, yaw) for x, y in points for yaw in HEADINGS]
        arm = cfg.arm_length + cfg.body_radius + self.step
        for target in dict.fromkeys(tuple(w.reach) for w in cfg.waypoints.values() if w.reach is not None):
            for x, y in points:
                if math.hypot(target[0] - x, target[1] - y) <= arm:
                    poses.append(Pose(x, y, math.atan2(target[1] - y, target[0] - x), target))
        first = next(iter(cfg.waypoints.values())).position if cfg.waypoints else (cfg.start[0] + 1.0, cfg.start[1])
        start = Pose(float(cfg.start[0]), float(cfg.start[1]), math.atan2(first[1] - cfg.start[1], first[0] - cfg.start[0]))
        own = {"location": self._location, **{flag: self._flag(zone) for flag, zone in layout.operator_flags.items()}}
        buttons = {}
        for w in cfg.waypoints.values():
            if w.press is not None:
                buttons[f"press_{w.press.replace('.', '_')}"] = tuple(w.position)
        paced = f"{self.name}:pace" in cell.refinements
        end, ends = self._end(start, cell.sf.scenario.duration)
        cell.add_person(PersonRole(self.name, poses, start, self._stand, own, self.step, buttons,
                                   refines=GRID if self.step < GRID else None, travel=self.travel,
                                   walk=self.walk, max_speed=self.max_speed if paced else None,
                                   top_speed=self.max_speed, end=end, ends=ends))
        pace = f"no faster than {self.max_speed:.3g} m/s (its walking speed and jitter)" if paced else "at any pace"
        cell.assume(f"{self.name} may walk anywhere on the floor {pace}, reach towards "
                    f"{'the points its waypoints reach for' if any(w.reach for w in cfg.waypoints.values()) else 'nothing'} "
                    "and press its buttons where its waypoints press them; its arm is either down or fully reached out; "
                    "each sensor reads it facing one of four headings (and each reach point, reaching): turned between "
                    "them it may read a few centimetres differently (a range detector 0.075 m nearer in the welding "
                    "cell), which neither the grid's slack nor a pace's bound counts")

    @property
    def max_speed(self) -> float:
        """m/s: the fastest this person walks in the twin (its walking speed at the top of its jitter)."""
        return self.cfg.walking_speed * (1.0 + self.cfg.speed_jitter)

    def _end(self, start: Pose, duration: float) -> tuple[Pose | None, str]:
        """Where the script leaves this person at the end of a run of ``duration`` s (its last stop, arm down, facing
        the way it walked there), when it is over by then even at the slowest pace its jitter allows; and in words."""
        cfg = self.cfg
        if any(mode is not TwinMode.MODEL for mode in (cfg.twin.mode, *(c.mode for c in cfg.twin.changes))):
            return None, f"{self.name} follows its physical twin, which ends where it will"
        sampled = [name for name, point in self.sf.scenario.configuration_points.items()
                   if any(path.split(".")[0] == self.name or path.startswith(f"entities.{self.name}.")
                          for path in point.paths)]
        nominal = (f" as the scenario writes it (a campaign sampling {', '.join(sampled)} may end it elsewhere or later)"
                   if sampled else "")
        if not cfg.waypoints:
            return start, f"{self.name} stands at its start {tuple(cfg.start)} throughout{nominal}"
        legs = plan_walk(dataclasses.replace(cfg, speed_jitter=0.0), 0, layout=self.layout)
        slowest = 1.0 - cfg.speed_jitter
        over = cfg.start_delay + sum((leg.arrive - leg.depart) / slowest + (leg.leave - leg.arrive) for leg in legs)
        # and the last turn (at most half a turn at turn_rate): after a last reach, back to the way it walked; else
        # to the last stretch's way, taken by the arrival at the last stop, before its wait
        last = legs[-1]
        over = max(over, over - (0.0 if last.reach is not None else last.leave - last.arrive) + math.pi / cfg.turn_rate)
        # the run's last record of the person is its last update before the end (none is made at the end itself)
        last_update = (math.ceil(duration / cfg.period - 1e-9) - 1) * cfg.period
        if over > last_update + 1e-9:
            return None, (f"{self.name}'s script may not be over by its last update ({over:.3g} s at its slowest pace, "
                          f"the last update at {last_update:.3g} s){nominal}")
        yaw = next((leg.heading for leg in reversed(legs) if leg.heading is not None), start.yaw)
        where = tuple(round(float(v), 3) for v in legs[-1].end)
        return (Pose(float(legs[-1].end[0]), float(legs[-1].end[1]), yaw),
                f"{self.name} ends at its last stop {where}, its script over by {over:.3g} s at its slowest pace"
                f"{nominal}")

    def refinement(self, cell: AbstractCell, witness: list[dict]) -> tuple[str, str, int] | None:
        """A witness in which this person crosses a place faster than it walks: model its pace; with its pace
        modelled, one that crosses a place only as fast as the grid's slack allows (a place's border lies somewhere
        between two grid points, so a crossing may be up to two steps shorter than the points say): halve the grid."""
        person = None if cell.places is None else next(
            (p for p in cell.places.people if p.role.module == self.name), None)
        if person is None:
            return None
        key = f"{self.name}:pace"
        if key not in cell.refinements:
            found = person.pace_departure(witness, cell.period, self.max_speed)
            return None if found is None else (key, *found)
        key = f"{self.name}:fine"
        if key not in cell.refinements:
            found = person.pace_departure(witness, cell.period, self.max_speed, exact=True)
            return None if found is None else (key, f"{found[0]} measured between the grid's points; their {GRID:g} "
                                                    f"m slack allows it: a {GRID / 2:g} m grid tells", found[1])
        return None

    def build(self, cell: AbstractCell) -> None:
        """Its place and buttons are the floor's (``cellsim.verify.floor``)."""

    # -- where it stands ----------------------------------------------------------------
    def _grid(self) -> list[tuple[float, float]]:
        layout, cfg = self.layout, self.cfg
        xs, ys = [cfg.start[0]], [cfg.start[1]]
        for w in cfg.waypoints.values():
            xs.append(w.position[0])
            ys.append(w.position[1])
        for f in layout.fixtures.values():
            for sx in (-1, 1):
                xs.append(f.center[0] + sx * f.size[0] / 2)
                ys.append(f.center[1] + sx * f.size[1] / 2)
        for zone in (*layout.operator_zones.values(), *layout.operator_flags.values()):
            xs += [zone.min[0], zone.max[0]]
            ys += [zone.min[1], zone.max[1]]
        step = self.step
        x0, x1 = math.floor((min(xs) - MARGIN) / step), math.ceil((max(xs) + MARGIN) / step)
        y0, y1 = math.floor((min(ys) - MARGIN) / step), math.ceil((max(ys) + MARGIN) / step)
        grid = [(i, j) for i in range(x0, x1 + 1) for j in range(y0, y1 + 1)]
        blocked = np.zeros(len(grid), bool)
        for outline in self.outlines:  # (all the grid's points at once: the fine grid has tens of thousands)
            blocked |= points_in_polygon([(i * step, j * step) for i, j in grid], outline)
        return [(round(i * step, 6), round(j * step, 6)) for (i, j), out in zip(grid, blocked) if not out]

    def _stand(self, context, pose: Pose | None) -> None:
        if pose is None:
            vector = [1e3, 1e3, 0.0, 0.0, 0.0, 0.0, 0.0]
        elif pose.reach is None:
            vector = [pose.x, pose.y, pose.yaw, 0.0, 0.0, 0.0, 0.0]
        else:
            vector = [pose.x, pose.y, pose.yaw, 1.0, *pose.reach]
        self.system.set_pose(context, vector)

    def _location(self, pose: Pose) -> str:
        standing = (pose.x, pose.y, 1.0)
        return next((name for name, zone in self.layout.operator_zones.items() if zone.contains(standing)),
                    self.layout.operator_outside)

    @staticmethod
    def _flag(zone):
        return lambda pose: zone.contains((pose.x, pose.y, 1.0))

    # -- a witness's walk as this kind's config --------------------------------------------
    def _approach(self, pose: Pose) -> tuple[float, float] | None:
        """Where the walk passes one grid step before a stop, so the person stands there facing ``pose.yaw``
        (the twin faces the way it walked); None for a reaching stop (it faces the reach) or when that
        point is inside a fixture."""
        if pose.reach is not None:
            return None
        point = (pose.x - self.step * math.cos(pose.yaw), pose.y - self.step * math.sin(pose.yaw))
        return None if any(point_in_polygon(point, outline) for outline in self.outlines) else point

    def _walked(self, a: tuple[float, float], b: tuple[float, float]) -> float:
        points = [a]
        if self.outlines:
            points += list(route(a, b, self.outlines) or ())
        points.append(b)
        return sum(math.dist(p, q) for p, q in zip(points, points[1:]))

    def travel(self, a: Pose, b: Pose) -> float:
        """Seconds the person takes from pose a to pose b at its walking speed, round the fixtures:
        withdrawing the arm at a, walking (through b's approach point), reaching out at b."""
        approach = self._approach(b)
        length = (self._walked((a.x, a.y), approach) + self.step) if approach else self._walked((a.x, a.y), (b.x, b.y))
        arm = REACH_TIME * ((a.reach is not None) + (b.reach is not None))
        return length / self.cfg.walking_speed + arm

    def walk(self, start: Pose, stops: list[tuple[Pose, float, float]], presses: dict[int, str]) -> dict:
        """The config keys of a walk from ``start`` through ``stops``: (pose, arrive at (s), leave at (s));
        ``presses``: stop index -> the button pressed there. A stop that reaches has its arm fully out from
        ``arrive`` to ``leave`` (the twin takes REACH_TIME either side); any other is walked into through its
        approach point, so the person faces the pose's heading."""
        waypoints: dict[str, dict] = {}
        here, clock, start_delay, previous = start, 0.0, 0.0, None
        for i, (pose, arrive, leave) in enumerate(stops):
            if pose.reach is not None:
                arrive, leave = arrive - REACH_TIME, leave + REACH_TIME
            way = self.travel(here, pose) - REACH_TIME * ((here.reach is not None) + (pose.reach is not None))
            depart = max(clock, arrive - way)  # leave the last stop so as to be here on time
            if previous is None:
                start_delay = depart
            else:
                previous["wait"] = round(depart - clock, 3)
            clock = depart + way
            approach = self._approach(pose)
            if approach is not None:
                waypoints[f"w{i + 1}_approach"] = {"position": [round(approach[0], 3), round(approach[1], 3)], "wait": 0.0}
            entry: dict = {"position": [round(pose.x, 3), round(pose.y, 3)], "wait": round(max(leave - clock, 0.0), 3)}
            if pose.reach is not None:
                entry["reach"] = [round(v, 3) for v in pose.reach]
            if i in presses:
                entry["press"] = presses[i]
            waypoints[f"w{i + 1}"] = entry
            here, previous = pose, entry
        return {
            "start": [round(start.x, 3), round(start.y, 3)],
            "start_delay": round(start_delay, 3),
            "speed_jitter": 0.0,
            "waypoints": waypoints,
        }

