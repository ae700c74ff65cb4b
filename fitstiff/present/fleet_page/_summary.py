"""The fleet page's summaries: the verdict at its top and the table of every cylinder and run
at its bottom (HTML)."""

from __future__ import annotations

import html
import os
from collections.abc import Mapping
from pathlib import Path
from typing import NamedTuple

import pandas as pd

from fitstiff.present.fleet_page._read import cylinder_dir
from fitstiff.present.fleet_page._sections import MAX_OUTLIERS_SHOWN
from fitstiff.present.fleet_page._text import _command, _flag, _fmt, _label, _pct, _pm, _q, _sizes


class _Verdict(NamedTuple):
    """The page's verdict box."""

    status: str              # "ok", "caution" or "bad" (the box's colour)
    details: list[str]       # one line each
    headline: str


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


def _verdict(table: pd.DataFrame, population: Mapping) -> _Verdict:
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
    return _Verdict(status, details, headline)
