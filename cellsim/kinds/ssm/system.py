"""Speed and separation monitoring (ISO/TS 15066, 5.5.4): the protective separation distance and the
speed a robot may have now.

Every control period it reads the separation d between the robot and the nearest person, either
measured on the geometry (the arm's collision shapes to every person's body, SceneGraph signed
distances: an ideal person-tracking sensor, with ``sensor_uncertainty`` added to the distance
budget) or from a sensor's channel (``separation: scanner.distance``, measured from the sensor,
not the arm), and the robot's speed towards that person v_r: on the geometry, the velocity of the
arm's nearest point along the line to the person's nearest point (never less than 0); from a
sensor, the tool's whole speed (the direction is unknown: its speed in any direction is assumed
towards the person).

The protective separation distance, with v_h the person's speed (``human_speed``, 1.6 m/s by
default after ISO 13855), T_r the reaction time, a the robot's braking deceleration and
T_s = v_r / a its stopping time from v_r:

    S_p = S_h + S_r + S_s + C + Z_d + Z_r
    S_h = v_h (T_r + T_s)      the person's approach while the robot reacts and stops
    S_r = v_r T_r              the robot's travel while it reacts
    S_s = v_r^2 / (2 a)        the robot's stopping distance, braking at a
    C   = intrusion_distance,  Z_d = sensor_uncertainty,  Z_r = robot_uncertainty

Once this module has ordered a stop (its limit 0), the robot's reaction is under way: T_r in
S_h and S_r is what is left of it, T_r less the time since the order, down to 0, so a robot
that has stopped has S_p = C + Z_d + Z_r and a person may stand near it. ``margin`` = d - S_p
(negative: the robot is too fast for the separation, or touched).

The speed limit is the v_r at which S_p = d, solved exactly, for the separation the robot
will have when it acts on the limit: the person may come v_h L nearer meanwhile, L the
latency of this module's period and the robot's (``latency``):

    v_max = sqrt((a T_r + v_h)^2 + 2 a D) - (a T_r + v_h),   D = d - C - Z_d - Z_r - v_h (T_r + L)

(0 when D <= 0). With v_h = 0 and Z_d = Z_r = 0 it is the published form
v_max = sqrt((a T_r)^2 + 2 a (d - C)) - a T_r. A robot that follows it brakes at a or faster
keeps ``margin`` >= 0: as d falls by v_h dt, S_p falls by (v_h + a T_r + v_r) dt. In ``ssmon``
the robot follows ``speed_limit`` continuously (its ``speed_limit`` input); a risk model or a
condition reads ``margin``. A separation with no value (a stale sensor) allows no speed: the
limit is 0, the robot stops, and the separation and margin have no value either (a condition on
them is undecided there, not held nor violated: nothing measured them). On the geometry, so does
a separation whose bodies the twin no longer knows: while the robot's or a person's physical link
is not ok (stale, corrupt, recovering), its digital body holds a pose the real one may have left.
A stopped robot starts again only once d exceeds S_p of its first speed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import QueryObject

from cellsim.channels import number_type
from cellsim.kinds.ssm.config import GEOMETRY, SsmConfig
from cellsim.proximity import NearestPair, witness_on
from cellsim.systems import UNCHANGED, CellSystem, read_scalar, write_scalar
from cellsim.vocabulary import PhysicalLink, SafetyMode

_SSMON = float(SafetyMode.SPEED_SEPARATION.code)
_NOBODY = np.full(1, math.nan)
"""``truth_people`` where no body is measured."""
_TRUSTED_LINKS = frozenset({float(PhysicalLink.UNUSED.code), float(PhysicalLink.OK.code)})
"""The physical links a digital body can be trusted through: none used (a digital model), or ok."""
_JUDGED = ("true_margin", "unwatched_margin_fall")
"""The channels the truth's own event writes, at the plant step."""
FAR_AWAY = 10.0
"""m: the separation read with nobody in the cell."""
DISC_RADIUS = 0.5
"""m: the Meshcat disc round a monitored arm's base."""


