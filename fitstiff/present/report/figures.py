"""The figures of the report pages (each drawn by a :mod:`fitstiff.present.plotting` function on
its own Axes): loops, residuals, friction against pressure, the chamber and the seal over the
stroke, the corner plot and the chain traces."""

from __future__ import annotations

import dataclasses
import math
import re
import warnings
from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.figure import Figure

from fitstiff.errors import InputError
from fitstiff.inference.posterior import INFERENCE_DATA
from fitstiff.inference.problem import Problem
from fitstiff.io.log import Log
from fitstiff.physics.derived import split_unit
from fitstiff.physics.model import Model
from fitstiff.present import plotting
from fitstiff.present.reopen import Chain, Curves, RunDirectory, read_json
from fitstiff.present.report.text import fmt, paragraph, html_table
from fitstiff.units import MM

__all__ = ["ReportFigure", "Section", "file_stem", "model_sections", "corner_figure",
           "chain_figures", "truth_of"]


# -- figures --------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class ReportFigure:
    """One figure of the report: ``figures/<name>.png`` and ``.svg``, shown with a caption."""

    name: str
    caption: str
    figure: Figure


@dataclasses.dataclass(frozen=True)
class Section:
    title: str
    html: str = ""                                 # already escaped
    figures: tuple[ReportFigure, ...] = ()


