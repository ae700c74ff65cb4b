"""The fleet page of ``fitstiff report DIR`` for a ``fitstiff fleet`` directory, and the
per-cylinder reports it links to, made on demand.

The page (``report.html``, figures in ``figures/`` as PNG and SVG, images embedded): the
verdict in numbers; per derived quantity the cylinders' estimates against the population fit
(log-normal, its mean's 95 % interval marked, outliers in red); the outliers ranked by their
q-value with their loops beside a typical cylinder's (the one nearest the population's
breakaway); the drifting cylinders' flagged quantity over their runs; and a table of every
cylinder and run whose rows link to ``cylinders/<cylinder>[/<run>]/report.html``. Such a
report is made by ``fitstiff report DIR --cylinder NAME [--run RUN]``
(:func:`cylinder_report`): the unit fitted again as the fleet fitted it, then reported as any
fit directory is.
"""

from __future__ import annotations

import base64
import html
import json
import math
from collections.abc import Mapping, Sequence
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from fitstiff import __version__
from fitstiff.errors import InputError
from fitstiff.output import OutputDir

__all__ = ["write_fleet_report", "cylinder_report", "cylinder_dir", "plot_distribution",
           "plot_loops", "plot_drift", "MAX_OUTLIERS_SHOWN"]

#: outliers whose loops the page draws (the rest are listed)
MAX_OUTLIERS_SHOWN = 8
_LABELS = {"presliding_slope_N_per_mm": ("pre-sliding slope", "N/mm"),
           "breakaway_N": ("breakaway", "N"), "presliding_range_mm": ("pre-sliding range", "mm"),
           "chamber_stiffness_N_per_mm": ("chamber stiffness", "N/mm")}


def _read(directory: Path) -> tuple[pd.DataFrame, dict, dict]:
    from fitstiff.fleet import FLEET, POPULATION

    missing = [name for name in (FLEET, POPULATION, "manifest.json")
               if not (directory / name).is_file()]
    if missing:
        raise InputError(str(directory), "fleet directory", f"has no {missing[0]}",
                         "give the --out directory of a finished fitstiff fleet run")
    table = pd.read_parquet(directory / FLEET)
    population = json.loads((directory / POPULATION).read_text(encoding="utf-8"))
    manifest = json.loads((directory / "manifest.json").read_text(encoding="utf-8"))
    return table, population, manifest


def cylinder_dir(cylinder: str, run: str = "") -> Path:
    """Where a unit's on-demand report lives, relative to the fleet directory."""
    return Path("cylinders") / cylinder / run if run else Path("cylinders") / cylinder


