"""The registry of module kinds: which kind a scenario's ``kind:`` names.

cellsim's own kinds and a user's are found the same way, the way python-can finds
its interfaces: through the ``cellsim.modules`` entry-point group, each naming a
subclass of :class:`cellsim.kind.ModuleKind`. Scenarios can then use a plug-in's
``kind:`` with no change to cellsim. The core names no concrete kind: the
scenario schema asks the registry which config a ``kind:`` means, ``build_cell``
asks each module's kind to build it, ``verify`` asks it for its abstraction.

Kinds are loaded lazily, one entry point at a time, so a plug-in that fails to
import only fails the scenarios that use it (with one line naming the plug-in).
"""

from __future__ import annotations

import contextlib
import functools
import importlib.metadata
from typing import Any

from cellsim.kind import SECTIONS, ModuleKind, Section

ENTRY_POINT_GROUP = "cellsim.modules"
__all__ = ["ENTRY_POINT_GROUP", "SECTIONS", "KindError", "ModuleKind", "get", "kind_names", "kind_of"]


class KindError(LookupError):
    """An unknown kind, or a plug-in that cannot provide its kind (the message is one line)."""


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
                        "cellsim.kind.ModuleKind")
    if kind.name != name:
        raise KindError(f"kind '{name}': {ep.value} declares the kind '{kind.name}'")
    why = _malformed(kind)
    if why is not None:
        raise KindError(f"kind '{name}' from {ep.value} is not a usable kind: {why}")
    _loaded[name] = kind
    return kind


def _malformed(kind: ModuleKind) -> str | None:
    """What a loaded kind lacks of what the core asks of every kind (its section, a dataclass config, a default module
    whose config needs nothing the scenario did not write), or None."""
    import dataclasses

    section = getattr(kind, "section", None)
    if section not in SECTIONS:
        return f"its section is {section!r}, not one of {', '.join(SECTIONS)}"
    config = getattr(kind, "config", None)
    if not (isinstance(config, type) and dataclasses.is_dataclass(config)):
        return f"its config is {config!r}, not a dataclass"
    if getattr(kind, "default_module", None):
        try:
            config(kind=kind.name)
        except Exception as e:  # noqa: BLE001 - the plug-in's to mend
            return (f"it adds the module '{kind.default_module}' to every scenario, but its config cannot be made "
                    f"from defaults ({type(e).__name__}: {_one_line(e)})")
    return None


@contextlib.contextmanager
def plugin_failures(kind: ModuleKind, sf, key: str, what: str):
    """Within the block a plug-in's kind does ``what`` (prepare, check, build) for the module at ``key``
    (``section.name``) of the scenario file ``sf``: the scenario errors it raises on purpose (ConfigError, naming their
    key) go on as they are; any other failure becomes ``sf.error(key, ...)``, one line naming the kind and the
    plug-in. cellsim's own kinds are not wrapped: their failures are cellsim's bugs, shown whole."""
    from cellsim.config.typed_yaml import ConfigError

    if type(kind).__module__.split(".")[0] == "cellsim":
        yield
        return
    try:
        yield
    except ConfigError:
        raise
    except Exception as e:  # noqa: BLE001 - a plug-in's failure is that plug-in's, said in one line
        raise sf.error(key, f"the kind '{kind.name}' (plug-in {type(kind).__module__}) failed to {what} module "
                            f"'{key.split('.', 1)[1]}': {type(e).__name__}: {_one_line(e)}") from None


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
