"""The value sets of the signals exchanged in a cell.

These are the channel data types of the interface between the safety controller
and the cell (paper, Table 1), plus the hazard phases, twin modes and operator
locations. Each is an ``enum.Enum`` whose *value* is the short name used by the
published case study (``pflim``, ``sharedTbl``, ...): that is what scenario and
risk-model files, black boxes and safety conditions spell.

On Drake ports an enum travels as its integer code (its position in the
declaration), in a one-element vector; ``code()`` and ``from_code()`` convert.
"""

from __future__ import annotations

import enum
from functools import cache


class CodedEnum(enum.Enum):
    """An enum carried on a Drake vector port as a float-valued integer code."""

    @classmethod
    @cache
    def _members(cls) -> tuple:
        return tuple(cls)

    @property
    def code(self) -> int:
        return self._members().index(self)

    @classmethod
    def from_code(cls, code: float):
        """The member for ``code``; ValueError for a code outside the enum (corrupt data)."""
        index = int(code)
        members = cls._members()
        if index != code or not 0 <= index < len(members):
            raise ValueError(f"{code!r} is not a code of {cls.__name__}")
        return members[index]

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(m.value for m in cls._members())


def value_set(name: str, values) -> type[CodedEnum]:
    """A CodedEnum of the names a scenario declares (a cell's places, activities, phases, steps).

    Members get positional names, so any value works (``mro``, ``_x_``, ``name``);
    every lookup is by value. Values must differ: ValueError names the first repeated.
    """
    values = list(values)
    seen: set[str] = set()
    for value in values:
        if value in seen:
            raise ValueError(f"'{value}' is listed twice")
        seen.add(value)
    return CodedEnum(name, [(f"V{i}", v) for i, v in enumerate(values)])


class SafetyMode(CodedEnum):
    """Safety mode of a machine, from the most permissive to the most restrictive."""

    NORMAL = "normal"  # full speed
    HAND_GUIDED = "hguid"  # hand-guided operation
    SPEED_SEPARATION = "ssmon"  # speed and separation monitoring (reduced speed)
    POWER_FORCE_LIMITING = "pflim"  # collaborative speed, at most 0.25 m/s at the tool
    MONITORED_STOP = "srmst"  # safety-rated monitored stop: standstill, powered
    STOPPED = "stopped"  # protective stop
    UNKNOWN = "unknown"  # a shadowed machine with no valid physical sample: assume the worst


class Range(CodedEnum):
    """Range detector reading, from the operator's distance to the sensor."""

    FAR = "far"
    NEAR = "near"
    CLOSE = "close"


class HazardPhase(CodedEnum):
    INACTIVE = "inact"  # not present
    ACTIVE = "act"  # detected, not yet handled
    MITIGATED = "mit"  # mitigation applied
    MITIGATED_1 = "mit1"  # intermediate mitigation steps of the published controller
    MITIGATED_2 = "mit2"
    RESUMING = "res"  # mitigation being lifted
    MISHAP = "mis"  # harm happened


class TwinMode(CodedEnum):
    """How an entity relates to its physical twin (paper, section 4.1.1)."""

    MODEL = "model"  # digital model: its digital behaviour drives its outputs
    SHADOW = "shadow"  # digital shadow: outputs follow the physical twin, nothing is sent
    TWIN = "twin"  # digital twin: as shadow, and commands go out to the physical twin


class PhysicalLink(CodedEnum):
    """State of an entity's link to its physical twin, as the entity sees it."""

    UNUSED = "unused"  # model mode: the physical twin is not consulted
    OK = "ok"  # a fresh, well-formed sample drives the entity
    STALE = "stale"  # no sample within the entity's stale_after: failing safe
    CORRUPT = "corrupt"  # the latest sample is malformed: failing safe
    RECOVERING = "recovering"  # good samples again, not yet recover_after in a row: still failing safe


PERMISSIVE_MODES = frozenset(
    {
        SafetyMode.NORMAL,
        SafetyMode.HAND_GUIDED,
        SafetyMode.SPEED_SEPARATION,
        SafetyMode.POWER_FORCE_LIMITING,
    }
)
