"""How cellsim writes numbers for people: one rule everywhere (terminal, report, dashboard).

* A measure (a duration, a distance, a speed, a factor, a configuration value, a
  share) has three significant figures and its unit: ``0.826 s``, ``36.3x``,
  ``2.50 m``, ``98.9%``. Trailing zeros stay, so a column of figures lines up.
* An instant on a run's clock (when a condition was violated, the window it
  required) has two decimals, 10 ms: the conditions' windows are half-seconds, and
  ``12.84 s ... required by 13.34 s`` must read as the 0.5 s it is.

Values that are not numbers are written as they are (``true``/``false`` for booleans).
"""

from __future__ import annotations

import math


def is_number(value: object) -> bool:
    """An int or a float, not a bool."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def sig3(value: object) -> str:
    """``value`` with three significant figures (``12.3``, ``0.0456``, ``3.20``, ``1.23e+05``).

    The exponent is the rounded value's: 0.9996 is ``1.00``, 99999.6 is ``1.00e+05``.
    """
    if not is_number(value):
        if isinstance(value, bool):
            return "true" if value else "false"
        return str(value)
    x = float(value)  # type: ignore[arg-type]
    if not math.isfinite(x):
        return str(x)
    if x == 0:
        return "0"
    exponent = int(f"{x:.2e}".partition("e")[2])
    if -3 <= exponent < 5:
        return f"{x:.{max(0, 2 - exponent)}f}"
    return f"{x:.2e}"


def measure(value: object, unit: str = "") -> str:
    """A measure with its unit: ``0.826 s``, ``2.50 m/s``; ``x`` and ``%`` attach (``36.3x``)."""
    text = sig3(value)
    if not unit:
        return text
    return f"{text}{unit}" if unit in ("x", "%") else f"{text} {unit}"


def percent(fraction: object) -> str:
    """A fraction as a share: ``0.989`` -> ``98.9%``."""
    return measure(100.0 * float(fraction), "%") if is_number(fraction) else "n/a"  # type: ignore[arg-type]


def probability(p: float | None) -> str:
    """A probability for people: 0.000998, 0.0372, 0.5, 1."""
    if p is None:
        return "-"
    return f"{p:.3g}"


def instant(t: float) -> str:
    """A moment of a run: ``12.84 s``."""
    return f"{t:.2f} s"
