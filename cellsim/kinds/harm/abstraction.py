"""The harm kind in the abstract cell: where a robot part may touch a person, so where harm may come.

A condition on a contact's severity (``NoHarm``: ``G(harm.severity <= 1)``) or on a clamping's
(``NoClamping``) is modelled from the distance between each arm and each person's body, bounded
from below as the ``ssm`` kind's true margin is (:mod:`cellsim.verify.clearance`): per stretch of
each arm's path (a region of a move, a pose it rests at, a path not modelled: anywhere within its
reach), measured at every pose of the floor. It cuts the floor nowhere: each place reads the least
bound over its poses (``SensedSignal.cuts``), so the model has not one state more, and a person in
a place may touch a stretch if any pose of the place may.

Where that is above 0, no robot part touches the person, and the severity and the clamping are 0,
as the twin's are. Where it is at most 0, a contact may be going on, and the model reads it as harm
and as clamping: it tells neither the region touched, nor the speed along the push, nor what lies
behind. (A contact with the head or the face is harm at any speed; a person walking into a still arm
at 1.3 m/s exceeds every other region's permissible speed in the shipped table.) So a condition on
them holds in the model only where no contact is reachable at all. Its witness is sought first where
the arm moves on one of its moves (``firm``), and the replay stands the person, at the witness's
last place, where the bound to the stretch the arm ends on is least (:meth:`HarmAbstraction.witness_pose`):
the twin judges that contact itself, its region, kind and speed.
"""

from __future__ import annotations

import math

from cellsim.verify.clearance import BODY_TOLERANCE, TOLERANCE, ArmSweep, BodyCover, Clearance, arm_groups
from cellsim.verify.expressions import Thresholds, VerifyError
from cellsim.verify.model import AbstractCell, ModuleAbstraction, SensedSignal, SensorRole, context_of, prism_name
from cellsim.verify.prism import holds

_BUILT: dict = {}
"""The arms' groups of stretches and their clearance, by the robots' configs and shapes: a verify builds its model once
a round, each time anew, and these are the same in every round (a few of the last ones kept)."""
JUDGED = ("severity", "clamping")
"""The channels the model has (each compared with positive numbers only: 0 is no contact)."""
WITHIN = 0.2
"""m: how far the bound is read (farther reads this): more than a finer grid's pose lies from the coarser one's it is
read from (:func:`cellsim.verify.floor._inherit`), so a pose far from every arm stays far."""
TOUCHING = 1
"""The highest code of a contact clearance (thresholds (0,): below 0, then 0) where a contact may be going on."""


