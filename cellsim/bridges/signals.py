"""The one conversion between an entity's fields and the signals of a DBC message.

A CAN device's frame carries some of an entity's fields as DBC signals: the
sample fields a device sends (``devices:`` of the bridge configuration, field ->
signal) or the command fields the daemon sends it (``commands:``, signal ->
field). :class:`SignalMap` is that mapping for one message, used by the bridge
daemon and by the emulated devices alike, so what a value becomes on the bus is
decided here once:

* an enumeration travels by name: a field's value is one of the signal's value
  names (``cantools`` codes it), a null command field is the signal's ``none``;
* a boolean is 0 or 1;
* a number is the signal's physical value: a sample beyond the signal's range is
  sent as the range's end (a scanner with nobody in range reads its maximum
  distance, ``inf``), a sample that is no number (NaN, or infinite where the
  signal has no range) cannot be sent at all (:class:`Unsendable`: the device
  skips the frame and the receiver's watchdog fails it safe);
* a command the frame cannot carry (a value missing, not among the signal's
  names, not finite, or beyond its range) is sent as the entity kind's *safe
  command* for that signal: a command is never bent into another one.

Back from a frame (values decoded with ``decode_choices=False``): an enumerated
signal's code becomes its name (``none`` a null command field), a boolean field
a bool, anything else a float.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

NONE = "none"
"""The value name of an enumerated command signal that carries no request (a null command field)."""


class Unsendable(ValueError):
    """A sample field no frame of its signal can carry (it is not a number: NaN)."""


class SignalMap:
    """The fields one DBC ``message`` carries, as ``pairs`` of (entity field, DBC signal name).

    ``types``: each field's ``ChannelType`` (booleans and enums decoded as such; unknown fields are
    numbers). ``safe``: the safe command's signal values, for a command frame (None: a sample frame).
    """

    def __init__(self, message, pairs: Iterable[tuple[str, str]], types: Mapping | None = None,
                 safe: Mapping[str, object] | None = None):
        self.message = message
        self.pairs = tuple(pairs)
        self.safe = None if safe is None else dict(safe)
        types = types or {}
        self._rows = []  # (field, signal, its value names or None, whether the field is a boolean)
        for field_name, signal_name in self.pairs:
            signal = message.get_signal_by_name(signal_name)
            names = None if signal.choices is None else {str(v): code for code, v in signal.choices.items()}
            ctype = types.get(field_name)
            self._rows.append((field_name, signal, names, ctype is not None and ctype.kind == "bool"))

    @classmethod
    def of_device(cls, message, fields: Mapping[str, str], types: Mapping | None = None) -> "SignalMap":
        """A device's sample frame: ``fields`` maps entity field -> signal."""
        return cls(message, fields.items(), types)

    @classmethod
    def of_command(cls, message, fields: Mapping[str, str], safe_fields: Mapping[str, object],
                   types: Mapping | None = None) -> "SignalMap":
        """A command frame: ``fields`` maps signal -> entity command field; ``safe_fields`` is the entity
        kind's safe command as command fields."""
        pairs = [(field_name, signal_name) for signal_name, field_name in fields.items()]
        safe = {signal_name: NONE if safe_fields[field_name] is None else safe_fields[field_name]
                for field_name, signal_name in pairs}
        return cls(message, pairs, types, safe)

    # -- fields -> signals -------------------------------------------------------------
    def signals(self, fields: Mapping[str, object]) -> dict[str, object]:
        """The frame's signal values (for ``cantools``' ``encode``, choices by name) of the entity's ``fields``."""
        return {signal.name: self._signal(field_name, signal, names, fields)
                for field_name, signal, names, _ in self._rows}

    def safe_signals(self) -> dict[str, object]:
        """The frame's signal values of the safe command."""
        if self.safe is None:
            raise ValueError(f"{self.message.name} is a device's sample frame: it has no safe command")
        return dict(self.safe)

    def _signal(self, field_name: str, signal, names, fields: Mapping[str, object]):
        command = self.safe is not None
        if command and field_name not in fields:
            return self.safe[signal.name]  # no command for it (yet): the safe one
        value = fields[field_name]
        if names is not None:
            name = NONE if value is None else str(value)
            if name in names:
                return name
            if command:
                return self.safe[signal.name]
            raise Unsendable(f"{self.message.name}.{signal.name}: {value!r} is not one of its values "
                             f"({', '.join(names)})")
        if isinstance(value, bool):
            return int(value)
        try:
            number = float(value)
        except (TypeError, ValueError):
            number = math.nan
        lo = -math.inf if signal.minimum is None else signal.minimum
        hi = math.inf if signal.maximum is None else signal.maximum
        if command:
            return number if math.isfinite(number) and lo <= number <= hi else self.safe[signal.name]
        clamped = min(max(number, lo), hi)
        if not math.isfinite(clamped):  # NaN, or infinite where the signal has no range to end it
            raise Unsendable(f"{self.message.name}.{signal.name}: {value!r} is not a number it can carry")
        return clamped

    # -- signals -> fields -------------------------------------------------------------
    def fields(self, values: Mapping[str, object]) -> dict[str, object]:
        """The entity's fields of a frame's decoded signal ``values`` (codes, not names)."""
        fields = {}
        for field_name, signal, names, boolean in self._rows:
            value = values[signal.name]
            if names is not None:
                value = str(signal.choices[int(value)])
                fields[field_name] = None if value == NONE and self.safe is not None else value
            elif boolean:
                fields[field_name] = bool(value)
            else:
                fields[field_name] = float(value)
        return fields
