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
:func:`plot_program`                    a planned program's displacement and where the rivals'
                                        predicted forces on it part
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

from fitstiff.present.plotting._common import DIRECTION_COLORS, REGION_COLORS
from fitstiff.present.plotting.chains import plot_autocorr, plot_corner, plot_trace
from fitstiff.present.plotting.loops import plot_loop, reversal_zoom_samples, reversal_zoom_window
from fitstiff.present.plotting.programs import plot_program
from fitstiff.present.plotting.residuals import (plot_friction_levels, plot_gap_heatmap,
                                                 plot_residual_signature, plot_residuals,
                                                 plot_structure,
                                                 sliding_friction_level)
from fitstiff.present.plotting.stroke import (StrokeContributions, contributions_over_stroke,
                                              plot_contributions_over_stroke)

__all__ = ["DIRECTION_COLORS", "REGION_COLORS", "StrokeContributions",
           "contributions_over_stroke", "plot_autocorr", "plot_contributions_over_stroke",
           "plot_corner", "plot_friction_levels", "plot_gap_heatmap", "plot_loop", "plot_program",
           "plot_residual_signature", "plot_residuals", "plot_structure", "plot_trace", "reversal_zoom_samples",
           "reversal_zoom_window", "sliding_friction_level"]
