"""The ssm kind: its config (``config``), system (``system``) and :class:`~cellsim.registry.ModuleKind` (``kind``)."""
