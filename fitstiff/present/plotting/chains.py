"""Posterior figures: the corner plot, chain traces and autocorrelation times."""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from numpy.typing import ArrayLike

from fitstiff.errors import InputError
from fitstiff.present.plotting._common import MODEL

__all__ = ["plot_autocorr", "plot_corner", "plot_trace"]

_AUTOCORR_RUNS = 50     # emcee's rule of thumb: run at least 50 autocorrelation times


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
    ax.plot(steps, np.median(values, axis=1), color=MODEL, lw=1.2, label="median over walkers")
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


def _chain(chain: ArrayLike, name: str) -> np.ndarray:
    a = np.asarray(chain, dtype=float)
    if a.ndim != 2 or a.shape[0] < 2:
        raise InputError(None, f"chain of '{name}'", f"has shape {a.shape}",
                         "give a (steps, walkers) array with at least 2 steps")
    if not np.all(np.isfinite(a)):
        raise InputError(None, f"chain of '{name}'", "contains NaN or inf",
                         "check the sampler's log-probability")
    return a
