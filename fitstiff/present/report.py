"""Posterior-plot reports: a fit or posterior directory -> ``report.html`` + ``figures/``.

>>> from fitstiff.present.report import write_report
>>> write_report("out/fit")                                   # doctest: +SKIP
PosixPath('out/fit/report.html')

**What it draws from.** :func:`fitstiff.present.reopen.open_run` re-opens the directory (the result
file decides the kind: ``posterior.json``, ``fit.json`` or ``diagnosis.json``), re-reads and
verifies the logs and rebuilds the problem; :mod:`fitstiff.present.reopen` recomputes the model's
curves (a fit's exactly, checked against ``fit.json``; a posterior's median and 90 % predictive band
from ``predictive.npz``, its per-term forces at the most probable draw of ``chain.h5``). This module is presentation only: figures,
tables, words and the page. A new kind adds an entry to
:data:`~fitstiff.present.reopen.RESULT_FILES` and a builder to ``_BUILDERS``; the trace and
autocorrelation plots use the whole chain, the corner plot ``posterior.nc``.

**The page** is one self-contained HTML file: inline CSS, every image an embedded base64 PNG,
no script, no external reference; it opens offline. Every figure is also written as PNG and
SVG to ``figures/``. The report's own manifest is ``report.manifest.json`` (the run's
``manifest.json`` stays as it was).
"""

from __future__ import annotations

import base64
import dataclasses
import html
import io
import json
import math
import re
import warnings
from collections.abc import Callable, Mapping, Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from fitstiff import __version__
from fitstiff.errors import InputError
from fitstiff.inference.posterior import INFERENCE_DATA, PosteriorRecord
from fitstiff.inference.problem import Problem
from fitstiff.io.log import Log
from fitstiff.io.output import OutputDir
from fitstiff.physics.derived import split_unit, to_display as derived_display
from fitstiff.physics.model import Model
from fitstiff.present import plotting
from fitstiff.present.reopen import (MANIFEST, RESULT_FILES, Z90, Chain, Curves, RunDirectory,
                                     fit_curves, open_run, posterior_curves, read_chain, read_json)
from fitstiff.units import MM

__all__ = ["FIGURES", "PLANNED", "REPORT", "REPORT_MANIFEST", "RESULT_FILES", "ReportFigure",
           "RunDirectory", "open_run", "write_report"]

REPORT = "report.html"
FIGURES = "figures"
REPORT_MANIFEST = "report.manifest.json"
PLANNED = (REPORT, f"{FIGURES}/")
"""What a report writes into its directory (besides :data:`REPORT_MANIFEST`)."""

_POSTERIOR_RMS_EXCESS = 0.10    # median curve worse than least squares by more: say so
_DPI = 100
_METADATA = {"png": {"Software": None}, "svg": {"Date": None}}


# -- figures --------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class ReportFigure:
    """One figure of the report: ``figures/<name>.png`` and ``.svg``, shown with a caption."""

    name: str
    caption: str
    figure: Figure


@dataclasses.dataclass(frozen=True)
class _Section:
    title: str
    html: str = ""                                 # already escaped
    figures: tuple[ReportFigure, ...] = ()


def _file_stem(name: str) -> str:
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
    return ReportFigure(f"loop_{_file_stem(log.name)}", caption, fig)


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
    return ReportFigure(f"residuals_{_file_stem(log.name)}", caption, fig)


def _friction_section(problem: Problem, curves: Curves) -> _Section | None:
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
        rows.append([log.name, _fmt(bar, 3), _fmt(level, 3), _fmt(modelled, 3),
                     _fmt(modelled - level, 3)])
        if bar is not None and math.isfinite(level):
            points.append((bar, level, modelled, log.name))
    html = _table(["log", "pressure [bar gauge]", "measured sliding friction [N]",
                   "model sliding friction [N]", "model − measured [N]"], rows) + _p(
        "Sliding friction: half the difference between the median seal force sliding toward B "
        "and toward A (offsets and spring forces cancel). Measured: the force minus the "
        "model's other terms (chamber, offset, ...); model: the fitted seal force. A model "
        "that misses how friction grows with pressure shows as a trend in the last column "
        "(add pressure_friction; its beta is the relative change per bar from its reference "
        "pressure).")
    if len({round(p[0], 2) for p in points}) < 2:
        return _Section("Friction against pressure", html=html)
    fig = Figure(figsize=(6.5, 4.2), layout="constrained")
    bar, level, modelled, names = zip(*points)
    plotting.plot_friction_levels(fig.add_subplot(), bar, level, modelled, names=names)
    figure = ReportFigure("friction_vs_pressure", "Sliding friction of every log against its "
                          "pressure level: measured (points) and the fitted model (crosses).",
                          fig)
    return _Section("Friction against pressure", html=html, figures=(figure,))


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


