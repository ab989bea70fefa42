"""A black box as a trace: one piecewise-constant signal per variable.

Every scalar channel of a run (enumerations, booleans, numbers) becomes a
:class:`~cellsim.logic.trace.Signal` under its channel name; a message's value
holds from its time stamp until the channel's next message (right-continuous,
piecewise constant). Vector channels (joint positions, positions) are not trace
variables. Aliases from the scenario's ``validation.variables`` give the short
names the conditions use (``safmod`` for ``robot.safety_mode``); an alias shares
its channel's signal.

The trace's domain is ``[0, end)``. ``end`` is the run's duration when the run
completed, or when a live run was stopped on request (status ``stopped``: its
duration is then the time it ran). Otherwise (a run interrupted or killed, a recording made beside the
real cell) it is the simulated time up to which the recorder had written every
message (``recorded_until`` in the metadata), and without that the latest
``t + period`` over the messages: a value last recorded at ``t`` was observed
for at least its channel's sample period, so a recording whose last message is
a mishap does not end at the instant the mishap began. Such a trace is
*incomplete*: verdicts that its cut could change are inconclusive (see
:class:`~cellsim.validation.conditions.ConditionVerdict`).

A black box whose content is not what the recorder writes (metadata that is not
JSON, unknown channel kinds, values outside a channel's domain, time stamps that
are not finite numbers, no messages) is refused with a ``BlackBoxError`` that
starts with "corrupt black box".
"""

from __future__ import annotations

import difflib
import json
import os
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from cellsim.atomic import write_text
from cellsim.logic.syntax import BoolDomain, EnumDomain, NumberDomain
from cellsim.logic.trace import Signal, Trace
from cellsim.channels import logic_domain
from cellsim.blackbox import BlackBox, BlackBoxError, run_end

Domain = EnumDomain | BoolDomain | NumberDomain


class TraceError(Exception):
    """The black box cannot give the trace asked for (unknown channel, no messages).

    ``variable`` names the alias at fault, when there is one; ``missing``: the channel it names is not there at all.
    """

    def __init__(self, message: str, variable: str | None = None, missing: bool = False):
        super().__init__(message)
        self.variable = variable
        self.missing = missing


def blackbox_domains(bb: BlackBox) -> dict[str, Domain]:
    """Domain of every scalar channel recorded in ``bb``."""
    domains = {name: logic_domain(i.kind, i.domain, i.unit) for name, i in bb.channels().items()}
    return {name: d for name, d in domains.items() if d is not None}


