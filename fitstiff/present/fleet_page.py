"""The fleet page of ``fitstiff report DIR`` for a ``fitstiff fleet`` directory, and the
per-cylinder reports it links to, made on demand.

The page (``report.html``, figures in ``figures/`` as PNG and SVG, images embedded, no script):

- the verdict: cylinder-runs and cylinders, errors, fits that did not converge, the population
  means with their 95 % intervals and spreads, the outliers and drifting cylinders at ``q``;
- **distributions**: per quantity of ``population.json`` a histogram of the cylinders'
  estimates - each cylinder once, the geometric mean over its usable runs, which is what the
  population model compares - with the population's log-normal density scaled to the
  histogram, its mean's 95 % interval (band) and the outliers (red);
- **outliers** ranked by q-value, the first :data:`MAX_OUTLIERS_SHOWN` with the first log of
  their first usable run drawn over a typical cylinder's (the one nearest the population's
  breakaway, i.e. its median on the log scale);
- **drift over runs**: each flagged quantity against the run index, relative to the first
  run, the drifting cylinders in colour and the other cylinders with runs faint;
- a table of every cylinder and run; a row links to ``cylinders/<cylinder>[/<run>]/report.html``
  once that report is made, by ``fitstiff report DIR --cylinder NAME [--run RUN]``
  (:func:`cylinder_report`: the unit fitted again as the fleet fitted it - model, options,
  reading - then reported as any fit directory is). The page says the exact command.
"""

from __future__ import annotations

import base64
import html
import json
import math
import os
import shlex
from collections.abc import Mapping, Sequence
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from fitstiff import __version__
from fitstiff.errors import InputError
from fitstiff.io.output import OutputDir

__all__ = ["write_fleet_report", "cylinder_report", "cylinder_dir", "plot_distribution",
           "plot_loops", "plot_drift", "MAX_OUTLIERS_SHOWN"]

#: outliers whose loops the page draws (all are listed in its outlier table)
MAX_OUTLIERS_SHOWN = 8
#: at most this many quantities get a drift panel
_MAX_DRIFT_PANELS = 4
_LABELS = {"presliding_slope_N_per_mm": ("pre-sliding slope", "N/mm"),
           "breakaway_N": ("breakaway", "N"), "presliding_range_mm": ("pre-sliding range", "mm"),
           "chamber_stiffness_N_per_mm": ("chamber stiffness", "N/mm"),
           "total_stiffness_N_per_mm": ("total stiffness", "N/mm")}
_MANIFEST = "manifest.json"
_NEEDED_COLUMNS = ("cylinder", "run", "run_index", "files", "converged", "identifiable",
                   "error")


def _label(name: str) -> tuple[str, str]:
    from fitstiff.physics.derived import split_unit

    if name in _LABELS:
        return _LABELS[name]
    label, unit = split_unit(name)
    return label.replace("_", " "), unit


