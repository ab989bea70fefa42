"""The guard_door kind: what cellsim needs of it, found through the ``cellsim.modules`` entry point."""

from __future__ import annotations

from cellsim.channels import BOOL
from cellsim.entity import TWIN_CHANNELS
from cellsim.kind import ModuleKind, Protocol
from cellsim.kinds.sensing import add_sensor

from cellsim_guard_door.config import GuardDoorConfig
from cellsim_guard_door.system import GuardDoor


class GuardDoorKind(ModuleKind):
    name = "guard_door"
    section = "entities"
    config = GuardDoorConfig
    summary = ("An interlocked guard door in a fence: open while a person's geometry is in its doorway; "
               "fails safe to open.")
    sample_fields = ("open",)
    """Its physical twin's state: the interlock switch (a bridge maps it to one CAN signal)."""
    channels = (
        ("open", "bool", "true while any person's geometry is in the doorway (the door switch reads open)"),
        *TWIN_CHANNELS,
    )

    def protocol(self, name, cfg):
        """What its physical twin reports: the interlock switch, one boolean (no commands)."""
        return Protocol((("open", BOOL),))

    def build(self, cell, name, cfg):
        return add_sensor(cell, name, GuardDoor(name, cfg))

    def abstraction(self, abstract, name, cfg):
        from cellsim_guard_door.abstraction import GuardDoorAbstraction

        return GuardDoorAbstraction(abstract, name, cfg)