def with_aliases(domains: dict[str, Domain], aliases: dict[str, str], channels: Iterable[str]) -> dict[str, Domain]:
    """The vocabulary of a run: its scalar channels plus the aliases (variable -> channel).

    Raises :class:`TraceError` naming the variable when an alias names a channel
    that does not exist (``channels`` lists them all), a vector channel, or hides
    another channel's name.
    """
    channels = set(channels)
    vocabulary = dict(domains)
    for variable, channel in aliases.items():
        if channel not in channels:
            close = difflib.get_close_matches(channel, sorted(channels), n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise TraceError(f"there is no channel '{channel}'{hint}", variable, missing=True)
        if channel not in domains:
            raise TraceError(f"channel '{channel}' is a vector, not a trace variable", variable)
        if variable in channels and variable != channel:
            raise TraceError("the name would hide the channel of the same name", variable)
        vocabulary[variable] = domains[channel]
    return vocabulary


@dataclass
class RunTrace:
    """A run's trace with the vocabulary its formulas are parsed against."""

    trace: Trace
    vocabulary: dict[str, Domain]
    complete: bool = True
    """Whether the trace ends where the run was meant to end (the run completed)."""

    def to_json(self) -> dict[str, list[list]]:
        """``{variable: [[t, value], ...]}`` (the ``--export-trace`` format)."""
        return {
            name: [[t, v] for t, v in zip(signal.times.tolist(), signal.values)]
            for name, signal in sorted(self.trace.signals.items())
        }


def trace_of_run(bb: BlackBox, aliases: dict[str, str] | None = None) -> RunTrace:
    """The trace of the run recorded in ``bb``, with ``aliases`` (variable -> channel) added."""
    aliases = dict(aliases or {})
    domains = blackbox_domains(bb)
    try:
        vocabulary = with_aliases(domains, aliases, bb.channels())
    except TraceError as e:
        raise TraceError(f"{bb.path}: variable '{e.variable}': {e}", e.variable) from None

    channels = bb.channels()
    samples: dict[str, tuple[list[float], list]] = {name: ([], []) for name in domains}
    reach = 0.0  # latest t + period over all messages
    for t, channel, value in checked_values(bb, list(samples), domains):
        times, values = samples[channel]
        reach = max(reach, t + channels[channel].period)
        if times and t <= times[-1]:
            if t < times[-1]:
                raise TraceError(f"{bb.path}: channel '{channel}' goes back in time at t = {t}")
            values[-1] = value  # two messages at one instant: the later one holds
            continue
        times.append(t)
        values.append(value)
    bb.check_vectors()  # not trace variables, but a run's record all the same: corrupt is corrupt
    bb.check_channels()
    metadata = bb.metadata()
    if not any(times for times, _ in samples.values()):
        if metadata.get("status") in ("interrupted", "running", "failed"):
            raise TraceError(f"{bb.path}: the run stopped ({metadata.get('status')}) before it recorded anything")
        raise BlackBoxError(f"{bb.path}: corrupt black box: it holds no messages")

    end, complete = run_end(bb, metadata, reach)
    if end <= 0.0:
        raise TraceError(f"{bb.path}: the run recorded no time (no messages after t = 0)")
    signals = {name: Signal(np.asarray(ts, dtype=np.float64), vs) for name, (ts, vs) in samples.items()}
    for variable, channel in aliases.items():
        signals[variable] = signals[channel]
    return RunTrace(Trace(signals, 0.0, end), vocabulary, complete)


LATEST = 1e9
"""s: no run lasts longer (about 31 years); a later time stamp is corrupt (and beyond what MCAP can stamp)."""


def checked_values(bb: BlackBox, channels: list[str], domains: dict[str, Domain]):
    """``(t, channel, value)`` of ``channels`` in time order (:meth:`BlackBox.iter_values`), each checked as it is
    read: a time stamp that is a number from 0 to ``LATEST`` s, and a value in its channel's domain (``domains``:
    those of the scalar channels; None, no value yet, is in every one). A BlackBoxError naming the channel and the
    time otherwise: what every reader of a black box (``check``, ``export``) refuses alike."""
    valid = {name: validator_of(d) for name, d in domains.items()}
    for t, channel, value in bb.iter_values(channels):
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not 0 <= t <= LATEST:
            raise BlackBoxError(f"{bb.path}: corrupt black box: a '{channel}' message has time stamp {t!r}")
        check = valid.get(channel)
        if value is not None and check is not None and not check(value):
            raise BlackBoxError(
                f"{bb.path}: corrupt black box: '{channel}' at t = {t} has value {value!r}, "
                f"outside its domain {_describe(domains[channel])}"
            )
        yield t, channel, value


def validator_of(domain: Domain):
    """Whether a recorded value belongs to ``domain`` (a predicate: its enum names, a boolean, a finite number)."""
    if isinstance(domain, EnumDomain):
        values = set(domain.values)
        return lambda v: isinstance(v, str) and v in values
    if isinstance(domain, BoolDomain):
        return lambda v: isinstance(v, bool)
    return lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)


def _describe(domain: Domain) -> str:
    if isinstance(domain, EnumDomain):
        return "{" + ", ".join(domain.values) + "}"
    return "boolean" if isinstance(domain, BoolDomain) else "finite number"


def write_trace_json(run_trace: RunTrace, path: str | os.PathLike) -> None:
    """Write the trace as JSON, atomically (:func:`cellsim.atomic.write_text`)."""
    lines = [f"  {json.dumps(name)}: {json.dumps(samples)}" for name, samples in run_trace.to_json().items()]
    write_text(path, "{\n" + ",\n".join(lines) + "\n}\n")
