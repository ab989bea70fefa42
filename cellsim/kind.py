"""What a module kind is: the base class a kind subclasses, cellsim's own and a plug-in's alike.

A *module kind* is the unit a user extends: a typed config (a dataclass with
``kind: Literal["name"]``), the Drake system it builds into a cell's diagram, and
what the rest of cellsim needs of it (its channels and physical-twin fields, its
files, its abstraction for ``cellsim verify``). A kind lives in one folder
(cellsim's in ``cellsim/kinds/<kind>/``) and subclasses :class:`ModuleKind`::

    from cellsim.kind import ModuleKind

    class ConveyorKind(ModuleKind):
        name = "conveyor"
        section = "entities"
        config = ConveyorConfig
        summary = "A belt carrying parts from the infeed to the robot."

        def build(self, cell, name, cfg):
            return cell.add(name, Conveyor(name, cfg))

and its package's ``pyproject.toml`` names the class in the ``cellsim.modules``
entry-point group, where :mod:`cellsim.registry` finds it::

    [project.entry-points."cellsim.modules"]
    conveyor = "my_cell.conveyor:ConveyorKind"

This module imports nothing of cellsim but the foundation's channel types: a kind
depends on it, and the registry loads kinds by name, so the two never form a circle.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal

from cellsim.channels import ChannelType

Section = Literal["entities", "behaviours", "services"]
SECTIONS: tuple[Section, ...] = ("entities", "behaviours", "services")
Doc = tuple[str, str, str]
"""A documented channel or input: ``(signal, type, meaning)``."""


@dataclass(frozen=True)
class Figure:
    """A figure of a run's summary: the last value ``channel`` took, about module ``subject``."""

    subject: str
    """The module the figure is about (a process's cycles are its robot's)."""
    key: str
    """Its key in a campaign's results (``cycles_completed``)."""
    label: str
    """What the summary calls it (``work cycles completed``)."""
    channel: str
    """The channel read (``process_controller.cycles_completed``)."""


OUTRUN = ("fast part", "fast fall", "region jump")
"""The findings of a measurement outrun between two looks (a run's verdicts on it may have missed something)."""


@dataclass(frozen=True)
class Finding:
    """What a run showed that its summary and report name with times and places, read back from its black box
    by the module's kind (:meth:`ModuleKind.findings`): a contact with a person, the closest approach, a blind spot,
    a robot part faster than the harm service's looks assume, a body region jumping farther in one update than they
    can see, a true SSM margin falling faster than its monitor's watch assumes (:data:`OUTRUN`);
    and, of a live twin's run, an entity whose samples it decided on slower than its scenario assumes
    (:func:`cellsim.live.reaction.reaction_findings`)."""

    subject: str
    """The module that measured it (``harm``, ``scanner``)."""
    what: Literal["contact", "closest approach", "blind spot", "slow reaction", "fast part", "fast fall", "region jump"]
    start: float
    """When it began (s)."""
    end: float | None
    """When it ended (s); None: it lasted to the end of the run, or it is an instant."""
    text: str
    """One line for people: what, where, how hard."""
    data: dict = field(default_factory=dict)
    """Its values, for reports (SI units; ``severity``, ``region``, ``field``...)."""

    @property
    def outrun(self) -> bool:
        """Whether it is a measurement outrun between two looks (:data:`OUTRUN`): the run may have missed something."""
        return self.what in OUTRUN

    def to_json(self) -> dict:
        return {"subject": self.subject, "what": self.what, "start": self.start, "end": self.end, "text": self.text,
                **self.data}


@dataclass(frozen=True)
class Glance:
    """One line a dashboard shows of a module: ``label`` (``{name}`` is the module's name) and the value of
    its channel ``signal``, with ``unit`` (SI) when it is a number; beyond ``far`` it reads "far"."""

    panel: Literal["cell", "robot"]
    """The dashboard's panel it goes in: the cell at a glance, or the arms and the people near them."""
    label: str
    signal: str
    unit: str = ""
    far: float | None = None


@dataclass(frozen=True)
class Comparison:
    """How a dashboard sets an entity beside its physical twin: the twin's vector channel ``signal`` against
    the sample ``fields`` (SI), shown times ``scale`` in ``unit``, differing beyond ``tolerance`` (SI).
    Without one, each sample field is compared with the twin's channel of its name."""

    signal: str
    fields: tuple[str, ...]
    tolerance: float
    scale: float = 1.0
    unit: str = ""


@dataclass(frozen=True)
class Protocol:
    """An entity's physical protocol, declared by its kind from its config alone (no system built): what
    its physical twin reports, what it is told, and what it is told when its supervisor is lost.

    The bridge daemon maps these fields to DBC signals (``cellsim.bridges.config``); a test checks each
    shipped cell's protocols against the built systems' channels, inputs and safe commands."""

    samples: tuple[tuple[str, ChannelType], ...]
    """(sample field, its type), in the entity's order: enums and booleans as such, other fields numbers (SI)."""
    commands: tuple[tuple[str, ChannelType], ...] = ()
    """(command field, its type), in the entity's order."""
    safe: dict[str, object] = field(default_factory=dict)
    """The safe command, command field -> value by name (None: no request): what the physical twin is told
    when its supervisor is lost."""


