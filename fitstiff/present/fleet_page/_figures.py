"""The fleet page's figures, each drawn on a given Axes: the distribution of one quantity over
the cylinders, an outlier's loops over a typical cylinder's, and a quantity over the runs."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.ticker import MaxNLocator


def plot_distribution(ax, values: np.ndarray, *, mean: float | None, spread: float | None,
                      interval: Sequence[float | None] | None, outliers: np.ndarray,
                      label: str, unit: str) -> None:
    """The cylinders' estimates of one quantity (histogram), the population's log-normal
    density (median ``mean``, log standard deviation ``spread``) scaled to the histogram, its
    mean's 95 % interval (band) and the outliers' values (red lines). A spread too small to
    draw as a curve is a line at the mean."""
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    outliers = np.asarray(outliers, float)
    outliers = outliers[np.isfinite(outliers)]
    ax.set_xlabel(f"{label} ({unit})" if unit else label)
    ax.set_ylabel("cylinders")
    if values.size == 0:
        ax.text(0.5, 0.5, "no estimates", ha="center", transform=ax.transAxes)
        return
    counts, edges, _ = ax.hist(values, bins=min(40, max(8, values.size // 8)),
                               color="#9ab", edgecolor="white", label="cylinders", zorder=2)
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    if interval is not None and None not in interval and all(map(math.isfinite, interval)):
        ax.axvspan(interval[0], interval[1], color="#2e7d32", alpha=0.22, zorder=1,
                   label="population mean, 95 %")
    width = edges[1] - edges[0]
    if mean is not None and math.isfinite(mean) and mean > 0:
        shown = f"spread {100 * spread:.1f} %" if spread is not None else "spread n/a"
        if spread is None or not spread > 0 or spread * mean < width / 4:
            ax.axvline(mean, color="#2e7d32", lw=1.5, zorder=3,
                       label=f"population mean ({shown})")
        else:
            lo = min(edges[0], mean * math.exp(-3 * spread))
            hi = max(edges[-1], mean * math.exp(3 * spread))
            x = np.linspace(lo, hi, 300)
            x = x[x > 0]
            density = np.exp(-0.5 * ((np.log(x) - math.log(mean)) / spread) ** 2) / (
                x * spread * math.sqrt(2 * math.pi))
            ax.plot(x, density * values.size * width, color="#2e7d32", zorder=3,
                    label=f"population ({shown})")
    for k, v in enumerate(outliers):
        ax.axvline(v, color="#c62828", lw=1.4, zorder=4, label="outlier" if k == 0 else None)
    ax.legend(fontsize=7, loc="upper right")


def plot_loops(ax, outlier, typical, *, title: str, missing: str = "") -> None:
    """Measured force against displacement (mm) of an outlier's log (red) over a typical
    cylinder's (grey), each less its median force; ``missing`` says why a log is absent."""
    drawn = False
    for log, color, label, width in ((typical, "#888", "typical", 1.0),
                                     (outlier, "#c62828", "outlier", 0.8)):
        if log is None:
            continue
        force = np.asarray(log.force)
        ax.plot(np.asarray(log.displacement) * 1e3, force - np.median(force), color=color,
                lw=width, label=label)
        drawn = True
    if missing:
        ax.text(0.02, 0.02, missing, fontsize=6, color="#c62828", transform=ax.transAxes,
                wrap=True)
    ax.set_title(title, fontsize=8)
    ax.set_xlabel("displacement (mm)", fontsize=8)
    ax.set_ylabel("force - median (N)", fontsize=8)
    ax.tick_params(labelsize=7)
    if drawn:
        ax.legend(fontsize=7)


def plot_drift(ax, runs: Mapping[str, tuple[np.ndarray, np.ndarray]], *,
               drifting: Sequence[str], label: str) -> None:
    """A quantity over its cylinders' runs (``{cylinder: (run_index, values)}``), relative
    to each cylinder's first run with a value: the ``drifting`` cylinders in colour, the
    others faint."""
    for name, (index, values) in runs.items():
        index, values = np.asarray(index, float), np.asarray(values, float)
        ok = np.isfinite(values) & (values != 0)
        if ok.sum() < 2:
            continue
        rel = 100 * (values[ok] / values[ok][0] - 1)
        if name in drifting:
            ax.plot(index[ok], rel, marker="o", lw=1.5, label=name, zorder=3)
        else:
            ax.plot(index[ok], rel, color="#bbb", lw=0.7, zorder=1)
    ax.axhline(0, color="#666", lw=0.8)
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("run index (0: first run)")
    ax.set_ylabel(f"{label}: change from first run (%)")
    if any(name in drifting for name in runs):
        ax.legend(fontsize=7, ncol=2)
