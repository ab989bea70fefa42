"""The harm service: what the robots do to each person's body, measured on the geometry.

A look finds the pairs of a robot part (an arm's collision shape) and a body region
(:mod:`cellsim.body`) nearer than ``cutoff`` (bounding spheres first, then SceneGraph's exact distance of each
pair they leave, :class:`cellsim.proximity.NearestPair`): every ``far_period``, and one plant step after
each person's update, while it returns none (a body moves only at its updates, a few centimetres at most
(``OperatorConfig.turn_rate``): it is seen where each update puts it, not on its way there; and no robot part
closes the cut-off in between, see ``HarmConfig.far_period``), and at every plant step while it returns some or
a robot part moves faster than half ``max_part_speed``. A cell where nobody is near an arm costs one
query per ``far_period``. For each robot part touching a region (signed distance <= 0):

* the relative speed along the contact's push (its normal while the overlap is shallow, see
  :meth:`HarmMonitor.measure`), ``v_rel``: the arm's point towards the region (the plant's body velocity at the
  contact point) less the region's point towards the arm (its motion over the person's last update period);
* its kind: *quasi-static* (clamping) when a fixture, the floor, another robot or another part of the arm
  lies within ``clamp_gap`` on the far side of the region (within ``clamp_angle_deg`` of the
  push), else *transient*;
* its severity against the limits table (:mod:`cellsim.kinds.harm.limits`): above 1 is harm.

The channels report the worst contact at each instant, recorded as it changes (at the rate it
happens), and each robot's least true distance to any region (up to ``cutoff``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import QueryObject
from pydrake.math import RigidTransform

from cellsim.channels import enum_type, number_type
from cellsim.kinds.harm.config import HarmConfig
from cellsim.proximity import NearestPair, bounding_sphere, inradius, lowest_point_z, nearest_on_box, witness_on
from cellsim.kinds.harm.limits import QUASI_STATIC, TRANSIENT, BodyLimits, severity
from cellsim.body import BLOCKS, REGIONS
from cellsim.systems import UNCHANGED, CellSystem, write_changed
from cellsim.vocabulary import value_set

NONE = "none"
"""What the contact channels read while no robot part touches anybody."""
CONTACT_KINDS = (NONE, TRANSIENT, QUASI_STATIC)
SHALLOW = 0.5
"""An overlap is shallow while it is less deep than this fraction of the thinner shape's half-thickness (its inradius):
short of the middle of either shape, where the direction of least overlap can turn (:meth:`HarmMonitor.measure`)."""
FAR, NEAR, FAST = 0.0, 1.0, 2.0
"""The service's state: measuring only at the looks of its schedule; at every plant step, while a pair is within reach
of a contact, or while a robot part moves faster than half ``max_part_speed``."""


@dataclass(frozen=True)
class Part:
    """A robot part: the robot, the plant body it is fixed to, and the robot's effective mass (kg)."""

    robot: str
    body: object
    """The plant's BodyIndex."""
    mass: float
    name: str
    rigid: int = -1
    """The bodies welded to ``body`` (one rigid assembly: a flange and its tool), named by the least of their
    indices; -1: the body alone."""


@dataclass(frozen=True)
class RegionGeometry:
    person: int
    """Index of the person (in ``people``)."""
    region: str
    frame: object
    """The person's SceneGraph frame the region is fixed to."""