def _model_sections(problem: Problem, curves: Curves) -> list[_Section]:
    """Loops, residuals and chamber against seal: every kind of report has them."""
    n = problem.n_logs
    stroke = _stroke_figure(problem, curves.model)
    return [
        _Section("Loops", figures=tuple(_loop_figure(problem, curves, i) for i in range(n))),
        _Section("Residuals", figures=tuple(_residual_figure(problem, curves, i)
                                            for i in range(n))),
        *filter(None, [_friction_section(problem, curves)]),
        _Section("Chamber against seal over the stroke",
                 html=_p(stroke) if isinstance(stroke, str) else "",
                 figures=() if isinstance(stroke, str) else (stroke,)),
    ]


def _corner_figure(run: RunDirectory, truth: Mapping[str, float]) -> ReportFigure:
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


def _chain_figures(run: RunDirectory, chain: Chain) -> list[ReportFigure]:
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
        out.append(ReportFigure(f"trace_{_file_stem(name)}", caption, fig))
    return out


def _truth(logs: Sequence[Log]) -> dict[str, float]:
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


# -- tables and words -----------------------------------------------------------------------
def _fmt(value: float | None, digits: int = 5) -> str:
    if value is None or not math.isfinite(value):
        return "n/a"
    return f"{value:.{digits}g}"


def _fmt_to(value: float | None, spread: float | None) -> str:
    """``value`` with the decimals that give ``spread`` (its uncertainty) two significant
    digits: 1.4000 for n = 1.40004 +/- 0.0026, not 1.4."""
    if value is None or spread is None or not (math.isfinite(spread) and spread > 0):
        return _fmt(value)
    return f"{value:.{max(0, 1 - math.floor(math.log10(spread)))}f}"


def _p(text: str) -> str:
    return f"<p>{html.escape(text)}</p>"