# -- figures (each takes an Axes) ------------------------------------------------------------
def plot_distribution(ax, values: np.ndarray, *, mean: float, spread: float | None,
                      interval: Sequence[float], outliers: np.ndarray, label: str,
                      unit: str) -> None:
    """The cylinders' estimates of one quantity, the population's log-normal density scaled
    to the histogram, its mean's 95 % interval (band) and the outliers (red)."""
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    outliers = np.asarray(outliers, float)
    if values.size == 0:
        ax.text(0.5, 0.5, "no estimates", ha="center", transform=ax.transAxes)
        return
    counts, edges, _ = ax.hist(values, bins=min(40, max(8, values.size // 8)),
                               color="#9ab", edgecolor="white", label="cylinders")
    ax.axvspan(interval[0], interval[1], color="#2e7d32", alpha=0.25,
               label="population mean, 95 %")
    if spread and spread > 0:
        x = np.linspace(edges[0], edges[-1], 300)
        x = x[x > 0]
        density = np.exp(-0.5 * ((np.log(x) - math.log(mean)) / spread) ** 2) / (
            x * spread * math.sqrt(2 * math.pi))
        ax.plot(x, density * values.size * (edges[1] - edges[0]), color="#2e7d32",
                label=f"population (spread {100 * spread:.1f} %)")
    for k, v in enumerate(outliers):
        ax.axvline(v, color="#c62828", lw=1.2, label="outlier" if k == 0 else None)
    ax.set_xlabel(f"{label} ({unit})")
    ax.set_ylabel("cylinders")
    ax.legend(fontsize=7, loc="upper right")


def plot_loops(ax, outlier, typical, *, title: str) -> None:
    """Measured force against displacement of an outlier's first log (red) over a typical
    cylinder's (grey); each log offset to its own mean force."""
    for log, color, label, width in ((typical, "#888", "typical", 1.0),
                                     (outlier, "#c62828", "outlier", 0.8)):
        if log is None:
            continue
        force = np.asarray(log.force)
        ax.plot(np.asarray(log.displacement) * 1e3, force - np.median(force), color=color,
                lw=width, label=label)
    ax.set_title(title, fontsize=8)
    ax.set_xlabel("displacement (mm)", fontsize=8)
    ax.set_ylabel("force - median (N)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7)


def plot_drift(ax, runs: Mapping[str, tuple[np.ndarray, np.ndarray]], *,
               drifting: Sequence[str], label: str) -> None:
    """A quantity over its cylinders' runs, relative to each cylinder's first run: the
    drifting cylinders in colour, the others with runs faint."""
    for name, (index, values) in runs.items():
        rel = 100 * (values / values[0] - 1)
        if name in drifting:
            ax.plot(index, rel, marker="o", lw=1.5, label=name)
        else:
            ax.plot(index, rel, color="#bbb", lw=0.7, zorder=0)
    ax.axhline(0, color="#666", lw=0.8)
    ax.set_xlabel("run")
    ax.set_ylabel(f"{label}: change from run 1 (%)")
    if drifting:
        ax.legend(fontsize=7, ncol=2)


# -- the page --------------------------------------------------------------------------------
def _first_runs(table: pd.DataFrame) -> pd.DataFrame:
    good = table[(table["error"] == "") & table["converged"].astype(bool)]
    return good.sort_values(["cylinder", "run_index"]).groupby("cylinder", sort=True).first()


def _figures(table, population, reading) -> list:
    from fitstiff.report import ReportFigure

    per = _first_runs(table)
    quantities = [q for q in population["quantities"] if q in per]
    out = []
    fig = Figure(figsize=(11, 3.2 * math.ceil(len(quantities) / 2)), layout="constrained")
    axes = fig.subplots(math.ceil(len(quantities) / 2), 2, squeeze=False).ravel()
    for ax, name in zip(axes, quantities):
        est = population["quantities"][name]
        label, unit = _LABELS.get(name, (name, ""))
        flagged = per[per["outlier"].astype(bool)
                      & per["outlier_quantities"].str.contains(name, regex=False)]
        plot_distribution(ax, per[name].to_numpy(float), mean=est["mean"],
                          spread=est["spread_sd_log"], interval=est["mean_interval_95"],
                          outliers=flagged[name].to_numpy(float), label=label, unit=unit)
    for ax in axes[len(quantities):]:
        ax.set_visible(False)
    out.append(ReportFigure("fleet_distributions", "Each cylinder's estimate (first run) "
                            "against the population: log-normal fit, its mean's 95 % "
                            "interval (band), outliers at q in red", fig))
    ranked = [o["cylinder"] for o in population["outliers"]][:MAX_OUTLIERS_SHOWN]
    if ranked:
        typical = _typical(per, population)
        typical_log = _first_log(per, typical, reading)
        cols = min(len(ranked), 4)
        fig = Figure(figsize=(3.0 * cols, 2.8 * math.ceil(len(ranked) / cols)),
                     layout="constrained")
        axes = fig.subplots(math.ceil(len(ranked) / cols), cols, squeeze=False).ravel()
        for ax, name in zip(axes, ranked):
            row = per.loc[name] if name in per.index else None
            plot_loops(ax, _first_log(per, name, reading), typical_log,
                       title=f"{name}: {row['outlier_size'] if row is not None else ''}")
        for ax in axes[len(ranked):]:
            ax.set_visible(False)
        out.append(ReportFigure("fleet_outliers", f"The outliers, most improbable first, "
                                f"their first log (red) over a typical cylinder's ({typical}, "
                                "nearest the population's breakaway; grey)", fig))
    multi = table[(table["error"] == "") & table.groupby("cylinder")["run"].transform(
        "count").gt(1)]
    drifting = [d["cylinder"] for d in population["drift"]]
    if len(multi):
        quantity = (population["drift"][0]["quantities"][0] if drifting else "breakaway_N")
        runs = {c: (g["run_index"].to_numpy(float), g[quantity].to_numpy(float))
                for c, g in multi.sort_values("run_index").groupby("cylinder")}
        fig = Figure(figsize=(8, 3.6), layout="constrained")
        plot_drift(fig.add_subplot(), runs, drifting=drifting,
                   label=_LABELS.get(quantity, (quantity, ""))[0])
        out.append(ReportFigure("fleet_drift", f"{_LABELS.get(quantity, (quantity,))[0]} over "
                                "the runs of every cylinder logged more than once; drifting "
                                "cylinders in colour", fig))
    return out


def _typical(per: pd.DataFrame, population) -> str:
    est = population["quantities"].get("breakaway_N")
    column = per["breakaway_N"] if "breakaway_N" in per else None
    if est is None or column is None or column.isna().all():
        return str(per.index[0])
    inliers = per[~per["outlier"].astype(bool)]
    pool = inliers if len(inliers) else per
    return str((pool["breakaway_N"] - est["mean"]).abs().idxmin())


def _first_log(per: pd.DataFrame, name: str, reading):
    from fitstiff.loading import load_log

    if name not in per.index:
        return None
    try:
        return load_log(per.loc[name, "files"].split(";")[0], **dict(reading or {}))
    except (InputError, OSError):
        return None


def _q(value: float) -> str:
    return f"q = {value:.2g}" if value >= 1e-12 else "q < 1e-12"


def _fmt(value, digits: int = 4) -> str:
    return "n/a" if value is None or not np.isfinite(value) else f"{value:.{digits}g}"


def _pm(value, err) -> str:
    return _fmt(value) if err is None or not np.isfinite(err) else f"{value:.4g} ± {err:.2g}"


def _unit_table(table: pd.DataFrame, base: Path) -> str:
    head = ["cylinder", "run", "converged", "identifiable", "rms (N)", "slope (N/mm)",
            "breakaway (N)", "flags", "error"]
    rows = []
    for _, r in table.iterrows():
        target = cylinder_dir(r["cylinder"], r["run"]) / "report.html"
        made = (base / target).is_file()
        name = html.escape(r["cylinder"])
        link = f'<a href="{html.escape(target.as_posix())}">{name}</a>' if made else name
        flags = ", ".join(f for f, on in (("outlier: " + str(r.get("outlier_size", "")),
                                           bool(r.get("outlier"))),
                                          (f"drift {100 * r.get('drift_per_run', 0):+.1f} %/run",
                                           bool(r.get("drift")))) if on)
        cells = [link, html.escape(r["run"]), "yes" if r["converged"] else "no",
                 "yes" if r["identifiable"] else "no", _fmt(r["rms_N"]),
                 _pm(r.get("presliding_slope_N_per_mm"),
                     r.get("presliding_slope_N_per_mm_stderr")),
                 _pm(r.get("breakaway_N"), r.get("breakaway_N_stderr")), html.escape(flags),
                 html.escape(r["error"])]
        cls = ' class="flag"' if r.get("outlier") or r.get("drift") or r["error"] else ""
        rows.append(f"<tr{cls}>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    return ("<table><thead><tr>" + "".join(f"<th>{h}</th>" for h in head)
            + "</tr></thead><tbody>" + "".join(rows) + "</tbody></table>")


def _verdict(table: pd.DataFrame, population) -> tuple[str, list[str], str]:
    errors = int((table["error"] != "").sum())
    unconverged = int(((table["error"] == "") & ~table["converged"].astype(bool)).sum())
    outliers, drift = population["outliers"], population["drift"]
    status = "bad" if errors or unconverged else "caution" if outliers or drift else "ok"
    headline = (f"{len(table)} cylinder-runs of {table['cylinder'].nunique()} cylinders: "
                f"{errors} with an error, {unconverged} not converged; {len(outliers)} "
                f"outlying and {len(drift)} drifting cylinders at a false-discovery rate of "
                f"{100 * population['q']:g} %.")
    details = []
    for name, est in population["quantities"].items():
        label, unit = _LABELS.get(name, (name, ""))
        spread = est["spread_sd_log"]
        lo, hi = est["spread_interval_95"]
        spread_text = ("n/a" if spread is None else
                       f"{100 * spread:.1f} % [{_fmt(100 * (lo or 0), 2)}, "
                       f"{_fmt(100 * (hi or 0), 2)}]")
        scatter = est.get("run_to_run_sd_log")
        details.append(f"{label}: population mean {est['mean']:.4g} {unit} "
                       f"[{est['mean_interval_95'][0]:.4g}, {est['mean_interval_95'][1]:.4g}], "
                       f"between-cylinder spread {spread_text}"
                       + (f", run-to-run {100 * scatter:.1f} %" if scatter is not None else "")
                       + f" ({est['cylinders']} cylinders)")
    for o in outliers[:MAX_OUTLIERS_SHOWN]:
        sizes = ", ".join(f"{_LABELS.get(k, (k,))[0]} {100 * v:+.0f} %"
                          for k, v in o["size"].items())
        details.append(f"outlier {o['cylinder']}: {sizes} ({_q(o['q_value'])})")
    if len(outliers) > MAX_OUTLIERS_SHOWN:
        details.append(f"... and {len(outliers) - MAX_OUTLIERS_SHOWN} more outliers (table)")
    for d in drift:
        per_run = ", ".join(f"{_LABELS.get(k, (k,))[0]} {100 * v:+.1f} % per run"
                            for k, v in d["per_run"].items())
        details.append(f"drifting {d['cylinder']}: {per_run} ({_q(d['q_value'])})")
    return status, details, headline


_CSS_EXTRA = """
tr.flag td { background: #fdf6e0; }
td { font-variant-numeric: tabular-nums; }
code { background: #f4f4f4; padding: 0 0.2em; }
"""


def write_fleet_report(directory: str | Path, *, out: str | Path | None = None) -> Path:
    """Write the fleet page of a ``fitstiff fleet`` directory; returns ``report.html``."""
    from fitstiff.report import FIGURES, REPORT, REPORT_MANIFEST, _CSS, _render

    directory = Path(directory)
    table, population, manifest = _read(directory)
    target_dir = Path(out) if out is not None else directory
    with OutputDir(target_dir, inputs=[directory / "fleet.parquet",
                                       directory / "population.json",
                                       directory / "manifest.json"],
                   planned=(REPORT, f"{FIGURES}/"), options={"directory": str(directory),
                                                             "kind": "fleet"},
                   manifest_name=REPORT_MANIFEST) as target:
        reading = manifest.get("options", {}).get("reading", {})
        figures = _figures(table, population, reading)
        images = {}
        for fig in figures:
            png = _render(fig.figure, "png")
            target.write_bytes(f"{FIGURES}/{fig.name}.png", png)
            target.write_bytes(f"{FIGURES}/{fig.name}.svg", _render(fig.figure, "svg"))
            images[fig.name] = base64.b64encode(png).decode("ascii")
        status, details, headline = _verdict(table, population)
        created = datetime.now(timezone.utc).isoformat(timespec="seconds")
        command = (f"fitstiff report {directory} --cylinder NAME [--run RUN]")
        parts = [
            "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
            '<meta name="viewport" content="width=device-width, initial-scale=1">',
            f"<title>fitstiff fleet report</title><style>{_CSS}{_CSS_EXTRA}</style></head>"
            "<body>", "<h1>Fleet report</h1>",
            f'<p class="meta">{html.escape(str(directory))} &middot; '
            f"{html.escape(manifest.get('command', ''))} &middot; fitstiff {__version__}, "
            f"report made {created}</p>",
            f'<div class="verdict {status}"><p class="headline">{html.escape(headline)}</p>'
            "<ul>" + "".join(f"<li>{html.escape(d)}</li>" for d in details) + "</ul></div>"]
        for fig in figures:
            parts.append(f'<figure id="{fig.name}"><img alt="{html.escape(fig.caption)}" '
                         f'src="data:image/png;base64,{images[fig.name]}">'
                         f"<figcaption>{html.escape(fig.caption)} (figures/{fig.name}.png, "
                         ".svg)</figcaption></figure>")
        parts += ["<h2>Every cylinder and run</h2>",
                  f"<p>A cylinder's name links to its own report once it is made: "
                  f"<code>{html.escape(command)}</code> fits it again as the fleet did and "
                  f"writes <code>cylinders/NAME[/RUN]/report.html</code> beside this page.</p>",
                  _unit_table(table, target_dir), "</body></html>"]
        path = target.write_bytes(REPORT, "\n".join(parts) + "\n")
        target.finish()
    return path


# -- a cylinder's report on demand -----------------------------------------------------------
def cylinder_report(directory: str | Path, cylinder: str, *, run: str | None = None) -> Path:
    """Fit one unit of a fleet directory again as the fleet fitted it (its model, options
    and reading), write ``fit.json`` to ``cylinders/<cylinder>[/<run>]/`` and its report there;
    returns the report's path. The fleet page links to it."""
    from fitstiff.cli.fit import parse_fix
    from fitstiff.fitting import fit
    from fitstiff.loading import load_logs
    from fitstiff.report import write_report

    directory = Path(directory)
    table, _, manifest = _read(directory)
    rows = table[table["cylinder"] == cylinder]
    if rows.empty:
        shown = ", ".join(sorted(set(table["cylinder"]))[:5])
        raise InputError(str(directory), f"--cylinder {cylinder}", "is not in the fleet",
                         f"give one of its cylinders ({shown} ...)")
    if run is not None:
        rows = rows[rows["run"] == run]
        if rows.empty:
            runs = ", ".join(repr(r) for r in table.loc[table["cylinder"] == cylinder, "run"])
            raise InputError(str(directory), f"--run {run}", f"is not a run of {cylinder}",
                             f"give one of {runs}")
    elif len(rows) > 1:
        raise InputError(str(directory), f"--cylinder {cylinder}", f"has {len(rows)} runs",
                         "name one with --run")
    row = rows.iloc[0]
    if row["error"]:
        raise InputError(str(directory), f"--cylinder {cylinder}", f"failed in the fleet: "
                         f"{row['error']}", "fix its logs and run the fleet again")
    options = dict(manifest.get("options", {}))
    model = options.get("model") or "chamber+dahl"
    fix_items = list(options.get("fix") or [])
    fit_options = {k: options[k] for k in ("solver", "starts", "seed", "max_steps", "denoise",
                                           "weights", "skip", "free") if k in options}
    if options.get("sample_range") is not None:
        fit_options["sample_range"] = tuple(options["sample_range"])
    reading = options.get("reading") or {}
    files = [Path(f) for f in row["files"].split(";")]
    inputs = files + [f.with_suffix(".json") for f in files if f.with_suffix(".json").is_file()]
    sub = directory / cylinder_dir(cylinder, row["run"])
    with OutputDir(sub, inputs=inputs, planned=["fit.json"], seed=fit_options.get("seed"),
                   command=f"fitstiff report {directory} --cylinder {cylinder}"
                           + (f" --run {row['run']}" if row["run"] else ""),
                   options={"model": model, "fix": fix_items, **fit_options, "compare": [],
                            "reading": reading}) as out:
        logs = load_logs(files, **reading)
        result = fit(logs, model, fix=parse_fix(fix_items, model), **fit_options)
        out.write_json("fit.json", result.to_dict())
        out.finish()
    return write_report(sub)
