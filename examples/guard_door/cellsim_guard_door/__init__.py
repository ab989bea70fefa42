"""cellsim-guard-door: an interlocked guard door as a cellsim module kind (``kind: guard_door``)."""