def _table(headers: Sequence[str], rows: Sequence[Sequence[str]], *,
           numeric_from: int = 1, prose: Sequence[int] = ()) -> str:
    """An HTML table; columns from ``numeric_from`` on are numbers (right-aligned, not
    wrapped), except the ``prose`` columns (sentences: left-aligned, wrapped, so a wide table
    still fits the page)."""
    def kind(j: int) -> str:
        return "prose" if j in prose else "num" if j >= numeric_from else "name"

    head = "".join(f"<th>{html.escape(h)}</th>" for h in headers)
    body = "".join(
        "<tr>" + "".join(f'<td class="{kind(j)}">{html.escape(c)}</td>'
                         for j, c in enumerate(row)) + "</tr>"
        for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


@dataclasses.dataclass(frozen=True)
class _Verdict:
    status: str                  # "ok", "caution" or "bad"
    headline: str
    details: tuple[str, ...]


def _per_log_noise(noise: Mapping[str, float], *, what: str = "force noise estimate") -> str:
    """``a force noise estimate of 0.2 N`` for one log; for several, every log's own (a mean
    would hide a log whose noise differs)."""
    if len(noise) == 1:
        return f"a {what} of {next(iter(noise.values())):.3g} N"
    return (f"{what}s of " + ", ".join(f"{v:.3g} N ({k})" for k, v in noise.items()))


def _fit_verdict(result: Mapping[str, Any]) -> _Verdict:
    rms = result["rms_N"]
    noise = _per_log_noise({p.get("name", f"log {i + 1}"): p["force_noise_N"]
                            for i, p in enumerate(result["per_log"])})
    warnings_ = tuple(result["warnings"])
    if result["converged"]:
        headline = (f"The fit converged ({result['solver']}, {result['steps']} steps): RMS "
                    f"residual {rms:.3g} N against {noise}.")
    else:
        headline = f"The fit did NOT converge: {result['message']}. Do not use its numbers."
    status = "bad" if not result["converged"] else ("caution" if warnings_ else "ok")
    if result.get("identifiable") is False:
        warnings_ = (headline,) + warnings_
        headline = _not_identifiable(result.get("identifiable_reason"),
                                     result.get("identifiability"))
        status = "bad"
    return _Verdict(status, headline, warnings_)


def _not_identifiable(reason: str | None, details: Mapping[str, Any] | None) -> str:
    """The red headline of a fit (or the fit a posterior started from) whose data do not
    separate the seal parameters (:mod:`fitstiff.inference.identifiability`): its
    ``identifiable_reason`` and ``identifiability``."""
    details = details or {}
    withheld = list(details.get("parameters", [])) + [
        split_unit(d)[0] for d in details.get("derived", [])]
    return ("The data do NOT identify the seal parameters: "
            f"{reason} No standard error is given for "
            f"{', '.join(withheld) or 'the affected quantities'}; do not quote them.")


def _posterior_verdict(record: PosteriorRecord, curves_rms: float) -> _Verdict:
    d = record.diagnostics
    tau = d.autocorr_time
    worst = max(tau, key=lambda k: tau[k])
    ess = d.effective_samples
    fewest = min(ess, key=lambda k: ess[k])
    if d.converged:
        headline = f"The chain converged: {d.reason}."
    else:
        headline = (f"The chain did NOT converge: {d.reason}. Its intervals are rough: run "
                    "longer (fitstiff posterior --resume --steps N) before quoting them.")
    details = [
        f"{d.steps} steps x {d.walkers} walkers, noise model {d.noise_model}; "
        f"burn-in {d.discard} steps discarded, thinned by {d.thin}: "
        f"{record.samples} samples kept.",
        f"Mean acceptance fraction {d.acceptance_fraction:.2f} (lowest walker "
        f"{d.acceptance_fraction_min:.2f}; 0.2-0.5 is healthy; proposal {d.moves}).",
        f"Integrated autocorrelation time: largest {tau[worst]:.3g} steps ({worst}); the chain "
        f"is {d.steps / tau[worst]:.3g} of them long ({d.tau_multiple:g} required).",
        f"Effective samples: fewest {ess[fewest]:.0f} ({fewest}).",
    ]
    if d.integrated:
        details.append(f"Integrated out analytically (exact conditional draws, not sampled): "
                       f"{', '.join(d.integrated)}.")
    cautions = [w for w in record.warnings if d.reason not in w]   # said above
    fit = record.fit
    misfit = any("posterior and least squares disagree" in w for w in record.warnings)
    if fit and not misfit and curves_rms > (1 + _POSTERIOR_RMS_EXCESS) * fit["rms_N"]:
        cautions.append(f"The posterior median curve's RMS residual, {curves_rms:.3g} N, is "
                        f"more than {100 * _POSTERIOR_RMS_EXCESS:.0f} % above the "
                        f"least-squares fit's {fit['rms_N']:.3g} N: the walkers have not "
                        "found the optimum.")
    status = "bad" if not d.converged else ("caution" if cautions else "ok")
    if record.identifiable is False:
        details.insert(0, headline)
        headline = _not_identifiable(record.identifiable_reason, record.identifiability)
        status = "bad"
    return _Verdict(status, headline, tuple(details + cautions))


def _entries(parameters: Mapping[str, Mapping[str, Any]],
             derived: Mapping[str, Mapping[str, Any]]) -> list[tuple[str, str, Mapping[str, Any]]]:
    """``(name, label, entry)`` of the parameters, then the derived quantities (their entries
    given a ``unit``)."""
    out = [(name, name, p) for name, p in parameters.items()]
    for name, d in derived.items():
        label, unit = split_unit(name)
        # a derived quantity that is a parameter of the model (Dahl's sigma0 is its pre-sliding
        # slope, Fc its breakaway) says so instead of reading as a second estimate
        same = next((n for n, p in parameters.items() if p.get("unit") == unit
                     and _center(p) is not None and _center(d) is not None
                     and math.isclose(_center(p), _center(d), rel_tol=1e-9)), None)
        out.append((name, f"{label} (= {same})" if same else label, {"unit": unit} | d))
    return out


def _center(entry: Mapping[str, Any]) -> float | None:
    """A fit entry's value or a posterior entry's median."""
    value = entry.get("value", entry.get("q50"))
    return None if value is None else float(value)


def _fit_tables(run: RunDirectory, truth: Mapping[str, float]) -> str:
    rows = []
    for name, label, e in _entries(run.result["parameters"], run.result["derived"]):
        value, stderr = e["value"], e.get("stderr")
        if e.get("fixed"):
            spread, interval = "fixed", ""
        elif stderr is None:
            spread, interval = "n/a", "n/a (not determined)"
        else:
            spread = _fmt_to(stderr, stderr)
            interval = (f"{_fmt_to(value - Z90 * stderr, stderr)} to "
                        f"{_fmt_to(value + Z90 * stderr, stderr)}")
        rows.append([label, _fmt_to(value, stderr), spread, interval, e["unit"],
                     _fmt(truth.get(name))])
    return _table(["quantity", "estimate", "standard error", "90 % interval", "unit", "truth"],
                  rows)


def _posterior_tables(run: RunDirectory, truth: Mapping[str, float]) -> str:
    record = run.posterior
    fit = record.fit or {}
    least_squares = {**fit.get("parameters", {}), **fit.get("derived", {})}
    rows = []
    for name, label, e in _entries(record.parameters, record.derived):
        if e.get("fixed"):
            rows.append([label, _fmt(e["value"]), "fixed", "", e["unit"], "",
                         _fmt(truth.get(name))])
            continue
        std, ls = e["std"], least_squares.get(name)
        rows.append([label, _fmt_to(e["q50"], std), _fmt_to(std, std),
                     f"{_fmt_to(e['q05'], std)} to {_fmt_to(e['q95'], std)}", e["unit"],
                     _value_pm(ls),
                     _fmt(truth.get(name))])
    return _table(["quantity", "median", "std", "90 % interval (5-95 %)", "unit",
                   "least squares ± stderr", "truth"], rows)


def _value_pm(entry: Mapping[str, object] | None) -> str:
    """``value ± stderr`` of a least-squares entry; the value alone where it has no stderr."""
    if entry is None or entry.get("value") is None:
        return ""
    value, stderr = entry["value"], entry.get("stderr")
    if stderr is None:
        return _fmt(value)
    return f"{_fmt_to(value, stderr)} ± {_fmt_to(stderr, stderr)}"


def _log_table(problem: Problem, curves: Curves, offsets: Sequence[float | None]) -> str:
    """Per log: size, pressure, the point model's chamber stiffness at its start, fit quality."""
    model = curves.model
    rows = []
    for i, log in enumerate(problem.logs):
        supply = log.rig.supply_pressure
        k_chamber = (derived_display("chamber_stiffness_N_per_mm",
                                     float(model.term("chamber").stiffness(problem.drives[i])))
                     if model.has("chamber") else None)
        rows.append([log.name, str(len(log)), _pressure_cell(log, supply), _fmt(k_chamber, 4),
                     _fmt(curves.rms(problem, i), 3), _fmt(problem.force_noise[i], 3),
                     _fmt(offsets[i], 3), "yes" if problem.denoised[i] else "no"])
    return _table(["log", "samples", "supply [bar gauge]", "chamber stiffness [N/mm]",
                   "RMS residual [N]", "force noise estimate [N]", "force offset [N]",
                   "displacement denoised"], rows)


def _pressure_cell(log: Log, supply: float | None) -> str:
    """The supply pressure, else the mean logged chamber pressure (regulated), else n/a."""
    if supply is not None:
        return _fmt(supply / 1e5, 3)
    logged = [(c.upper(), float(np.mean(g)) / 1e5) for c in "ab"
              if getattr(log, f"pressure_{c}") is not None
              and (g := log.gauge(c)) is not None]
    if not logged:
        return "n/a"
    return "regulated " + " / ".join(f"{c} {_fmt(v, 3)}" for c, v in logged)


def _inputs_table(run: RunDirectory) -> str:
    rows = [[str(path), f"{digest[:16]}...", "unchanged since the run"]
            for path, digest in run.inputs]
    return _table(["input file", "sha256", "check"], rows, numeric_from=3)


_DEFINITIONS = _p(
    "presliding_slope: the seal's stiffness at zero friction force (Dahl, LuGre: sigma0; right "
    "after a reversal from saturation these models start about twice as steep); breakaway: the "
    "largest friction force before gross sliding; presliding_range: travel after a reversal "
    "until the friction force has made 95 % of its swing; chamber_stiffness: linearised "
    "stiffness of the closed chambers at the first log's start (every log's in the table "
    "below); total_stiffness: their sum.")


# -- the two kinds --------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class _Report:
    title: str
    verdict: _Verdict
    summary: str                       # HTML
    sections: tuple[_Section, ...]
    summary_title: str = "Estimates"
    #: the numbers engineers quote, in one line at the top (:func:`_quote`); empty for none
    numbers: str = ""


#: the quantities of the report's first line: (derived name, label)
_QUOTED = (("presliding_slope_N_per_mm", "pre-sliding slope"), ("breakaway_N", "breakaway"))


def _quote(entries: Mapping[str, Mapping[str, Any]], *, posterior: bool) -> str:
    """``pre-sliding slope 40.01 N/mm [39.98, 40.04], breakaway 18.000 N [17.985, 18.016]
    (90 % intervals)``: the derived quantities of a fit (estimate ± 1.645 standard errors) or
    a posterior (median, 5-95 %), each to the digits its uncertainty warrants; "not
    determined" where the data leave one without an uncertainty."""
    parts = []
    for name, label in _QUOTED:
        e = entries.get(name)
        if e is None:
            continue
        unit = split_unit(name)[1]
        if posterior:
            value, spread = e["q50"], e.get("std")
            low, high = e.get("q05"), e.get("q95")
        else:
            value, spread = e["value"], e.get("stderr")
            low = None if spread is None else value - Z90 * spread
            high = None if spread is None else value + Z90 * spread
        if spread is None or low is None or high is None:
            parts.append(f"{label} {_fmt(value)} {unit} (not determined)")
        else:
            parts.append(f"{label} {_fmt_to(value, spread)} {unit} "
                         f"[{_fmt_to(low, spread)}, {_fmt_to(high, spread)}]")
    text = ", ".join(parts)
    return f"{text[:1].upper()}{text[1:]} (90 % intervals)" if parts else ""


def _fit_report(run: RunDirectory, *, draws: int) -> _Report:
    del draws                          # a fit has no posterior draws
    curves = fit_curves(run)
    truth = _truth(run.problem.logs)
    offsets = [p["offset_N"] for p in run.result["per_log"]]
    summary = (_fit_tables(run, truth)
               + _p("Standard errors from the Laplace covariance, inflated for autocorrelated "
                    "residuals; the 90 % interval is estimate ± 1.645 standard errors.")
               + _DEFINITIONS
               + _log_table(run.problem, curves, offsets))
    return _Report(f"Fit report: {run.result['model']}", _fit_verdict(run.result), summary,
                   tuple(_model_sections(run.problem, curves)),
                   numbers=_quote(run.result["derived"], posterior=False))


def _posterior_report(run: RunDirectory, *, draws: int) -> _Report:
    chain = read_chain(run)
    curves = posterior_curves(run, chain, draws=draws)
    problem = run.problem
    truth = _truth(problem.logs)
    rms = math.sqrt(sum(curves.rms(problem, i) ** 2 * len(log)
                        for i, log in enumerate(problem.logs))
                    / sum(len(log) for log in problem.logs))
    nuisances = run.posterior.nuisances
    offsets = [nuisances.get(f"offset[{log.name}]", {}).get("q50") for log in problem.logs]
    summary = (_posterior_tables(run, truth)
               + _p("Posterior medians, standard deviations and central 90 % intervals. The "
                    "least-squares column is the fit the walkers started from.")
               + _DEFINITIONS
               + _log_table(problem, curves, offsets))
    sections = _model_sections(problem, curves) + [
        _Section("Posterior", figures=(_corner_figure(run, truth),)),
        _Section("Chains: trace and autocorrelation time",
                 html=_p("Model parameters only; the per-log offsets and initial friction "
                         "states are in chain.h5 and posterior.nc."),
                 figures=tuple(_chain_figures(run, chain))),
    ]
    return _Report(f"Posterior report: {run.posterior.model}",
                   _posterior_verdict(run.posterior, rms), summary, tuple(sections),
                   numbers=_quote(run.posterior.derived, posterior=True))


def _diagnosis_report(run: RunDirectory, *, draws: int) -> _Report:
    """The diagnosis page: verdict, gap heat maps, candidate and detectability tables,
    residual signatures and loops before / after the accepted effects."""
    del draws
    from fitstiff.diagnosis import HELDOUT, Diagnosis
    from fitstiff.diagnosis.gap import region_summary
    from fitstiff.segments.segmentation import segment
    from fitstiff.signal.noise import NoiseFloor

    result = Diagnosis.from_dict(run.result)
    logs = run.logs
    try:
        with np.load(run.path / HELDOUT) as arrays:
            heldout = Diagnosis.heldout_from_arrays(dict(arrays), len(logs))
    except (OSError, KeyError, ValueError) as exc:
        raise InputError(str(run.path / HELDOUT), "held-out residuals of the diagnosis",
                         f"cannot be read ({exc})", "run fitstiff diagnose again") from None
    for which, residuals in heldout.items():
        for log, r in zip(logs, residuals):
            if r.shape != (len(log),):
                raise InputError(str(run.path / HELDOUT), f"{which} residuals of {log.name}",
                                 f"have {r.shape[0]} samples, the log {len(log)}",
                                 "run fitstiff diagnose again")
    segs = [segment(log) for log in logs]
    noise = [NoiseFloor(float(result.noise_N[log.name]["sigma_N"]),
                        float(result.noise_N[log.name]["rho"])) for log in logs]
    masks = _diagnosis_masks(run)
    before, after = heldout["before"], heldout["after"]
    changed = bool(result.accepted)

    fig = Figure(figsize=(12, 3.6 + 0.3 * len(logs)), layout="constrained")
    axes = fig.subplots(1, 2 if changed else 1, squeeze=False)[0]
    # the RMS above the noise in N, on one colour scale before and after: the z-score
    # saturates on real logs (every cell of the O-ring set above any cap, up to 1.8e5), so
    # before and after looked the same
    tables = [region_summary(r, segs, noise, masks, value="excess_N")
              for r in ((before, after) if changed else (before,))]
    top = max((float(np.nanmax(t.to_numpy())) for t in tables
               if np.isfinite(t.to_numpy()).any()), default=0.0)
    label = "held-out RMS above the noise floor [N]"
    for ax, table, title in zip(axes, tables, (f"baseline {result.baseline}",
                                               f"with {', '.join(result.accepted)}")):
        plotting.plot_gap_heatmap(ax, table, label=label, limit=max(top, 1e-9))
        ax.set_title(title)
    heat = ReportFigure("gap_heatmap", "Held-out misfit per region and log: RMS above the "
                        "log's noise floor in N, sqrt(max(rms^2 - sigma^2, 0)) (0: at the "
                        "noise; blank: no such samples)"
                        + (", before and after the accepted effects on one colour scale."
                           if changed else "."), fig)
    signature = _signature_figure(logs, segs, before, after if changed else None, masks)
    loops = tuple(_diagnosis_loop(log, b, a if changed else None, result, i)
                  for i, (log, b, a) in enumerate(zip(logs, before, after)))
    gap = result.gap
    summary = (_diagnosis_tables(result)
               + _p(f"Held-out RMS of the baseline {gap['heldout_rms_N']:.3g} N, of "
                    f"{result.final_model} {gap['final_heldout_rms_N']:.3g} N; noise floor "
                    f"{gap['noise_N']:.3g} N pooled over the logs, from the data alone ("
                    + _per_log_noise({k: float(v["sigma_N"])
                                      for k, v in result.noise_N.items()},
                                     what="noise floor") + "). Folds: "
                    + "; ".join(result.folds) + "."))
    sections = [
        _Section("Where the baseline misses", figures=(heat,)),
        _Section("Residual signatures", figures=(signature,)),
        _Section("Loops", figures=loops),
    ]
    return _Report(f"Diagnosis: {result.baseline}", _diagnosis_verdict(result), summary,
                   tuple(sections), summary_title="Candidate effects")


def _diagnosis_masks(run: RunDirectory) -> list[np.ndarray]:
    options = run.manifest.get("options", {})
    out = []
    for log in run.logs:
        keep = np.ones(len(log), dtype=bool)
        if options.get("sample_range") is not None:
            start, stop = options["sample_range"]
            keep[:] = False
            keep[slice(start, stop)] = True
        keep[:int(options.get("skip") or 0)] = False
        out.append(keep)
    return out


def _signature_figure(logs, segs, before, after, masks) -> ReportFigure:
    since, velocity, pressure, position, time = [], [], [], [], []
    for log, seg in zip(logs, segs):
        x = np.asarray(log.displacement)
        origin = np.concatenate([[0], seg.reversals])
        last = origin[np.searchsorted(origin, np.arange(len(log)), side="right") - 1]
        since.append(np.abs(x - x[last]) / MM)
        velocity.append((seg.velocity if seg.velocity is not None
                         else np.full(len(log), np.nan)) / MM)
        level = seg.pressure_level
        pressure.append(np.full(len(log), np.nan if level is None else level / 1e5))
        start = log.rig.start_position
        position.append((x + (start if start is not None else 0.0)) / MM)
        time.append(np.asarray(log.time) if log.time is not None
                    else np.full(len(log), np.nan))
    keep = np.concatenate(masks)
    b = np.concatenate(before)[keep]
    a = None if after is None else np.concatenate(after)[keep]
    panels = [(since, "displacement since the last reversal (mm)"),
              (velocity, "velocity (mm/s)"), (pressure, "pressure level (bar gauge)"),
              (position, "position (mm)"), (time, "time (s)")]
    fig = Figure(figsize=(12, 7.0), layout="constrained")
    axes = fig.subplots(2, 3).ravel()
    for ax, (values, label) in zip(axes, panels):
        v = np.concatenate(values)[keep]
        if not np.any(np.isfinite(v)):
            ax.set_axis_off()
            ax.text(0.5, 0.5, f"no {label.split(' (')[0]} in these logs", ha="center",
                    transform=ax.transAxes)
            continue
        plotting.plot_residual_signature(ax, v, b, a, xlabel=label)
    axes[-1].set_axis_off()
    caption = ("Held-out residuals (model - measured) of every log against the variables that "
               "reveal effects: displacement since the last reversal (pre-sliding shape, "
               "memory), velocity (viscous, Stribeck), pressure level (pressure-dependent "
               "friction), position (stroke ends, chamber), time (drift, leakage). Red: "
               "baseline" + ("; blue: with the accepted effects" if after is not None else "")
               + "; lines: binned mean, bands: +-1 sd.")
    return ReportFigure("residual_signatures", caption, fig)


def _diagnosis_loop(log, before, after, result, i) -> ReportFigure:
    fig = Figure(figsize=(12, 4.2), layout="constrained")
    axes = fig.subplots(1, 2 if after is not None else 1, squeeze=False)[0]
    force = np.asarray(log.force)
    plotting.plot_loop(axes[0], log, force + before, label=f"{result.baseline} (held out)")
    axes[0].set_title(f"{log.name}: baseline")
    if after is not None:
        plotting.plot_loop(axes[1], log, force + after,
                           label=f"{result.final_model} (held out)")
        axes[1].set_title(f"{log.name}: with {', '.join(result.accepted)}")
    caption = (f"{log.name}: measured force and the held-out prediction (fitted without this "
               "log or this block of loops) of the baseline"
               + (" and of the model with the accepted effects." if after is not None else "."))
    return ReportFigure(f"diagnosis_loop_{_file_stem(log.name)}", caption, fig)


def _diagnosis_tables(result) -> str:
    rows = []
    for c in result.candidates:
        det = result.detectability.get(c.effect, {})
        detect = (f"{det['size']:.3g} {det['unit']} ({det['parameter']})" if det.get("testable")
                  else "not testable")
        rows.append([c.effect, _fmt(c.score, 4), c.p_text,
                     _fmt(c.heldout_rms_before_N, 4), _fmt(c.heldout_rms_after_N, 4),
                     _fmt(c.shrink, 2), "yes" if c.accepted else "no",
                     ", ".join(c.regions_improved) or "-", detect,
                     (c.fitted_text + (f" ({c.reading})" if c.reading else ""))
                     if c.accepted else c.why])
    table = _table(["candidate", "score", "p", "held-out before N", "held-out after N",
                    "shrink", "accepted", "regions improved", "detectable at 80 %",
                    "fitted (95 % interval) / why not"],
                   rows, numeric_from=1, prose=(7, 9))
    untestable = [f"{e}: {d['reason']}; record {d['record']}"
                  for e, d in result.detectability.items() if not d.get("testable")]
    skipped = [f"{e}: {why}" for e, why in result.skipped.items()]
    return (table
            + _p("Score: the Lagrange-multiplier statistic of the effect at its null value "
                 "(for one-sided effects z squared with the sign of z: negative where the data "
                 "push the parameter below its null, i.e. away from the effect); p after the "
                 "grid correction; "
                 "the screen's level is alpha / number of candidates = "
                 f"{result.settings.get('screen_level', float('nan')):.2g}. An effect is "
                 "accepted when its held-out RMS falls and it removes at least "
                 f"{result.settings.get('min_shrink', float('nan')):.0%} of the gap above "
                 "the noise.")
            + ("".join(_p("Not testable with these logs - " + u) for u in untestable))
            + ("".join(_p("Not screened - " + u) for u in skipped)))


def _diagnosis_verdict(result) -> _Verdict:
    if not result.gap.get("baseline_converged", True):
        return _Verdict("bad", "The baseline did not converge on every fold: do not trust "
                        "this diagnosis.", tuple(result.verdict))
    if result.accepted and not result.unexplained:
        status = "ok"
    elif result.accepted or not result.unexplained:
        status = "caution" if result.unexplained else "ok"
    else:
        status = "bad"
    headline = (f"Accepted: {', '.join(result.accepted)}." if result.accepted
                else "No candidate effect is accepted.")
    if not result.accepted and not result.unexplained:
        headline += " The baseline is adequate: its held-out misfit is at the noise floor."
    elif result.unexplained:
        headline += " Part of the gap stays unexplained (see the heat map)."
    return _Verdict(status, headline, tuple(result.verdict))


_BUILDERS: Mapping[str, Callable[..., _Report]] = {"posterior": _posterior_report,
                                                   "fit": _fit_report,
                                                   "diagnosis": _diagnosis_report}


# -- writing --------------------------------------------------------------------------------
def write_report(directory: str | Path, *, out: str | Path | None = None,
                 draws: int = 100) -> Path:
    """Write ``report.html`` and ``figures/*.png|svg`` for a fit or posterior directory.

    Args:
        directory: the ``--out`` directory of ``fitstiff fit`` or ``fitstiff posterior``.
        out: where to write (default ``directory``); a manifest ``report.manifest.json``
            goes with it.
        draws: posterior draws evaluated for the median curve and the predictive band.

    Returns:
        The path of ``report.html``.

    Raises:
        InputError: see :func:`open_run`; a fit that the re-read logs do not reproduce.
    """
    if not (isinstance(draws, int) and draws >= 2):
        raise InputError(None, f"draws {draws!r}", "must be a whole number >= 2",
                         "give e.g. 100")
    directory = Path(directory)
    if not directory.is_dir():
        raise InputError(str(directory), "report directory", "does not exist or is not a "
                         "directory", "give the --out directory of fitstiff fit or fitstiff "
                         "posterior")
    if (directory / "fleet.parquet").is_file():        # a fitstiff fleet directory
        from fitstiff.present.fleet_page import write_fleet_report

        return write_fleet_report(directory, out=out)
    with OutputDir(Path(out) if out is not None else directory,
                   inputs=_recorded_inputs(directory), planned=PLANNED,
                   options={"directory": str(directory), "draws": draws},
                   manifest_name=REPORT_MANIFEST) as target:
        run = open_run(directory)
        target.inputs = ([run.result_file, run.path / MANIFEST]
                         + [run.path / f for f in run.manifest.get("outputs", [])]
                         + [p for p, _ in run.inputs])
        target.options["kind"] = run.kind
        report = _BUILDERS[run.kind](run, draws=draws)
        images = {}
        for section in report.sections:
            for fig in section.figures:
                png = _render(fig.figure, "png")
                target.write_bytes(f"{FIGURES}/{fig.name}.png", png)
                target.write_bytes(f"{FIGURES}/{fig.name}.svg", _render(fig.figure, "svg"))
                images[fig.name] = base64.b64encode(png).decode("ascii")
        path = target.write_bytes(REPORT, _html(report, run, images))
        target.finish()
    return path


def _recorded_inputs(directory: Path) -> list[Path]:
    """The files a report reads, as far as the run directory tells without loading anything:
    its result files, manifest and the manifest's inputs (never written by the report)."""
    paths = [directory / name for name in RESULT_FILES.values()] + [directory / MANIFEST]
    try:
        manifest = json.loads((directory / MANIFEST).read_text(encoding="utf-8"))
        started = Path(manifest.get("cwd", "."))
        records = [manifest, *manifest.get("earlier_runs", [])]
        paths += [started / entry["path"] for record in records
                  for entry in record.get("inputs", [])]
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        pass                     # open_run says what is wrong with the manifest
    return paths


def _render(fig: Figure, fmt: str) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format=fmt, dpi=_DPI, metadata=_METADATA[fmt])
    return buffer.getvalue()