@dataclass(frozen=True)
class SsmParameters:
    """The terms of ISO/TS 15066's formula, in SI units."""

    human_speed: float
    reaction_time: float
    deceleration: float
    intrusion_distance: float = 0.0
    sensor_uncertainty: float = 0.0
    robot_uncertainty: float = 0.0
    latency: float = 0.0
    """L (s): from a limit computed to the robot moving under it (this module's and the robot's periods)."""

    @property
    def allowances(self) -> float:
        """C + Z_d + Z_r (m)."""
        return self.intrusion_distance + self.sensor_uncertainty + self.robot_uncertainty

    def protective_distance(self, robot_speed: float, reaction: float | None = None) -> float:
        """S_p (m) for the robot's speed towards the person v_r (m/s); ``reaction``: the reaction time
        still to come (s), default all of T_r (0 once a stop was ordered T_r ago)."""
        v_h, a, v_r = self.human_speed, self.deceleration, max(robot_speed, 0.0)
        t_r = self.reaction_time if reaction is None else reaction
        stopping_time = v_r / a
        return v_h * (t_r + stopping_time) + v_r * t_r + v_r * v_r / (2.0 * a) + self.allowances

    def true_protective_distances(self, robot_speeds: np.ndarray, reaction: float,
                                  stopping_speed: float = 0.0) -> np.ndarray:
        """:meth:`true_protective_distance` of many speeds at once (m/s, an array; ``reaction`` s still to come)."""
        v_h, a = self.human_speed, self.deceleration
        v_r = np.maximum(robot_speeds, 0.0)
        stopping_time = np.maximum(v_r, stopping_speed) / a
        return v_h * (reaction + stopping_time) + v_r * reaction + v_r * stopping_time / 2.0

    def true_protective_distance(self, robot_speed: float, reaction: float | None = None,
                                 stopping_speed: float = 0.0) -> float:
        """S_p (m) on the truth: the true speed towards the person v_r and no allowances (C, Z_d and Z_r are for
        what a sensor cannot know); the person's speed is still v_h, which they may take at any instant.

        The robot brakes its whole path at once, so every point of the arm stops when its tool does: the stopping
        time T_s is the robot's, ``stopping_speed`` (m/s, the tool's whole speed) over a, not the point's speed
        towards the person over a (a part moving sideways would have none while the arm is still moving); at least
        v_r / a. The point's speed falls to 0 over T_s: it travels v_r T_s / 2 while braking."""
        t_r = self.reaction_time if reaction is None else reaction
        v_r = max(robot_speed, 0.0)
        stopping_time = max(v_r, stopping_speed) / self.deceleration
        return self.human_speed * (t_r + stopping_time) + v_r * t_r + v_r * stopping_time / 2.0

    def separation_for(self, limit: float) -> float:
        """The separation d (m) whose speed limit is ``limit`` (m/s): :meth:`speed_limit`'s inverse (at 0, the
        largest separation that allows no speed)."""
        v_h, t_r, a = self.human_speed, self.reaction_time, self.deceleration
        b = a * t_r + v_h
        return limit * (limit + 2.0 * b) / (2.0 * a) + self.allowances + v_h * (t_r + self.latency)

    def speed_limit(self, separation: float) -> float:
        """v_max (m/s): the robot speed whose S_p is the separation d (m) less the person's approach
        over the latency; 0 when none is."""
        v_h, t_r, a = self.human_speed, self.reaction_time, self.deceleration
        budget = separation - self.allowances - v_h * (t_r + self.latency)
        if not budget > 0.0:  # NaN too
            return 0.0
        b = a * t_r + v_h
        return math.sqrt(b * b + 2.0 * a * budget) - b


