"""The chamber's gas spring against the seal's pre-sliding spring over the stroke
(:func:`contributions_over_stroke`, :func:`plot_contributions_over_stroke`)."""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.axes import Axes

from fitstiff.errors import InputError
from fitstiff.io.log import Rig
from fitstiff.physics.derived import presliding_curve
from fitstiff.physics.model import Model
from fitstiff.physics.stiffness import chamber_stiffness, table_positions
from fitstiff.physics.terms import FrictionBase
from fitstiff.units import MM

if TYPE_CHECKING:
    from fitstiff.inference.fitting import FitResult

__all__ = ["StrokeContributions", "contributions_over_stroke", "plot_contributions_over_stroke"]


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
