"""The fleet page's text: quantity labels, numbers, q-values and sizes as written, and the
command that makes a unit's report."""

from __future__ import annotations

import math
import shlex
from collections.abc import Mapping
from pathlib import Path

_LABELS = {"presliding_slope_N_per_mm": ("pre-sliding slope", "N/mm"),
           "breakaway_N": ("breakaway", "N"), "presliding_range_mm": ("pre-sliding range", "mm"),
           "chamber_stiffness_N_per_mm": ("chamber stiffness", "N/mm"),
           "total_stiffness_N_per_mm": ("total stiffness", "N/mm")}


def _label(name: str) -> tuple[str, str]:
    from fitstiff.physics.derived import split_unit

    if name in _LABELS:
        return _LABELS[name]
    label, unit = split_unit(name)
    return label.replace("_", " "), unit


def _q(value: float | None) -> str:
    if value is None or not math.isfinite(value):
        return "q n/a"
    return f"q = {value:.2g}" if value >= 1e-12 else "q < 1e-12"


def _fmt(value, digits: int = 4) -> str:
    try:
        value = float(value)
    except (TypeError, ValueError):
        return "n/a"
    return "n/a" if not math.isfinite(value) else f"{value:.{digits}g}"


def _pm(value, err) -> str:
    if _fmt(value) == "n/a" or _fmt(err) == "n/a":
        return _fmt(value)
    return f"{float(value):.4g} ± {float(err):.2g}"


def _flag(value) -> bool:
    """A boolean column's cell; missing (None, NaN) is False."""
    return value is not None and not (isinstance(value, float) and math.isnan(value)) \
        and bool(value)


def _pct(value) -> str:
    return "n/a" if _fmt(value) == "n/a" else f"{100 * float(value):+.1f} %"


def _sizes(sizes: Mapping[str, float], *, per_run: bool = False) -> str:
    tail = " per run" if per_run else ""
    return ", ".join(f"{_label(k)[0]} {100 * v:+.1f} %{tail}" for k, v in sizes.items())


def _command(directory: Path, cylinder: str, run: str) -> str:
    return ("fitstiff report " + shlex.quote(str(directory)) + " --cylinder "
            + shlex.quote(cylinder) + (" --run " + shlex.quote(run) if run else ""))
