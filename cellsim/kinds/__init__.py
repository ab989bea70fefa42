"""cellsim's own module kinds, one folder each: its config, its system, its abstraction for ``cellsim verify``,
and its :class:`~cellsim.kind.ModuleKind` (``kind.py``), which the ``cellsim.modules`` entry points name.

A plug-in kind is written the same way, in a package of its own (docs/architecture.md)."""
