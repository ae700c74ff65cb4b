"""Unit suffixes of log columns, parsed with pint.

A column such as ``force_kN`` or ``p_a_psi_abs`` carries its unit after the quantity name.
:func:`parse_unit` turns that unit text into the factor that converts the column to SI
(s, m, N, Pa). Any unit pint knows with the right dimension is accepted: ``ms``, ``um``,
``inch``/``in``, ``lbf``, ``kPa``, ``mbar``, ``psi`` ... Units are case-sensitive, as in SI
(``mN`` is millinewton, ``MN`` meganewton; ``pa`` is not pascal).

Pressures are gauge unless the unit ends in ``_abs`` (``bar_abs``): absolute.

>>> parse_unit("force", "kN").scale
1000.0
>>> spec = parse_unit("pressure", "bar_abs")
>>> (spec.scale, spec.absolute)
(100000.0, True)
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Literal

from fitstiff.errors import InputError

__all__ = ["BAR", "MM", "Kind", "KINDS", "UnitSpec", "parse_unit"]

MM = 1e-3
"""Metres per millimetre (the scale of fitstiff.io.log.RIG_KEYS: SI = mm * MM, mm = SI / MM)."""

BAR = 1e5
"""Pascal per bar."""

Kind = Literal["time", "length", "force", "pressure"]

ABSOLUTE_SUFFIX = "_abs"


@dataclasses.dataclass(frozen=True)
class _KindInfo:
    si_unit: str                  # pint name of the SI unit we store in
    dimension: str                # pint dimension it must have
    examples: tuple[str, ...]     # shown to the user when a unit is rejected


KINDS: dict[str, _KindInfo] = {
    "time": _KindInfo("second", "[time]", ("s", "ms", "us", "min")),
    "length": _KindInfo("meter", "[length]", ("m", "mm", "um", "inch")),
    "force": _KindInfo("newton", "[force]", ("N", "mN", "kN", "lbf")),
    "pressure": _KindInfo("pascal", "[pressure]", ("Pa", "kPa", "MPa", "bar", "mbar", "psi")),
}


@dataclasses.dataclass(frozen=True)
class UnitSpec:
    """A parsed unit: SI value = logged value * ``scale``; ``absolute`` only for pressures."""

    text: str
    scale: float
    absolute: bool = False


@functools.cache
def _registry():
    """The one pint registry (made on first use: importing pint and building it is slow)."""
    import pint

    return pint.UnitRegistry()


def parse_unit(kind: Kind, text: str, *, where: str | None = None,
               what: str = "unit") -> UnitSpec:
    """Parse the unit ``text`` of a quantity of ``kind`` (time, length, force, pressure).

    ``where`` (usually the file) and ``what`` (usually ``"column 'force_kN'"``) name the place
    in the :class:`~fitstiff.errors.InputError` raised for an unknown unit or one of the wrong
    dimension; the message lists units accepted for ``kind``.
    """
    info = KINDS[kind]
    unit = text
    absolute = kind == "pressure" and unit.endswith(ABSOLUTE_SUFFIX)
    if absolute:
        unit = unit[: -len(ABSOLUTE_SUFFIX)]

    def reject(found: str) -> InputError:
        fix = f"use a {kind} unit pint understands, e.g. {', '.join(info.examples)}"
        near = [u for u in info.examples if u.lower() == unit.lower()]
        if near:
            fix = f"did you mean '{near[0]}{ABSOLUTE_SUFFIX if absolute else ''}'? units are " \
                  f"case-sensitive; {fix}"
        if kind == "pressure":
            fix += f" (append '{ABSOLUTE_SUFFIX}' for absolute pressure)"
        return InputError(where, what, found, fix)

    if not unit.strip():
        raise reject("has no unit")
    registry = _registry()
    try:
        parsed = registry.parse_units(unit)
    except Exception:  # pint raises a zoo of types (UndefinedUnitError, ValueError, tokenizer)
        raise reject(f"unknown unit '{text}'") from None
    if parsed.dimensionality != registry.get_dimensionality(info.dimension):
        raise reject(f"unit '{text}' is not a {kind} unit (it measures "
                     f"{parsed.dimensionality})")
    scale = float(registry.Quantity(1.0, parsed).to(info.si_unit).magnitude)
    return UnitSpec(text=text, scale=scale, absolute=absolute)