class ModuleKind:
    """What a scenario's ``kind:`` means: subclass it and set the class attributes; override
    :meth:`build` (always) and :meth:`prepare`, :meth:`check` and :meth:`abstraction` as the kind needs.

    Modules are built by ``stage``, lower first, then in the order the scenario lists them:
    entities (0) before the behaviours wired to them (10), the safety controller (20), which
    reads every channel, and the recorder (30), which taps them all.
    """

    name: ClassVar[str]
    """The ``kind:`` a scenario writes."""
    section: ClassVar[Section]
    """Where a scenario lists its modules: entities, behaviours or services."""
    config: ClassVar[type]
    """Its config dataclass (with ``kind: Literal[name]``)."""
    summary: ClassVar[str]
    """One sentence for ``cellsim modules`` and the schema's docs."""
    stage: ClassVar[int] = 0
    supervises: ClassVar[bool] = False
    """A supervisor of the cell (a safety controller): a cell emulated under the twin's command
    (``cellsim emulate --commanded-by-twin``) leaves it out, the twin's supervises instead."""
    files: ClassVar[dict[str, str]] = {}
    """Config fields naming files relative to the scenario (rebased when it is exported, copied into a
    campaign's snapshot) -> what a message calls the file (``robot model``)."""
    sample_fields: ClassVar[tuple[str, ...]] = ()
    """An entity's physical-sample fields (its physical twin's state), for docs and bridges."""
    command_fields: ClassVar[tuple[str, ...]] = ()
    """An entity's command fields (what it sends its physical twin in twin mode)."""
    channels: ClassVar[tuple[Doc, ...]] = ()
    """Documented channels; a test checks them against built systems."""
    inputs: ClassVar[tuple[Doc, ...]] = ()
    """Documented inputs others drive (a safety controller's ``commands:`` as ``MODULE.input``, a process);
    a test checks them against built systems."""
    formats: ClassVar[tuple[tuple[str, str, type], ...]] = ()
    """The file formats it reads, for the schema's docs: (heading, one sentence, the file's dataclass)."""
    glance: ClassVar[tuple[Glance, ...]] = ()
    """What a dashboard shows of each module of the kind, at a glance."""
    comparison: ClassVar[Comparison | None] = None
    """How a dashboard compares an entity of the kind with its physical twin (None: field by field)."""
    default_module: ClassVar[str | None] = None
    """A module every scenario has: one of this kind under this name, with its config's defaults, is added
    to the kind's section when a scenario lists none of the kind (the harm service)."""

    def build(self, cell: Any, name: str, cfg: Any) -> Any:
        """Add the module's system to ``cell.builder`` (a :class:`cellsim.diagrams.cell.CellBuild`) and return it
        (or ``None`` when it adds nothing, e.g. a recorder not wanted)."""
        raise NotImplementedError(f"kind '{self.name}' builds nothing")

    def prepare(self, cell: Any, name: str, cfg: Any) -> None:
        """Before the plant is finalised (a robot adds its arm model to the plant)."""

    def check(self, sf: Any, name: str, cfg: Any) -> None:
        """Cross-checks at load time, without building: raise the scenario file's ConfigError (files exist,
        referenced modules exist)."""

    def protocol(self, name: str, cfg: Any) -> Protocol | None:
        """An entity's physical protocol (:class:`Protocol`), from its config; None for a module without a
        physical twin (a behaviour, a service)."""
        return None

    def figures(self, name: str, cfg: Any) -> list[Figure]:
        """The figures of a run's summary the module gives (its channels' last values): none by default."""
        return []

    def findings(self, name: str, cfg: Any, blackbox: Any) -> list[Finding]:
        """What the module's channels in a run's black box (a ``cellsim.blackbox.BlackBox``) show that the run's
        summary and report must name (contacts, blind spots): none by default."""
        return []

    def conditions(self, name: str, cfg: Any) -> dict[str, Any]:
        """The safety conditions every scenario with this module is judged by, name -> ``Described``
        (``cellsim.config.validation``): added to the scenario's own unless it waives one with a reason
        (``validation.waive``). A condition reading a channel the built cell lacks is left out. Several
        modules giving a condition of one name are judged together (each must hold)."""
        return {}

    def abstraction(self, abstract: Any, name: str, cfg: Any) -> Any:
        """What the module is in the abstract model ``cellsim verify`` checks (a
        ``cellsim.verify.model.Abstraction``), or None: a kind without one cannot be verified (``verify``
        says so and stops)."""
        return None

    def __repr__(self) -> str:
        return f"<module kind {self.name!r} ({type(self).__module__}.{type(self).__qualname__})>"
