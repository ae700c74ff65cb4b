"""Figures of fits and posteriors (issue 6, the posterior-plot report; DESIGN §4).

Every function draws on a matplotlib :class:`~matplotlib.axes.Axes` that the caller made and
returns it: no pyplot state, no ``show``, any backend (Agg included). Options are keyword-only.
Axes carry units: displacement and stroke position in mm, force in N, stiffness in N/mm, time
in s.

======================================  ===========================================================
:func:`plot_loop`                       measured force-displacement loop with the model's force,
                                        optional predictive band, per-term forces and a zoom window
:func:`reversal_zoom_window`            the displacement window just after a reversal (Fig. 4's
                                        pre-sliding view), for ``plot_loop(..., zoom=...)``
:func:`reversal_zoom_samples`           the samples of one pre-sliding curve after a reversal, for
                                        ``plot_loop(..., samples=...)``
:func:`plot_residuals`                  residuals over time or displacement, by segmentation region
                                        or direction of motion
:func:`sliding_friction_level`          a log's friction level in gross sliding (N)
:func:`plot_friction_levels`            sliding friction against pressure, one point per log
:func:`plot_contributions_over_stroke`  chamber against seal restoring force over the stroke
                                        (:func:`contributions_over_stroke` gives the numbers)
:func:`plot_corner`                     corner plot of posterior samples (takes a *Figure*)
:func:`plot_trace`, :func:`plot_autocorr`  MCMC diagnostics of one parameter's chain
======================================  ===========================================================

>>> from matplotlib.figure import Figure
>>> fig = Figure(figsize=(9, 4))
>>> full, zoomed = fig.subplots(1, 2)
>>> seg, log = result.problem.segmentations[0], result.problem.logs[0]    # doctest: +SKIP
>>> force = result.problem.per_log(result.theta)[0]["force"]               # doctest: +SKIP
>>> plot_loop(full, log, force)                                            # doctest: +SKIP
>>> plot_loop(zoomed, log, force, zoom=reversal_zoom_window(seg, log))    # doctest: +SKIP
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Mapping, Sequence
from types import MappingProxyType
from typing import TYPE_CHECKING, Literal

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure
from matplotlib.path import Path
from numpy.typing import ArrayLike

from fitstiff.errors import InputError
from fitstiff.io.log import Log, Rig
from fitstiff.physics.derived import presliding_curve
from fitstiff.physics.model import Model
from fitstiff.physics.stiffness import chamber_stiffness, table_positions
from fitstiff.physics.terms import FrictionBase
from fitstiff.segments.segmentation import REGIONS, Segmentation
from fitstiff.units import MM

if TYPE_CHECKING:
    from fitstiff.inference.fitting import FitResult

__all__ = [
    "DIRECTION_COLORS",
    "REGION_COLORS",
    "StrokeContributions",
    "contributions_over_stroke",
    "plot_autocorr",
    "plot_contributions_over_stroke",
    "plot_corner",
    "plot_friction_levels",
    "plot_gap_heatmap",
    "plot_loop",
    "plot_residual_signature",
    "plot_residuals",
    "plot_trace",
    "reversal_zoom_samples",
    "reversal_zoom_window",
    "sliding_friction_level",
]

REGION_COLORS: Mapping[str, str] = MappingProxyType({
    "presliding": "tab:orange", "sliding": "tab:blue", "dwell": "tab:red",
    "standstill": "tab:gray"})
"""Colour of each motion region (the partition :attr:`Segmentation.region`) in every figure.
The overlapping ``stroke_end`` flag is not drawn."""

_MEASURED = "0.55"
_MODEL = "tab:red"
_NOT_FITTED = "0.85"
DIRECTION_COLORS: Mapping[str, str] = MappingProxyType({
    "toward B": "tab:green", "toward A": "tab:purple", "standing": "tab:gray"})
"""Colour of each direction of motion (:attr:`Segmentation.direction` +1, -1, 0)."""
_BAND = "#f5c2c2"       # opaque, so a band the loop crosses twice is not darker there
_ZOOM_PAD = 0.05        # of the force span in a zoom window
_AUTOCORR_RUNS = 50     # emcee's rule of thumb: run at least 50 autocorrelation times


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
    keep = _run_of(samples, log)
    x = log.displacement[keep] / MM
    force = (np.asarray(log.force) if measured is None
             else _per_sample(measured, log, "measured"))[keep]
    model = _per_sample(prediction, log, "prediction")[keep]
    terms = {name: _per_sample(values, log, f"contribution '{name}'")[keep]
             for name, values in (contributions or {}).items()}
    fitted = (np.ones(len(log), dtype=bool) if used is None
              else _per_sample(used, log, "used").astype(bool))[keep]
    shown = [force, model]
    if band is not None:
        lower, upper = (b[keep] for b in _band(band, log))
        ax.add_collection(_ribbon(x, lower, upper, facecolor=_BAND, label="predictive band"))
        shown += [lower, upper]
    if not fitted.all():
        ax.plot(x, force, color=_NOT_FITTED, lw=0.8, label="not fitted")
        force, model = np.where(fitted, force, np.nan), np.where(fitted, model, np.nan)
        terms = {name: np.where(fitted, values, np.nan) for name, values in terms.items()}
    ax.plot(x, force, color=_MEASURED, lw=0.8, label=measured_label)
    ax.plot(x, model, color=_MODEL, lw=1.2, label=label)
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
    _check_segmentation(segmentation, log)
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
        u = _per_sample(used, log, "used").astype(bool)
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
    lower, upper = (_per_sample(b, log, f"band {side}")
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
    pad = _ZOOM_PAD * (hi - lo) if hi > lo else 1.0
    ax.set_xlim(low, high)
    ax.set_ylim(lo - pad, hi + pad)


# -- residuals ------------------------------------------------------------------------------------
def plot_residuals(ax: Axes, log: Log, residual: ArrayLike, segmentation: Segmentation, *,
                   against: Literal["displacement", "time"] = "displacement",
                   by: Literal["region", "direction"] = "region",
                   used: ArrayLike | None = None) -> Axes:
    """Force residuals with the segmentation's motion regions (or directions), one legend
    entry each.

    Against time the regions shade the background (one collection per region) behind the
    residual trace; against displacement, where the regions overlap along the axis, each
    region's residuals are drawn as points in its colour (:data:`REGION_COLORS`,
    :data:`DIRECTION_COLORS`).

    Args:
        ax: where to draw.
        log: the log.
        residual: model minus measured force at each sample (N).
        segmentation: the log's segmentation.
        against: ``"displacement"`` (mm) or ``"time"`` (s; the log needs time).
        by: colour by motion ``"region"`` or by ``"direction"`` of motion (a misfit that
            changes sign with the direction is a friction level; one that does not, a
            spring or an offset).
        used: per sample, whether it carried weight in the fit; the others are drawn as
            "not fitted" (light grey) in neither region nor direction.

    Returns:
        ``ax``.
    """
    res = _per_sample(residual, log, "residual")
    _check_segmentation(segmentation, log)
    fitted = (np.ones(len(log), dtype=bool) if used is None
              else _per_sample(used, log, "used").astype(bool))
    if by == "region":
        colors, codes = REGION_COLORS, {r: REGIONS.index(r) for r in REGION_COLORS}
        per_sample = segmentation.region
    elif by == "direction":
        colors, codes = DIRECTION_COLORS, dict(zip(DIRECTION_COLORS, (1, -1, 0)))
        per_sample = segmentation.direction
    else:
        raise InputError(log.name, f"residuals by '{by}'", "is not a colouring",
                         "use by='region' or by='direction'")
    masks = {r: m for r in colors if (m := (per_sample == codes[r]) & fitted).any()}
    if not fitted.all():
        masks["not fitted"] = ~fitted
        colors = {**colors, "not fitted": _NOT_FITTED}
    if against == "time":
        if log.time is None:
            raise InputError(log.name, "residuals against time",
                             "the log has no time column (quasi-static)",
                             "plot against='displacement'")
        t = np.asarray(log.time)
        edges = np.concatenate([t[:1], (t[1:] + t[:-1]) / 2, t[-1:]])   # sample k: edges[k:k+2]
        for region, mask in masks.items():
            ax.add_collection(_spans(edges, mask, ax, facecolor=colors[region],
                                     alpha=0.25, label=region), autolim=False)
        ax.plot(t, res, color="k", lw=0.6)
        ax.set_xlim(t[0], t[-1])
        ax.set_xlabel("time [s]")
    elif against == "displacement":
        x = log.displacement / MM
        for region, mask in masks.items():
            ax.plot(x[mask], res[mask], ls="", marker=".", ms=2.5, color=colors[region],
                    label=region)
        ax.set_xlabel("displacement [mm]")
    else:
        raise InputError(log.name, f"residuals against '{against}'", "is not an axis",
                         "use against='displacement' or against='time'")
    ax.axhline(0.0, color="k", lw=0.6, alpha=0.6)
    if not fitted.all() and fitted.any():        # the scale of the fitted residuals
        lo, hi = float(np.nanmin(res[fitted])), float(np.nanmax(res[fitted]))
        pad = _ZOOM_PAD * (hi - lo) if hi > lo else 1.0
        ax.set_ylim(min(lo, 0.0) - pad, max(hi, 0.0) + pad)
    ax.set_ylabel("residual, model − measured [N]")
    ax.grid(True, alpha=0.3)
    ax.legend(title=by, fontsize="small", markerscale=3, loc="lower left",
              bbox_to_anchor=(0.0, 1.0), ncols=len(masks), frameon=False)
    return ax


def _spans(edges: np.ndarray, mask: np.ndarray, ax: Axes, **style) -> PolyCollection:
    """Full-height rectangles over the runs of ``mask`` (x in data, y in axes coordinates)."""
    step = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(step == 1), np.flatnonzero(step == -1)
    rects = [[(edges[a], 0.0), (edges[b], 0.0), (edges[b], 1.0), (edges[a], 1.0)]
             for a, b in zip(starts, stops, strict=True)]
    return PolyCollection(rects, transform=ax.get_xaxis_transform(), linewidths=0, **style)


# -- chamber against seal over the stroke ---------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class StrokeContributions:
    """Chamber and seal restoring force over the stroke for one small displacement.

    Attributes:
        displacement_mm: the displacement ``u`` (+ toward the B cap).
        position_mm: closing positions ``x`` (length of chamber A), those where the displaced
            piston stays at least ``|u|`` from either cap (closer in, the chamber force of a
            chamber without dead volume grows without bound).
        chamber_N: restoring force of the closed chambers, exact polytropic law,
            ``|F(u) - F(0)|`` with both chambers closed at ``x`` at the rig's supply pressure.
        seal_N: the seal's force swing ``|u|`` after a reversal from saturation (the
            pre-sliding curve; independent of the position).
        crossover_mm: positions where the chamber force equals the seal's (ascending).
        n: the polytropic exponent used.
    """

    displacement_mm: float
    position_mm: np.ndarray
    chamber_N: np.ndarray
    seal_N: float
    crossover_mm: np.ndarray
    n: float


def contributions_over_stroke(model: Model, rig: Rig, *, displacement_mm: float = 0.5,
                              count: int = 700, n: float | None = None) -> StrokeContributions:
    """Where the chamber and where the seal dominates (the paper's §4 discussion).

    Args:
        model: a model with a ``chamber`` term and a friction base (a fitted one:
            ``result.model``).
        rig: the cylinder (bore, stroke, dead lengths, supply pressure).
        displacement_mm: the small displacement ``u`` (mm, + toward the B cap; the exact law
            differs between the directions near the caps).
        count: number of positions (centres of equal slices of the stroke,
            :func:`fitstiff.physics.stiffness.table_positions`).
        n: polytropic exponent; default the model's (needed when its chamber used measured
            pressures, so that ``n`` was not fitted).
    """
    if not model.has("chamber") or not model.terms_of(FrictionBase):
        raise InputError(None, f"model '{model.spec}'", "needs a chamber term and a friction base",
                         "use a model such as chamber+dahl")
    chamber = model.term("chamber")
    if n is None and not chamber.closed:
        raise InputError(None, "chamber over the stroke",
                         "the chambers are regulated (the logged pressures drive the model), "
                         "so the logs do not determine n",
                         "give n (1.4 for fast, adiabatic compression)")
    n = float(chamber.n if n is None else n)
    u = float(displacement_mm) * MM
    if not (math.isfinite(u) and u != 0):
        raise InputError(None, "displacement_mm", f"found {displacement_mm!r}",
                         "give a small non-zero displacement in mm")
    stroke = rig.require("stroke", needed_for="the chamber force over the stroke")
    x = table_positions(stroke, count)
    x = x[np.minimum(x + u, stroke - x - u) >= abs(u)]
    chamber_n = np.array([abs(chamber_stiffness(rig, position=float(p), displacement=u,
                                                n=n).force_exact) for p in x])
    travel, force = (np.asarray(a) for a in presliding_curve(model))
    if abs(u) > travel[-1]:
        raise InputError(None, "displacement_mm", f"{displacement_mm:g} mm is beyond the seal's "
                         f"pre-sliding curve ({travel[-1] / MM:.3g} mm)", "give a smaller one")
    seal = float(np.interp(abs(u), travel, force - force[0]))
    gap = chamber_n - seal
    k = np.flatnonzero(np.sign(gap[1:]) != np.sign(gap[:-1]))
    crossings = x[k] - gap[k] * (x[k + 1] - x[k]) / (gap[k + 1] - gap[k])
    return StrokeContributions(displacement_mm=float(displacement_mm), position_mm=x / MM,
                               chamber_N=chamber_n, seal_N=seal, crossover_mm=crossings / MM,
                               n=n)


def plot_contributions_over_stroke(ax: Axes, source: FitResult | Model, *, rig: Rig | None = None,
                                   displacement_mm: float = 0.5, stiffness: bool = False,
                                   count: int = 700, n: float | None = None,
                                   log_scale: bool = True) -> Axes:
    """Chamber against seal restoring force (or secant stiffness) over the stroke.

    Draws the chamber (exact law, closed at each position at the supply pressure), the seal
    (constant: its swing ``|u|`` after a reversal) and their sum; marks and labels the
    crossovers and the log's closing position. Near the caps the chamber dominates, in the
    middle of the stroke the seal (for the paper's cylinder).

    Args:
        ax: where to draw.
        source: a :class:`~fitstiff.inference.fitting.FitResult` (its model, and by default the
            rig of its first log) or a :class:`~fitstiff.physics.model.Model`.
        rig: the cylinder; needed with a model, overrides a fit's.
        displacement_mm, count, n: see :func:`contributions_over_stroke`.
        stiffness: draw the secant stiffness ``F / |u|`` (N/mm) instead of the force (N).
        log_scale: logarithmic force axis (the chamber force diverges at a cap without dead
            volume).

    Returns:
        ``ax``.
    """
    if isinstance(source, Model):
        model = source
        if rig is None:
            raise InputError(None, "chamber over the stroke", "a model was given without a rig",
                             "pass rig=Rig(...) or a FitResult")
    else:
        model = source.model
        rig = source.problem.logs[0].rig if rig is None else rig
    c = contributions_over_stroke(model, rig, displacement_mm=displacement_mm, count=count, n=n)
    scale, unit, what = ((1 / abs(c.displacement_mm), "N/mm", "secant stiffness") if stiffness
                         else (1.0, "N", "restoring force"))
    x = c.position_mm
    seal = np.full(x.shape, c.seal_N * scale)
    ax.plot(x, c.chamber_N * scale, color="tab:blue", label=f"chamber (exact law, n = {c.n:.3g})")
    ax.plot(x, seal, color="tab:orange", label="seal (pre-sliding curve)")
    ax.plot(x, c.chamber_N * scale + seal, color="k", ls="--", lw=1, label="total")
    if c.crossover_mm.size:
        ax.plot(c.crossover_mm, np.full(c.crossover_mm.shape, c.seal_N * scale), "o",
                color="k", ms=5, label="crossover")
        for xc in c.crossover_mm:
            inward = 1 if xc < rig.stroke / MM / 2 else -1   # below the seal, toward mid-stroke
            ax.annotate(f"{xc:.0f} mm", (xc, c.seal_N * scale), xytext=(6 * inward, -4),
                        textcoords="offset points", ha="left" if inward > 0 else "right",
                        va="top", fontsize="small")
    if rig.start_position is not None:
        ax.axvline(rig.start_position / MM, color="0.5", ls=":", lw=1,
                   label=f"closing position {rig.start_position / MM:.0f} mm")
    if log_scale:
        ax.set_yscale("log")
    ax.set_xlim(0, rig.stroke / MM)
    ax.set_xlabel("piston position x (length of chamber A) [mm]")
    ax.set_ylabel(f"{what} over {c.displacement_mm:g} mm [{unit}]")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize="small", loc="upper center")
    return ax


# -- posterior ------------------------------------------------------------------------------------
def plot_corner(fig: Figure, samples: ArrayLike, names: Sequence[str], *,
                truths: Sequence[float] | None = None,
                quantiles: Sequence[float] = (0.05, 0.5, 0.95)) -> Figure:
    """Corner plot (pairwise 2-D and 1-D marginal histograms) of posterior samples.

    Takes a Figure, not an Axes: a corner plot is a grid of ``K x K`` axes, which the
    ``corner`` package lays out itself (``fig`` must have no axes yet, or exactly ``K * K``).

    Args:
        fig: an empty figure (e.g. ``Figure(figsize=(2.5 * K, 2.5 * K))``).
        samples: ``(n_samples, K)`` draws.
        names: ``K`` axis labels, with units (``"sigma0 [N/mm]"``).
        truths: ``K`` true values to mark (synthetic data).
        quantiles: three increasing quantiles (low, middle, high), marked on the 1-D
            histograms and quoted in their titles (name, then the middle one and its distances
            to the others; default the 5/50/95 % of ``posterior.json``).

    Returns:
        ``fig``. Needs the ``corner`` package (``pip install corner``).
    """
    data = np.asarray(samples, dtype=float)
    if data.ndim != 2 or data.shape[1] != len(names) or data.shape[0] < 2:
        raise InputError(None, "corner samples", f"have shape {data.shape} for {len(names)} names",
                         "give an (n_samples, K) array with one name per column")
    if truths is not None and len(truths) != len(names):
        raise InputError(None, "corner truths", f"{len(truths)} values for {len(names)} names",
                         "give one true value per name")
    if not np.all(np.isfinite(data)):
        raise InputError(None, "corner samples", "contain NaN or inf", "drop those draws")
    q = np.asarray(quantiles, dtype=float)
    if q.shape != (3,) or not (0 < q[0] < q[1] < q[2] < 1):
        raise InputError(None, "corner quantiles", f"found {list(quantiles)}",
                         "give three increasing quantiles in (0, 1), e.g. (0.05, 0.5, 0.95)")
    try:
        with warnings.catch_warnings():   # corner imports arviz, which announces a refactor
            warnings.simplefilter("ignore", FutureWarning)
            import corner
    except ModuleNotFoundError:
        raise InputError(None, "corner plot", "the 'corner' package is not installed",
                         "pip install corner") from None
    corner.corner(data, fig=fig, labels=list(names), truths=truths, quantiles=list(q))
    k = len(names)
    for ax, column, name in zip(np.asarray(fig.axes).reshape(k, k).diagonal(), data.T, names):
        ax.set_title(_quantile_title(name, *np.quantile(column, q)), fontsize="medium")
    return fig


def _quantile_title(name: str, low: float, mid: float, high: float) -> str:
    """``name`` over ``mid`` and its distances to the outer quantiles, with the decimals that
    give the smaller distance two significant digits (corner's fixed ``.2f`` shows a
    posterior 40.003 +0.024 -0.025 as 40.00 +0.02 -0.02, and n = 1.3998 +0.0043 as 1.40 +0.00)."""
    spread = min(mid - low, high - mid)
    d = max(0, 1 - math.floor(math.log10(spread))) if spread > 0 else 3
    return f"{name}\n${mid:.{d}f}^{{+{high - mid:.{d}f}}}_{{-{mid - low:.{d}f}}}$"


def plot_trace(ax: Axes, chain: ArrayLike, name: str, *, unit: str = "") -> Axes:
    """Trace of one parameter: every walker's value over the steps and their median.

    Args:
        ax: where to draw.
        chain: ``(steps, walkers)`` values of the parameter.
        name: the parameter's name; ``unit`` its display unit.
    """
    values = _chain(chain, name)
    steps = np.arange(values.shape[0])
    lines = ax.plot(steps, values, color="k", lw=0.5, alpha=0.3)
    lines[0].set_label(f"walkers ({values.shape[1]})")
    ax.plot(steps, np.median(values, axis=1), color=_MODEL, lw=1.2, label="median over walkers")
    ax.set_xlabel("step")
    ax.set_ylabel(f"{name} [{unit}]" if unit else name)
    ax.legend(fontsize="small")
    return ax


def plot_autocorr(ax: Axes, chain: ArrayLike, name: str, *, points: int = 12) -> Axes:
    """Running estimate of the integrated autocorrelation time against the chain length.

    emcee's estimator (autocorrelation averaged over walkers, Sokal's window ``c = 5``) on the
    first ``N`` steps for ``points`` log-spaced ``N``, with the line ``N / 50``: the chain is
    long enough once the estimate has levelled off below it (``N > 50 tau``).

    Args:
        ax: where to draw.
        chain: ``(steps, walkers)`` values of the parameter (at least 10 steps).
        name: the parameter's name.
        points: number of chain lengths ``N``.
    """
    from emcee.autocorr import integrated_time

    values = _chain(chain, name)
    if values.shape[0] < 10:
        raise InputError(None, f"chain of '{name}'", f"has {values.shape[0]} steps",
                         "give at least 10 steps")
    lengths = np.unique(np.geomspace(10, values.shape[0], points).astype(int))
    with np.errstate(invalid="ignore", divide="ignore"):      # NaN where nothing moved
        tau = [float(integrated_time(values[:m, :, None], tol=0, quiet=True)[0])
               for m in lengths]
    ax.loglog(lengths, tau, "o-", color="tab:blue", label=f"tau estimate, {name}")
    ax.loglog(lengths, lengths / _AUTOCORR_RUNS, "k--", lw=1, label=f"N / {_AUTOCORR_RUNS}")
    ax.set_xlabel("chain length N [steps]")
    ax.set_ylabel("integrated autocorrelation time tau [steps]")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize="small")
    return ax


# -- checks ---------------------------------------------------------------------------------------
def plot_gap_heatmap(ax: Axes, table, *, label: str = "z-score of the RMS against the noise",
                     limit: float = 30.0) -> Axes:
    """Region x log heat map of a held-out misfit table (rows regions, columns logs, as
    :func:`fitstiff.diagnosis.gap.region_summary` returns); cells are annotated with their
    value, blank where the log has no such samples. The colour scale runs from 0 to
    ``limit`` (larger values are drawn at it); the report gives the before and after maps one
    ``limit``, the largest cell of the two."""
    values = np.asarray(table.to_numpy(), dtype=float)
    if values.ndim != 2 or values.size == 0:
        raise InputError(None, "gap table", f"has shape {values.shape}",
                         "give a region x log table")
    shown = np.ma.masked_invalid(np.clip(values, 0.0, limit))
    image = ax.imshow(shown, cmap="Reds", vmin=0.0, vmax=limit, aspect="auto")
    ax.set_xticks(range(values.shape[1]), [str(c) for c in table.columns], rotation=30,
                  ha="right")
    ax.set_yticks(range(values.shape[0]), [str(r) for r in table.index])
    for (i, j), v in np.ndenumerate(values):
        if np.isfinite(v):
            ax.text(j, i, f"{v:.3g}", ha="center", va="center", fontsize=8,
                    color="white" if min(max(v, 0), limit) > 0.6 * limit else "black")
    ax.figure.colorbar(image, ax=ax, label=label)
    return ax


def plot_residual_signature(ax: Axes, x: ArrayLike, before: ArrayLike, after: ArrayLike | None,
                            *, xlabel: str, bins: int = 30) -> Axes:
    """Held-out residual against one variable (displacement since reversal, velocity,
    pressure, position, time): the samples faint, the binned mean and +-1 sd of the residual
    before (and after) the accepted effects. A trend or a step is an effect's signature."""
    x = np.asarray(x, dtype=float)
    before = np.asarray(before, dtype=float)
    if x.shape != before.shape or (after is not None and np.shape(after) != x.shape):
        raise InputError(None, "residual signature", f"arrays of shapes {x.shape}, "
                         f"{before.shape}, {np.shape(after)}", "give arrays of one length")
    ok = np.isfinite(x)
    series = [("before", before, "tab:red")]
    if after is not None:
        series.append(("after", np.asarray(after, dtype=float), "tab:blue"))
    edges = np.quantile(x[ok], np.linspace(0, 1, bins + 1)) if ok.any() else np.zeros(2)
    edges = np.unique(edges)
    for name, r, color in series:
        ax.plot(x[ok], r[ok], ".", ms=1.5, alpha=0.15, color=color, rasterized=True)
        if edges.size < 2:
            continue
        idx = np.clip(np.searchsorted(edges, x[ok], side="right") - 1, 0, edges.size - 2)
        counts = np.bincount(idx, minlength=edges.size - 1)
        keep = counts > 2
        mean = np.bincount(idx, r[ok], minlength=edges.size - 1)[keep] / counts[keep]
        sq = np.bincount(idx, r[ok] ** 2, minlength=edges.size - 1)[keep] / counts[keep]
        sd = np.sqrt(np.clip(sq - mean**2, 0, None))
        centre = 0.5 * (edges[:-1] + edges[1:])[keep]
        ax.plot(centre, mean, "-", color=color, lw=1.8, label=f"{name}: binned mean")
        ax.fill_between(centre, mean - sd, mean + sd, color=color, alpha=0.15, lw=0)
    ax.axhline(0.0, color="0.3", lw=0.8)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("held-out residual (N)")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper right", fontsize=8)
    else:
        ax.set_title("one value only: no trend to show", fontsize=9)
    return ax