class HarmMonitor(CellSystem):
    """Ports:
      geometry_query (input): SceneGraph's QueryObject.
      body_poses, body_velocities (inputs): the plant's body poses and spatial velocities (world frame).
      <person>_pose, <person>_previous_pose (inputs): each person's pose state now and at their last update.
      severity (channel): the worst contact's severity now (v_rel / v_max; 0: no contact; above 1: harm).
      clamping (channel): the worst quasi-static (clamping) contact's severity now (0: none).
      contact_region, contact_person, contact_part, contact_kind (channels): the worst contact's body region,
        person, robot part and kind (none: no contact).
      contact_speed (channel, m/s): its relative speed along its push (:meth:`measure`).
      separation_<robot> (channel, m): the robot's least true distance to any body region (negative:
        overlapping), read up to ``cutoff``.
      nearest_region, nearest_person (channels): the body region nearest to any robot within ``cutoff``, and whose it
        is, else none.
      region_jump (channel, m): the most a body region moved in one of its person's updates, while a robot part was
        within ``cutoff``, beyond its own thickness and the thinnest robot part's together (the largest yet; above 0:
        it may have passed through a part unseen, between two looks).
      unwatched_part_speed (channel, m/s): the fastest any point of a robot part moved at a look ending an interval
        the service watched only at its looks (above ``max_part_speed``: a contact in it may have been missed).
    """

    def __init__(self, module: str, cfg: HarmConfig, step: float, limits: BodyLimits, robots: dict[str, float],
                 people: list[str], parts: list[str], plant):
        """``robots``: each robot's effective mass (kg); ``people``: the persons' module names; ``parts``: every
        robot part's name (``<robot>_<link>``); ``plant``: the cell's MultibodyPlant (its output ports' types)."""
        super().__init__(module, step)
        self.cfg = cfg
        self.far_every = max(1, math.floor(cfg.far_period / step + 1e-9))
        """Plant steps from one far look to the next: ``far_period`` rounded down to whole steps (never later)."""
        self.reach = cfg.max_part_speed * self.far_every * step
        """m: a pair farther apart than this at one look cannot touch before the next (at most ``far_every`` steps
        later; the people stand still in between)."""
        self._near = self.declare_state("near", [FAR])  # FAR, NEAR or FAST
        self._looks: tuple[int, np.ndarray] | None = None  # (steps in one round, whether each is a look): _schedule
        self.limits = limits
        self.robots = list(robots)
        self.people = list(people)
        self.cos_clamp = math.cos(math.radians(cfg.clamp_angle_deg))
        self.query_port = self.DeclareAbstractInputPort("geometry_query", AbstractValue.Make(QueryObject()))
        self.body_poses_port = self.DeclareAbstractInputPort("body_poses", plant.get_body_poses_output_port().Allocate())
        self.body_velocities_port = self.DeclareAbstractInputPort(
            "body_velocities", plant.get_body_spatial_velocities_output_port().Allocate())
        self.pose_ports = []
        self.person_systems: list = []
        self.parts: dict = {}  # arm GeometryId -> Part
        self.bodies: dict = {}  # region GeometryId -> RegionGeometry
        self.clamps: list = []  # GeometryIds a region can be pinned against
        self.fixtures: dict = {}  # the layout's fixtures: GeometryId -> name
        self.region_type = value_set(f"{module}_region", [NONE, *REGIONS])
        self.person_type = value_set(f"{module}_person", [NONE, *people])
        self.part_type = value_set(f"{module}_part", [NONE, *parts])
        self.kind_type = value_set(f"{module}_contact_kind", CONTACT_KINDS)
        m, speed = number_type("m"), number_type("m/s")
        self._outputs = [
            self.declare_channel("severity", number_type(None), 0.0, description="Worst contact's severity now (above 1: harm)"),
            self.declare_channel("clamping", number_type(None), 0.0, description="Worst clamping contact's severity now"),
            self.declare_channel("contact_region", enum_type(self.region_type), NONE, description="Body region of the worst contact"),
            self.declare_channel("contact_person", enum_type(self.person_type), NONE, description="Person of the worst contact"),
            self.declare_channel("contact_part", enum_type(self.part_type), NONE, description="Robot part of the worst contact"),
            self.declare_channel("contact_kind", enum_type(self.kind_type), NONE, description="Transient or quasi-static (clamping)"),
            self.declare_channel("contact_speed", speed, 0.0, description="Worst contact's relative speed along its push"),
            self.declare_channel("nearest_region", enum_type(self.region_type), NONE, description="Body region nearest a robot"),
            self.declare_channel("nearest_person", enum_type(self.person_type), NONE, description="Person nearest a robot"),
            *(self.declare_channel(f"separation_{robot}", m, cfg.cutoff, description=f"True least distance from {robot} to a body")
              for robot in self.robots),
        ]
        self._jump = self.declare_channel(
            "region_jump", m, 0.0,
            description="Most a body region moved in one update near a robot, beyond it and the thinnest part's thickness")
        self._unwatched = self.declare_channel(
            "unwatched_part_speed", speed, 0.0,
            description="Fastest a robot part's point moved at a look ending an interval watched only at looks, "
                        "the largest yet")
        # nobody near: no contact (codes 0: none), each separation at the cut-off
        self._clear = [0.0] * (len(self._outputs) - len(self.robots)) + [cfg.cutoff] * len(self.robots)
        # nearest_region, nearest_person and the separations (the last channels): measured to the cut-off at each far look
        self._first_far = len(self._outputs) - len(self.robots) - 2

    def add_person(self, name: str, system) -> tuple:
        """Declare a person's pose inputs; returns the (pose, previous pose) ports to connect. The person's body must
        move only at their periodic updates (each is followed by a look): not a kind that also updates on a
        sample's arrival."""
        if getattr(system, "takes_samples_on_arrival", False):
            raise ValueError(f"{self.module}: person {name} moves on a sample's arrival, between the updates the harm "
                             "service looks after")
        ports = (self.declare_input(f"{name}_pose", 7), self.declare_input(f"{name}_previous_pose", 7))
        self.pose_ports.append(ports)
        self.person_systems.append(system)
        return ports

    def set_geometries(self, inspector, parts: dict, bodies: dict, fixtures: dict) -> None:
        """``parts``: arm GeometryId -> Part; ``bodies``: region GeometryId -> (person index, region); ``fixtures``:
        the layout's fixtures, GeometryId -> name."""
        self.fixtures = dict(fixtures)
        self.parts = dict(parts)
        self.bodies = {g: RegionGeometry(p, region, inspector.GetFrameId(g)) for g, (p, region) in bodies.items()}
        self._shapes = {g: inspector.GetShape(g) for g in self.bodies}  # for how near the floor each region is
        self.clamps = [*fixtures, *parts]  # what a region can be pinned against: fixtures, every arm's shapes
        self._blocker_shapes = {g: inspector.GetShape(g) for g in self.clamps}
        # each region's and blocker's bounding sphere in its frame: a pair whose spheres lie farther apart than
        # clamp_gap is not measured (no region can rest on it); within one look each pair is measured once
        self._spheres = {g: bounding_sphere(inspector.GetShape(g), RigidTransform()) for g in [*self.bodies, *self.clamps]}
        self._blocker_radii = np.array([self._spheres[g][1] for g in self.clamps])
        self._pairs_near: dict = {}  # this look's: (region, blocker) -> their closest points within clamp_gap, or None
        self._blockers_near: dict = {}  # this look's: region -> the blockers whose spheres lie within clamp_gap of it
        self._blocker_centres = None  # this look's: where each blocker's sphere is (m, world)
        self._pairs = NearestPair(inspector, list(self.parts), list(self.bodies))  # every robot part and body region
        # each touching pair's push, its normal while the overlap was last shallow (3 per pair, zero while it does
        # not touch), and how deep its overlap is still shallow (m): see measure()
        self._pair_index = {(a, b): i for i, (a, b) in enumerate((a, b) for a in self.parts for b in self.bodies)}
        self._onset = self.declare_state("onset", np.zeros(3 * len(self._pair_index)))
        self._shallow = [SHALLOW * min(inradius(inspector.GetShape(a)), inradius(inspector.GetShape(b)))
                         for a, b in self._pair_index]
        parts = list(self.parts.values())
        self._robot_rows = [[i for i, part in enumerate(parts) if part.robot == robot] for robot in self.robots]
        # each arm body's shapes within a sphere about a point fixed to it: (body index, centre in its frame, radius)
        spheres: dict = {}
        for geometry, part in self.parts.items():
            centre, radius = bounding_sphere(inspector.GetShape(geometry), inspector.GetPoseInFrame(geometry))
            spheres.setdefault(int(part.body), []).append((centre, radius))
        self.spheres = [(body, centre, radius) for body, found in spheres.items() for centre, radius in found]
        # how far from its body's origin each arm body's shapes reach (m): its points' speed is at most |v| + |w| that
        self._extents = [(body, max(float(np.linalg.norm(c)) + r for c, r in found)) for body, found in spheres.items()]
        unbounded = [self.parts[g].name for g in self.parts if not math.isfinite(bounding_sphere(
            inspector.GetShape(g), inspector.GetPoseInFrame(g))[1])]
        if unbounded:
            raise ValueError(f"{self.module}: the shape of robot part {unbounded[0]} cannot be bounded (a box, cylinder, "
                             "sphere, capsule, ellipsoid or mesh can): its speed could not be measured")
        self._looks = self._schedule()
        # each person's regions by frame: (frame, their centres in it (m), how far each may move in one update unseen)
        thinnest = 2.0 * min(inradius(inspector.GetShape(g)) for g in self.parts)
        grouped: dict = {}
        for g, body in self.bodies.items():
            grouped.setdefault((body.person, body.frame), []).append(
                (inspector.GetPoseInFrame(g).translation(), 2.0 * inradius(self._shapes[g]) + thinnest))
        self._moving = [[(frame, np.array([c for c, _ in found]), np.array([a for _, a in found]))
                         for (p, frame), found in grouped.items() if p == person] for person in range(len(self.people))]

    def _schedule(self) -> tuple[int, np.ndarray]:
        """When the service looks while nothing is near: one plant step after each person's update, where the body
        may have jumped (a turn), and at least every ``far_every`` steps, one step after each multiple of them (where
        a person updated at the multiple is seen too). (Steps in one round of the schedule, whether each is a look.)"""
        step = self.period
        cadences = [(self.far_every, 1 % self.far_every)]
        for system in self.person_systems:
            every = max(1, round(system.period / step))
            cadences.append((every, (round(system.offset / step) + 1) % every))
        steps = math.lcm(*(every for every, _ in cadences))
        if steps > 1_000_000:  # periods with no small common multiple: one plant-step look per step of the round
            raise ValueError(f"{self.module}: the people's update periods and far_period have no common multiple within "
                             f"{1_000_000 * step:g} s; make them multiples of one another")
        looks = np.zeros(steps, dtype=bool)
        for every, phase in cadences:
            looks[phase::every] = True
        return steps, looks

    def _part_speed(self, context) -> float:
        """The fastest any point of a robot part moves now (m/s), bounded from each arm body's spatial velocity."""
        velocities = self.body_velocities_port.Eval(context)
        fastest = 0.0
        for body, extent in self._extents:
            w_v = velocities[body].get_coeffs()
            speed = math.sqrt(w_v[3] * w_v[3] + w_v[4] * w_v[4] + w_v[5] * w_v[5]) + extent * math.sqrt(
                w_v[0] * w_v[0] + w_v[1] * w_v[1] + w_v[2] * w_v[2])
            fastest = max(fastest, speed)
        return fastest

    def _far(self, context) -> bool:
        """Whether every robot part is farther than the cut-off from every person, by bounding volumes alone (each
        part's sphere, each person's vertical cylinder of radius ``reach``): then no query is needed at all."""
        poses = self.body_poses_port.Eval(context)
        people = [(port.Eval(context), system.reach) for (port, _), system in zip(self.pose_ports, self.person_systems)]
        for body, centre, radius in self.spheres:
            c = poses[body] @ centre
            for pose, reach in people:
                if math.hypot(c[0] - pose[0], c[1] - pose[1]) - radius - reach <= self.cfg.cutoff:
                    return False
        return True

    # -- in Meshcat (cellsim.visual.cues) ------------------------------------------------------------
    LOOKS = {"touched": (1.0, 0.75, 0.1, 0.9), "harm": (0.9, 0.05, 0.05, 0.95)}
    """A body region in contact: amber within its limit, red above it (severity above 1)."""

    replay_channels = ("contact_person", "contact_region", "severity")

    def show_recorded(self, cell, root_context, values: dict) -> None:
        """Nothing to pose: the contact is drawn by colour (``visual_cues``, ``recolour``)."""

    def contact_look(self, values: dict) -> tuple[str, str, str] | None:
        """(person, region, look) of the worst contact in the channels' ``values``; None without one."""
        person, region, level = (values.get(f"{self.module}.{s}") for s in self.replay_channels)
        if region in (None, NONE):
            return None
        return person, region, "harm" if (level or 0.0) > 1.0 else "touched"

    def recolour(self, values: dict) -> dict:
        """The recorded worst contact's body region, coloured by its severity: GeometryId -> (r, g, b, a)."""
        contact = self.contact_look(values)
        if contact is None:
            return {}
        person, region, look = contact
        return {g: self.LOOKS[look] for g, body in self.bodies.items()
                if body.region == region and self.people[body.person] == person}

    def visual_cues(self, view) -> list:
        """Each body region, while the worst contact is with it, drawn over in amber (within the limit) or red (harm)."""
        from pydrake.geometry import Rgba

        from cellsim.visual.cues import Cue, Part

        inspector = view.inspector
        channels = tuple(f"{self.module}.{s}" for s in self.replay_channels)
        grouped: dict[tuple[int, str], list] = {}
        for geometry, body in self.bodies.items():
            grouped.setdefault((body.person, body.region), []).append(geometry)
        cues = []
        for (person, region), geometries in grouped.items():
            name = f"{self.module}/{self.people[person]}/{region}"
            looks = {look: tuple(
                Part(f"{view.frame_path(inspector.GetFrameId(g))}/harm_{region}_{look}/{i}", inspector.GetShape(g),
                     Rgba(*rgba), inspector.GetPoseInFrame(g), 1.08) for i, g in enumerate(geometries))
                for look, rgba in self.LOOKS.items()}
            cues.append(Cue(name, channels, looks, self._look_of(self.people[person], region)))
        return cues

    def _look_of(self, person: str, region: str):
        """A cue's choice for one person's region: its look while the worst contact is with it, else none."""

        def choose(values):
            contact = self.contact_look(values)
            return contact[2] if contact is not None and contact[:2] == (person, region) else None

        return choose

    # -- measuring ------------------------------------------------------------------------------
    def update(self, context, xd):
        """At every plant step (one event, so that a look falls on a plant step exactly): measure while the last look
        found a pair within reach or a fast part; else only at the looks of the schedule (:meth:`_schedule`)."""
        state = context.get_discrete_state(self._near).GetAtIndex(0)
        steps, looks = self._looks
        look = looks[round(context.get_time() / self.period) % steps]
        if state != FAR:
            return self._measure(context, xd, look, state)
        return self._far_look(context, xd) if look else UNCHANGED

    def _far_look(self, context, xd):
        """A look of the schedule while nothing was within reach: is anything within the cut-off now?"""
        fast, wrote = self._note_speed(context, xd, unwatched=True)
        if not fast and self._far(context):
            previous = [context.get_discrete_state(g).GetAtIndex(0) for g in self._outputs]
            if previous != self._clear:
                write_changed(xd, self._outputs, self._clear, previous)
            elif not wrote:
                return UNCHANGED
            return None
        return self._measure(context, xd, True, FAR, fast)

    def _note_speed(self, context, xd, unwatched: bool = False) -> tuple[bool, bool]:
        """At a look of the schedule: (whether a robot part moves faster than half ``max_part_speed``, whether
        ``unwatched_part_speed`` was written: the fastest yet at a look ending an ``unwatched`` interval, one measured
        only at its looks)."""
        speed = self._part_speed(context)
        wrote = unwatched and speed > context.get_discrete_state(self._unwatched).GetAtIndex(0)
        if wrote:
            xd.get_mutable_vector(self._unwatched).SetAtIndex(0, speed)
        return speed > 0.5 * self.cfg.max_part_speed, wrote

    def _measure(self, context, xd, look: bool, state: float, fast: bool | None = None):
        """Measure now: at a look of the schedule, every pair within the cut-off; in between, those within reach of a
        contact. The plant-step measuring stays on while a pair is within reach, and while the last look found a
        robot part fast (``fast``: found already at this look)."""
        if fast is None:
            fast = self._note_speed(context, xd)[0] if look else state == FAST
        query = self.query_port.Eval(context)
        pairs, values, onsets = self._look(context, query, self.cfg.cutoff if look else self.reach)
        self._write_onsets(context, xd, onsets)
        now = FAST if fast else NEAR if any(p.distance <= self.reach for p in pairs) else FAR
        if now != state:
            xd.get_mutable_vector(self._near).SetAtIndex(0, now)
        if look and pairs:
            self._note_jump(context, xd)
        previous = [context.get_discrete_state(g).GetAtIndex(0) for g in self._outputs]
        if not look:  # what lies beyond reach (nothing found within it) stays as the last look saw it
            for i in range(self._first_far, len(values)):
                if values[i] == self._clear[i]:
                    values[i] = previous[i]
        write_changed(xd, self._outputs, values, previous)
        return None

    def _note_jump(self, context, xd) -> None:
        """At a look finding a robot part within the cut-off: how far each body region moved at its person's last
        update (where the update put it against where the one before did), beyond its own thickness and the thinnest
        robot part's; the largest yet is ``region_jump``. A region that moves farther than that in one update may pass
        through a part between two looks unseen (docs/harm.md)."""
        worst = context.get_discrete_state(self._jump).GetAtIndex(0)
        found = worst
        for person, ((now_port, before_port), system) in enumerate(zip(self.pose_ports, self.person_systems)):
            now, before = now_port.Eval(context), before_port.Eval(context)
            if np.array_equal(now, before):
                continue
            X_now, X_before = system.frame_poses(tuple(now)), system.frame_poses(tuple(before))
            for frame, centres, allowed in self._moving[person]:
                a, b = X_now.value(frame).GetAsMatrix34(), X_before.value(frame).GetAsMatrix34()
                moved = np.linalg.norm(centres @ (a[:, :3] - b[:, :3]).T + (a[:, 3] - b[:, 3]), axis=1)
                found = max(found, float((moved - allowed).max()))
        if found > worst:
            xd.get_mutable_vector(self._jump).SetAtIndex(0, found)

    def _write_onsets(self, context, xd, onsets: dict) -> None:
        """Keep the pushes of the contacts going on now (``onsets``: pair index -> push), zero every other pair's."""
        before = context.get_discrete_state(self._onset).get_value()
        if not onsets and not before.any():
            return
        after = np.zeros_like(before)
        for k, push in onsets.items():
            after[3 * k:3 * k + 3] = push
        if not np.array_equal(after, before):
            xd.get_mutable_vector(self._onset).SetFromVector(after)

    def reading(self, context) -> dict:
        """What the service measures at ``context``'s instant (its own context), channel by channel, decoded: the
        worst contact's severity, region, person, part, kind and speed, and each robot's separation."""
        _, values, _ = self._look(context, self.query_port.Eval(context), self.cfg.cutoff)
        return {spec.signal: spec.type.decode([value]) for (spec, _), value in zip(self.channels, values)}

    def _look(self, context, query, within: float) -> tuple[list, list[float], dict]:
        """(the robot-part/body-region pairs that decide the channels: each robot's nearest within ``within`` (m), and
        every one touching; the channels' values they give; the pushes of the contacts, see :meth:`measure`)."""
        pairs = self._pairs.nearest_and_touching(query, within, self._robot_rows)
        return (pairs, *self.measure(context, query, pairs)) if pairs else (pairs, list(self._clear), {})

    def measure(self, context, query, pairs) -> tuple[list[float], dict]:
        """The channels' values for the pairs a look found near, and each contact's push (pair index -> unit vector
        from the arm into the region, in the world), kept in the ``onset`` state while the pair touches.

        The body does not give way in the twin, so an arm that keeps pressing sinks into a region; deep in it, past
        either shape's middle, the direction of least overlap turns (sideways, or back out), and the contact normal of
        that instant would read a press that goes on as no push at all. So a contact's push is its normal while the
        overlap is shallow (:data:`SHALLOW`), following the arm as it slides over the region, and once deeper the
        last shallow one's; it is judged along that push and along the normal of the instant, whichever reads worse
        (an edge of a box turns the normal at once, however shallow). An arm drawing back out of deep within a region
        may so read as pushing (the normal of the instant points back the way it came): the reading errs on harm."""
        onset = context.get_discrete_state(self._onset).get_value()
        self._pairs_near, self._blockers_near, self._blocker_centres = {}, {}, None  # (the geometry has moved)
        onsets = {}
        separation = dict.fromkeys(self.robots, self.cfg.cutoff)
        nearest, nearest_distance = None, self.cfg.cutoff
        touching = []
        for pair in pairs:  # distances alone first: most near pairs touch nothing
            region, other = (pair.id_A, pair.id_B) if pair.id_A in self.bodies else (pair.id_B, pair.id_A)
            part = self.parts[other]
            if pair.distance < separation[part.robot]:
                separation[part.robot] = pair.distance
            if pair.distance < nearest_distance:
                nearest, nearest_distance = self.bodies[region], pair.distance
            if pair.distance <= 0.0:
                touching.append((pair, region, other, part))
        worst = (0.0, NONE, NONE, NONE, NONE, 0.0)  # severity, region, person, part, kind, speed
        clamping = 0.0
        motion = _Motion(self, context)
        for pair, region, other, part in touching:
            body = self.bodies[region]
            on_a = pair.id_A == region
            p_W = witness_on(query, pair, region)
            k = self._pair_index[(other, region)]
            normal = pair.nhat_BA_W if on_a else -pair.nhat_BA_W  # from the arm into the region, now
            push = onset[3 * k:3 * k + 3]
            if not push.any() or -pair.distance <= self._shallow[k]:
                push = normal
            onsets[k] = push
            relative = motion.of_part(part, p_W) - motion.of_region(body, p_W)
            judged = []  # (severity, speed, kind) along the push, and along the normal of the instant where it differs
            for direction in (push,) if push is normal else (push, normal):
                speed = float(relative @ direction)
                pinned = self._pinned(query, body.person, body.region, p_W, other, part, direction, region)
                kind = QUASI_STATIC if pinned else TRANSIENT
                judged.append((severity(self.limits.regions[body.region], part.mass, kind, speed), speed, kind))
            level, speed, kind = max(judged, key=lambda found: found[:2])
            clamping = max([clamping, *(found[0] for found in judged if found[2] == QUASI_STATIC)])
            if level > worst[0] or worst[1] == NONE:
                worst = (level, body.region, self.people[body.person], part.name, kind, max(speed, 0.0))
        level, region, person, part, kind, speed = worst
        return [
            level, clamping, self.region_type(region).code, self.person_type(person).code, self.part_type(part).code,
            self.kind_type(kind).code, speed, *self._nearest_codes(nearest), *(separation[r] for r in self.robots),
        ], onsets

    def _nearest_codes(self, nearest: RegionGeometry | None) -> tuple[float, float]:
        """The nearest_region and nearest_person channels' codes for the region geometry ``nearest`` (None: nobody)."""
        if nearest is None:
            return float(self.region_type(NONE).code), float(self.person_type(NONE).code)
        return float(self.region_type(nearest.region).code), float(self.person_type(self.people[nearest.person]).code)

    def _pinned(self, query, person: int, region: str, p_W, touching, part: Part, push, touched=None) -> bool:
        """Whether the person's ``region`` touched at ``p_W`` is pinned: something they cannot pass (a fixture, an
        arm's shape that does not move with the pushing one, the floor) lies within clamp_gap of that region, or, for
        a region of a block that moves as one (:data:`cellsim.body.BLOCKS`: the trunk, the skull), of any of the
        block's (a chest pushed against a wall touches it with the back; a face, with the back of the head), behind the
        contact along the push, within clamp_angle_deg of it as seen from the contact. A head, a neck or a limb
        resting on nothing is not pinned by what the back rests on: it turns or bends away. Asked only of a region
        being touched: it costs nothing otherwise. ``touched``: the region's geometry the robot touches; a limb is
        pinned only by what rests against that very limb (not the other hand: default, every shape of the region)."""
        block = next((block for block in BLOCKS if region in block), None)
        if block is None and touched is not None:
            regions = [touched]
        else:
            regions = [g for g, b in self.bodies.items() if b.person == person and b.region in (block or (region,))]
        for other in self.clamps:
            if other == touching:
                continue
            behind = self.parts.get(other)
            if behind is not None and behind.robot == part.robot and (
                    behind.body == part.body or (part.rigid >= 0 and behind.rigid == part.rigid)):
                continue  # the same link, or a shape welded to it (a tool on its flange): it moves with the push
            for region in regions:
                pair = self._resting(query, region, other)
                if pair is None:
                    continue
                if self._behind(witness_on(query, pair, other) - p_W, push):
                    return True
                if block is None and self._beneath(query, other, region, p_W, push):
                    return True
        # the floor (z = 0, the layout's ground) is a blocker too: a foot or a shin pushed down onto it is pinned
        for region in regions:
            lowest = lowest_point_z(self._shapes[region], query.GetPoseInWorld(region))
            if lowest is not None and lowest <= self.cfg.clamp_gap and self._behind(
                    np.array([0.0, 0.0, lowest - float(p_W[2])]), push):
                return True
        return False

    def _resting(self, query, region, other):
        """The closest points of ``region`` and the blocker ``other`` where they lie within clamp_gap, else None;
        measured once a look, and not at all where their bounding spheres lie farther apart than clamp_gap."""
        key = (region, other)
        if key not in self._pairs_near:
            pair = None
            if other in self._near_blockers(query, region):
                pair = query.ComputeSignedDistancePairClosestPoints(region, other)
                if pair.distance > self.cfg.clamp_gap:
                    pair = None
            self._pairs_near[key] = pair
        return self._pairs_near[key]

    def _near_blockers(self, query, region) -> set:
        """The blockers whose bounding spheres lie within clamp_gap of ``region``'s, this look (an unbounded sphere
        counts as near: it is measured)."""
        near = self._blockers_near.get(region)
        if near is None:
            if self._blocker_centres is None:
                self._blocker_centres = np.array([query.GetPoseInWorld(g) @ self._spheres[g][0]
                                                  for g in self.clamps]).reshape(-1, 3)
            centre, radius = self._spheres[region]
            apart = (np.linalg.norm(self._blocker_centres - query.GetPoseInWorld(region) @ centre, axis=1)
                     - self._blocker_radii - radius)
            near = self._blockers_near[region] = {g for g, gap in zip(self.clamps, apart)
                                                  if not gap > self.cfg.clamp_gap}
        return near

    def _beneath(self, query, blocker, region, p_W, push) -> bool:
        """Whether the ``blocker``'s point nearest the contact ``p_W`` itself lies behind it along the ``push``, no
        farther than the touched limb is thick (``region``) and clamp_gap: a limb lying along a surface (a forearm on
        a shelf) touches it over its length, and the pair's one witness point may sit at its far end, off the push's
        line (a review found a press straight down at the elbow end read free). Fixtures are boxes; another blocker
        shape is left to the witness alone."""
        nearest = nearest_on_box(self._blocker_shapes[blocker], query.GetPoseInWorld(blocker), p_W)
        if nearest is None:
            return False
        towards = nearest - p_W
        return (float(np.linalg.norm(towards)) <= 2.0 * inradius(self._shapes[region]) + self.cfg.clamp_gap
                and self._behind(towards, push))

    def _behind(self, towards, push) -> bool:
        """Whether a blocker's point ``towards`` away from the contact (m) lies behind it along the ``push``, within
        clamp_angle_deg as seen from the contact."""
        length = float(np.linalg.norm(towards))
        return length == 0.0 or float(towards @ push) >= self.cos_clamp * length


