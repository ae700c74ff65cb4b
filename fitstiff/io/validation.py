"""Validation of values at the boundary: numbers, ranges, JSON files, CSV cells, input files.

Everything a user hands to fitstiff passes one of these checks before any computation sees
it, and every refusal is one :class:`~fitstiff.errors.InputError` line naming the place, what
was found and how to fix it:

- :func:`number`: a metadata value (sidecar, format file, command line, Python mapping) is a
  real number - not a boolean (JSON ``true`` is not 1), not text, not a list - finite, and
  inside the physically plausible range given with its unit. The rig keys declare their
  ranges in :data:`fitstiff.io.log.RIG_KEYS`.
- :func:`read_json`: a JSON file (sidecar, format file, priors) is a regular file of at most
  :data:`MAX_JSON_BYTES`, valid JSON without a repeated key (JSON would keep the last one
  silently), nested at most :data:`MAX_JSON_DEPTH` deep with at most :data:`MAX_JSON_VALUES`
  values.
- :func:`is_decimal`: a CSV cell or command-line number is written as a plain decimal, with an
  optional exponent (``12``, ``-0.5``, ``1.5e-3``); Python literal syntax (``1_000``), hex,
  non-ASCII digits and the words ``nan`` / ``inf`` are not numbers in a log.
- :data:`CHANNEL_LIMITS`: the magnitude a logged channel can physically have (SI), so that
  no computation downstream can overflow on a value that passed the loader.
- :func:`regular_file`: an input path is an existing regular file (a named pipe, a device or
  a directory would block or fail the read).
- :func:`cli_number`: the ``type`` of numeric command-line options (plain decimals only).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import stat
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from fitstiff.errors import InputError

__all__ = ["CHANNEL_LIMITS", "MAX_JSON_BYTES", "MAX_JSON_DEPTH", "MAX_JSON_VALUES",
           "MIN_TIME_STEP_S", "ChannelLimit", "cli_number", "describe_type", "exists",
           "is_decimal", "number", "parse_decimal", "read_json", "regular_file", "shown"]

MAX_JSON_BYTES = 1 << 20      # a sidecar is a few hundred bytes, a format file a few kB
MAX_JSON_DEPTH = 16
MAX_JSON_VALUES = 10_000

#: a plain decimal number with an optional exponent (ASCII digits only)
_DECIMAL = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")


_BLANKS = " \t\r\n\f\v"     # ASCII blanks around a number (float() takes more than these)


def is_decimal(text: str) -> bool:
    """``text`` (surrounding ASCII blanks allowed) is a plain decimal number, e.g. ``-1.5e3``.

    >>> [is_decimal(t) for t in ("12", " -0.5 ", "1.5e-3", ".5", "1_000", "nan", "0x10", "")]
    [True, True, True, True, False, False, False, False]
    """
    return _DECIMAL.fullmatch(text.strip(_BLANKS)) is not None


def parse_decimal(text: str) -> float | None:
    """The value of a plain decimal (:func:`is_decimal`), ``None`` for anything else.

    The result may be infinite when the exponent overflows (``1e999``); callers check.
    """
    return float(text) if is_decimal(text) else None


def describe_type(value: object) -> str:
    """How a value reads in JSON terms, short, for messages: ``true (a boolean)``,
    ``'32' (text)``, ``[32] (a list)``, ``an object``, ``null``."""
    if isinstance(value, (bool, np.bool_)):
        return f"{'true' if value else 'false'} (a boolean)"
    if isinstance(value, str):
        return f"{shown(value)} (text)"
    if isinstance(value, Mapping):
        return "an object"
    if isinstance(value, (list, tuple)):
        return f"{shown(value)} (a list)"
    if value is None:
        return "null"
    return shown(value)


def shown(value: object) -> str:
    """A short ``repr`` of any value, for messages (``'gamma'``, ``['c']``, ``1e+300``)."""
    if isinstance(value, (int, np.integer)) and abs(int(value)).bit_length() > 128:
        return f"an integer of about {int(abs(int(value)).bit_length() * 0.30103)} digits"
    try:
        text = repr(value)
    except (ValueError, RecursionError):     # e.g. an integer beyond str()'s digit limit
        text = f"<{type(value).__name__}>"
    return _short(text)


def _short(text: str, limit: int = 40) -> str:
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _fmt(value: float) -> str:
    return f"{value:g}"


def number(value: object, *, where: str | None, what: str, unit: str = "",
           low: float | None = None, high: float | None = None, low_open: bool = False,
           meaning: str | None = None, example: float | None = None) -> float:
    """``value`` as a float, checked: a real number, finite, within ``[low, high]``.

    ``low_open`` excludes ``low`` itself (``stroke > 0``). ``meaning`` (e.g. "the piston
    bore diameter"), ``unit`` (e.g. "mm") and ``example`` (a typical value) make the fix of
    the message. Integers and floats (also numpy scalars) are numbers; booleans, text, lists
    and objects are not.

    >>> number(32, where="run1.json", what="key 'bore_mm'", unit="mm", low=1, high=1000)
    32.0
    >>> number(True, where="run1.json", what="key 'bore_mm'", unit="mm")
    Traceback (most recent call last):
    ...
    fitstiff.errors.InputError: run1.json: key 'bore_mm': found true (a boolean), not a number; \
give a number in mm, e.g. 1
    """
    in_unit = f" in {unit}" if unit else ""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer,
                                                                      np.floating)):
        shown = _fmt(example if example is not None else (low if low and low > 0 else 1))
        fix = f"give a number{in_unit}, e.g. {shown}"
        if isinstance(value, str) and parse_decimal(value) is not None:
            fix = f"write the number without quotes ({value.strip(_BLANKS)}){in_unit}"
        raise InputError(where, what, f"found {describe_type(value)}, not a number", fix)
    try:
        result = float(value)
    except OverflowError:      # a JSON integer with hundreds of digits
        result = math.inf if value > 0 else -math.inf
    if not math.isfinite(result):
        shown = describe_type(value) if isinstance(value, (int, np.integer)) else repr(result)
        raise InputError(where, what, f"found {shown}, not a finite number",
                         f"give a finite number{in_unit}")
    too_low = low is not None and (result < low or (low_open and result == low))
    if too_low or (high is not None and result > high):
        if low is None:
            span = f"at most {_fmt(high)} {unit}"
        else:
            span = f"{'above' if low_open else 'from'} {_fmt(low)}"
            if high is not None:
                span += f" {'up ' if low_open else ''}to {_fmt(high)}"
            span = f"{span} {unit}"
        span = span.strip()
        about = f"{meaning}{in_unit}" if meaning else f"a value{in_unit}"
        raise InputError(where, what, f"found {_fmt(result)} {unit}".rstrip()
                         + f", outside the plausible range ({span})",
                         f"give {about} (check the unit and the decimal point)")
    return result


def cli_number(text: str) -> float:
    """``type=`` of numeric command-line options: a finite plain decimal number.

    Raises :class:`argparse.ArgumentTypeError`, which the parser reports as one line with
    exit code 2 (``argument --bore-mm: ...``).
    """
    value = parse_decimal(text)
    if value is None:
        raise argparse.ArgumentTypeError(
            f"found {text!r}, not a plain decimal number; write digits with an optional "
            "decimal point and exponent, e.g. 32, 0.5 or 1.5e3")
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"found {text!r}, not a finite number")
    return value


# ------------------------------------------------------------------------------ channels

class ChannelLimit:
    """The largest magnitude (SI) a logged channel can physically have, and why."""

    def __init__(self, bound: float, unit: str, why: str):
        self.bound, self.unit, self.why = bound, unit, why

    def describe(self) -> str:
        return f"{self.bound:g} {self.unit} ({self.why})"


#: quantity -> magnitude bound of its SI values (pressures: absolute)
CHANNEL_LIMITS: dict[str, ChannelLimit] = {
    "time": ChannelLimit(1e12, "s", "about 30 000 years"),
    "displacement": ChannelLimit(100.0, "m", "longer than any cylinder stroke"),
    "force": ChannelLimit(1e7, "N", "10 MN, beyond any cylinder or load cell"),
    "p_a": ChannelLimit(1e9, "Pa", "10 000 bar, beyond any pneumatic or hydraulic chamber"),
    "p_b": ChannelLimit(1e9, "Pa", "10 000 bar, beyond any pneumatic or hydraulic chamber"),
}
#: the shortest sample interval accepted (1 GHz sampling)
MIN_TIME_STEP_S = 1e-9


# --------------------------------------------------------------------------------- files

_FILE_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a named pipe (FIFO)"),
               (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
               (stat.S_ISSOCK, "a socket"))


def regular_file(path: str | os.PathLike[str], *, what: str = "file",
                 fix: str = "check the path") -> os.stat_result:
    """``stat`` of ``path`` if it is an existing regular file, else an :class:`InputError`.

    Never opens the file, so a named pipe or a device is refused instead of blocking.
    """
    where = str(path)
    try:
        info = os.stat(path)
    except OSError as exc:
        raise InputError(where, what, f"cannot be read ({exc.strerror})", fix) from None
    if not stat.S_ISREG(info.st_mode):
        kind = next((name for test, name in _FILE_KINDS if test(info.st_mode)),
                    "not a regular file")
        raise InputError(where, what, f"is {kind}, not a regular file",
                         "save the data to a regular file and give its path")
    return info


def exists(path: str | os.PathLike[str]) -> bool:
    """``path`` exists as anything (file, pipe, directory...), without opening it."""
    try:
        os.stat(path)
    except OSError:
        return False
    return True


class _Limits:
    def __init__(self, where: str, what: str):
        self.where, self.what = where, what

    def pairs(self, pairs: list[tuple[str, Any]]) -> dict[str, Any]:
        """JSON object hook: a key given twice is an error (JSON would keep the last)."""
        out: dict[str, Any] = {}
        for key, value in pairs:
            if key in out:
                raise InputError(self.where, f"{self.what}, key '{_short(key)}'",
                                 "appears twice", "keep one of the two entries")
            out[key] = value
        return out


def read_json(path: str | os.PathLike[str], *, what: str = "file",
              example: str = '{"bore_mm": 25}') -> object:
    """The parsed content of a JSON file, within the limits of this module.

    ``what`` names the file's role in messages (``"file"``, ``"--priors"``); ``example``
    shows a valid document in the fix.
    """
    where = str(path)
    info = regular_file(path, what=what,
                        fix="check the path and that it is a UTF-8 JSON file")
    if info.st_size > MAX_JSON_BYTES:
        raise InputError(where, what, f"is {info.st_size} bytes, more than the "
                         f"{MAX_JSON_BYTES} accepted for a JSON metadata file",
                         f"give a small JSON object, e.g. {example}")
    try:
        raw = Path(path).read_bytes()
        text = raw.decode("utf-8-sig")
    except OSError as exc:
        raise InputError(where, what, f"cannot be read ({exc.strerror})",
                         "check the path") from None
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise InputError(where, f"{what}, line {line}",
                         f"byte 0x{raw[exc.start]:02x} is not UTF-8",
                         "save the file as UTF-8") from None
    limits = _Limits(where, what)
    try:
        value = json.loads(text, object_pairs_hook=limits.pairs)
    except json.JSONDecodeError as exc:
        label = "" if what == "file" else f"{what}, "
        raise InputError(where, f"{label}line {exc.lineno}, column {exc.colno}",
                         f"malformed JSON ({exc.msg})", "fix the JSON syntax") from None
    except InputError:
        raise
    except RecursionError:
        raise InputError(where, what, f"is nested deeper than {MAX_JSON_DEPTH} levels",
                         f"give a flat JSON object, e.g. {example}") from None
    except ValueError as exc:       # e.g. an integer literal with thousands of digits
        raise InputError(where, what, f"holds a value JSON cannot represent "
                         f"({_short(str(exc), 60)})", "give ordinary numbers") from None
    _check_tree(value, where=where, what=what, example=example)
    return value


def _check_tree(value: object, *, where: str, what: str, example: str) -> None:
    """At most ``MAX_JSON_DEPTH`` levels and ``MAX_JSON_VALUES`` values (no recursion)."""
    stack: list[tuple[object, int]] = [(value, 1)]
    count = 0
    while stack:
        node, depth = stack.pop()
        count += 1
        if depth > MAX_JSON_DEPTH:
            raise InputError(where, what, f"is nested deeper than {MAX_JSON_DEPTH} levels",
                             f"give a flat JSON object, e.g. {example}")
        if count > MAX_JSON_VALUES:
            raise InputError(where, what, f"holds more than {MAX_JSON_VALUES} values",
                             f"give a small JSON object, e.g. {example}")
        if isinstance(node, dict):
            stack.extend((v, depth + 1) for v in node.values())
        elif isinstance(node, list):
            stack.extend((v, depth + 1) for v in node)
