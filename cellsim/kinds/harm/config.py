"""The harm kind's configuration: the limits table, how near a pair must be to be measured, clamping."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

from cellsim.config.typed_yaml import FieldError, Range


@dataclass
class HarmConfig:
    """The harm service: contact between the robots and each person's body regions, judged against a
    biomechanical limits table. Every cell with a robot and a person has one (named ``harm``) unless the
    scenario lists its own."""

    kind: Literal["harm"]
    limits: str | None = None
    """A biomechanical limits table (YAML, relative to the scenario; see docs/harm.md); null: cellsim's
    own, the values of ISO/TS 15066 Annex A as published."""
    cutoff: Annotated[float, Range(0.01, 5.0, unit="m")] = 0.5
    """Pairs of a robot part and a body region farther apart than this (m) cost nothing; the separation
    channels read it while nothing is nearer."""
    clamp_gap: Annotated[float, Range(0.0, 0.2, unit="m")] = 0.02
    """A region touched by the robot is pinned (the contact is quasi-static, clamping) when a fixture,
    another robot or another part of the arm is this near (m) on the far side of it."""
    clamp_angle_deg: Annotated[float, Range(0.0, 90.0, unit="deg")] = 60.0
    """How far (degrees) from straight behind the region, seen along the robot's push, that surface may lie."""
    far_period: Annotated[float, Range(0.0001, 0.1, unit="s")] = 0.04
    """While no robot part is within ``cutoff`` of anybody, how often that is checked (s); once one is, contact is
    measured at every plant step. A person's body moves only at their updates, each followed by a look one plant step
    later, so between two looks only the robots move: nothing closes the cut-off between them faster than
    cutoff / far_period (12.5 m/s by default), a load error unless that is at least ``max_part_speed``."""
    max_part_speed: Annotated[float, Range(0.1, 50.0, unit="m/s")] = 5.0
    """The fastest any point of a robot part is taken to move between two looks (m/s). Measured at each look (the
    plant's body velocities): a part faster than half of it switches the plant-step measuring on; one found faster
    than it at the end of an interval watched only at the looks is a finding of the run (a contact in it may have been
    missed)."""

    def __post_init__(self):
        if self.cutoff / self.far_period < self.max_part_speed:
            raise FieldError("far_period", f"a robot part could close the cut-off ({self.cutoff:g} m) between two "
                             f"checks {self.far_period:g} s apart at {self.cutoff / self.far_period:.3g} m/s, below "
                             f"max_part_speed ({self.max_part_speed:g} m/s): shorten far_period or widen cutoff")