class _Motion:
    """Velocities of points of the arms and of the people at one instant (evaluated when first asked)."""

    def __init__(self, monitor: HarmMonitor, context):
        self.monitor, self.context = monitor, context
        self._bodies = self._velocities = None
        self._frames: dict = {}

    def of_part(self, part: Part, p_W) -> np.ndarray:
        """Velocity (m/s) of the arm's point at ``p_W`` (m), from the plant's body pose and spatial velocity."""
        if self._bodies is None:
            self._bodies = self.monitor.body_poses_port.Eval(self.context)
            self._velocities = self.monitor.body_velocities_port.Eval(self.context)
        index = int(part.body)
        X_WB = self._bodies[index]
        return self._velocities[index].Shift(p_W - X_WB.translation()).translational()

    def of_region(self, body: RegionGeometry, p_W) -> np.ndarray:
        """Velocity (m/s) of the person's point at ``p_W``: where it was at their previous update, to where it is."""
        poses = self._frames.get(body.person)
        if poses is None:
            system = self.monitor.person_systems[body.person]
            now_port, before_port = self.monitor.pose_ports[body.person]
            now, before = now_port.Eval(self.context), before_port.Eval(self.context)
            if np.array_equal(now, before):
                poses = self._frames[body.person] = ()
            else:
                poses = self._frames[body.person] = (system.frame_poses(tuple(now)), system.frame_poses(tuple(before)),
                                                     system.period)
        if not poses:
            return np.zeros(3)
        now, before, period = poses
        X_now, X_before = now.value(body.frame), before.value(body.frame)
        return (p_W - X_before @ (X_now.inverse() @ p_W)) / period
