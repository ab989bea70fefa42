"""Twin modes: what drives an entity's outputs, and what it sends to its physical twin.

Every entity is an ``EntitySystem``. Besides its digital behaviour it has

* input ``physical_sample``: the latest sample from its physical twin, a vector
  ``[timestamp (s, simulation clock), valid (0/1), *sample_fields]``. In
  simulation it is fixed to "no sample" (``cellsim.physical.no_sample``); beside
  the real cell the live twin feeds it from Zenoh (the emulator's or the bridge
  daemon's samples); tests replay a black box into it.
* output ``physical_command``: ``[active (0/1), *command_fields]``, the commands
  addressed to this entity; ``active`` is 1 only in ``twin`` mode, so a
  network bridge forwards them to the physical twin only then.
* channels ``<entity>.twin_mode`` and ``<entity>.physical_link``.

In ``model`` mode the digital behaviour drives the outputs. In ``shadow`` and
``twin`` mode the outputs follow the physical sample; when that sample is older
than ``stale_after`` or malformed, the entity *fails safe* (each entity says
what that means: a light barrier reads broken, a range detector reads close).

The mode changes at the times in the scenario's ``twin.changes`` or when a
script calls ``set_twin_mode``; every change is a message on ``twin_mode``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from cellsim.channels import enum_type
from cellsim.scenario import TwinSettings
from cellsim.systems import CellSystem, read_scalar, write_scalar
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
        self._next_change_group = self.declare_state("next_twin_change", [0.0])
        # [good samples in a row, time stamp of the last one]: trust comes back only after several
        self._recovery_group = self.declare_state("recovery", [0.0, -np.inf])
        self.physical_sample_port = self.declare_input("physical_sample", 2 + len(sample_fields))
        self._command_group = self.declare_state("physical_command", np.zeros(1 + len(command_fields)))
        self.physical_command_port = self.DeclareStateOutputPort("physical_command", self._command_group)

    # -- scripts --------------------------------------------------------------
    def set_twin_mode(self, root_context, mode: TwinMode | str) -> None:
        """Switch this entity's twin mode in a diagram's (root) context, e.g. between AdvanceTo calls."""
        mode = TwinMode(mode)
        own = self.GetMyMutableContextFromRoot(root_context)
        own.get_mutable_discrete_state(self._mode_group).SetAtIndex(0, float(mode.code))
        own.get_mutable_discrete_state(self._recovery_group).SetFromVector([0.0, -np.inf])
        if mode is not TwinMode.TWIN:  # commands go out in twin mode only
            own.get_mutable_discrete_state(self._command_group).SetZero()

    def physical_state(self, root_context) -> list[float]:
        """What this entity's physical twin would report now: its sample fields as port codes.

        The emulator publishes this for a digital model playing the physical twin.
        By default each field is the channel of that name; an entity whose fields
        are not channels (joint angles, a person's pose) says otherwise.
        """
        own = self.GetMyContextFromRoot(root_context)
        return [read_scalar(own, self.group(name)) for name in self.sample_fields]

    def twin_mode(self, root_context) -> TwinMode:
        return _MODES[int(read_scalar(self.GetMyContextFromRoot(root_context), self._mode_group))]

    # -- update helpers ---------------------------------------------------------
    def consult_physical(self, context, xd) -> PhysicalView:
        """Apply scheduled mode changes and judge the physical sample; writes mode and link."""
        mode_code = read_scalar(context, self._mode_group)
        changes = self.twin.changes
        if mode_code == 0.0 and not changes:  # model mode for good: the common case, kept cheap
            return _MODEL_VIEW
        t = context.get_time()
        mode = _MODES[int(mode_code)]
        if changes:
            nxt = start = int(read_scalar(context, self._next_change_group))
            while nxt < len(changes) and changes[nxt].at <= t + 1e-9:
                mode = changes[nxt].mode
                nxt += 1
            if nxt != start:
                write_scalar(xd, self._next_change_group, nxt)
                write_scalar(xd, self._mode_group, mode.code)
                xd.get_mutable_vector(self._recovery_group).SetFromVector([0.0, -np.inf])
                if mode is not TwinMode.TWIN:  # commands go out in twin mode only
                    xd.get_mutable_vector(self._command_group).SetZero()
        if mode is TwinMode.MODEL:
            link, sample = PhysicalLink.UNUSED, None
        else:
            raw = self.physical_sample_port.Eval(context)
            link, sample = self._judge(raw, t)
            link, sample = self._recover(context, xd, raw[0], link, sample)
        if link.code != read_scalar(context, self._link_group):
            write_scalar(xd, self._link_group, link.code)
        return PhysicalView(mode, link, sample)

    def _recover(self, context, xd, stamp: float, link: PhysicalLink, sample):
        """Trust a good sample only once ``recover_after`` good ones came in a row."""
        good, last = context.get_discrete_state(self._recovery_group).get_value()
        needed = self.twin.recover_after
        if link is PhysicalLink.OK:
            if stamp != last:
                good, last = min(good + 1.0, float(needed)), stamp
            if good < needed:
                link, sample = PhysicalLink.RECOVERING, None
        else:
            good = 0.0
        if [good, last] != context.get_discrete_state(self._recovery_group).get_value().tolist():
            xd.get_mutable_vector(self._recovery_group).SetFromVector([good, last])
        return link, sample

    def _judge(self, raw: np.ndarray, t: float) -> tuple[PhysicalLink, np.ndarray | None]:
        stamp, valid = raw[0], raw[1]
        if not valid > 0.5 or not math.isfinite(stamp) or t - stamp > self.twin.stale_after:
            return PhysicalLink.STALE, None
        sample = raw[2:]
        if not np.all(np.isfinite(sample)) or not self.sample_is_valid(sample):
            return PhysicalLink.CORRUPT, None
        return PhysicalLink.OK, sample

    def sample_is_valid(self, sample: np.ndarray) -> bool:
        """Entity-specific check of a finite sample (enum codes in range...)."""
        return True

    def write_command(self, xd, mode: TwinMode, values: Callable[[], tuple]) -> None:
        """Publish the commands addressed to this entity (``values()``) in twin mode.

        Outside twin mode the command output is all zeros (inactive): leaving twin
        mode, by schedule or ``set_twin_mode``, clears it.
        """
        if mode is TwinMode.TWIN:
            xd.get_mutable_vector(self._command_group).SetFromVector(np.array([1.0, *values()], float))


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
