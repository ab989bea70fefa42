"""The light_barrier kind: its config (``config``), system (``system``), abstraction for verify (``abstraction``) and :class:`~cellsim.kind.ModuleKind` (``kind``)."""
