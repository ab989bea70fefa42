"""Named channels: the typed messages modules publish.

In the paper's framework, modules talk over publish-subscribe channels. Here the
wiring is a Drake Diagram's ports, and a *channel* is an output port that carries
one typed signal of the cell, named ``<module>.<signal>`` (``robot.safety_mode``,
``light_barrier.broken``). A message is published on a channel whenever the
publishing module's periodic update changes it (or, for sampled quantities, at
every update); the black-box recorder taps every channel and stores each message
with the simulated time, the channel, the source module and a JSON payload.

On its port, every channel is a float vector: an enum is its integer code, a
boolean is 0 or 1, a number is in SI units (see ``ChannelType.unit``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from cellsim.logic.syntax import BoolDomain, EnumDomain, NumberDomain
from cellsim.numbers import sig3
from cellsim.vocabulary import CodedEnum

Kind = Literal["enum", "bool", "number", "vector"]
NO_VALUE = -1.0
"""The code of "no value" on an optional channel (e.g. no activity request)."""
RecordPolicy = Literal["on_change", "every_sample"]


@dataclass(frozen=True)
class ChannelType:
    """What a channel carries and how its port vector reads as a message payload."""

    kind: Kind
    enum: type[CodedEnum] | None = None
    size: int = 1
    unit: str | None = None
    optional: bool = False
    """Code -1 means "no value" (a command that is not requested); its payload is null."""

    def decode(self, vector: np.ndarray):
        """The payload value (JSON-ready) of a port vector of this type."""
        if self.optional and vector[0] == NO_VALUE:
            return None
        if self.kind == "enum":
            return self.enum.from_code(vector[0]).value
        if self.kind == "bool":
            return bool(vector[0] > 0.5)
        if self.kind == "number":
            return _json_number(vector[0])
        return [_json_number(x) for x in vector]

    def encode(self, value) -> np.ndarray:
        """The port vector for a payload value (inverse of ``decode``)."""
        if value is None and self.optional:
            return np.array([NO_VALUE])
        if self.kind == "enum":
            member = value if isinstance(value, CodedEnum) else self.enum(value)
            return np.array([float(member.code)])
        if self.kind == "bool":
            return np.array([1.0 if value else 0.0])
        return np.asarray(value, dtype=float).reshape(self.size)

    def domain(self):
        """The value set, as written in risk models and safety conditions."""
        if self.kind == "enum":
            return list(self.enum.names())
        return self.kind


def _json_number(x: float):
    x = float(x)
    if not math.isfinite(x):
        return None
    return round(x, 6)


def enum_type(enum: type[CodedEnum]) -> ChannelType:
    return ChannelType("enum", enum=enum)


BOOL = ChannelType("bool")


def number_type(unit: str | None) -> ChannelType:
    return ChannelType("number", unit=unit)


def vector_type(size: int, unit: str | None) -> ChannelType:
    return ChannelType("vector", size=size, unit=unit)


@dataclass(frozen=True)
class ChannelSpec:
    """A channel's identity and contract.

    ``period`` is the publisher's update period in seconds: the value can only
    change at multiples of it, and the recorder looks at it at every one (never
    less often: a check judges the values the readers of the channel acted on).
    ``record`` says when the recorder writes a message: ``on_change`` (when it
    differs from the last written) or ``every_sample`` (at every update).
    ``offset`` (s, less than ``period``): the updates fall at ``offset + k * period``
    (a live twin's deciding modules update one plant step after the grid, see
    :meth:`cellsim.systems.CellSystem.decide_after`).
    """

    module: str
    signal: str
    type: ChannelType
    period: float
    record: RecordPolicy = "on_change"
    description: str = ""
    offset: float = 0.0

    @property
    def sample_period(self) -> float:
        """How often the recorder looks at this channel (s): at every update of its publisher."""
        return self.period

    @property
    def name(self) -> str:
        return f"{self.module}.{self.signal}"


def value_text(value, *, none: str = "-", true: str = "true", false: str = "false") -> str:
    """A channel's value as short text for people: enums by name, booleans in words, numbers to
    three significant figures, no value as ``none``."""
    if value is None:
        return none
    if isinstance(value, bool):
        return true if value else false
    if isinstance(value, float):
        return sig3(value)
    return str(value)


# -- as variables of the condition language (cellsim.logic) ---------------------------------------------
def logic_domain(kind: str, domain: object, unit: str | None) -> EnumDomain | BoolDomain | NumberDomain | None:
    """The logic domain of a channel (its kind, enum values, unit), or ``None`` for a vector."""
    if kind == "enum":
        return EnumDomain(tuple(domain))
    if kind == "bool":
        return BoolDomain()
    if kind == "number":
        return NumberDomain(unit)
    return None


def channel_domains(specs: Iterable[ChannelSpec]) -> dict[str, EnumDomain | BoolDomain | NumberDomain]:
    """Domain of every scalar channel a diagram publishes (before anything is recorded)."""
    domains = {s.name: logic_domain(s.type.kind, s.type.domain(), s.type.unit) for s in specs}
    return {name: d for name, d in domains.items() if d is not None}
