"""Hysteresis loops: measured force against displacement with the model's curve (and a
predictive band), and the zoom on a reversal."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import PolyCollection
from matplotlib.path import Path
from numpy.typing import ArrayLike

from fitstiff.errors import InputError
from fitstiff.io.log import Log
from fitstiff.present.plotting._common import (BAND, MEASURED, MODEL, NOT_FITTED, ZOOM_PAD,
                                               check_segmentation, samples_of, run_of)
from fitstiff.segments.segmentation import Segmentation
from fitstiff.units import MM

__all__ = ["plot_loop", "reversal_zoom_samples", "reversal_zoom_window"]


# -- loops ----------------------------------------------------------------------------------------
def plot_loop(ax: Axes, log: Log, prediction: ArrayLike, *,
              band: tuple[ArrayLike, ArrayLike] | None = None,
              contributions: Mapping[str, ArrayLike] | None = None,
              zoom: tuple[float, float] | None = None, label: str = "model",
              measured: ArrayLike | None = None, measured_label: str = "measured",
              samples: slice | None = None, used: ArrayLike | None = None) -> Axes:
    """Measured force over displacement with the model's force on top.

    Args:
        ax: where to draw.
        log: the measured log.
        prediction: the model's force at each sample of ``log`` (N), e.g.
            ``result.problem.per_log(result.theta)[i]["force"]``.
        band: ``(lower, upper)`` force at each sample (N), e.g. posterior-predictive
            quantiles; drawn as a ribbon along the measured path (valid for a path that turns
            back on itself, unlike ``fill_between``).
        contributions: label -> force of one term at each sample (N), drawn dashed (e.g. the
            chamber and the seal from ``per_log(...)["contributions"]``).
        zoom: ``(low, high)`` displacement window (mm); the force axis fits the measured,
            predicted and band values inside it. :func:`reversal_zoom_window` picks the window
            after a reversal, where the pre-sliding curve shows.
        label: legend label of ``prediction``.
        measured: the measured curve to draw instead of the log's force (N per sample), e.g.
            the seal's force as measured: the force minus the model's other terms.
        measured_label: legend label of the measured curve.
        samples: draw only this run of samples (e.g. :func:`reversal_zoom_samples`: one
            pre-sliding curve instead of every pass through a displacement window); the
            axes fit them unless ``zoom`` is given.
        used: per sample, whether it carried weight in the fit (``--range``, ``--skip``);
            the others are drawn light grey as "not fitted", without the model.

    Returns:
        ``ax``.

    Raises:
        InputError: an array whose length is not the log's, a band with ``lower > upper``, a
            zoom window that is empty or holds no sample, a ``samples`` run that holds none.
    """
    keep = run_of(samples, log)
    x = log.displacement[keep] / MM
    force = (np.asarray(log.force) if measured is None
             else samples_of(measured, log, "measured"))[keep]
    model = samples_of(prediction, log, "prediction")[keep]
    terms = {name: samples_of(values, log, f"contribution '{name}'")[keep]
             for name, values in (contributions or {}).items()}
    fitted = (np.ones(len(log), dtype=bool) if used is None
              else samples_of(used, log, "used").astype(bool))[keep]
    shown = [force, model]
    if band is not None:
        lower, upper = (b[keep] for b in _band(band, log))
        ax.add_collection(_ribbon(x, lower, upper, facecolor=BAND, label="predictive band"))
        shown += [lower, upper]
    if not fitted.all():
        ax.plot(x, force, color=NOT_FITTED, lw=0.8, label="not fitted")
        force, model = np.where(fitted, force, np.nan), np.where(fitted, model, np.nan)
        terms = {name: np.where(fitted, values, np.nan) for name, values in terms.items()}
    ax.plot(x, force, color=MEASURED, lw=0.8, label=measured_label)
    ax.plot(x, model, color=MODEL, lw=1.2, label=label)
    for name, values in terms.items():
        ax.plot(x, values, lw=1.0, ls="--", label=name)
    ax.set_xlabel("displacement [mm]")
    ax.set_ylabel("force [N]")
    if zoom is None:
        ax.autoscale_view()
    else:
        _zoom(ax, log, x, shown, zoom)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small")
    return ax


def reversal_zoom_window(segmentation: Segmentation, log: Log, *, reversal: int | None = None,
                         travel_mm: float | None = None,
                         margin: float = 0.15) -> tuple[float, float]:
    """The displacement window (mm) spanning ``travel_mm`` of travel after one reversal.

    Args:
        segmentation: the log's segmentation (:func:`fitstiff.segments.segmentation.segment`).
        log: the log.
        reversal: position in ``segmentation.reversals`` (negative counts from the end);
            default: of the reversals followed by at least ``travel_mm``, the one after the
            longest travel (its friction state is the most saturated, so the pre-sliding
            curve after it is the full one).
        travel_mm: travel shown after the reversal; default the segmentation's pre-sliding
            range (0.5 mm unless set otherwise).
        margin: extra width on both sides, as a fraction of ``travel_mm``.

    Returns:
        ``(low, high)`` in mm, for ``plot_loop(..., zoom=...)``.
    """
    k, travel = _pick_reversal(segmentation, log, reversal, travel_mm, used=None)
    x = log.displacement / MM
    reversals = segmentation.reversals
    turn = x[reversals[k]]
    approach = turn - x[reversals[k - 1] if k else 0]
    end = turn - math.copysign(travel, approach)      # the leg after turns back
    low, high = sorted((turn, end))
    return low - margin * travel, high + margin * travel


def reversal_zoom_samples(segmentation: Segmentation, log: Log, *, reversal: int | None = None,
                          travel_mm: float | None = None,
                          used: ArrayLike | None = None) -> slice:
    """The samples of one pre-sliding curve: from a reversal until ``travel_mm`` after it.

    Unlike :func:`reversal_zoom_window` (a displacement window, which every pass of the log
    through it crosses), this is one curve, for ``plot_loop(..., samples=...)``.

    Args:
        segmentation: the log's segmentation.
        log: the log.
        reversal: position in ``segmentation.reversals``; default as in
            :func:`reversal_zoom_window`, among the reversals whose samples were fitted.
        travel_mm: travel after the reversal; default the segmentation's pre-sliding range.
        used: per sample, whether it carried weight in the fit: the default reversal is one
            whose curve lies in the fitted samples, when there is one.

    Returns:
        ``slice(start, stop)`` of sample indices, ``start`` the reversal.
    """
    k, travel = _pick_reversal(segmentation, log, reversal, travel_mm, used=used)
    x = log.displacement / MM
    reversals = segmentation.reversals
    start = int(reversals[k])
    leg_end = int(reversals[k + 1]) + 1 if k + 1 < reversals.size else len(log)
    beyond = np.flatnonzero(np.abs(x[start:leg_end] - x[start]) >= travel)
    stop = start + int(beyond[0]) + 1 if beyond.size else leg_end
    return slice(start, max(stop, start + 2))


def _pick_reversal(segmentation: Segmentation, log: Log, reversal: int | None,
                   travel_mm: float | None, *, used: ArrayLike | None) -> tuple[int, float]:
    """``(k, travel in mm)``: the chosen position in ``segmentation.reversals``."""
    check_segmentation(segmentation, log)
    reversals = segmentation.reversals
    if reversals.size == 0:
        raise InputError(log.name, "reversal zoom window", "the log has no direction reversal",
                         "give plot_loop a zoom window (low_mm, high_mm) of your own")
    travel = segmentation.presliding_range / MM if travel_mm is None else float(travel_mm)
    if not (math.isfinite(travel) and travel > 0):
        raise InputError(log.name, "zoom travel_mm", f"found {travel_mm!r}",
                         "give a positive travel in mm")
    if reversal is not None:
        if not (isinstance(reversal, (int, np.integer))
                and -reversals.size <= reversal < reversals.size):
            raise InputError(log.name, f"reversal {reversal!r}", "is not a reversal index",
                             f"give a whole number from {-reversals.size} to "
                             f"{reversals.size - 1}")
        return int(reversal) % reversals.size, travel
    x = log.displacement / MM
    nxt = np.append(reversals[1:], len(log) - 1)
    before = np.abs(x[reversals] - x[np.insert(reversals[:-1], 0, 0)])
    after = np.abs(x[nxt] - x[reversals])
    fitted = np.ones(reversals.size, dtype=bool)
    if used is not None:
        u = samples_of(used, log, "used").astype(bool)
        fitted = u[reversals] & u[nxt]
        if not fitted.any():
            fitted[:] = True
    enough = fitted & (after >= travel)
    k = int(np.argmax(np.where(enough, before, -np.inf)) if enough.any()
            else np.argmax(np.where(fitted, after, -np.inf)))
    return k, travel


def _band(band, log: Log) -> tuple[np.ndarray, np.ndarray]:
    if len(band) != 2:
        raise InputError(log.name, "band", f"has {len(band)} arrays",
                         "give (lower, upper), one force array each")
    lower, upper = (samples_of(b, log, f"band {side}")
                    for b, side in zip(band, ("lower", "upper"), strict=True))
    if np.any(lower > upper):
        raise InputError(log.name, "band", f"lower above upper at {np.sum(lower > upper)} samples",
                         "give (lower, upper) in that order")
    return lower, upper


def _ribbon(x: np.ndarray, lower: np.ndarray, upper: np.ndarray, **style) -> PolyCollection:
    """One quadrilateral per step between consecutive samples: a band along any path.

    The quadrilaterals form one compound path, each drawn counter-clockwise (left to right
    along the lower edge), so the non-zero fill rule fills their union in one pass: no seams,
    and the legend's "best" placement tests one path instead of one per sample.
    """
    back = x[1:] < x[:-1]                       # steps toward smaller x: swap their ends

    def end(a: np.ndarray, first: bool) -> np.ndarray:
        return np.where(back == first, a[1:], a[:-1])

    xa, xb = end(x, True), end(x, False)
    quads = np.stack([np.column_stack([xa, end(lower, True)]),
                      np.column_stack([xb, end(lower, False)]),
                      np.column_stack([xb, end(upper, False)]),
                      np.column_stack([xa, end(upper, True)]),
                      np.column_stack([xa, end(lower, True)])], axis=1)
    codes = np.tile([Path.MOVETO, Path.LINETO, Path.LINETO, Path.LINETO, Path.CLOSEPOLY],
                    len(quads))
    ribbon = PolyCollection([], linewidths=0, **style)
    ribbon.set_verts_and_codes([quads.reshape(-1, 2)], [codes])
    return ribbon


def _zoom(ax: Axes, log: Log, x: np.ndarray, curves: Sequence[np.ndarray],
          window: tuple[float, float]) -> None:
    low, high = (float(v) for v in window)
    if not (math.isfinite(low) and math.isfinite(high) and low < high):
        raise InputError(log.name, "zoom window", f"found {window!r}",
                         "give (low_mm, high_mm) with low < high")
    inside = (x >= low) & (x <= high)
    if not inside.any():
        raise InputError(log.name, f"zoom window {low:g}..{high:g} mm", "holds no sample",
                         f"choose a window within the log's {x.min():g}..{x.max():g} mm")
    values = np.concatenate([c[inside] for c in curves])
    lo, hi = float(np.nanmin(values)), float(np.nanmax(values))
    pad = ZOOM_PAD * (hi - lo) if hi > lo else 1.0
    ax.set_xlim(low, high)
    ax.set_ylim(lo - pad, hi + pad)
