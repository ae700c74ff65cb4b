"""The fleet page's three figure sections: the distributions of the quantities, the ranked
outliers with their loops, and the drift over runs. Each is its text (HTML) and its figure
(a :class:`~fitstiff.present.report.ReportFigure`, or ``None``)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import NamedTuple

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from fitstiff.present.fleet_page._figures import plot_distribution, plot_drift, plot_loops
from fitstiff.present.fleet_page._numbers import (_first_log, _outliers_of, _per_cylinder,
                                                  _quantity_mask, _typical)
from fitstiff.present.fleet_page._text import _label, _q, _sizes

#: outliers whose loops the page draws (all are listed in its outlier table)
MAX_OUTLIERS_SHOWN = 8
#: at most this many quantities get a drift panel
_MAX_DRIFT_PANELS = 4


class _Part(NamedTuple):
    """A part of a section: its text (HTML) and its figure (``None``: none drawn)."""

    text: str
    figure: object       # a ReportFigure or None


class _Section(NamedTuple):
    """A section of the page, under its title."""

    title: str
    text: str            # HTML
    figure: object       # a ReportFigure or None


def _page_sections(table: pd.DataFrame, population: Mapping,
                   manifest: Mapping) -> list[_Section]:
    """The distributions, outliers and drift sections of the page, figures drawn."""
    from fitstiff.present.report.text import paragraph

    reading = (manifest.get("options") or {}).get("reading") or {}
    per = _per_cylinder(table, [q for q in population["quantities"] if q in table])
    distributions = _distribution_figure(per, population)
    outliers = _outlier_part(per, population, reading, manifest)
    drift = _drift_part(table, population)
    return [_Section("Distributions", "" if distributions else
                     paragraph("No quantity has a population (fewer than two usable cylinders)."),
                     distributions),
            _Section("Outliers", outliers.text, outliers.figure),
            _Section("Drift over runs", drift.text, drift.figure)]


def _distribution_figure(per: pd.DataFrame, population: Mapping):
    from fitstiff.present.report import ReportFigure

    quantities = [q for q in population["quantities"] if q in per]
    if not quantities:
        return None
    cols = 1 if len(quantities) == 1 else 2
    rows = math.ceil(len(quantities) / cols)
    fig = Figure(figsize=(5.6 * cols, 3.3 * rows), layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    for ax, name in zip(axes, quantities):
        est = population["quantities"][name]
        label, unit = _label(name)
        flagged = per.loc[per.index.isin(_outliers_of(population, name)), name]
        values = per[name].to_numpy(float)
        plot_distribution(ax, values, mean=est.get("mean"), spread=est.get("spread_sd_log"),
                          interval=est.get("mean_interval_95"), outliers=flagged.to_numpy(float),
                          label=label, unit=unit)
        ax.set_title(f"{label}: {int(np.isfinite(values).sum())} cylinders", fontsize=9)
    for ax in axes[len(quantities):]:
        ax.set_visible(False)
    return ReportFigure(
        "fleet_distributions",
        "Each cylinder's estimate once: the geometric mean over its usable runs (converged, "
        "identifiable; a cylinder logged once: its one estimate), which is what the "
        "population model compares. Green: the population's log-normal density (median the "
        "population mean, log-sd the between-cylinder spread) scaled to the histogram, and "
        "the population mean's 95 % interval (band); red: the outliers of that quantity.",
        fig)


def _outlier_part(per, population, reading, manifest) -> _Part:
    """The ranked outlier table (HTML) and the loops figure (or ``None``)."""
    from fitstiff.present.report import ReportFigure
    from fitstiff.present.report.text import html_table, paragraph

    outliers = sorted(population["outliers"], key=lambda o: (
        o.get("q_value") if o.get("q_value") is not None else math.inf))
    q = population["q"]
    if not outliers:
        return _Part(paragraph(f"No cylinder is an outlier at a false-discovery rate of "
                               f"{100 * q:g} %."), None)
    rows = [[str(k + 1), o["cylinder"], _sizes(o.get("size", {})), _q(o.get("q_value"))]
            for k, o in enumerate(outliers)]
    text = (paragraph(f"{len(outliers)} cylinder{'s' if len(outliers) > 1 else ''} outlying at a "
               f"false-discovery rate of {100 * q:g} %, most improbable first; the size is "
               "the cylinder's estimate against the population mean.")
            + html_table(["rank", "cylinder", "size against the population mean", "q-value"],
                     rows, numeric_from=3, prose=(2,)))
    shown = outliers[:MAX_OUTLIERS_SHOWN]
    typical = _typical(per, population)
    typical_log, why_typical = _first_log(per, typical, reading, manifest)
    cols = min(len(shown), 4)
    fig = Figure(figsize=(3.1 * cols, 2.9 * math.ceil(len(shown) / cols)),
                 layout="constrained")
    axes = fig.subplots(math.ceil(len(shown) / cols), cols, squeeze=False).ravel()
    for ax, o in zip(axes, shown):
        log, why = _first_log(per, o["cylinder"], reading, manifest)
        sizes = ", ".join(f"{_label(k)[0]} {100 * v:+.0f} %" for k, v in o["size"].items())
        plot_loops(ax, log, typical_log, title=f"{o['cylinder']}\n{sizes}",
                   missing="; ".join(filter(None, [why, why_typical])))
    for ax in axes[len(shown):]:
        ax.set_visible(False)
    more = len(outliers) - len(shown)
    caption = (f"The outliers, most improbable first: measured force against displacement "
               f"of the first log of each one's first usable run (red) over the same of a "
               f"typical cylinder ({typical}, nearest the population's breakaway; grey), each "
               f"less its median force."
               + (f" {more} more outlier{'s' if more > 1 else ''} not drawn (see the table)."
                  if more > 0 else ""))
    return _Part(text, ReportFigure("fleet_outliers", caption, fig))


def _drift_part(table, population) -> _Part:
    """A sentence (HTML) and the drift figure (or ``None``)."""
    from fitstiff.present.report import ReportFigure
    from fitstiff.present.report.text import paragraph

    q = population["q"]
    counts = table.groupby("cylinder")["run_index"].transform("count")
    multi = table[counts > 1]
    drift = population["drift"]
    if multi.empty:
        return _Part(paragraph("Every cylinder was logged in one run: there is no drift to "
                               "test."), None)
    flagged = list(dict.fromkeys(n for d in drift for n in d.get("quantities", ())
                                 if n in table))
    quantities = (flagged or [n for n in ("breakaway_N", *population["quantities"])
                              if n in table][:1])[:_MAX_DRIFT_PANELS]
    if not quantities:
        return _Part(paragraph("No quantity to draw over the runs."), None)
    fig = Figure(figsize=(6.2 * min(len(quantities), 2), 3.7 * math.ceil(len(quantities) / 2)),
                 layout="constrained")
    axes = fig.subplots(math.ceil(len(quantities) / 2), min(len(quantities), 2),
                        squeeze=False).ravel()
    for ax, name in zip(axes, quantities):
        keep = _quantity_mask(multi, name)
        rows = multi[keep].sort_values("run_index", kind="stable")
        runs = {c: (g["run_index"].to_numpy(float), g[name].to_numpy(float))
                for c, g in rows.groupby("cylinder", sort=True)}
        drifting = [d["cylinder"] for d in drift if name in d.get("quantities", ())]
        plot_drift(ax, runs, drifting=drifting, label=_label(name)[0])
    for ax in axes[len(quantities):]:
        ax.set_visible(False)
    n_multi = multi["cylinder"].nunique()
    if drift:
        text = paragraph(f"{len(drift)} of the {n_multi} cylinders logged in several runs drift at "
                  f"a false-discovery rate of {100 * q:g} %: "
                  + "; ".join(f"{d['cylinder']} ({_sizes(d.get('per_run', {}), per_run=True)}"
                              f", {_q(d.get('q_value'))})" for d in drift) + ".")
    else:
        text = paragraph(f"None of the {n_multi} cylinders logged in several runs drifts at a "
                  f"false-discovery rate of {100 * q:g} % (drawn: {_label(quantities[0])[0]}).")
    caption = ("Each flagged quantity over the runs, relative to each cylinder's first run: "
               "the drifting cylinders in colour, the other cylinders with several runs in "
               "grey." if flagged else
               f"{_label(quantities[0])[0]} over the runs of every cylinder logged more than "
               "once, relative to its first run (no cylinder drifts).")
    return _Part(text, ReportFigure("fleet_drift", caption, fig))
