"""The blackbox kind: its config (``config``) and :class:`~cellsim.kind.ModuleKind` (``kind``); the recorder itself is the core's (``cellsim.recorder``), which the simulation loop drains."""
