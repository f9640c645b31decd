"""Numbers with units, for people: one place decides how a value in a unit is written.

Energies span twelve orders of magnitude in one run (a CPU at 4 MHz spends microjoules where a
radio spends joules), so they take an SI prefix and four significant digits: ``22.34 µJ``, never
``2.234e-05 J``.
"""

from __future__ import annotations

PREFIXES = (("T", 1e12), ("G", 1e9), ("M", 1e6), ("k", 1e3), ("", 1.0), ("m", 1e-3), ("µ", 1e-6), ("n", 1e-9),
            ("p", 1e-12))
DIGITS = 4


def prefix(value: float) -> tuple[str, float]:
    """The SI prefix and scale that put ``value`` in [1, 1000) (the smallest prefix below that; "" for 0)."""
    size = abs(value)
    if size == 0:
        return "", 1.0
    for name, scale in PREFIXES:
        if size >= scale:
            return name, scale
    return PREFIXES[-1]


def si(value: float, unit: str, digits: int = DIGITS) -> str:
    """``value`` with an SI prefix and ``digits`` significant digits: si(2.234e-05, "J") == "22.34 µJ"."""
    value = float(f"{value:.{digits}g}")  # round first, so that 999.96 J reads 1 kJ, not 1000 J
    name, scale = prefix(value)
    return f"{value / scale:.{digits}g} {name}{unit}"


def quantity(value: float | None, unit: str) -> str:
    """A metric's value as the launch summary table, the monitor and the plots write it: joules with an
    SI prefix, seconds to the hundredth, ratios as percentages, counts as they are."""
    if value is None:
        return "-"
    if unit == "J":
        return si(value, unit)
    if unit == "s":
        return f"{value:.2f} s"
    if unit == "ratio":
        return f"{100 * value:.1f} %"
    return f"{value}" if isinstance(value, int) else f"{value:.2f}"