class SpeedSeparationMonitor(CellSystem):
    """Ports:
      robot_state (input): the robot's plant state [q (rad), v (rad/s)].
      robot_safety_mode (input): the robot's safety mode (its code): the true margin is watched at every plant step
        near 0 only in ssmon, where TrueSSM judges it.
      geometry_query (input, geometry separation only): SceneGraph's QueryObject.
      separation_measured (input, a sensor's separation only): that sensor's distance (m).
      <entity>_link (inputs, geometry separation only): the physical link (its code) of the robot and of each
        person whose bodies the separation is measured between (``watch_links``): while one is not ok or unused,
        the separation has no value and the limit is 0.
      separation (channel, m): the separation d used (negative: overlapping).
      protective_distance (channel, m): S_p for the robot's current speed towards the person.
      margin (channel, m): d - S_p.
      speed_limit (channel, m/s): v_max, the speed the robot may have now (its speed_limit input).
      unwatched_margin_fall (channel, m/s): the fastest the true margin fell, in ssmon, between two judgements it
        was not watched between while the robot alone moved (no person's update nor stop order between them: those
        jump the margin and are judged a step later); above ``max_margin_fall``: a dip below 0 may have been missed.
      true_margin (channel, m): on the truth, whatever the monitor's separation comes from: the least, over every
        pair of an arm's shape and a person's body region, of their true separation less S_p of the shape's true
        speed towards that region, with no allowances; read up to FAR_AWAY (a falsification search climbs it from
        anywhere in the cell). Judged one plant step after each of the monitor's updates and each person's (a
        person's move is seen at once, not at the monitor's next update), and at every plant step while it is
        near 0 (``max_margin_fall``): see ``watch_truth``.
    """

    def __init__(self, module: str, cfg: SsmConfig, parameters: SsmParameters, kinematics, base_xy=(0.0, 0.0),
                 cap: float = math.inf):
        """``base_xy``: where the arm's base stands (m, for its Meshcat cue); ``cap``: its ssmon cap (m/s)."""
        super().__init__(module, cfg.period)
        self.parameters = parameters
        self.kinematics = kinematics
        self.base_xy = tuple(base_xy)
        self.cap = cap
        self.from_geometry = cfg.separation == GEOMETRY
        self.robot_state_port = self.declare_input("robot_state", 2 * kinematics.num_joints)
        # (its builder wires it, no controller drives it: untyped)
        self.robot_mode_port = self.declare_input("robot_safety_mode", default=SafetyMode.SPEED_SEPARATION.code)
        self.query_port = self.DeclareAbstractInputPort("geometry_query", AbstractValue.Make(QueryObject()))
        if not self.from_geometry:
            self.separation_port = self.declare_input("separation_measured")
        self.pairs = None
        """Finds the nearest pair of an arm's shape and a person's body region (``set_geometries``)."""
        self.link_ports: list = []
        """The robot's and the people's physical links, on the geometry (``watch_links``)."""
        self.bodies: dict = {}
        """Arm GeometryId -> the body of the private kinematics plant it is fixed to."""
        far = parameters.speed_limit(FAR_AWAY)
        self._stop_ordered = self.declare_state("stop_ordered_at", [math.nan])  # s; NaN: the limit is not 0
        m = number_type("m")
        self._separation = self.declare_channel("separation", m, FAR_AWAY, record="every_sample",
                                                description="Separation to the nearest person")
        self._protective = self.declare_channel("protective_distance", m, parameters.protective_distance(0.0),
                                                record="every_sample", description="Protective separation distance S_p")
        self._margin = self.declare_channel("margin", m, FAR_AWAY - parameters.protective_distance(0.0),
                                            record="every_sample", description="Separation less S_p")
        self._limit = self.declare_channel("speed_limit", number_type("m/s"), far, record="every_sample",
                                           description="Speed the robot may have now")
        self._true_margin = self.declare_channel(
            "true_margin", m, FAR_AWAY - parameters.true_protective_distance(0.0),
            description="True separation less S_p of the robot's true speed towards the person, without allowances")

    # -- in Meshcat (cellsim.visual.cues) ------------------------------------------------
    LOOKS = {"free": (0.2, 0.75, 0.3), "limited": (0.95, 0.7, 0.1), "stopped": (0.85, 0.1, 0.1),
             "too_fast": (0.8, 0.1, 0.8)}
    """The floor disc round the arm's base: its speed free (up to the ssmon cap), limited, stopped by the
    monitor, or faster than its separation allows (margin < 0)."""

    def visual_cues(self, view) -> list:
        """A disc on the floor round the arm's base, coloured by what the monitor allows now."""
        from pydrake.geometry import Cylinder, Rgba
        from pydrake.math import RigidTransform

        from cellsim.visual.cues import Cue, parts_of

        x, y = self.base_xy
        disc = [(RigidTransform([x, y, 0.004]), Cylinder(DISC_RADIUS, 0.008))]
        looks = {look: parts_of(f"{self.module}/ssm/{look}", disc, Rgba(*rgb, 0.55)) for look, rgb in self.LOOKS.items()}
        return [Cue(f"{self.module}/ssm", (f"{self.module}.margin", f"{self.module}.speed_limit"), looks, self.look)]

    def look(self, values: dict) -> str | None:
        """The disc's look for the monitor's channel values (None before any)."""
        margin, limit = values.get(f"{self.module}.margin"), values.get(f"{self.module}.speed_limit")
        if margin is None or limit is None:
            return None
        if margin < 0.0:
            return "too_fast"
        if limit <= 0.0:
            return "stopped"
        return "limited" if limit < self.cap else "free"

    def set_geometries(self, inspector, arm: dict, people: list) -> None:
        """``inspector``: SceneGraph's model inspector; ``arm``: each of the robot's GeometryIds -> the name of the
        body it is fixed to; ``people``: every person's body regions (GeometryIds)."""
        plant = self.kinematics.plant
        self.bodies = {g: plant.GetBodyByName(body) for g, body in arm.items()}
        self.pairs = NearestPair(inspector, list(arm), people)

    def watch_links(self, entities: list[str]) -> list:
        """Declare an input of the physical link of each of ``entities`` (on the geometry, the robot and the people;
        from a sensor, the sensor), by module name; returns the ports to connect to their ``physical_link`` channels.
        The separation has no value (and the limit is 0) while one is not ok or unused."""
        self.link_ports = [self.declare_input(f"{entity}_link", default=PhysicalLink.UNUSED.code) for entity in entities]
        return self.link_ports

    def bodies_trusted(self, context) -> bool:
        """Whether every digital body the separation is measured between follows its physical twin, or has none."""
        return all(port.Eval(context)[0] in _TRUSTED_LINKS for port in self.link_ports)

    def watch_truth(self, step: float, people: list[float], robot: float, max_fall: float) -> None:
        """Judge ``true_margin`` in an event of its own at the plant step (``step``, s): one step after each update
        of the people (their ``people`` periods, s, from t = 0; Drake's updates at one time read the state before
        any, so judged at this monitor's own update it would see a person's move a period late); while the robot
        is in ssmon (where TrueSSM judges the margin), one step after each of the robot's updates (its ``robot``
        period: its mode changes then) and of this monitor's (a stop order lifted raises S_p at once); and, in
        ssmon, at every step while the margin is nearer 0 than it can fall, at ``max_fall`` m/s, before the next
        of those."""
        from dataclasses import replace

        self._step = step
        self._truth_periods = (list(people), robot, max_fall)
        self._close = self.declare_state("truth_close", [0.0])  # 1: judged at every step
        self._judged = self.declare_state("truth_judged", [math.nan, math.nan, math.nan])  # (s, m, stop order): last
        # where the people's body regions were at the last judgement (their bounding spheres' centres, m): a margin
        # that changed with them jumped, one that changed without them fell with the robot alone
        regions = len(self.pairs.b.ids) if self.pairs is not None else 0
        self._people_at = self.declare_state("truth_people", np.full(max(1, 3 * regions), math.nan))
        self._fall = self.declare_channel(
            "unwatched_margin_fall", number_type("m/s"), 0.0,
            description="Fastest the true margin fell between two judgements in ssmon not watched at every step")
        self._schedule_truth()
        self.DeclarePeriodicDiscreteUpdateEvent(step, 0.0, self._judge_truth)
        self.channels = [(replace(spec, period=step, offset=0.0) if spec.signal in _JUDGED else spec, port)
                         for spec, port in self.channels]

    def _schedule_truth(self) -> None:
        """The judging schedule of :meth:`watch_truth`, with this monitor's own updates at its offset."""
        step = self._step
        people, robot, max_fall = self._truth_periods
        always = [max(1, round(p / step)) for p in people]
        in_ssmon = [(max(1, round(robot / step)), 1), (max(1, round(self.period / step)), round(self.offset / step) + 1)]
        rounds = math.lcm(*always, *(every for every, _ in in_ssmon))
        if rounds > 1_000_000:
            raise ValueError(f"{self.module}: the robot's, the people's and its own periods have no common multiple "
                             f"within {1_000_000 * step:g} s; make them multiples of one another")
        looks = np.zeros(rounds, dtype=np.int8)  # 0: no look; 1: a look; 2: a look while the robot is in ssmon
        for every, phase in in_ssmon:
            looks[phase % every::every] = 2
        for every in always:
            looks[1 % every::every] = 1
        at = np.flatnonzero(looks)
        gap = int(max(np.diff(at).max(initial=0), at[0] + rounds - at[-1]))  # the longest wait in ssmon, in steps
        self._truth_looks = (rounds, looks)
        self._watch_below = max_fall * gap * step
        """m: a true margin above this at a judgement cannot reach 0 before the next scheduled one."""

    def decide_after(self, offset: float) -> None:
        """As any module's; the true margin stays judged at the plant step (:meth:`watch_truth`), one step after this
        monitor's updates at their offset."""
        from dataclasses import replace

        super().decide_after(offset)
        if getattr(self, "_truth_looks", None) is not None:
            self._schedule_truth()
            self.channels = [(replace(spec, offset=0.0) if spec.signal in _JUDGED else spec, port)
                             for spec, port in self.channels]

    def measure(self, context) -> tuple[float, float]:
        """(separation d in m, robot speed towards the person v_r in m/s), as the monitor has them; d is NaN (no value)
        when it is not known: a stale sensor's, or bodies the twin no longer tracks (``bodies_trusted``)."""
        kin = self.kinematics
        kin.plant.SetPositionsAndVelocities(kin.context, self.robot_state_port.Eval(context))
        if not self.from_geometry or not self.bodies_trusted(context):
            # a sensor's reading, unless its link is not ok (a stale sensor reads 0 m, failing safe: no value here)
            d = self.separation_port.Eval(context)[0] if not self.from_geometry and self.bodies_trusted(context) \
                else math.nan
            tool_velocity = kin.tool.CalcSpatialVelocityInWorld(kin.context).translational()
            return (d if math.isfinite(d) else math.nan), float(np.linalg.norm(tool_velocity))  # (inf: no value)
        return self.truth(context)

    def truth(self, context) -> tuple[float, float]:
        """(the true separation d in m, read up to FAR_AWAY, and the robot's true speed towards that person
        v_r in m/s: the nearest pair's), on the geometry; the kinematics set to the robot's state already."""
        if not self.pairs:
            return FAR_AWAY, 0.0
        query = self.query_port.Eval(context)
        nearest = self.pairs(query, FAR_AWAY)
        if nearest is None:
            return FAR_AWAY, 0.0
        return min(nearest.distance, FAR_AWAY), self._towards(query, nearest)

    def _towards(self, query, pair) -> float:
        """The speed (m/s, not below 0) of the arm's point of ``pair`` towards the person's (its whole speed where
        they overlap); the kinematics set to the robot's state already."""
        kin = self.kinematics
        arm = pair.id_A if pair.id_A in self.bodies else pair.id_B
        body = self.bodies[arm]
        w_v = body.EvalSpatialVelocityInWorld(kin.context).get_coeffs()
        return _speed_towards(pair, arm == pair.id_A, witness_on(query, pair, arm),
                              body.EvalPoseInWorld(kin.context).translation(), w_v[3:], w_v[:3])

    def true_margin(self, context, reaction: float, regions: np.ndarray | None = None) -> float:
        """The least, over every pair of an arm's shape and a body region, of their true separation less S_p (no
        allowances, ``reaction`` s of reaction still to come, the robot's stopping time from its tool's speed: see
        :meth:`SsmParameters.true_protective_distance`) of the shape's true speed towards that region; read up
        to FAR_AWAY. Pairs are measured in order of a lower bound (their bounding spheres' distance less S_p of the
        shape's fastest point: its sphere centre's speed and the sphere's radius turning), until none can be lower
        than the least found."""
        kin, sp = self.kinematics, self.parameters.true_protective_distance
        least = FAR_AWAY - sp(0.0, reaction)
        if not self.pairs:
            return least
        kin.plant.SetPositionsAndVelocities(kin.context, self.robot_state_port.Eval(context))
        stopping = float(np.linalg.norm(kin.tool.CalcSpatialVelocityInWorld(kin.context).translational()))
        query = self.query_port.Eval(context)
        centres = self.pairs.a.centres(query)
        if regions is None:  # (the body regions' sphere centres: the caller's, where it has them)
            regions = self.pairs.b.centres(query)
        bounds = self.pairs.bounds_from(centres, regions)
        ids_a, ids_b = self.pairs.a.ids, self.pairs.b.ids
        motion = [self.bodies[g].EvalSpatialVelocityInWorld(kin.context).get_coeffs() for g in ids_a]
        # each shape's sphere centre's velocity, and its points' most beyond that (the sphere's radius turning)
        centre_v = np.empty((len(ids_a), 3))
        turning = np.empty(len(ids_a))
        for i, g in enumerate(ids_a):
            wx, wy, wz, vx, vy, vz = motion[i].tolist()
            rx, ry, rz = (centres[i] - self.bodies[g].EvalPoseInWorld(kin.context).translation()).tolist()
            centre_v[i] = (vx + wy * rz - wz * ry, vy + wz * rx - wx * rz, vz + wx * ry - wy * rx)
            w = math.sqrt(wx * wx + wy * wy + wz * wz)
            turning[i] = self.pairs.a.radii[i] * w if w else 0.0  # (no NaN from a sphere of no bound standing still)
        speed = np.linalg.norm(centre_v, axis=1)
        fastest = (speed + turning)[:, None]
        # towards a region the witness points' direction lies within asin((r_i + r_j) / D) of the centres': the
        # speed along it is at most the centre's along the centres' direction, plus its speed times the two
        # directions' distance (2 sin of half that angle), plus the turning; spheres that meet: the whole speed
        apart = regions[None, :, :] - centres[:, None, :]
        distance = np.linalg.norm(apart, axis=2)
        spread = self.pairs._radii / np.maximum(distance, 1e-12)
        separate = spread < 1.0
        along = np.einsum("ik,ijk->ij", centre_v, apart) / np.maximum(distance, 1e-12)
        skew = 2.0 * np.sin(0.5 * np.arcsin(np.minimum(spread, 1.0)))
        towards = np.where(separate, np.maximum(along + speed[:, None] * skew, 0.0) + turning[:, None], fastest)
        towards = np.minimum(towards, fastest)
        protective = self.parameters.true_protective_distances(towards, reaction, stopping)  # at its bound speed
        lower = bounds - protective
        lower[bounds > FAR_AWAY] = np.inf  # beyond FAR_AWAY a pair reads as nobody near
        lower[np.isnan(lower)] = -np.inf  # a shape no sphere holds: measured first
        flat = lower.ravel()
        columns = lower.shape[1]
        shape_poses: dict[int, np.ndarray] = {}  # each arm shape's pose (3 x 4), taken when its first pair is measured
        for k in np.argsort(flat, kind="stable"):
            if not flat[k] < least:
                break  # no pair from here on can have a lower margin
            i, j = divmod(int(k), columns)
            pair = query.ComputeSignedDistancePairClosestPoints(ids_a[i], ids_b[j])
            if pair.distance > FAR_AWAY:
                continue
            bound = protective[i, j] if pair.distance > 0.0 else sp(fastest[i, 0], reaction, stopping)
            if pair.distance - bound < least:  # its exact distance, its speed bounded: worth its witness's speed
                on_a = pair.id_A == ids_a[i]
                X_WA = shape_poses.get(i)
                if X_WA is None:
                    X_WA = shape_poses[i] = query.GetPoseInWorld(ids_a[i]).GetAsMatrix34()
                p_W = X_WA[:, :3] @ (pair.p_ACa if on_a else pair.p_BCb) + X_WA[:, 3]
                speed = _speed_towards(pair, on_a, p_W, centres[i], centre_v[i], motion[i][:3])
                least = min(least, pair.distance - sp(speed, reaction, stopping))
        return least

    def _reaction(self, context, t: float, since: float) -> float:
        """The reaction time still to come at ``t`` (s): all of T_r, or what is left of it once a stop was ordered
        at ``since`` (NaN: none was)."""
        t_r = self.parameters.reaction_time
        return t_r if math.isnan(since) else max(0.0, t_r - (t - since))

    def _judge_truth(self, context, xd):
        """At every plant step (``watch_truth``'s event): the true margin, at a look of the schedule or while near 0."""
        close = context.get_discrete_state(self._close).GetAtIndex(0) != 0.0
        rounds, looks = self._truth_looks
        t = context.get_time()
        look = looks[round(t / self._step) % rounds]
        if not close and (not look or (look == 2 and self.robot_mode_port.Eval(context)[0] != _SSMON)):
            return UNCHANGED
        since = read_scalar(context, self._stop_ordered)
        reaction = self._reaction(context, t, since)
        regions = self._regions_now(context)
        margin = self.true_margin(context, reaction, regions)
        in_ssmon = self.robot_mode_port.Eval(context)[0] == _SSMON
        now_close = margin < self._watch_below and in_ssmon
        then, before, since_then = context.get_discrete_state(self._judged).get_value()
        people = _NOBODY if regions is None else regions.ravel()
        moved = not np.array_equal(people, context.get_discrete_state(self._people_at).get_value(), equal_nan=True)
        if moved:
            xd.get_mutable_vector(self._people_at).SetFromVector(people)
        jumped = moved or not (since == since_then or (math.isnan(since) and math.isnan(since_then)))
        if in_ssmon and not close and t > then and not jumped:
            # an interval watched only at its ends, the robot alone moving (a person's move, or a stop order given or
            # lifted, is a jump of the margin judged a step after it, not a fall): how fast did it fall?
            fall = (before - margin) / (t - then)
            if fall > read_scalar(context, self._fall):
                write_scalar(xd, self._fall, fall)
        xd.get_mutable_vector(self._judged).SetFromVector([t, margin, since])
        write_scalar(xd, self._true_margin, margin)
        write_scalar(xd, self._close, 1.0 if now_close else 0.0)
        return None

    def _regions_now(self, context) -> np.ndarray | None:
        """Where the people's body regions are now: their bounding spheres' centres (m, one row each); None: nobody's
        bodies are measured (``truth_people`` keeps them flat)."""
        if self.pairs is None or not self.pairs.b.ids:
            return None
        return self.pairs.b.centres(self.query_port.Eval(context))

    def update(self, context, xd):
        t = context.get_time()
        d, v_r = self.measure(context)
        limit = self.parameters.speed_limit(d)
        since = read_scalar(context, self._stop_ordered)  # NaN: no stop ordered
        if limit > 0.0:
            since = math.nan
        elif math.isnan(since):
            since = t
        reaction = self._reaction(context, t, since)
        protective = self.parameters.protective_distance(v_r, reaction)
        write_scalar(xd, self._stop_ordered, since)
        write_scalar(xd, self._separation, d)
        write_scalar(xd, self._protective, protective)
        write_scalar(xd, self._margin, d - protective)
        write_scalar(xd, self._limit, limit)


