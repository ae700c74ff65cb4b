"""From cells to SI values: which column holds which quantity (header names with units, or a
mapping), each cell a plain decimal number, then the physical checks of each channel (magnitude,
time increasing and evenly enough sampled, pressures, the stroke). Every refusal names the file,
line and column."""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping

import numpy as np

from fitstiff.errors import InputError
from fitstiff.io.columns import (ENTRY_FORM, EXAMPLE_NAMES, QUANTITIES, REQUIRED_QUANTITIES,
                                 ColumnSpec, match_header)
from fitstiff.io.loading._text import _Table, _is_number, _q
from fitstiff.io.log import Rig
from fitstiff.io.validation import CHANNEL_LIMITS, MIN_TIME_STEP_S, is_decimal
from fitstiff.units import parse_unit

#: one line that is a plain decimal: removing every such line of a whole column leaves nothing
#: when every cell is one (one pass; the cell loop then finds the culprit). A single
#: ``fullmatch`` of the repeated group kept a backtracking frame per line: 800 MB for a
#: million-row column (issue 16)
_DECIMAL_LINE = re.compile(r"^[ \t\r\f\v]*[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)"
                           r"(?:[eE][+-]?[0-9]+)?[ \t\r\f\v]*\n", re.MULTILINE)


# ---------------------------------------------------------------------------------- columns

@dataclasses.dataclass(frozen=True)
class _Column:
    spec: ColumnSpec
    index: int      # 0-based


def _columns(table: _Table, mapping: Mapping[str, ColumnSpec]) -> dict[str, _Column]:
    found = _mapped(table, mapping) if mapping else _named(table)
    for quantity in REQUIRED_QUANTITIES:
        if quantity in found:
            continue
        if mapping:
            raise InputError(table.where, "column mapping", f"has no {quantity} entry",
                             f"add {quantity}=COLUMN:UNIT to --columns or the format file")
        raise InputError(table.where, "header", f"has no {quantity} column (columns: "
                         f"{', '.join(table.header or [])})",
                         f"name it {quantity}_<unit>, e.g. {EXAMPLE_NAMES[quantity]}, or map "
                         f"the columns with --columns {ENTRY_FORM}")
    return found


def _named(table: _Table) -> dict[str, _Column]:
    if table.header is None:
        raise InputError(table.where, "columns", "the file has no header and no column "
                         "mapping was given", f"map the columns with --columns {ENTRY_FORM} "
                         "or --format")
    found: dict[str, _Column] = {}
    for index, name in enumerate(table.header):
        match = match_header(name)
        if match is None:
            continue
        quantity, unit = match
        label = table.label(index)
        if not unit:
            raise InputError(table.where, label, "has no unit suffix",
                             f"name it {quantity}_<unit>, e.g. {EXAMPLE_NAMES[quantity]}")
        if quantity in found:
            raise InputError(table.where, f"{table.label(found[quantity].index)} and {label}",
                             f"both hold {quantity}",
                             "keep one (delete or rename the other) or pick one with --columns")
        spec = ColumnSpec(quantity, name, parse_unit(QUANTITIES[quantity], unit,
                                                     where=table.where, what=label))
        found[quantity] = _Column(spec, index)
    return found


def _mapped(table: _Table, mapping: Mapping[str, ColumnSpec]) -> dict[str, _Column]:
    found: dict[str, _Column] = {}
    for quantity, spec in mapping.items():
        what = f"column mapping entry '{spec.describe()}'"
        if isinstance(spec.column, int):
            if spec.column > table.width:
                raise InputError(table.where, what, f"the file has {table.width} columns",
                                 f"give a column number from 1 to {table.width}")
            index = spec.column - 1
        elif table.header is None:
            raise InputError(table.where, what, f"names column '{spec.column}' but the file "
                             "has no header", "give the column's 1-based number instead")
        elif spec.column not in table.header:
            raise InputError(table.where, what, f"there is no column '{spec.column}' "
                             f"(columns: {', '.join(table.header)})",
                             "give a header name or a 1-based column number")
        else:
            index = table.header.index(spec.column)
        clash = next((c for c in found.values() if c.index == index), None)
        if clash is not None:
            raise InputError(table.where, what, f"uses {table.label(index)}, already mapped "
                             f"by '{clash.spec.describe()}'", "map each column at most once")
        found[quantity] = _Column(spec, index)
    return found


# ----------------------------------------------------------------------------------- values

