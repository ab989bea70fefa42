"""The emulator's fault grammar: ``--fault ENTITY=KIND[@T0[-T1]]`` and ``--rate ENTITY=HZ``.

What the command line of ``cellsim emulate`` says about faults and rates, parsed, and the
rules for which fault applies where: an entity on Zenoh has the faults of its Zenoh outlet
(``ZENOH_FAULTS``); with ``--can``, a CAN device of the bridge configuration
has the bus faults (``BUS_FAULTS``) and only those; without ``--can`` there is
no bus, so no bus fault. Each problem is a ``FaultError`` whose message is the one line the
user sees (``cellsim: error: ...``).

Times are the emulator's simulated seconds: ``welder=crc@3-5`` from 3 s to 5 s, ``robot=freeze@2``
from 2 s to the end, ``robot=silence`` throughout.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable

from cellsim.cell_io import Fault

__all__ = ["ALL_FAULTS", "BUS_FAULTS", "MAX_RATE", "MIN_RATE", "ZENOH_FAULTS", "Fault", "FaultError",
           "check_entities", "check_faults", "parse_fault", "parse_rate"]

ZENOH_FAULTS = ("silence", "freeze", "corrupt", "delay", "replay")
"""The faults an entity's Zenoh outlet injects (``cellsim.live.emulator.ZenohOutlet``)."""
BUS_FAULTS = ("drop", "crc", "replay", "length", "flood", "delay")
"""The faults a CAN device of the emulated cell injects on the bus (``cellsim.bridges.devices.CanOutlet``)."""

ALL_FAULTS = (*ZENOH_FAULTS, *(k for k in BUS_FAULTS if k not in ZENOH_FAULTS))
"""Every fault some outlet knows (Zenoh's, then the bus's): what ``--fault`` accepts before it knows the cell."""

MIN_RATE, MAX_RATE = 0.1, 1000.0
"""The samples per second ``--rate`` accepts."""


class FaultError(ValueError):
    """A ``--fault`` or ``--rate`` that cannot be: the message is the one line the user sees."""


def parse_fault(text: str) -> Fault:
    """The fault of ``ENTITY=KIND[@T0[-T1]]`` (T0 default 0, T1 default: the end; 0 <= T0 < T1).

    KIND is any fault of ``ALL_FAULTS``: whether it applies to the entity is ``check_faults``'s to say.
    """
    entity, _, rest = text.partition("=")
    kind, _, window = rest.partition("@")
    start, _, end = window.partition("-")
    try:
        at, until = float(start) if start else 0.0, float(end) if end else float("inf")
    except ValueError:
        at = until = -1.0
    if not entity or kind not in ALL_FAULTS or not 0.0 <= at < until or at != at:
        raise FaultError(
            f"--fault {text!r}: expected ENTITY=KIND[@T0[-T1]] (seconds, T0 < T1) with KIND one of {', '.join(ALL_FAULTS)}"
        )
    return Fault(entity, kind, at, until)


def parse_rate(text: str) -> tuple[str, float]:
    """(entity, samples per second) of ``ENTITY=HZ``, HZ from ``MIN_RATE`` to ``MAX_RATE``."""
    entity, _, hz = text.partition("=")
    try:
        value = float(hz)
    except ValueError:
        value = -1.0
    if not entity or not MIN_RATE <= value <= MAX_RATE:
        raise FaultError(f"--rate {text!r}: expected ENTITY=HZ with HZ from {MIN_RATE:g} to {MAX_RATE:g}")
    return entity, value


def check_entities(faults: Iterable[Fault], rates: Iterable[str], entities: Collection[str]) -> None:
    """Every fault and rate names an entity of the scenario (the first that does not: a FaultError)."""
    unknown = [f.entity for f in faults if f.entity not in entities]
    unknown += [e for e in rates if e not in entities]
    if unknown:
        raise FaultError(f"--fault/--rate: no entity named {unknown[0]!r} (entities: {', '.join(entities)})")


def check_faults(faults: Iterable[Fault], entities: Collection[str], can_devices: Collection[str] | None,
                 protocols: dict[str, tuple[str, tuple[str, ...]]] | None = None) -> None:
    """Every fault applies to its entity: a FaultError for the first that does not.

    ``entities``: the scenario's entity names; ``can_devices``: the entities that are CAN devices
    (``--can``: the bridge configuration's devices), or None without a bus; ``protocols``: other
    entities speaking a device protocol -> (what they are, their faults): a UR controller's RTDE, a
    PLC's OPC UA. A CAN device has the bus faults only, such an entity its protocol's, any other entity
    the Zenoh faults only; without a bus no entity has a bus fault.
    """
    faults = list(faults)
    check_entities(faults, (), entities)
    protocols = protocols or {}
    if can_devices is not None or protocols:
        for f in faults:
            what, kinds = protocols.get(f.entity) or (
                ("a CAN device", BUS_FAULTS) if can_devices and f.entity in can_devices else ("on Zenoh", ZENOH_FAULTS))
            if f.kind not in kinds:
                raise FaultError(f"--fault {f.entity}={f.kind}: {f.entity} is {what}; its faults: {', '.join(kinds)}")
    elif any(f.kind not in ZENOH_FAULTS for f in faults):
        bad = next(f for f in faults if f.kind not in ZENOH_FAULTS)
        raise FaultError(f"--fault {bad.entity}={bad.kind}: a bus fault needs --can; on Zenoh: {', '.join(ZENOH_FAULTS)}")
