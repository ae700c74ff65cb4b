"""Numerical guards at the boundaries of the computations.

The loader bounds every value (:mod:`fitstiff.io.validation`), so a computation on a loaded log
cannot overflow; logs made in memory, rig values set in code and models at extreme parameter
values can still reach one. These guards stop a non-finite number where it would otherwise
flow on silently - the residuals and Jacobian of a fit, its covariance, the log-posterior,
a result document before it is written - and turn it into one
:class:`~fitstiff.errors.InputError` that names the log and the likely cause, found by
:func:`likely_cause` (``force spike of 1e+300 N at line 812``).

:func:`check_logs` refuses, before a fit, a log with a non-finite or implausible value (a log
made in memory did not pass the loader) or one that gives a fit nothing to determine (no
motion).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence

import numpy as np

from fitstiff.errors import InputError
from fitstiff.io.log import Log
from fitstiff.io.validation import CHANNEL_LIMITS

__all__ = ["MIN_TRAVEL_M", "check_finite", "check_logs", "first_nonfinite", "likely_cause",
           "nonfinite_error"]

#: a log whose displacement spans less than this did not move (1 nm, below any sensor)
MIN_TRAVEL_M = 1e-9
_SPIKE = 1e3          # |value - median| / spread above which a sample is called a spike
_SHORT_CHAMBER = 1e-6  # m, a closed chamber this short is singular (drive.MIN_CHAMBER_LENGTH)

#: channel -> (Log attribute, display unit, SI per display unit)
_CHANNELS = (("force", "force", "N", 1.0), ("displacement", "displacement", "mm", 1e-3),
             ("pressure A", "pressure_a", "bar abs", 1e5),
             ("pressure B", "pressure_b", "bar abs", 1e5), ("time", "time", "s", 1.0))
_QUANTITY = {"force": "force", "displacement": "displacement", "pressure_a": "p_a",
             "pressure_b": "p_b", "time": "time"}


def _where(log: Log) -> str:
    return str(log.path) if log.path is not None else log.name


def _sample(log: Log, i: int) -> str:
    """Where sample ``i`` is: ``line 812`` for sample 810 of a file with a header row (as
    the loader counts lines), ``sample 810`` for a log made in memory."""
    if log.path is not None and "header" in log.source:
        return f"line {i + 1 + int(bool(log.source['header']))}"
    return f"sample {i}"


def check_logs(logs: Iterable[Log]) -> None:
    """Logs a fit can use: every channel finite and within its physical bound
    (:data:`~fitstiff.io.validation.CHANNEL_LIMITS`, as the loader checks; a log made in memory
    did not pass the loader), and motion: a displacement that spans less than
    :data:`MIN_TRAVEL_M` gives a fit nothing to determine (no reversal, no slope, no
    friction level)."""
    for log in logs:
        for label, attribute, unit, scale in _CHANNELS:
            values = getattr(log, attribute)
            if values is None:
                continue
            v = np.asarray(values, dtype=float)
            limit = CHANNEL_LIMITS[_QUANTITY[attribute]]
            bad = np.flatnonzero(~(np.abs(v) <= limit.bound))
            if bad.size:
                i = int(bad[0])
                raise InputError(_where(log), f"{label}, {_sample(log, i)}",
                                 f"found {v[i] / scale:.4g} {unit}, beyond the plausible "
                                 f"magnitude {limit.describe()}",
                                 "correct or remove the sample (a spike?) and check the unit")
        x = np.asarray(log.displacement, dtype=float)
        span = float(np.ptp(x)) if x.size else 0.0
        if not span >= MIN_TRAVEL_M:
            found = (f"every value is {x[0]:g} m" if span == 0 else
                     f"it spans only {span:.3g} m")
            raise InputError(_where(log), "displacement", f"{found}: the piston does not move, "
                             "so there is no motion to fit",
                             "give a log recorded while the piston moves (inspect it with "
                             "fitstiff inspect)")


def _chamber_cause(log: Log) -> tuple[float, str] | None:
    """A chamber that (nearly) closes to zero length during the log, if the rig says so."""
    rig = log.rig
    if rig.stroke is None or rig.start_position is None:
        return None
    x = np.asarray(log.displacement, dtype=float)
    if not x.size or not np.isfinite(x).all():
        return None
    lengths = (("A", rig.start_position + (rig.dead_length_a or 0.0) + x, "dead_length_a_mm"),
               ("B", rig.stroke - rig.start_position + (rig.dead_length_b or 0.0) - x,
                "dead_length_b_mm"))
    for chamber, length, key in lengths:
        i = int(np.argmin(length))
        if length[i] < _SHORT_CHAMBER:
            return (math.inf, f"chamber {chamber} closes to {length[i] * 1e3:.3g} mm at "
                              f"{_sample(log, i)} (start_position_mm, stroke_mm and {key}), "
                              "where the gas spring is singular")
    return None


def _spike(log: Log) -> tuple[float, str] | None:
    """The most extreme sample of any channel, as ``(score, description)``."""
    best: tuple[float, str] | None = None
    for label, attribute, unit, scale in _CHANNELS:
        values = getattr(log, attribute)
        if values is None or not len(values):
            continue
        v = np.asarray(values, dtype=float)
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            return (math.inf, f"{label} is {v[bad[0]]} at {_sample(log, int(bad[0]))}")
        if attribute == "time":
            continue     # monotone: no spike, and a long pause is real
        with np.errstate(over="ignore", invalid="ignore"):
            median = float(np.median(v))
            q25, q75 = np.percentile(v, [25, 75])
            spread = max(float(q75 - q25), 1e-12 * float(np.max(np.abs(v))), 1e-300)
            score = np.abs(v - median) / spread
        i = int(np.argmax(score))
        if score[i] > _SPIKE and (best is None or score[i] > best[0]):
            best = (float(score[i]),
                    f"{label} spike of {v[i] / scale:.4g} {unit} at {_sample(log, i)} (the "
                    f"middle half of the channel spans {q25 / scale:.4g}..{q75 / scale:.4g} "
                    f"{unit})")
    return best


def likely_cause(logs: Sequence[Log]) -> tuple[Log | None, str]:
    """The log and the most probable reason a computation on ``logs`` is not finite."""
    found: list[tuple[float, Log, str]] = []
    for log in logs:
        for cause in (_spike(log), _chamber_cause(log)):
            if cause is not None:
                found.append((cause[0], log, cause[1]))
    if found:
        _, log, text = max(found, key=lambda item: item[0])
        return log, text
    return None, ("no single extreme sample stands out: extreme rig metadata or parameter "
                  "values (--fix, priors) are likely")


def nonfinite_error(logs: Sequence[Log], what: str, *, state: str = "not finite"
                    ) -> InputError:
    """The :class:`InputError` for a non-finite ``what`` (e.g. "the fit's residuals")."""
    log, cause = likely_cause(logs)
    where = (_where(log) if log is not None
             else ", ".join(_where(item) for item in logs) or None)
    return InputError(where, what, f"{state} (likely cause: {cause})",
                      "correct or remove the offending samples or values and run again; "
                      "fitstiff inspect shows each channel's range")


def check_finite(logs: Sequence[Log], what: str, *arrays, limit: float | None = None) -> None:
    """A :func:`nonfinite_error` unless every entry of ``arrays`` is finite (and, with
    ``limit``, at most ``limit`` in magnitude: squares and sums of such entries cannot
    overflow downstream)."""
    for array in arrays:
        a = np.asarray(array, dtype=float)
        ok = np.isfinite(a) if limit is None else np.abs(np.nan_to_num(a, nan=np.inf)) <= limit
        if not np.all(ok):
            raise nonfinite_error(logs, what, state="not finite" if limit is None else
                                  f"not finite or beyond {limit:g} in magnitude")


def first_nonfinite(obj, path: str = "") -> tuple[str, object] | None:
    """``(path, value)`` of the first non-finite number in a result document, else ``None``.

    Walks mappings, lists, tuples, numpy / JAX arrays and scalars; ``None`` (a value the
    producer marks as not determined) is fine. The path reads like ``derived.breakaway_N.q50``.
    """
    if isinstance(obj, Mapping):
        for key, value in obj.items():
            hit = first_nonfinite(value, f"{path}.{key}" if path else str(key))
            if hit:
                return hit
        return None
    if isinstance(obj, (list, tuple)):
        for i, value in enumerate(obj):
            hit = first_nonfinite(value, f"{path}[{i}]")
            if hit:
                return hit
        return None
    if isinstance(obj, (bool, np.bool_, str, bytes)) or obj is None:
        return None
    if hasattr(obj, "shape") and hasattr(obj, "dtype"):
        array = np.asarray(obj)
        if array.dtype.kind in "fc":
            bad = np.flatnonzero(~np.isfinite(array).ravel())
            if bad.size:
                index = np.unravel_index(int(bad[0]), array.shape) if array.ndim else ()
                label = path + "".join(f"[{j}]" for j in index)
                return label, array.ravel()[bad[0]]
        return None
    if isinstance(obj, (float, np.floating)) and not math.isfinite(float(obj)):
        return path, obj
    return None