_CSS = """
body { font-family: -apple-system, "Segoe UI", Helvetica, Arial, sans-serif; color: #222;
       max-width: 1240px; margin: 0 auto; padding: 1em 1.5em 3em; line-height: 1.45; }
h1 { font-size: 1.6em; margin-bottom: 0.2em; }
h2 { font-size: 1.25em; border-bottom: 1px solid #ccc; padding-bottom: 0.2em; margin-top: 1.8em; }
.meta { color: #666; font-size: 0.9em; }
.verdict { border-left: 6px solid; padding: 0.6em 1em; margin: 1em 0; border-radius: 3px; }
.verdict.ok { border-color: #2e7d32; background: #edf7ee; }
.verdict.caution { border-color: #e0a800; background: #fdf6e0; }
.verdict.bad { border-color: #c62828; background: #fdecea; }
.verdict .headline { font-weight: 600; margin: 0 0 0.4em; }
.numbers { font-size: 1.25em; font-weight: 600; margin: 0.4em 0 0.8em; }
.verdict ul { margin: 0; padding-left: 1.3em; }
table { border-collapse: collapse; margin: 0.8em 0; font-size: 0.92em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; }
th { background: #f2f2f2; text-align: left; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
td.prose { text-align: left; white-space: normal; min-width: 12em; }
figure { margin: 1.2em 0 1.8em; }
figure img { max-width: 100%; height: auto; border: 1px solid #eee; }
figcaption { color: #444; font-size: 0.9em; margin-top: 0.3em; }
"""