def _read(directory: Path) -> tuple[pd.DataFrame, dict, dict]:
    from fitstiff.fleet import FLEET, POPULATION

    fix = "give the --out directory of a finished fitstiff fleet run (or run it again there)"
    missing = [name for name in (FLEET, POPULATION, _MANIFEST)
               if not (directory / name).is_file()]
    if missing:
        raise InputError(str(directory), "fleet directory", f"has no {missing[0]}", fix)
    try:
        table = pd.read_parquet(directory / FLEET)
    except Exception as exc:           # noqa: BLE001  - pyarrow raises many kinds
        raise InputError(str(directory / FLEET), "fleet table", "cannot be read ("
                         + " ".join(str(exc).split())[:120] + ")", fix) from None
    texts = {}
    for name in (POPULATION, _MANIFEST):
        try:
            texts[name] = json.loads((directory / name).read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise InputError(str(directory / name), name, f"cannot be read ({exc})",
                             fix) from None
    absent = [c for c in _NEEDED_COLUMNS if c not in table]
    if absent:
        raise InputError(str(directory / FLEET), f"column {absent[0]!r}", "is missing", fix)
    population = texts[POPULATION]
    if not (isinstance(population, dict)
            and all(k in population for k in ("q", "quantities", "outliers", "drift"))):
        raise InputError(str(directory / POPULATION), "population", "is not a fitstiff fleet "
                         "population (q, quantities, outliers, drift)", fix)
    table = table.copy()
    table["error"] = table["error"].fillna("").astype(str)
    table["run"] = table["run"].fillna("").astype(str)
    table["cylinder"] = table["cylinder"].astype(str)
    for flag in ("converged", "identifiable"):
        table[flag] = table[flag].fillna(False).astype(bool)
    return table, population, texts[_MANIFEST]


def cylinder_dir(cylinder: str, run: str = "") -> Path:
    """Where a unit's on-demand report lives, relative to the fleet directory."""
    return Path("cylinders") / cylinder / run if run else Path("cylinders") / cylinder


def _files(files: str, manifest: Mapping) -> list[Path]:
    """A row's ``files`` as paths; relative ones from where the fleet was run."""
    cwd = Path(manifest.get("cwd") or ".")
    return [p if p.is_absolute() else cwd / p
            for p in (Path(f) for f in str(files).split(";") if f)]


# -- figures (each takes an Axes) ------------------------------------------------------------
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


# -- the numbers -----------------------------------------------------------------------------
def _usable(table: pd.DataFrame) -> pd.Series:
    """The rows the population uses: no error, converged, identifiable."""
    return (table["error"] == "") & table["converged"] & table["identifiable"]


def _quantity_mask(table: pd.DataFrame, name: str) -> np.ndarray:
    """The rows whose estimate of ``name`` enters the population (as population.py)."""
    value = table[name].to_numpy(float)
    err = (table[f"{name}_stderr"].to_numpy(float) if f"{name}_stderr" in table
           else np.zeros_like(value))
    return _usable(table).to_numpy() & np.isfinite(value) & (value > 0) & np.isfinite(err)


def _per_cylinder(table: pd.DataFrame, quantities: Sequence[str]) -> pd.DataFrame:
    """One row per cylinder: per quantity the geometric mean over its usable runs (the
    population model's per-cylinder estimate), ``files`` of its first usable run (else of
    its first run) and ``runs``."""
    ordered = table.sort_values(["cylinder", "run_index"], kind="stable")
    usable = ordered[_usable(ordered)]
    first = usable.groupby("cylinder", sort=True).first()
    fallback = ordered.groupby("cylinder", sort=True).first()
    out = pd.DataFrame(index=fallback.index)
    out["files"] = first["files"].reindex(out.index).fillna(fallback["files"])
    out["usable"] = out.index.isin(first.index)
    out["runs"] = ordered.groupby("cylinder", sort=True).size()
    for name in quantities:
        keep = _quantity_mask(ordered, name)
        logs = np.log(np.where(keep, ordered[name].to_numpy(float), 1.0))
        geo = pd.Series(logs[keep], index=ordered["cylinder"].to_numpy()[keep])
        out[name] = np.exp(geo.groupby(level=0).mean()).reindex(out.index)
    return out


def _outliers_of(population: Mapping, name: str) -> list[str]:
    return [o["cylinder"] for o in population["outliers"] if name in o.get("quantities", ())]


def _typical(per: pd.DataFrame, population: Mapping) -> str | None:
    """The cylinder nearest the population's breakaway (on the log scale) among those not
    flagged; ``None`` without a usable one."""
    flagged = {o["cylinder"] for o in population["outliers"]}
    pool = per[per["usable"] & ~per.index.isin(flagged)]
    if pool.empty:
        pool = per[per["usable"]]
    if pool.empty:
        return None
    est = population["quantities"].get("breakaway_N") or {}
    column = pool["breakaway_N"] if "breakaway_N" in pool else None
    if column is None or column.isna().all() or not est.get("mean"):
        return str(pool.index[0])
    return str((np.log(column) - math.log(est["mean"])).abs().idxmin())


def _first_log(per: pd.DataFrame, name: str | None, reading: Mapping, manifest: Mapping):
    """The first log of a cylinder's first usable run, and why not when it cannot be read."""
    from fitstiff.io.loading import load_logs

    if name is None or name not in per.index:
        return None, "no such cylinder"
    files = _files(per.loc[name, "files"], manifest)
    if not files:
        return None, f"{name}: no logs"
    try:
        return load_logs(files[:1], **dict(reading or {}))[0], ""
    except (InputError, OSError, TypeError, ValueError) as exc:
        return None, f"{name}: log not read ({' '.join(str(exc).split())[:80]})"


def _q(value: float | None) -> str:
    if value is None or not math.isfinite(value):
        return "q n/a"
    return f"q = {value:.2g}" if value >= 1e-12 else "q < 1e-12"


def _fmt(value, digits: int = 4) -> str:
    try:
        value = float(value)
    except (TypeError, ValueError):
        return "n/a"
    return "n/a" if not math.isfinite(value) else f"{value:.{digits}g}"


def _pm(value, err) -> str:
    if _fmt(value) == "n/a" or _fmt(err) == "n/a":
        return _fmt(value)
    return f"{float(value):.4g} ± {float(err):.2g}"


def _flag(value) -> bool:
    """A boolean column's cell; missing (None, NaN) is False."""
    return value is not None and not (isinstance(value, float) and math.isnan(value)) \
        and bool(value)


def _pct(value) -> str:
    return "n/a" if _fmt(value) == "n/a" else f"{100 * float(value):+.1f} %"


def _sizes(sizes: Mapping[str, float], *, per_run: bool = False) -> str:
    tail = " per run" if per_run else ""
    return ", ".join(f"{_label(k)[0]} {100 * v:+.1f} %{tail}" for k, v in sizes.items())


# -- the page's parts ------------------------------------------------------------------------
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


def _outlier_part(per, population, reading, manifest):
    """The ranked outlier table (HTML) and the loops figure (or ``None``)."""
    from fitstiff.present.report import ReportFigure
    from fitstiff.present.report.text import html_table, paragraph

    outliers = sorted(population["outliers"], key=lambda o: (
        o.get("q_value") if o.get("q_value") is not None else math.inf))
    q = population["q"]
    if not outliers:
        return paragraph(f"No cylinder is an outlier at a false-discovery rate of "
                         f"{100 * q:g} %."), None
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
    return text, ReportFigure("fleet_outliers", caption, fig)


def _drift_part(table, population):
    """A sentence (HTML) and the drift figure (or ``None``)."""
    from fitstiff.present.report import ReportFigure
    from fitstiff.present.report.text import paragraph

    q = population["q"]
    counts = table.groupby("cylinder")["run_index"].transform("count")
    multi = table[counts > 1]
    drift = population["drift"]
    if multi.empty:
        return paragraph("Every cylinder was logged in one run: there is no drift to test."), None
    flagged = list(dict.fromkeys(n for d in drift for n in d.get("quantities", ())
                                 if n in table))
    quantities = (flagged or [n for n in ("breakaway_N", *population["quantities"])
                              if n in table][:1])[:_MAX_DRIFT_PANELS]
    if not quantities:
        return paragraph("No quantity to draw over the runs."), None
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
    return text, ReportFigure("fleet_drift", caption, fig)


def _command(directory: Path, cylinder: str, run: str) -> str:
    return ("fitstiff report " + shlex.quote(str(directory)) + " --cylinder "
            + shlex.quote(cylinder) + (" --run " + shlex.quote(run) if run else ""))


def _unit_table(table: pd.DataFrame, population: Mapping, directory: Path,
                page_dir: Path) -> str:
    sizes = {o["cylinder"]: _sizes(o.get("size", {})) for o in population["outliers"]}
    head = ["cylinder", "run", "converged", "identifiable", "rms (N)", "slope (N/mm)",
            "breakaway (N)", "flags", "error"]
    rows = []
    for _, r in table.iterrows():
        target = directory / cylinder_dir(r["cylinder"], r["run"]) / "report.html"
        name = html.escape(r["cylinder"])
        if target.is_file():
            href = Path(os.path.relpath(target, page_dir)).as_posix()
            cell = f'<a href="{html.escape(href)}">{name}</a>'
        elif r["error"]:
            cell = name
        else:
            cell = (f'<span title="{html.escape(_command(directory, r["cylinder"], r["run"]))}">'
                    f"{name}</span>")
        flags = []
        if _flag(r.get("outlier")):
            flags.append(f"outlier: {sizes.get(r['cylinder']) or r.get('outlier_size', '')}")
        if _flag(r.get("drift")):
            flags.append(f"drift {_pct(r.get('drift_per_run'))}/run")
        cells = [cell, html.escape(r["run"]), "yes" if r["converged"] else "no",
                 "yes" if r["identifiable"] else "no", _fmt(r.get("rms_N")),
                 _pm(r.get("presliding_slope_N_per_mm"),
                     r.get("presliding_slope_N_per_mm_stderr")),
                 _pm(r.get("breakaway_N"), r.get("breakaway_N_stderr")),
                 html.escape("; ".join(flags)), html.escape(r["error"])]
        bad = r["error"] or not r["converged"]
        cls = ' class="bad"' if bad else ' class="flag"' if flags else ""
        rows.append(f"<tr{cls}>" + "".join(
            f'<td class="{"num" if 4 <= j <= 6 else "prose" if j >= 7 else "name"}">{c}</td>'
            for j, c in enumerate(cells)) + "</tr>")
    return ("<table><thead><tr>" + "".join(f"<th>{h}</th>" for h in head)
            + "</tr></thead><tbody>" + "".join(rows) + "</tbody></table>")


def _verdict(table: pd.DataFrame, population: Mapping) -> tuple[str, list[str], str]:
    errors = int((table["error"] != "").sum())
    unconverged = int(((table["error"] == "") & ~table["converged"]).sum())
    outliers, drift = population["outliers"], population["drift"]
    status = "bad" if errors or unconverged else "caution" if outliers or drift else "ok"
    headline = (f"{len(table)} cylinder-runs of {table['cylinder'].nunique()} cylinders: "
                f"{errors} with an error, {unconverged} not converged; {len(outliers)} "
                f"outlying and {len(drift)} drifting cylinders at a false-discovery rate of "
                f"{100 * population['q']:g} %.")
    details = []
    for name, est in population["quantities"].items():
        label, unit = _label(name)
        lo, hi = (list(est.get("spread_interval_95") or []) + [None, None])[:2]
        spread = est.get("spread_sd_log")
        spread_text = ("n/a" if spread is None else f"{100 * spread:.1f} % "
                       f"[{_fmt(None if lo is None else 100 * lo, 2)}, "
                       f"{_fmt(None if hi is None else 100 * hi, 2)}]")
        scatter = est.get("run_to_run_sd_log")
        m_lo, m_hi = (list(est.get("mean_interval_95") or []) + [None, None])[:2]
        details.append(f"{label}: population mean {_fmt(est.get('mean'))} {unit} "
                       f"[{_fmt(m_lo)}, {_fmt(m_hi)}], between-cylinder spread {spread_text}"
                       + (f", run-to-run {100 * scatter:.1f} %" if scatter is not None else "")
                       + f" ({est.get('cylinders', '?')} cylinders)")
    for o in outliers[:MAX_OUTLIERS_SHOWN]:
        details.append(f"outlier {o['cylinder']}: {_sizes(o.get('size', {}))} "
                       f"({_q(o.get('q_value'))})")
    if len(outliers) > MAX_OUTLIERS_SHOWN:
        details.append(f"... and {len(outliers) - MAX_OUTLIERS_SHOWN} more outliers (see "
                       "Outliers)")
    for d in drift:
        details.append(f"drifting {d['cylinder']}: {_sizes(d.get('per_run', {}), per_run=True)}"
                       f" ({_q(d.get('q_value'))})")
    for _, r in table[table["error"] != ""].head(3).iterrows():
        details.append(f"error {r['cylinder']}{'/' + r['run'] if r['run'] else ''}: "
                       f"{r['error']}")
    return status, details, headline


_CSS_EXTRA = """
tr.flag td { background: #fdf6e0; }
tr.bad td { background: #fdecea; }
td.name { white-space: nowrap; }
td span[title] { border-bottom: 1px dotted #999; }
code { background: #f4f4f4; padding: 0 0.2em; }
"""


def write_fleet_report(directory: str | Path, *, out: str | Path | None = None) -> Path:
    """Write the fleet page of a ``fitstiff fleet`` directory (``report.html``, ``figures/``,
    ``report.manifest.json`` in ``out``, default ``directory``); returns ``report.html``.

    Raises:
        InputError: the directory lacks ``population.json`` or ``manifest.json``, or one of
            its files cannot be read.
    """
    from fitstiff.present.report import FIGURES, REPORT, REPORT_MANIFEST
    from fitstiff.present.report.page import CSS, render_figure
    from fitstiff.present.report.text import paragraph

    directory = Path(directory)
    table, population, manifest = _read(directory)
    table = table.sort_values(["cylinder", "run_index"], kind="stable").reset_index(drop=True)
    target_dir = Path(out) if out is not None else directory
    with OutputDir(target_dir, inputs=[directory / "fleet.parquet",
                                       directory / "population.json",
                                       directory / _MANIFEST],
                   planned=(REPORT, f"{FIGURES}/"), options={"directory": str(directory),
                                                             "kind": "fleet"},
                   manifest_name=REPORT_MANIFEST) as target:
        reading = (manifest.get("options") or {}).get("reading") or {}
        per = _per_cylinder(table, [q for q in population["quantities"] if q in table])
        distributions = _distribution_figure(per, population)
        outlier_html, outlier_fig = _outlier_part(per, population, reading, manifest)
        drift_html, drift_fig = _drift_part(table, population)
        sections = [("Distributions", "" if distributions else
                     paragraph("No quantity has a population (fewer than two usable cylinders)."),
                     distributions),
                    ("Outliers", outlier_html, outlier_fig),
                    ("Drift over runs", drift_html, drift_fig)]
        images = {}
        for _, _, fig in sections:
            if fig is None:
                continue
            png = render_figure(fig.figure, "png")
            target.write_bytes(f"{FIGURES}/{fig.name}.png", png)
            target.write_bytes(f"{FIGURES}/{fig.name}.svg", render_figure(fig.figure, "svg"))
            images[fig.name] = base64.b64encode(png).decode("ascii")
        status, details, headline = _verdict(table, population)
        created = datetime.now(timezone.utc).isoformat(timespec="seconds")
        parts = [
            "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
            '<meta name="viewport" content="width=device-width, initial-scale=1">',
            f"<title>Fleet: {html.escape(directory.name)}</title>"
            f"<style>{CSS}{_CSS_EXTRA}</style></head><body>",
            f"<h1>Fleet: {html.escape(directory.name)}</h1>",
            f'<p class="meta">{html.escape(str(directory))} &middot; '
            f"{html.escape(str(manifest.get('command', '')))} &middot; model "
            f"{html.escape(str((manifest.get('options') or {}).get('model', '')))} &middot; "
            f"fitstiff {__version__}, report made {created}</p>",
            f'<div class="verdict {status}"><p class="headline">{html.escape(headline)}</p>'
            "<ul>" + "".join(f"<li>{html.escape(d)}</li>" for d in details) + "</ul></div>"]
        for title, text, fig in sections:
            parts += [f"<h2>{html.escape(title)}</h2>", text]
            if fig is not None:
                parts.append(f'<figure id="{fig.name}"><img alt="{html.escape(fig.caption)}" '
                             f'src="data:image/png;base64,{images[fig.name]}">'
                             f"<figcaption>{html.escape(fig.caption)} (figures/{fig.name}.png,"
                             " .svg)</figcaption></figure>")
        example = table[table["error"] == ""].head(1)
        example_cmd = (_command(directory, example["cylinder"].iloc[0], example["run"].iloc[0])
                       if len(example) else "")
        parts += ["<h2>Every cylinder and run</h2>",
                  "<p>A cylinder's name links to its own report (loops, residuals, estimates) "
                  "once that is made; it is made on demand, fitting the cylinder-run again as "
                  "the fleet did (same model, options and reading of the logs): "
                  f"<code>{html.escape(_command(directory, 'NAME', ''))} [--run RUN]</code>"
                  + (f", e.g. <code>{html.escape(example_cmd)}</code>" if example_cmd else "")
                  + " (a name's tooltip gives its command). It writes "
                  "<code>cylinders/NAME[/RUN]/report.html</code> in the fleet directory; run "
                  f"<code>{html.escape('fitstiff report ' + shlex.quote(str(directory)))}"
                  "</code> again to link it. Slope and breakaway are ± one standard error; "
                  "highlighted: flagged (yellow), an error or not converged (red).</p>",
                  _unit_table(table, population, directory, target_dir), "</body></html>"]
        path = target.write_bytes(REPORT, "\n".join(parts) + "\n")
        target.finish()
    return path


# -- a cylinder's report on demand -----------------------------------------------------------
def cylinder_report(directory: str | Path, cylinder: str, *, run: str | None = None) -> Path:
    """Fit one unit of a fleet directory again as the fleet fitted it (its model, options
    and reading), write ``fit.json`` to ``cylinders/<cylinder>[/<run>]/`` and its report there;
    returns the report's path. The fleet page links to it.

    Raises:
        InputError: an unknown cylinder or run, a cylinder with several runs and no ``run``,
            a unit that failed in the fleet, or what fitting it raises.
    """
    from fitstiff.inference.fitting import fit
    from fitstiff.io.loading import load_logs
    from fitstiff.physics.model import DEFAULT_MODEL, parse_fix
    from fitstiff.present.report import write_report

    directory = Path(directory)
    table, _, manifest = _read(directory)
    rows = table[table["cylinder"] == cylinder]
    if rows.empty:
        names = sorted(set(table["cylinder"]))
        shown = ", ".join(names[:5]) + (" ..." if len(names) > 5 else "")
        raise InputError(str(directory), f"--cylinder {cylinder}", "is not in the fleet",
                         f"give one of its cylinders ({shown})")
    if run is not None:
        found = rows[rows["run"] == run]
        if found.empty:
            runs = ", ".join(repr(r) for r in rows["run"])
            raise InputError(str(directory), f"--run {run}", f"is not a run of {cylinder}",
                             f"give one of {runs}" if rows["run"].ne("").any()
                             else "leave --run out: it was logged once")
        rows = found
    elif len(rows) > 1:
        raise InputError(str(directory), f"--cylinder {cylinder}", f"has {len(rows)} runs",
                         "name one with --run (" + ", ".join(rows["run"]) + ")")
    row = rows.iloc[0]
    if row["error"]:
        raise InputError(str(directory), f"--cylinder {cylinder}", f"failed in the fleet: "
                         f"{row['error']}", "fix its logs and run the fleet again")
    options = dict(manifest.get("options") or {})
    model = options.get("model") or DEFAULT_MODEL
    fix_items = list(options.get("fix") or [])
    fit_options = {k: options[k] for k in ("solver", "starts", "seed", "max_steps", "denoise",
                                           "weights", "skip", "free")
                   if options.get(k) is not None}
    if options.get("sample_range") is not None:
        fit_options["sample_range"] = tuple(options["sample_range"])
    reading = options.get("reading") or {}
    files = _files(row["files"], manifest)
    inputs = files + [f.with_suffix(".json") for f in files if f.with_suffix(".json").is_file()]
    sub = directory / cylinder_dir(cylinder, row["run"])
    with OutputDir(sub, inputs=inputs, planned=["fit.json"], seed=fit_options.get("seed"),
                   command=_command(directory, cylinder, row["run"]),
                   options={"model": model, "fix": fix_items, **fit_options, "compare": [],
                            "reading": reading}) as out:
        logs = load_logs(files, **reading)
        result = fit(logs, model, fix=parse_fix(fix_items, model), **fit_options)
        out.write_json("fit.json", result.to_dict())
        out.finish()
    return write_report(sub)
