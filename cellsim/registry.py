"""Module kinds: the library a scenario's ``kind:`` names.

A *module kind* is the unit a user extends: a typed config (a dataclass with
``kind: Literal["name"]``), the Drake system it builds into a cell's diagram, and
what the rest of cellsim needs of it (its channels and physical-twin fields, its
files, its abstraction for ``cellsim verify``). cellsim's own kinds and a user's
are found the same way, the way python-can finds its interfaces: through the
``cellsim.modules`` entry-point group. A kind lives in one folder (cellsim's in
``cellsim/kinds/<kind>/``) and subclasses :class:`ModuleKind`::

    class ConveyorKind(ModuleKind):
        name = "conveyor"
        section = "entities"
        config = ConveyorConfig
        summary = "A belt carrying parts from the infeed to the robot."

        def build(self, cell, name, cfg):
            return cell.add(name, Conveyor(name, cfg))

and its package's ``pyproject.toml`` names the class::

    [project.entry-points."cellsim.modules"]
    conveyor = "my_cell.conveyor:ConveyorKind"

Scenarios can then use ``kind: conveyor`` with no change to cellsim. The core names
no concrete kind: the scenario schema asks the registry which config a ``kind:``
means, ``build_cell`` asks each module's kind to build it, ``verify`` asks it for
its abstraction.

Kinds are loaded lazily, one entry point at a time, so a plug-in that fails to
import only fails the scenarios that use it (with one line naming the plug-in).
"""

from __future__ import annotations

import functools
import importlib.metadata
from typing import Any, ClassVar, Literal

ENTRY_POINT_GROUP = "cellsim.modules"
Section = Literal["entities", "behaviours", "services"]
SECTIONS: tuple[Section, ...] = ("entities", "behaviours", "services")
Doc = tuple[str, str, str]
"""A documented channel or input: ``(signal, type, meaning)``."""


class KindError(LookupError):
    """An unknown kind, or a plug-in that cannot provide its kind (the message is one line)."""


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

    def build(self, cell: Any, name: str, cfg: Any) -> Any:
        """Add the module's system to ``cell.builder`` (a :class:`cellsim.diagrams.cell.CellBuild`) and return it
        (or ``None`` when it adds nothing, e.g. a recorder not wanted)."""
        raise NotImplementedError(f"kind '{self.name}' builds nothing")

    def prepare(self, cell: Any, name: str, cfg: Any) -> None:
        """Before the plant is finalised (a robot adds its arm model to the plant)."""

    def check(self, sf: Any, name: str, cfg: Any) -> None:
        """Cross-checks at load time, without building: raise the scenario file's ConfigError (files exist,
        referenced modules exist)."""

    def abstraction(self, abstract: Any, name: str, cfg: Any) -> Any:
        """What the module is in the abstract model ``cellsim verify`` checks (a
        ``cellsim.verify.model.Abstraction``), or None: a kind without one cannot be verified (``verify``
        says so and stops)."""
        return None

    def __repr__(self) -> str:
        return f"<module kind {self.name!r} ({type(self).__module__}.{type(self).__qualname__})>"


@functools.cache
def _entry_points() -> dict[str, list[importlib.metadata.EntryPoint]]:
    found: dict[str, list] = {}
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        found.setdefault(ep.name, []).append(ep)
    return found


_loaded: dict[str, ModuleKind] = {}


def kind_names(section: Section | None = None) -> list[str]:
    """Every kind's name (of one section: this loads each kind to learn its section)."""
    names = sorted(_entry_points())
    if section is None:
        return names
    out = []
    for name in names:
        try:
            if get(name).section == section:
                out.append(name)
        except KindError:
            continue  # a broken plug-in is reported where a scenario uses it
    return out


def get(name: str) -> ModuleKind:
    """The kind called ``name``; KindError if there is none or its plug-in is broken."""
    kind = _loaded.get(name)
    if kind is not None:
        return kind
    eps = _entry_points().get(name)
    if not eps:
        raise KindError(f"unknown kind '{name}'")
    distinct = {ep.value for ep in eps}
    if len(distinct) > 1:
        raise KindError(f"kind '{name}' is provided twice: by {' and by '.join(sorted(distinct))}")
    ep = eps[0]
    try:
        loaded = ep.load()
        kind = loaded() if isinstance(loaded, type) and issubclass(loaded, ModuleKind) else loaded
    except Exception as e:  # noqa: BLE001 - any failure of a plug-in's import is that plug-in's
        raise KindError(f"kind '{name}' comes from {ep.value}, which failed to load: {type(e).__name__}: {_one_line(e)}") from None
    if not isinstance(kind, ModuleKind):
        raise KindError(f"kind '{name}': {ep.value} is a {type(kind).__name__}, not a subclass of "
                        "cellsim.registry.ModuleKind")
    if kind.name != name:
        raise KindError(f"kind '{name}': {ep.value} declares the kind '{kind.name}'")
    _loaded[name] = kind
    return kind


def kind_of(config: Any) -> ModuleKind:
    """The kind of a module's config object."""
    return get(config.kind)


def _one_line(error: Exception) -> str:
    return " ".join(str(error).split())[:300]


class ModuleConfig:
    """Type marker for :mod:`cellsim.config.typed_yaml`: a module config chosen by its ``kind``.

    ``dict[str, EntityModule]`` in a schema means "each value is the config of
    whichever entity kind its ``kind:`` key names".
    """

    section: Section

    @classmethod
    def __kind_names__(cls) -> list[str]:
        return kind_names(cls.section)

    @classmethod
    def __kind_config__(cls, name: str) -> type:
        kind = get(name)
        if kind.section != cls.section:
            raise KindError(f"kind '{name}' is one of the {kind.section}, not of the {cls.section}")
        return kind.config


class EntityModule(ModuleConfig):
    section = "entities"


class BehaviourModule(ModuleConfig):
    section = "behaviours"


class ServiceModule(ModuleConfig):
    section = "services"
