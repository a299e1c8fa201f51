"""Lengths with units, for people: idmd speaks metres (``x.move(2.5e-07)``); this module reads
``"250nm"``, ``"1.5um"``, ``"2mm"``, ``"2e-6m"`` and writes metres in a unit, with the same rules
as ``idmctl`` (tools/cli.h)::

    from idm.units import length, in_unit
    x.move(length("250nm"))            # 2.5e-07 m
    print(in_unit(x.position(), "nm"))  # e.g. 249.6

The units are nm, um, mm and m, case-sensitive (``Mm`` would be megametres). A length is divided by
the unit's exact power of ten, so ``length("250nm")`` is the double closest to 250e-9 m."""

from __future__ import annotations

import math
import re
from typing import Optional

__all__ = ["UNITS", "length", "in_unit", "format_length"]

#: how many of each unit make a metre (exact in a double)
UNITS = {"nm": 1e9, "um": 1e6, "mm": 1e3, "m": 1.0}

_NUMBER = re.compile(r"[0-9.eE+-]+\Z")
_ACCEPTED = "a number and a unit, one of nm, um, mm, m (e.g. 250nm, 1.5mm)"


def _unit(name: str) -> float:
    try:
        return UNITS[name]
    except KeyError:
        raise ValueError("unit %r is not one of %s" % (name, ", ".join(UNITS))) from None


def length(text: str, what: str = "length", bare: Optional[str] = "m") -> float:
    """Metres from ``"250nm"``, ``"-1.5um"``, ``"2e-6m"``. A bare number (``"5"``) is in
    ``bare`` (None: refused, as ambiguous). ValueError naming ``what``, the text and the accepted
    units for anything else."""
    if not isinstance(text, str):
        raise TypeError("%s: a length is text such as '250nm', not %r" % (what, text))
    m = re.search(r"[A-Za-z]*\Z", text)
    number, suffix = text[:m.start()], m.group()
    if "\u00b5" in text or "\u03bc" in text:
        raise ValueError("%s: '%s': write um for micrometres; %s" % (what, text, _ACCEPTED))
    if not number or not _NUMBER.match(number):
        raise ValueError("%s: '%s' is not a length: %s" % (what, text, _ACCEPTED))
    if not suffix and bare is None:
        raise ValueError("%s: '%s' has no unit: write %sum, %sm, ... (a bare number is metres "
                         "only when the caller says so)" % (what, text, text, text))
    unit = suffix or bare
    if unit not in UNITS:
        raise ValueError("%s: '%s': unknown unit '%s', accepted %s (case matters; a bare number "
                         "is metres)" % (what, text, unit, ", ".join(UNITS)))
    try:
        value = float(number)
    except ValueError:
        raise ValueError("%s: '%s' is not a length: %s" % (what, text, _ACCEPTED)) from None
    if not math.isfinite(value):
        raise ValueError("%s: '%s' is not a length: %s" % (what, text, _ACCEPTED))
    return value / UNITS[unit]


def in_unit(metres: float, unit: str) -> float:
    """``metres`` in ``unit`` (``in_unit(1e-6, "nm")`` is 1000.0000000000001: round to show)."""
    return metres * _unit(unit)


def format_length(metres: float, unit: str) -> str:
    """``metres`` in ``unit`` to 12 significant digits, as ``idmctl --unit`` prints it
    (``format_length(1e-6, "nm")`` is ``"1000"``)."""
    text = "%.12g" % in_unit(metres, unit)
    mantissa, e, exponent = text.partition("e")
    return mantissa + ("e%d" % int(exponent) if e else "")
