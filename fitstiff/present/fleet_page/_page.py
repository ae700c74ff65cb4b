"""The fleet page itself: :func:`write_fleet_report` puts the verdict, the figure sections
and the table of every unit into one ``report.html``, its figures beside it."""

from __future__ import annotations

import base64
import html
import shlex
from collections.abc import Mapping, Sequence
from datetime import datetime, timezone
from pathlib import Path

import pandas as pd

from fitstiff import __version__
from fitstiff.io.output import OutputDir
from fitstiff.present.fleet_page._read import _MANIFEST, _read
from fitstiff.present.fleet_page._sections import _page_sections, _Section
from fitstiff.present.fleet_page._summary import _unit_table, _verdict, _Verdict
from fitstiff.present.fleet_page._text import _command

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
        sections = _page_sections(table, population, manifest)
        images = _write_figures(target, sections)
        parts = (_head(directory, manifest, _verdict(table, population))
                 + _figure_sections(sections, images)
                 + _units_section(table, population, directory, target_dir))
        path = target.write_bytes(REPORT, "\n".join(parts) + "\n")
        target.finish()
    return path


def _write_figures(target: OutputDir, sections: Sequence[_Section]) -> dict[str, str]:
    """Each section's figure as PNG and SVG in ``figures/``; the PNGs in base64 by name."""
    from fitstiff.present.report import FIGURES
    from fitstiff.present.report.page import render_figure

    images = {}
    for _, _, fig in sections:
        if fig is None:
            continue
        png = render_figure(fig.figure, "png")
        target.write_bytes(f"{FIGURES}/{fig.name}.png", png)
        target.write_bytes(f"{FIGURES}/{fig.name}.svg", render_figure(fig.figure, "svg"))
        images[fig.name] = base64.b64encode(png).decode("ascii")
    return images


def _head(directory: Path, manifest: Mapping, verdict: _Verdict) -> list[str]:
    """The page's lines up to the verdict box."""
    from fitstiff.present.report.page import CSS

    status, details, headline = verdict
    created = datetime.now(timezone.utc).isoformat(timespec="seconds")
    return [
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


def _figure_sections(sections: Sequence[_Section], images: Mapping[str, str]) -> list[str]:
    """The page's lines of the sections, each figure embedded."""
    parts = []
    for title, text, fig in sections:
        parts += [f"<h2>{html.escape(title)}</h2>", text]
        if fig is not None:
            parts.append(f'<figure id="{fig.name}"><img alt="{html.escape(fig.caption)}" '
                         f'src="data:image/png;base64,{images[fig.name]}">'
                         f"<figcaption>{html.escape(fig.caption)} (figures/{fig.name}.png,"
                         " .svg)</figcaption></figure>")
    return parts


def _units_section(table: pd.DataFrame, population: Mapping, directory: Path,
                   page_dir: Path) -> list[str]:
    """The page's last lines: how a unit's report is made, the table of every unit."""
    example = table[table["error"] == ""].head(1)
    example_cmd = (_command(directory, example["cylinder"].iloc[0], example["run"].iloc[0])
                   if len(example) else "")
    return ["<h2>Every cylinder and run</h2>",
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
            _unit_table(table, population, directory, page_dir), "</body></html>"]