def _speed_towards(pair, arm_is_a: bool, p_W, c_W, v_c, w) -> float:
    """The speed (m/s, not below 0) towards the person of the arm's witness point ``p_W`` of ``pair`` (its whole
    speed where they overlap), from the velocity ``v_c`` of a point ``c_W`` fixed to the arm's body and its angular
    velocity ``w`` (world frame): v = v_c + w x (p - c)."""
    rx, ry, rz = (p_W - c_W).tolist()
    wx, wy, wz = w.tolist()
    vx, vy, vz = v_c.tolist()
    vx, vy, vz = vx + wy * rz - wz * ry, vy + wz * rx - wx * rz, vz + wx * ry - wy * rx
    if pair.distance <= 0.0:
        return math.sqrt(vx * vx + vy * vy + vz * vz)
    nx, ny, nz = pair.nhat_BA_W.tolist()  # from B to A: towards the person when the person is A
    speed = vx * nx + vy * ny + vz * nz
    return max(-speed if arm_is_a else speed, 0.0)


def parameters_of(cfg: SsmConfig, robot_cfg) -> SsmParameters:
    """The formula's terms; the deceleration defaults to what the robot delivers braking from its planned full speed
    (:func:`cellsim.kinds.robot.system.braking_deceleration`)."""
    from cellsim.kinds.robot.system import braking_deceleration

    deceleration = cfg.deceleration
    if deceleration is None:
        deceleration = braking_deceleration(robot_cfg)
    return SsmParameters(cfg.human_speed, cfg.reaction_time, deceleration, cfg.intrusion_distance,
                         cfg.sensor_uncertainty, cfg.robot_uncertainty, latency=cfg.period + robot_cfg.period)
