"""A light curtain measuring geometry: its beams fill a box, broken while a person's geometry is in it."""

from __future__ import annotations


from pydrake.geometry import Box, GeometryInstance, MakePhongIllustrationProperties, ProximityProperties, Rgba
from pydrake.math import RigidTransform

from cellsim.channels import BOOL, enum_type
from cellsim.kinds.sensing import REACH, GeometrySensor
from cellsim.systems import read_scalar, write_scalar
from cellsim.vocabulary import TwinMode, value_set
from cellsim.kinds.light_barrier.config import LightBarrierConfig

BEAMS_CLEAR = Rgba(1.0, 0.15, 0.1, 0.12)
BEAMS_BROKEN = Rgba(1.0, 0.0, 0.0, 0.7)


class LightBarrier(GeometrySensor):
    """A light curtain whose beams fill a box.

    Ports:
      geometry_query (input): SceneGraph QueryObject.
      physical_sample (input): [t, link, broken (0/1)].
      reset (input, with restart_interlock): a rising edge resets a tripped curtain whose beams are clear.
      broken (channel, bool): true while any target geometry intersects the beams; with
        restart_interlock, *latched*: from the first break until a reset.
      interrupted (channel, bool, with restart_interlock): the beams interrupted now, latch or not.
      unseen (channel): a blind spot: ``beams`` while a person's body truly meets the beams (by the geometry)
        and the curtain reports them clear (its physical twin's sample, in shadow or twin mode), else none.
    Fails safe (reads broken and interrupted) when its physical sample is stale or corrupt.
    """

    def __init__(self, module: str, cfg: LightBarrierConfig):
        super().__init__(module, cfg.period, cfg.twin, ("broken",))
        self.cfg = cfg
        self.beam_id = None
        self._broken = self.declare_channel(
            "broken", BOOL, False, description="Beams interrupted (with a restart interlock: tripped until reset)"
        )
        self.unseen_readings = value_set(f"{module}_unseen", ["none", "beams"])
        self._unseen = self.declare_channel(
            "unseen", enum_type(self.unseen_readings), "none",
            description="Blind spot: a person truly in the beams while the curtain reports them clear")
        if cfg.restart_interlock:
            self.reset_port = self.declare_input("reset", ctype=BOOL, default=0.0)
            self._reset_seen = self.declare_state("reset_seen", [0.0])
            self._interrupted = self.declare_channel(
                "interrupted", BOOL, False, description="Beams interrupted now (the latch aside)")

    def register_geometry(self, scene_graph) -> list:
        source = scene_graph.RegisterSource(self.module)
        beams = GeometryInstance(RigidTransform(list(self.cfg.center)), Box(*self.cfg.size), f"{self.module}/beams")
        beams.set_proximity_properties(ProximityProperties())
        beams.set_illustration_properties(MakePhongIllustrationProperties([1.0, 0.15, 0.1, 0.25]))
        self.beam_id = scene_graph.RegisterAnchoredGeometry(source, beams)
        return [self.beam_id]

    # -- in Meshcat (cellsim.visual.cues) ------------------------------------------------
    def visual_cues(self, view) -> list:
        """The beams: faint while clear, red while broken."""
        from cellsim.visual.cues import Cue, parts_of

        box = [(RigidTransform(list(self.cfg.center)), Box(*self.cfg.size))]
        channel = f"{self.module}.broken"
        looks = {
            "clear": parts_of(f"{self.module}/beams/clear", box, BEAMS_CLEAR),
            "broken": parts_of(f"{self.module}/beams/broken", box, BEAMS_BROKEN),
        }
        choose = lambda values: None if values.get(channel) is None else ("broken" if values[channel] else "clear")  # noqa: E731
        return [Cue(f"{self.module}/beams", (channel,), looks, choose, (view.geometry_path(self.beam_id),))]

    def sight(self):
        """Broken beams see whoever stands within REACH of their footprint."""
        from cellsim.visual.cues import Sight

        channel = f"{self.module}.broken"
        (x, y, _), (sx, sy, _) = self.cfg.center, self.cfg.size
        near = lambda xy: abs(xy[0] - x) <= sx / 2 + REACH and abs(xy[1] - y) <= sy / 2 + REACH  # noqa: E731
        return Sight((channel,), lambda values, xy: bool(values.get(channel)) and near(xy))

    @property
    def volumes(self) -> list:
        return [self.beam_id]

    def measure(self, context) -> bool:
        """Whether a person's body meets the beams: one broadphase query of the pairs overlapping now."""
        query = self.query_port.Eval(context)
        beam, targets = self.beam_id, self.target_set
        return any(pair.distance <= 0.0 and ((pair.id_A == beam and pair.id_B in targets)
                                             or (pair.id_B == beam and pair.id_A in targets))
                   for pair in query.ComputeSignedDistancePairwiseClosestPoints(0.0))

    def update(self, context, xd):
        view = self.consult_physical(context, xd)
        physical = view.mode is not TwinMode.MODEL and view.sample is not None
        if view.mode is TwinMode.MODEL:
            truly = broken = self.measure(context)  # the reading is the geometry: it misses nobody
        elif view.sample is None:
            broken = True  # failing safe: broken (and the truth kept for the next update's judgement)
            truly = self.query_port.HasValue(context) and self.measure(context)
        else:
            broken = view.sample[0] > 0.5
            truly = self.query_port.HasValue(context) and self.measure(context)
        if self.cfg.restart_interlock:
            write_scalar(xd, self._interrupted, 1.0 if broken else 0.0)
            broken = self._interlocked(context, xd, broken)
        write_scalar(xd, self._broken, 1.0 if broken else 0.0)
        # a blind spot: a body in the beams the reading (latched, with an interlock) never showed
        unseen = 1.0 if any(truth and not shown for truth, shown in self.held_to(
            context, xd, 1.0 if truly else 0.0, 1.0 if broken else 0.0, physical, max)) else 0.0
        if unseen != read_scalar(context, self._unseen):
            write_scalar(xd, self._unseen, unseen)

    def _interlocked(self, context, xd, beams_broken: bool) -> bool:
        """Tripped from the first break until a reset (a rising edge) while the beams are clear."""
        reset = self.reset_port.Eval(context)[0] > 0.5
        seen = read_scalar(context, self._reset_seen) > 0.5
        if reset != seen:
            write_scalar(xd, self._reset_seen, 1.0 if reset else 0.0)
        tripped = read_scalar(context, self._broken) > 0.5
        if beams_broken:
            return True
        return tripped and not (reset and not seen)
