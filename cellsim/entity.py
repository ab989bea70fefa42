"""Twin modes: what drives an entity's outputs, and what it sends to its physical twin.

Every entity is an ``EntitySystem``. Besides its digital behaviour it has

* input ``physical_sample``: the newest sample from its physical twin, a vector
  ``[t (s, simulation clock), link (PhysicalLink code), *sample_fields]``, as its
  source judged it (``cellsim.link``: freshness, order, recover-after). The
  builder (``cellsim.diagrams.cell``) decides the source: none in simulation (the input
  reads stale), a black box replayed, or Zenoh beside the real cell.
* input ``twin_mode_request``: ``[serial, TwinMode code]``; the entity switches
  mode at its next update after the serial changes (the live twin's mode control).
* output ``physical_command``: ``[active (0/1), *command_fields]``, the commands
  addressed to this entity, as its supervisors drive its inputs of those names
  now (direct feedthrough: a command goes out the step its supervisor decides
  it, not after this entity's next update, whose period would only add delay);
  ``active`` is 1 only in ``twin`` mode, so a network bridge forwards them to the
  physical twin only then.
* output ``physical_state``: what this entity's physical twin would report now
  (its sample fields as port codes): the emulator publishes it.
* channels ``<entity>.twin_mode`` and ``<entity>.physical_link``.

In a live twin an entity updated less often than the cell's fastest controller
*takes each sample on arrival* (:meth:`EntitySystem.take_samples_on_arrival`): in
shadow and twin mode it also updates at each of that controller's periods when a
new sample (or a change of its link) has come, not only at its own period, which
would only add up to that period of delay between the physical sensor and its
supervisor.

In ``model`` mode the digital behaviour drives the outputs. In ``shadow`` and
``twin`` mode they follow the physical sample; when the link is not ok (stale,
corrupt, recovering) or the sample is malformed, the entity *fails safe* (each
kind says what that means, once: a light barrier reads broken, a range detector
reads close). What the entity's physical twin is told when its supervisor is
lost is the kind's ``safe_command``, used by every party that fails safe on its
behalf (the emulator's command sources, the bridge daemon).

The mode changes at the times in the scenario's ``twin.changes``, on a request
at ``twin_mode_request``, or when a script calls ``set_twin_mode``; every change
is a message on ``twin_mode``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cellsim.channels import NO_VALUE, enum_type
from cellsim.config.twin import TwinSettings
from cellsim.systems import UNCHANGED, CellSystem, read_scalar, write_scalar
from cellsim.vocabulary import PhysicalLink, TwinMode

_MODES = tuple(TwinMode)


@dataclass(frozen=True)
class PhysicalView:
    """The outcome of consulting the physical twin in one update."""

    mode: TwinMode
    link: PhysicalLink
    sample: np.ndarray | None  # the sample fields when link is OK, else None

    @property
    def follows_physical(self) -> bool:
        return self.mode is not TwinMode.MODEL


class EntitySystem(CellSystem):
    """A cell entity with a digital behaviour and a link to a physical twin."""

    def __init__(
        self,
        module: str,
        period: float,
        twin: TwinSettings,
        sample_fields: tuple[str, ...],
        command_fields: tuple[str, ...] = (),
    ):
        super().__init__(module, period)
        self.twin = twin
        self.sample_fields = sample_fields
        self.command_fields = command_fields
        self._mode_group = self.declare_channel(
            "twin_mode", enum_type(TwinMode), twin.mode, description="How this entity relates to its physical twin"
        )
        self._link_group = self.declare_channel(
            "physical_link",
            enum_type(PhysicalLink),
            PhysicalLink.UNUSED,
            description="Freshness and validity of the physical twin's samples",
        )
        # [index of the next scheduled change, serial of the last mode request applied]
        self._next_change_group = self.declare_state("next_twin_change", [0.0, 0.0])
        self.physical_sample_port = self.declare_input("physical_sample", 2 + len(sample_fields))
        self.mode_request_input = self.declare_input("twin_mode_request", 2)
        self.takes_mode_requests = False
        """Set by the builder when something drives ``twin_mode_request`` (a live twin)."""
        self._command_ports = None  # its inputs of the command fields' names, looked up once the kind declared them
        self.physical_command_port = self.DeclareVectorOutputPort("physical_command", 1 + len(command_fields),
                                                                  self._calc_command)
        self.physical_state_port = self.DeclareVectorOutputPort(
            "physical_state", len(sample_fields), lambda context, out: out.SetFromVector(self.physical_state(context))
        )

    # -- what the kind declares ------------------------------------------------------
    takes_samples_on_arrival: bool = True
    """Whether the live twin may update this entity when a sample arrives (:meth:`take_samples_on_arrival`); a
    kind whose outputs in shadow mode mean something over its own period (a person's motion, which the harm
    service reads as motion over one update period) says False."""

    def safe_command(self) -> dict[str, float]:
        """The command codes this entity's physical twin gets when its supervisor is lost.

        By default a safety-mode request is ``stopped`` and every other command its
        no-request default; a kind with a safer choice says so (a machine: its off
        activity). The one declaration every party uses that fails safe on the
        entity's behalf: the emulator's command sources and the bridge daemon.
        """
        from cellsim.vocabulary import SafetyMode

        safe = {}
        for name in self.command_fields:
            ctype = self.input_types.get(name)
            if ctype is not None and ctype.kind == "enum" and ctype.enum is SafetyMode:
                safe[name] = float(SafetyMode.STOPPED.code)
            else:
                safe[name] = float(self.input_defaults.get(name, NO_VALUE))
        return safe

    def physical_state(self, context) -> list[float]:
        """What this entity's physical twin would report now: its sample fields as port codes
        (``context``: this system's own).

        The emulator publishes this for a digital model playing the physical twin.
        By default each field is the channel of that name; an entity whose fields
        are not channels (joint angles, a person's pose) says otherwise.
        """
        return [read_scalar(context, self.group(name)) for name in self.sample_fields]

    def recorded_as(self, field: str) -> tuple[str, int]:
        """The channel (and element of its vector) a black box records sample field ``field`` on:
        by default the channel of that name (a black box replayed as the physical twin)."""
        return f"{self.module}.{field}", 0

    # -- the live twin ----------------------------------------------------------
    def take_samples_on_arrival(self, every: float, time_step: float) -> bool:
        """Also update every ``every`` seconds (the period of the cell's fastest controller) in shadow and twin
        mode, when a new physical sample (or a change of its link) came since the last look.

        Called by the live twin's builder, before the recorder is built. The looks fall on the same grid as
        every entity's updates (offset 0), so every reading changes at the same instants; the controllers decide
        one plant step later (``CellSystem.decide_after``) on the readings of their period: the record holds no
        reading they could not act on, and no conjunction of two readings they could not see. The entity's channels can
        then change at multiples of the common divisor of its period and ``every``, which becomes their
        period (the recorder looks at them that often). Returns whether it was set: not for a kind that says it
        must not (``takes_samples_on_arrival``), nor for an entity updated that often already.
        """
        import math
        from dataclasses import replace

        if not self.takes_samples_on_arrival or self.period <= every * (1 + 1e-9):
            return False
        self._taken_group = self.declare_state("taken_sample", [-np.inf, np.nan])
        self._own_period = self.period
        self.DeclarePeriodicDiscreteUpdateEvent(every, 0.0, self._on_arrival)
        steps = math.gcd(max(1, round(self.period / time_step)), max(1, round(every / time_step)))
        self.channels = [(replace(spec, period=steps * time_step), port) for spec, port in self.channels]
        return True

    def _on_arrival(self, context, xd):
        """A look at the physical sample: the kind's update when one arrived (or the link changed) since the last
        look, in shadow and twin mode; at the entity's own period its update does it."""
        if read_scalar(context, self._mode_group) == TwinMode.MODEL.code:
            return UNCHANGED
        raw = self.physical_sample_port.Eval(context)
        taken = context.get_discrete_state(self._taken_group).get_value()
        if raw[0] == taken[0] and raw[1] == taken[1]:
            return UNCHANGED
        xd.get_mutable_vector(self._taken_group).SetFromVector(raw[:2])
        t = context.get_time()
        if abs(t / self._own_period - round(t / self._own_period)) > 1e-6:  # else its periodic update runs now
            self.update(context, xd)
        return None  # the sample taken is written, whatever the update did

    # -- scripts --------------------------------------------------------------
    def set_twin_mode(self, root_context, mode: TwinMode | str) -> None:
        """Switch this entity's twin mode in a diagram's (root) context, e.g. between AdvanceTo calls."""
        mode = TwinMode(mode)
        own = self.GetMyMutableContextFromRoot(root_context)
        own.get_mutable_discrete_state(self._mode_group).SetAtIndex(0, float(mode.code))

    def twin_mode(self, root_context) -> TwinMode:
        return _MODES[int(read_scalar(self.GetMyContextFromRoot(root_context), self._mode_group))]

    # -- update helpers ---------------------------------------------------------
    def consult_physical(self, context, xd) -> PhysicalView:
        """Apply scheduled and requested mode changes and read the physical sample; writes mode and link."""
        mode_code = read_scalar(context, self._mode_group)
        changes = self.twin.changes
        if mode_code == 0.0 and not changes and not self.takes_mode_requests:  # model mode for good: kept cheap
            return _MODEL_VIEW
        t = context.get_time()
        mode = _MODES[int(mode_code)]
        before = context.get_discrete_state(self._next_change_group).get_value().tolist()
        nxt, seen = int(before[0]), before[1]
        while changes and nxt < len(changes) and changes[nxt].at <= t + 1e-9:
            mode = changes[nxt].mode
            nxt += 1
        if self.takes_mode_requests:
            serial, requested = self.mode_request_input.Eval(context)
            if serial != seen:
                mode, seen = _MODES[int(requested)], serial
        if [nxt, seen] != before:
            xd.get_mutable_vector(self._next_change_group).SetFromVector([nxt, seen])
        if mode.code != mode_code:
            write_scalar(xd, self._mode_group, mode.code)
        if mode is TwinMode.MODEL:
            link, sample = PhysicalLink.UNUSED, None
        else:
            link, sample = self._read(self.physical_sample_port.Eval(context))
        if link.code != read_scalar(context, self._link_group):
            write_scalar(xd, self._link_group, link.code)
        return PhysicalView(mode, link, sample)

    def _read(self, raw: np.ndarray) -> tuple[PhysicalLink, np.ndarray | None]:
        """The link its source judged, and the sample when the link is ok and the sample well formed."""
        code = raw[1]
        if not valid_code(code, PhysicalLink) or code == PhysicalLink.UNUSED.code:
            return PhysicalLink.CORRUPT, None
        link = PhysicalLink.from_code(code)
        if link is not PhysicalLink.OK:
            return link, None
        sample = raw[2:]
        if not np.all(np.isfinite(sample)) or not self.sample_is_valid(sample):
            return PhysicalLink.CORRUPT, None
        return PhysicalLink.OK, sample

    def sample_is_valid(self, sample: np.ndarray) -> bool:
        """Entity-specific check of a finite sample (enum codes in range...)."""
        return True

    def _calc_command(self, context, out) -> None:
        """``physical_command``: in twin mode [1, the inputs of the command fields' names]; else all zeros
        (leaving twin mode, by schedule, request or ``set_twin_mode``, silences it at once)."""
        if read_scalar(context, self._mode_group) != TwinMode.TWIN.code:
            out.SetZero()
            return
        if self._command_ports is None:
            self._command_ports = [(name, self.GetInputPort(name)) for name in self.command_fields]
        out.SetFromVector(np.array([1.0, *(self.command_value(name, port.Eval(context)[0])
                                          for name, port in self._command_ports)], float))

    def command_value(self, name: str, value: float) -> float:
        """The code sent to the physical twin for command field ``name`` when its input reads ``value``: by
        default the input itself; a kind whose input's default every protocol cannot carry (an unlimited speed)
        says what it sends instead."""
        return value

TWIN_CHANNELS = (
    ("twin_mode", "enum", "model / shadow / twin"),
    ("physical_link", "enum", "unused / ok / stale / corrupt / recovering"),
)
"""The channels every entity publishes about its physical twin, as ``cellsim modules`` documents them."""

_MODEL_VIEW = PhysicalView(TwinMode.MODEL, PhysicalLink.UNUSED, None)


def valid_code(value: float, enum) -> bool:
    """Whether a float carries a valid code of a CodedEnum."""
    try:
        enum.from_code(value)
    except ValueError:
        return False
    return True
