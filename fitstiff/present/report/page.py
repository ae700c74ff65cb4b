"""Writing a report: :func:`write_report` opens a finished run, builds its kind's sections,
renders the figures (PNG and SVG without dates) and the HTML page, and commits them with their
manifest."""

from __future__ import annotations

import base64
import html
import io
import json
from collections.abc import Callable, Mapping
from datetime import datetime, timezone
from pathlib import Path

from matplotlib.figure import Figure

from fitstiff import __version__
from fitstiff.errors import InputError
from fitstiff.io.output import OutputDir
from fitstiff.present.reopen import MANIFEST, RESULT_FILES, RunDirectory, open_run
from fitstiff.present.report.diagnosis import diagnosis_report
from fitstiff.present.report.kinds import Report, fit_report, posterior_report
from fitstiff.present.report.text import inputs_table, paragraph

__all__ = ["FIGURES", "PLANNED", "REPORT", "REPORT_MANIFEST", "write_report", "render_figure"]

REPORT = "report.html"
FIGURES = "figures"
REPORT_MANIFEST = "report.manifest.json"
PLANNED = (REPORT, f"{FIGURES}/")
"""What a report writes into its directory (besides :data:`REPORT_MANIFEST`)."""
_DPI = 100
_METADATA = {"png": {"Software": None}, "svg": {"Date": None}}


_BUILDERS: Mapping[str, Callable[..., Report]] = {"posterior": posterior_report,
                                                   "fit": fit_report,
                                                   "diagnosis": diagnosis_report}


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
                png = render_figure(fig.figure, "png")
                target.write_bytes(f"{FIGURES}/{fig.name}.png", png)
                target.write_bytes(f"{FIGURES}/{fig.name}.svg", render_figure(fig.figure, "svg"))
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


def render_figure(fig: Figure, fmt: str) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format=fmt, dpi=_DPI, metadata=_METADATA[fmt])
    return buffer.getvalue()


CSS = """
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


def _html(report: Report, run: RunDirectory, images: Mapping[str, str]) -> str:
    v = report.verdict
    details = "".join(f"<li>{html.escape(d)}</li>" for d in v.details)
    created = datetime.now(timezone.utc).isoformat(timespec="seconds")
    parts = [
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{html.escape(report.title)}</title><style>{CSS}</style></head><body>",
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
              paragraph("The logs were re-read from these files, checked against the SHA-256 the "
                 "run's manifest recorded."),
              inputs_table(run), "</body></html>"]
    return "\n".join(parts) + "\n"