def sliding_friction_level(force: ArrayLike, segmentation: Segmentation, *,
                           used: ArrayLike | None = None) -> float:
    """The friction level of a log in gross sliding (N): half the difference between the
    median force sliding toward B and sliding toward A.

    ``force`` is the seal's force, measured (the log's force minus the model's other terms)
    or modelled; an offset and a spring force symmetric in the two directions cancel. NaN
    when either direction has no sliding sample (among ``used``).
    """
    f = np.asarray(force, dtype=float)
    if f.shape != (segmentation.n_samples,):
        raise InputError(segmentation.name, "force", f"has shape {f.shape}",
                         f"give one value per sample ({segmentation.n_samples})")
    keep = segmentation.region == REGIONS.index("sliding")
    if used is not None:
        keep &= np.asarray(used, dtype=bool)
    toward_b, toward_a = (keep & (segmentation.direction == d) for d in (1, -1))
    if not (toward_b.any() and toward_a.any()):
        return math.nan
    return 0.5 * abs(float(np.median(f[toward_b])) - float(np.median(f[toward_a])))


def plot_friction_levels(ax: Axes, pressure_bar: ArrayLike, measured: ArrayLike,
                         model: ArrayLike | None = None, *,
                         names: Sequence[str] | None = None) -> Axes:
    """Sliding friction level against pressure, one point per log.

    Args:
        ax: where to draw.
        pressure_bar: each log's pressure level (bar gauge).
        measured: each log's measured level (N, :func:`sliding_friction_level` of the force
            minus the model's other terms).
        model: each log's modelled level (N), drawn as a line through the logs.
        names: each log's name, written beside its point.

    Returns:
        ``ax``.
    """
    p = np.asarray(pressure_bar, dtype=float)
    order = np.argsort(p)
    ax.plot(p[order], np.asarray(measured, dtype=float)[order], ls="", marker="o",
            color=_MEASURED, label="measured")
    if model is not None:
        ax.plot(p[order], np.asarray(model, dtype=float)[order], marker="x", color=_MODEL,
                label="model")
    for i, name in enumerate(names or ()):
        ax.annotate(name, (p[i], float(np.asarray(measured)[i])), fontsize="x-small",
                    xytext=(4, 4), textcoords="offset points")
    ax.set_xlabel("pressure [bar gauge]")
    ax.set_ylabel("sliding friction [N]")
    ax.set_ylim(bottom=0.0)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small")
    return ax


