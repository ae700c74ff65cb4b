"""Residuals and the gap: residuals over time with the motion regions behind them, the region x
log heat map, residual signatures before and after, and friction levels against pressure."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import PolyCollection
from numpy.typing import ArrayLike

from fitstiff.errors import InputError
from fitstiff.io.log import Log
from fitstiff.present.plotting._common import (DIRECTION_COLORS, REGION_COLORS, MEASURED, MODEL,
                                               NOT_FITTED, ZOOM_PAD, check_segmentation, samples_of)
from fitstiff.segments.segmentation import REGIONS, Segmentation
from fitstiff.units import MM

__all__ = ["plot_friction_levels", "plot_gap_heatmap", "plot_residual_signature", "plot_structure",
           "plot_residuals", "sliding_friction_level"]


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
    res = samples_of(residual, log, "residual")
    check_segmentation(segmentation, log)
    fitted = (np.ones(len(log), dtype=bool) if used is None
              else samples_of(used, log, "used").astype(bool))
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
        colors = {**colors, "not fitted": NOT_FITTED}
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
        pad = ZOOM_PAD * (hi - lo) if hi > lo else 1.0
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
                            *, xlabel: str, bins: int = 30,
                            ylabel: str = "held-out residual (N)") -> Axes:
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
    ax.set_ylabel(ylabel)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper right", fontsize=8)
    else:
        ax.set_title("one value only: no trend to show", fontsize=9)
    return ax


def plot_structure(ax: Axes, x: ArrayLike, residual: ArrayLike, prediction: ArrayLike, *,
                   sign: ArrayLike | None = None, shape: dict | None = None, xlabel: str,
                   bins: int = 30) -> Axes:
    """A description of the unexplained residual (:mod:`fitstiff.diagnosis.structure`): the
    held-out residual against the variable it follows before (red) and after (blue) taking
    the description's held-out prediction off, and the fitted shape (black). A
    sign-dependent description is drawn times its ``sign`` (the direction of motion, or of
    the force's change), where it is one curve."""
    x = np.asarray(x, dtype=float)
    r = np.asarray(residual, dtype=float)
    pred = np.asarray(prediction, dtype=float)
    s = np.ones_like(r) if sign is None else np.asarray(sign, dtype=float)
    keep = s != 0
    signed = sign is not None
    plot_residual_signature(ax, x[keep], (r * s)[keep], ((r - pred) * s)[keep], xlabel=xlabel,
                            bins=bins, ylabel="held-out residual" + (" x direction" if signed
                                                                     else "") + " (N)")
    if shape and shape.get("x"):
        curve = shape.get("toward_B") if signed else shape.get("y")
        if curve is not None:
            xs = np.asarray(shape["x"], dtype=float)
            ys = np.array([np.nan if v is None else v for v in curve], dtype=float)
            ax.plot(xs, ys, "-", color="black", lw=2.0, label="fitted description")
            ax.legend(loc="upper right", fontsize=8)
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
            color=MEASURED, label="measured")
    if model is not None:
        ax.plot(p[order], np.asarray(model, dtype=float)[order], marker="x", color=MODEL,
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