def _values(table: _Table, column: _Column, *, no_header: bool) -> np.ndarray:
    """The column's numbers as written in the file; the first bad cell is an error.

    A cell is a plain decimal number with an optional exponent (:func:`is_decimal`):
    ``float`` would also take ``1_000``, ``nan``, ``infinity`` or non-ASCII digits.
    """
    cells = table.cells(column.index)
    i = None
    if _DECIMAL_LINE.sub("", "\n".join(cells) + "\n"):
        i = next((i for i, c in enumerate(cells) if not is_decimal(c)), None)
    if i is not None:
        fix = "make every cell of this column a number"
        if not cells[i].strip():
            found = "the cell is empty"
            fix = "fill it in or remove the row"
        elif _is_number(cells[i]) and not np.isfinite(float(cells[i])):
            found = f"found {_q(cells[i])}, not a finite number"
            fix = "replace it with a measured value or remove the row"
        elif _is_number(cells[i]):
            found = f"found {_q(cells[i])}, not a plain decimal number"
            fix = ("write digits with an optional decimal point and exponent, e.g. 1000 or "
                   "1.5e3 (no digit separators, words or non-ASCII digits)")
        else:
            found = f"found {_q(cells[i])}, not a number"
            if "," in cells[i] and _is_number(cells[i].replace(",", ".")):
                fix = "use a decimal point, not a decimal comma"
            elif i == 0 and no_header:
                fix = "line 1 looks like a header: drop --no-header (no_header=False)"
        raise _at(table, column, i, found, fix)
    try:
        values = np.fromiter((float(c) for c in cells), dtype=np.float64, count=len(cells))
    except ValueError:      # cannot happen for plain decimals; never a traceback if it does
        i = next(i for i, c in enumerate(cells) if not _is_number(c))
        raise _at(table, column, i, f"found {_q(cells[i])}, not a number",
                  "make every cell of this column a number") from None
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:            # an exponent beyond the float range: 1e999
        raise _at(table, column, bad[0], f"found {_q(cells[bad[0]])}, not a finite number",
                  "replace it with a measured value or remove the row")
    return values


#: channels screened for spikes (:mod:`fitstiff.signal.spikes`): display unit and SI per unit
_SHOWN = {"force": ("N", 1.0), "displacement": ("mm", 1e-3), "p_a": ("bar abs", 1e5),
          "p_b": ("bar abs", 1e5)}


def _check_magnitude(table: _Table, column: _Column, si: np.ndarray) -> None:
    """Every SI value within the channel's physical bound (:data:`CHANNEL_LIMITS`)."""
    limit = CHANNEL_LIMITS[column.spec.quantity]
    with np.errstate(over="ignore", invalid="ignore"):
        bad = np.flatnonzero(~(np.abs(si) <= limit.bound))
    if bad.size:
        i = int(bad[0])
        spec = column.spec
        scaled = f" (unit '{spec.unit.text}'" + (f", scale {spec.scale:g}" if spec.scale != 1
                                                 else "") + ")"
        absolute = " absolute" if spec.quantity.startswith("p_") else ""
        raise _at(table, column, i, f"found {_q(_cell(table, column, i))}{scaled} = "
                  f"{si[i]:.4g} {limit.unit}{absolute}, beyond the plausible magnitude of a "
                  f"{spec.quantity.replace('p_', 'pressure ')} channel, {limit.describe()}",
                  "correct the cell or remove the row, and check the column's unit")


def _at(table: _Table, column: _Column, i: int, found: str, fix: str) -> InputError:
    return InputError(table.where, f"line {table.line(i)}, {table.label(column.index)}", found,
                      fix)


def _cell(table: _Table, column: _Column, i: int) -> str:
    return table.row(i)[column.index].strip()


def _check_time(table: _Table, column: _Column, time: np.ndarray) -> None:
    bad = np.flatnonzero(~(np.diff(time) > 0))
    if bad.size:
        i = int(bad[0])
        raise _at(table, column, i + 1, f"time does not increase: {_q(_cell(table, column, i))} "
                  f"on line {table.line(i)}, then {_q(_cell(table, column, i + 1))} on line "
                  f"{table.line(i + 1)}",
                  "time must increase strictly: correct or remove the offending row (the "
                  "loader never drops or reorders rows)")


def _check_time_step(table: _Table, column: _Column, time: np.ndarray) -> None:
    short = np.flatnonzero(np.diff(time) < MIN_TIME_STEP_S)
    if short.size:
        i = int(short[0])
        raise _at(table, column, i + 1, f"the time step from line {table.line(i)} is "
                  f"{time[i + 1] - time[i]:.3g} s, shorter than {MIN_TIME_STEP_S:g} s (1 GHz "
                  "sampling)", f"check the time unit ('{column.spec.unit.text}') and the "
                  "cells (a sampling that fast is not a force log)")


def _check_pressure(table: _Table, column: _Column, pressure: np.ndarray) -> None:
    bad = np.flatnonzero(pressure < 0)
    if bad.size:
        i = int(bad[0])
        unit = column.spec.unit
        kind = "absolute" if unit.absolute else "gauge"
        raise _at(table, column, i, f"found {_q(_cell(table, column, i))} ({kind}) = "
                  f"{pressure[i] / 1e5:.4g} bar absolute, below vacuum",
                  f"check the unit ('{unit.text}') and whether the column is gauge or absolute "
                  "(absolute: unit ending in _abs), the sign (:flip) and ambient_bar "
                  "(--ambient-bar)")


def _check_stroke(table: _Table, column: _Column, displacement: np.ndarray, rig: Rig) -> None:
    if rig.stroke is None or rig.start_position is None:
        return
    x = rig.start_position + displacement
    bad = np.flatnonzero((x < 0) | (x > rig.stroke))
    if bad.size:
        i = int(bad[0])
        raise _at(table, column, i, f"found {_q(_cell(table, column, i))}: x = x0 + displacement "
                  f"= {x[i] * 1e3:.4g} mm, outside the stroke 0..{rig.stroke * 1e3:.4g} mm",
                  "check the displacement unit and sign (:flip), start_position_mm "
                  "(--start-position-mm) and stroke_mm (--stroke-mm)")