class HarmAbstraction(ModuleAbstraction):
    """Contact possible wherever an arm's bound distance to a body may be at most 0; the severity and the clamping read
    above every number they are compared with there, 0 elsewhere. Every other channel of the service only watches."""

    def __init__(self, cell: AbstractCell, name: str, cfg):
        super().__init__(cell, name, cfg)
        self.groups: list | None = None
        """[(robot, its groups of stretches (``ArmGroup``))], in the order of the ``contact<k>`` signals, once contact
        is modelled."""
        self.judged: list[str] = []

    def declare(self, cell: AbstractCell) -> None:
        for signal in cell.types:
            if signal.startswith(f"{self.name}.") and signal.removeprefix(f"{self.name}.") not in JUDGED:
                cell.unmodelled[signal] = (f"only contact itself is in the model ({self.name}'s severity and clamping); "
                                           "the twin judges the rest in every run (cellsim check, the campaign)")

    def declare_for_readers(self, cell: AbstractCell) -> None:
        """Where a condition reads the severity or the clamping, compared with numbers above 0 only: measure each
        arm's groups of stretches' clearance at every pose of the floor (cutting nothing)."""
        read = [f"{self.name}.{s}" for s in JUDGED if f"{self.name}.{s}" in cell.reads]
        for signal in read:
            # a contact reads above every number it is compared with: sound only where a higher value makes the
            # conditions the likelier to fail (kept below a limit), never where one asks it to be high
            worse = all((op in ("<", "<=") and positive) or (op in (">", ">=") and not positive)
                        for op, positive in cell.signed.get(signal, set()))
            if worse and all(t > 0.0 for t in cell.thresholds.get(signal, set())):
                self.judged.append(signal)
            else:
                cell.unmodelled[signal] = ("only its comparisons with numbers above 0 that ask it to stay below them "
                                           "are modelled (a contact reads as the worst)")
        if not self.judged:
            return
        from cellsim.kinds.robot.abstraction import RobotAbstraction

        system, inspector, plant = self.system, cell.cell.scene_graph.model_inspector(), cell.cell.plant
        robots = cell.sf.scenario.modules_of_kind("robot")
        arms = {robot: [(plant.get_body(part.body).name(), inspector.GetShape(g), inspector.GetPoseInFrame(g))
                        for g, part in system.parts.items() if part.robot == robot] for robot in system.robots}
        key = (repr(cell.sf.scenario.layout), *((robot, repr(robots[robot]), tuple(
            (body, repr(shape), pose.GetAsMatrix34().tobytes()) for body, shape, pose in arms[robot])) for robot in arms))
        built = _BUILT.get(key)
        if built is None:  # (the same in every round of a verify: its cell's arms do not change)
            groups = []
            for robot_name, shapes in arms.items():
                robot = RobotAbstraction(cell, robot_name, robots[robot_name])
                kin = robot.system.kinematics
                try:
                    sweep = ArmSweep(kin.plant, kin.context, [(kin.plant.GetBodyByName(body), shape, pose)
                                                              for body, shape, pose in shapes])
                    reach = sweep.reach(robot.system.poses[0])
                except ValueError as e:
                    raise VerifyError(f"{self.name}: contact with {robot_name} cannot be bounded: {e}") from None
                groups.append((robot_name, arm_groups(sweep, robot.stretches(), reach)[0]))
            clouds = [group.spheres for _, found in groups for group in found]
            built = (groups, Clearance(clouds, [[0.0]] * len(clouds), WITHIN))
            while len(_BUILT) >= 4:
                _BUILT.pop(next(iter(_BUILT)))
            _BUILT[key] = built
        groups, clearance = built
        try:
            bodies = BodyCover(inspector, list(system.bodies))
        except ValueError as e:
            raise VerifyError(f"{self.name}: contact cannot be bounded: {e}") from None
        self.groups = groups
        self.clearance, self.bodies = clearance, bodies  # (kept for the tests that hold the bounds to SceneGraph's)
        of = context_of(system)
        # a person between grid points stands up to half the grid's diagonal nearer than the nearest of them: the
        # bound is read that much less (it moves no more than the body does), so a contact there is in the model too
        self.slack = max(p.step for p in cell.people) * math.sqrt(2.0) / 2.0 if cell.people else 0.0
        signals = {}
        for k, _, _ in self._contacts():
            port = f"contact{k}"
            cell.internal[f"{self.name}.{port}"] = Thresholds((0.0,))
            signals[port] = SensedSignal(lambda distances, k=k: distances[k] - self.slack, None, cuts=False)
            cell.read(f"{self.name}.{port}", self.name, required=False)  # (its .of_<person> formulas are read)
        cell.add_sensor(SensorRole(self.name, signals, measure=lambda root: clearance.of(
            bodies.at(system.query_port.Eval(of(root))))))

    def _contacts(self):
        """Each group of stretches with its ``contact<k>`` signal: (k, robot, group)."""
        k = 0
        for robot, found in self.groups or ():
            for group in found:
                yield k, robot, group
                k += 1

    def build(self, cell: AbstractCell) -> None:
        if self.groups is None:
            return
        touching, moving = [], []
        for k, _, group in self._contacts():
            near = [f"{prism_name(f'{self.name}.contact{k}.of_{p.module}')} <= {TOUCHING}" for p in cell.people]
            if not near:
                continue
            touching.append(f"({group.guard}) & ({' | '.join(near)})")
            if group.rate is not None:  # firm: the arm on one of its moves (not resting at a pose, nor anywhere)
                resting = "".join(f" & !({g})" for g in group.at_rest)
                moving.append(f"({group.guard}){resting} & ({' | '.join(near)})")
        contact = " | ".join(f"({t})" for t in touching) or "false"
        firm = " | ".join(f"({m})" for m in moving) or "false"
        for signal in self.judged:
            encoding = Thresholds(tuple(sorted(cell.thresholds.get(signal, {1.0}))))
            top = encoding.regions - 1
            cell.define(signal, f"(({contact}) ? {top} : 0)", encoding, firm=f"(({firm}) ? {top} : 0)")
        robots = ", ".join(robot for robot, _ in self.groups)
        cell.assume(
            f"{self.name}: a part of {robots} may touch a person in a place if it may at one of the place's grid poses "
            f"or within {self.slack:.3g} m of one (half the grid's diagonal): the arm's shapes and each body region "
            f"covered by spheres (reaching at most {TOLERANCE:g} m and {BODY_TOLERANCE:g} m beyond them), the arm "
            "anywhere between the samples of its moves, or anywhere within its reach on a path not modelled (a person "
            "turned between two of its four headings, or partly reached out, may stand nearer). Any such contact is "
            "taken as harm and as clamping: "
            "the model tells neither the region touched nor the speed along the push (a head's contact is harm at any "
            "speed; a person walking into a still arm exceeds every other region's permissible speed in the shipped "
            "table); the twin judges each witness's contact, the person standing where the bound is least")

    def leaves_unrefined(self, prop) -> str | None:
        """A harm condition's witness refines nothing: the bound's looseness (its spheres, the grid) no module's
        refinement tightens, and the one a person's walk offers (their pace) grows the model many times over (the
        machine-tending cell's: 358,130 states to 2.2 million, 545 s end to end where 60 s did without)."""
        if not self.chooses_pose_for(prop):
            return None
        return (f"{self.name}'s witnesses ask for none: no module's refinement tightens the contact bound, and a "
                "person's pace, which such a witness may also need, grows the model many times over")

    def chooses_pose_for(self, prop) -> bool:
        """Whether ``prop`` reads this service's contact (its witness's last stop is then :meth:`witness_pose`'s)."""
        return self.groups is not None and any(prism_name(s) in (getattr(prop, "bad", "") or "") for s in self.judged)

    def witness_pose(self, cell: AbstractCell, prop, person, place: int, state: dict):
        """Where ``person`` (``PersonPlaces``) should stand in ``place``, the last of a witness of ``prop`` ending in
        ``state``: where the bound to a stretch the arm ends on is least, if that may touch and ``prop`` reads this
        service's contact; else None (the replay's own choice)."""
        if not self.chooses_pose_for(prop):
            return None
        there = person.at(place)
        best = None
        for k, _, group in self._contacts():
            found = there.least.get(f"{self.name}.contact{k}")
            if found is None or found[1] > 0.0:
                continue
            try:
                on = holds(group.guard, state)
            except (KeyError, ValueError):  # the arm outside the property's cone (or a guard not read): anywhere
                on = True
            if on and (best is None or found[1] < best[1]):
                best = found
        return None if best is None else best[0]