def _run_of(samples: slice | None, log: Log) -> slice:
    if samples is None:
        return slice(None)
    if not isinstance(samples, slice) or samples.step not in (None, 1):
        raise InputError(log.name, f"samples {samples!r}", "is not a run of samples",
                         "give slice(start, stop), e.g. reversal_zoom_samples(...)")
    if len(range(*samples.indices(len(log)))) < 2:
        raise InputError(log.name, f"samples {samples.start}:{samples.stop}",
                         "hold fewer than two samples",
                         f"give a run within the log's {len(log)} samples")
    return samples


def _per_sample(values: ArrayLike, log: Log, what: str) -> np.ndarray:
    a = np.asarray(values, dtype=float)
    if a.shape != (len(log),):
        raise InputError(log.name, what, f"has shape {a.shape}, the log {len(log)} samples",
                         "give one value per sample of the log")
    return a


def _check_segmentation(segmentation: Segmentation, log: Log) -> None:
    if segmentation.n_samples != len(log):
        raise InputError(log.name, f"segmentation of '{segmentation.name}'",
                         f"has {segmentation.n_samples} samples, the log {len(log)}",
                         "pass the segmentation of this log "
                         "(fitstiff.segments.segmentation.segment)")


def _chain(chain: ArrayLike, name: str) -> np.ndarray:
    a = np.asarray(chain, dtype=float)
    if a.ndim != 2 or a.shape[0] < 2:
        raise InputError(None, f"chain of '{name}'", f"has shape {a.shape}",
                         "give a (steps, walkers) array with at least 2 steps")
    if not np.all(np.isfinite(a)):
        raise InputError(None, f"chain of '{name}'", "contains NaN or inf",
                         "check the sampler's log-probability")
    return a