def _html(report: _Report, run: RunDirectory, images: Mapping[str, str]) -> str:
    v = report.verdict
    details = "".join(f"<li>{html.escape(d)}</li>" for d in v.details)
    created = datetime.now(timezone.utc).isoformat(timespec="seconds")
    parts = [
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{html.escape(report.title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{html.escape(report.title)}</h1>",
        f'<p class="meta">{html.escape(str(run.path))} &middot; '
        f"{html.escape(run.manifest.get('command', ''))} &middot; fitstiff {__version__}, "
        f"report made {created}</p>",
        (f'<p class="numbers">{html.escape(report.numbers)}</p>' if report.numbers else ""),
        f'<div class="verdict {v.status}"><p class="headline">{html.escape(v.headline)}</p>'
        + (f"<ul>{details}</ul>" if details else "") + "</div>",
        f"<h2>{html.escape(report.summary_title)}</h2>", report.summary,
    ]
    for section in report.sections:
        parts += [f"<h2>{html.escape(section.title)}</h2>", section.html]
        for fig in section.figures:
            parts.append(f'<figure id="{fig.name}"><img alt="{html.escape(fig.caption)}" '
                         f'src="data:image/png;base64,{images[fig.name]}">'
                         f"<figcaption>{html.escape(fig.caption)} (figures/{fig.name}.png, "
                         f".svg)</figcaption></figure>")
    parts += ["<h2>Inputs</h2>",
              _p("The logs were re-read from these files, checked against the SHA-256 the "
                 "run's manifest recorded."),
              _inputs_table(run), "</body></html>"]
    return "\n".join(parts) + "\n"