def file_stem(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


def _used(problem: Problem, i: int) -> np.ndarray | None:
    """The samples that carried weight in the run, or ``None`` when all did."""
    used = problem.sample_weights[i] > 0
    return None if used.all() else used


def _seal(curves: Curves, i: int) -> np.ndarray | None:
    """The model's seal force of log ``i`` (its friction terms), ``None`` without one."""
    seals = [f for label, f in curves.contributions[i].items() if label.startswith("seal (")]
    return np.sum(seals, axis=0) if seals else None


def _loop_figure(problem: Problem, curves: Curves, i: int) -> ReportFigure:
    log, seg = problem.logs[i], problem.segmentations[i]
    band = curves.band[i] if curves.band else None
    used = _used(problem, i)
    seal = _seal(curves, i)
    others = None if seal is None else curves.force[i] - seal     # chamber, offset, ...
    friction_view = seal is not None and any(not label.startswith("seal (")
                                             for label in curves.contributions[i])
    try:
        samples = plotting.reversal_zoom_samples(seg, log, used=used)
    except InputError as exc:          # no reversal: the whole loop only
        samples, note = None, f" No zoom: {exc}."
    else:
        t = f"t = {log.time[samples.start]:.4g} s, " if log.time is not None else ""
        note = (f" Right: the pre-sliding curve after one reversal ({t}sample "
                f"{samples.start}), {seg.presliding_range / MM:g} mm of travel from the reversal "
                "that follows the longest travel (the curve from saturation, as in the paper's "
                "Fig. 4).")
    panels = 1 + friction_view + (samples is not None)
    fig = Figure(figsize=(5.2 * panels + 1.0, 4.6), layout="constrained")
    axes = list(fig.subplots(1, panels, squeeze=False)[0])
    ax = axes.pop(0)
    plotting.plot_loop(ax, log, curves.force[i], band=band,
                       contributions=curves.contributions[i], label=curves.label, used=used)
    ax.set_title(f"{log.name}: whole log")
    if friction_view:
        ax = axes.pop(0)
        plotting.plot_loop(ax, log, seal, measured=np.asarray(log.force) - others,
                           measured_label="measured − other terms", label="seal model",
                           used=used)
        ax.set_title("seal force alone")
        note += (" Middle: the seal's force as measured (the force minus the model's other "
                 "terms and offset) against the modelled seal force, so a friction misfit "
                 "under a large chamber force shows.")
    if samples is not None:
        ax = axes.pop(0)
        plotting.plot_loop(ax, log, curves.force[i], band=band, samples=samples,
                           label=curves.label)
        ax.set_title("pre-sliding after a reversal")
    shaded = " The shaded band is the 90 % posterior-predictive band." if band else ""
    excluded = (" Light grey: samples outside the fitted range (not fitted)."
                if used is not None else "")
    caption = (f"{log.name}: measured force against displacement with the model "
               f"({curves.label}); dashed: the force of each term (the per-log offset "
               f"not included).{shaded}{excluded}{note}")
    return ReportFigure(f"loop_{file_stem(log.name)}", caption, fig)


def _residual_figure(problem: Problem, curves: Curves, i: int) -> ReportFigure:
    log, seg = problem.logs[i], problem.segmentations[i]
    used = _used(problem, i)
    views = [("displacement", "region"), ("displacement", "direction")]
    views += [("time", "region")] if log.has_time else []
    fig = Figure(figsize=(5.2 * len(views) + 1.0, 4.0), layout="constrained")
    residual = curves.residual(problem, i)
    for ax, (axis, by) in zip(fig.subplots(1, len(views), squeeze=False)[0], views):
        plotting.plot_residuals(ax, log, residual, seg, against=axis, by=by, used=used)
    fitted = "" if used is None else f" over the {int(used.sum())} fitted samples"
    fig.suptitle(f"{log.name}: RMS {curves.rms(problem, i):.3g} N{fitted}, force noise "
                 f"estimate {problem.force_noise[i]:.3g} N")
    caption = (f"{log.name}: residual (model - measured) against displacement, coloured by "
               "motion region (pre-sliding after a reversal, sliding, dwell after a standstill, "
               "standstill) and by direction of motion, and against time. Structure that "
               "repeats at every reversal, a level that differs between the regions, or one "
               "that flips sign with the direction (a friction level) is what the model misses."
               + ("" if used is None else f" The RMS is{fitted}; light grey: samples outside "
                  "the fitted range."))
    return ReportFigure(f"residuals_{file_stem(log.name)}", caption, fig)


def _friction_section(problem: Problem, curves: Curves) -> Section | None:
    """Sliding friction per log and pressure, measured (force minus the model's other terms)
    and modelled; ``None`` when the model has no seal."""
    rows, points = [], []
    for i, (log, seg) in enumerate(zip(problem.logs, problem.segmentations)):
        seal = _seal(curves, i)
        if seal is None:
            return None
        used = problem.sample_weights[i] > 0
        measured = np.asarray(log.force) - (curves.force[i] - seal)
        level = plotting.sliding_friction_level(measured, seg, used=used)
        modelled = plotting.sliding_friction_level(seal, seg, used=used)
        bar = None if seg.pressure_level is None else seg.pressure_level / 1e5
        rows.append([log.name, fmt(bar, 3), fmt(level, 3), fmt(modelled, 3),
                     fmt(modelled - level, 3)])
        if bar is not None and math.isfinite(level):
            points.append((bar, level, modelled, log.name))
    html = html_table(["log", "pressure [bar gauge]", "measured sliding friction [N]",
                   "model sliding friction [N]", "model − measured [N]"], rows) + paragraph(
        "Sliding friction: half the difference between the median seal force sliding toward B "
        "and toward A (offsets and spring forces cancel). Measured: the force minus the "
        "model's other terms (chamber, offset, ...); model: the fitted seal force. A model "
        "that misses how friction grows with pressure shows as a trend in the last column "
        "(add pressure_friction; its beta is the relative change per bar from its reference "
        "pressure).")
    if len({round(p[0], 2) for p in points}) < 2:
        return Section("Friction against pressure", html=html)
    fig = Figure(figsize=(6.5, 4.2), layout="constrained")
    bar, level, modelled, names = zip(*points)
    plotting.plot_friction_levels(fig.add_subplot(), bar, level, modelled, names=names)
    figure = ReportFigure("friction_vs_pressure", "Sliding friction of every log against its "
                          "pressure level: measured (points) and the fitted model (crosses).",
                          fig)
    return Section("Friction against pressure", html=html, figures=(figure,))


def _stroke_figure(problem: Problem, model: Model) -> ReportFigure | str:
    """Chamber against seal over the stroke at the highest supply pressure of the logs, or why
    it cannot be drawn."""
    rigs = [log.rig for log in problem.logs]
    rig = max(rigs, key=lambda r: -math.inf if r.supply_pressure is None else r.supply_pressure)
    fig = Figure(figsize=(12, 4.6), layout="constrained")
    ax = fig.add_subplot()
    try:
        plotting.plot_contributions_over_stroke(ax, model, rig=rig)
    except InputError as exc:
        return f"The chamber-against-seal figure is not drawn: {exc}."
    bar = "" if rig.supply_pressure is None else f" at {rig.supply_pressure / 1e5:g} bar"
    ax.set_title(f"fitted cylinder: chamber against seal over the stroke{bar}")
    caption = ("Restoring force of the closed chambers (exact polytropic law, closed at each "
               "position) against the seal's force swing over 0.5 mm after a reversal, over "
               f"the whole stroke{bar} (the highest supply pressure of the logs). Where the "
               "chamber line is below the seal's, the seal sets the stiffness.")
    return ReportFigure("chamber_vs_seal", caption, fig)


def model_sections(problem: Problem, curves: Curves) -> list[Section]:
    """Loops, residuals and chamber against seal: every kind of report has them."""
    n = problem.n_logs
    stroke = _stroke_figure(problem, curves.model)
    return [
        Section("Loops", figures=tuple(_loop_figure(problem, curves, i) for i in range(n))),
        Section("Residuals", figures=tuple(_residual_figure(problem, curves, i)
                                            for i in range(n))),
        *filter(None, [_friction_section(problem, curves)]),
        Section("Chamber against seal over the stroke",
                 html=paragraph(stroke) if isinstance(stroke, str) else "",
                 figures=() if isinstance(stroke, str) else (stroke,)),
    ]


def corner_figure(run: RunDirectory, truth: Mapping[str, float]) -> ReportFigure:
    """Corner plot of the model parameters and the derived quantities from ``posterior.nc``
    (derived quantities equal to a parameter, such as Dahl's slope = sigma0, shown once)."""
    import arviz as az

    path = run.path / INFERENCE_DATA
    if not path.is_file():
        raise InputError(str(path), "posterior samples", "are missing",
                         "run fitstiff posterior again into this directory")
    with warnings.catch_warnings():      # arviz announces a refactor
        warnings.simplefilter("ignore", FutureWarning)
        posterior = az.from_netcdf(str(path)).posterior
    columns: list[np.ndarray] = []
    labels: list[str] = []
    truths: list[float | None] = []
    record = run.posterior
    names = record.free_parameters
    for name in names + tuple(record.derived):
        values = np.asarray(posterior[name]).ravel()
        if (not np.all(np.isfinite(values)) or np.ptp(values) == 0
                or any(np.allclose(values, c, rtol=1e-9, atol=0) for c in columns)):
            continue
        label, unit = (name, record.parameters[name]["unit"]) if name in names \
            else split_unit(name)
        columns.append(values)
        labels.append(f"{label} [{unit}]" if unit not in ("", "-") else label)
        truths.append(truth.get(name))
    k = len(columns)
    fig = Figure(figsize=(2.3 * k, 2.3 * k))
    plotting.plot_corner(fig, np.column_stack(columns), labels,
                         truths=truths if any(t is not None for t in truths) else None)
    marked = (" Blue lines: the true values of the synthetic logs (from their .truth.json)."
              if any(t is not None for t in truths) else "")
    caption = ("Posterior of the parameters and derived quantities (derived at the first "
               "log's operating point): pairwise samples and marginal histograms with the 5, "
               "50 and 95 % quantiles (dashed) quoted above each column." + marked)
    return ReportFigure("corner", caption, fig)


def chain_figures(run: RunDirectory, chain: Chain) -> list[ReportFigure]:
    """Trace (with the burn-in marked) and running autocorrelation time, per parameter."""
    problem = run.problem
    out = []
    for j, name in enumerate(problem.par.names):
        values = chain.display[:, :, j]
        fig = Figure(figsize=(12, 3.8), layout="constrained")
        ax_trace, ax_tau = fig.subplots(1, 2)
        plotting.plot_trace(ax_trace, values, name, unit=run.posterior.parameters[name]["unit"])
        ax_trace.axvline(chain.discard, color="tab:blue", ls=":", lw=1.2,
                         label=f"burn-in end (step {chain.discard})")
        ax_trace.legend(fontsize="small")
        plotting.plot_autocorr(ax_tau, values, name)
        tau = run.posterior.diagnostics.autocorr_time[name]
        caption = (f"{name}: every walker's value over the steps (left; the steps before the "
                   f"dotted line are discarded as burn-in) and the running estimate of its "
                   f"integrated autocorrelation time (right; {tau:.3g} steps over the whole "
                   "chain). The chain is long enough where the estimate has levelled off "
                   "below the dashed line N / 50.")
        out.append(ReportFigure(f"trace_{file_stem(name)}", caption, fig))
    return out


def truth_of(logs: Sequence[Log]) -> dict[str, float]:
    """True values (display units) from ``<stem>.truth.json`` beside the logs: parameters
    that every truth file agrees on, derived quantities of the first log (where the report's
    derived quantities are evaluated). Empty without truth files."""
    files = [log.path.with_name(f"{log.path.stem}.truth.json") if log.path else None
             for log in logs]
    if not files or not all(f is not None and f.is_file() for f in files):
        return {}
    truths = [read_json(f) for f in files]
    params = [{k: v["value"] for k, v in t.get("parameters", {}).items()} for t in truths]
    out = {k: v for k, v in params[0].items() if all(p.get(k) == v for p in params)}
    return out | dict(truths[0].get("derived", {}))
