"""The machine kind: a machine with activities, supported safety modes and, optionally, a cycle."""

from __future__ import annotations

from cellsim.entity import TWIN_CHANNELS
from cellsim.kinds.machine.config import MachineConfig
from cellsim.kinds.machine.system import Machine
from cellsim.channels import enum_type, number_type
from cellsim.kind import ModuleKind, Protocol
from cellsim.vocabulary import SafetyMode, value_set


class MachineKind(ModuleKind):
    name = "machine"
    section = "entities"
    config = MachineConfig
    summary = "A machine with named activities and supported safety modes, working while commanded or for a cycle."
    sample_fields = ("safety_mode", "activity")
    command_fields = ("safety_mode_request", "activity_request", "command")
    channels = (
        ("safety_mode", "enum", "its safety mode; unknown when shadowing with no valid sample"),
        ("activity", "enum", "one of its activities; its working one when shadowing with no valid sample"),
        ("cycles_completed", "number", "only with a cycle_time: cycles finished"),
        ("busy", "bool", "only with a cycle_time: a cycle is under way (paused included); false again once it ends or is abandoned"),
        *TWIN_CHANNELS,
    )
    inputs = (
        ("safety_mode_request", "enum", "the safety mode a safety controller requests"),
        ("activity_request", "enum", "an activity a safety controller requests (e.g. its off one), or none"),
        ("command", "number", "1 while its process starts (with a cycle_time) or operates it"),
    )

    def protocol(self, name, cfg):
        modes, activities = enum_type(SafetyMode), enum_type(value_set(f"{name}_activity", cfg.activities))
        return Protocol(
            (("safety_mode", modes), ("activity", activities)),
            (("safety_mode_request", modes), ("activity_request", activities), ("command", number_type(None))),
            # its supervisor lost: stopped, its off activity requested, no work commanded
            {"safety_mode_request": SafetyMode.STOPPED.value, "activity_request": cfg.off, "command": 0.0},
        )

    def build(self, cell, name, cfg):
        return cell.add(name, Machine(name, cfg))

    def abstraction(self, abstract, name, cfg):
        from cellsim.kinds.machine.abstraction import MachineAbstraction

        return MachineAbstraction(abstract, name, cfg)
