"""The blackbox kind: its config (``config``) and :class:`~cellsim.registry.ModuleKind` (``kind``); the recorder itself is the core's (``cellsim.recorder``), which the simulation loop drains."""
