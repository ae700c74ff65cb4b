"""Posterior-plot reports: a fit or posterior directory -> ``report.html`` + ``figures/``.

>>> from fitstiff.present.report import write_report
>>> write_report("out/fit")                                   # doctest: +SKIP
PosixPath('out/fit/report.html')

**What it draws from.** :func:`fitstiff.present.reopen.open_run` re-opens the directory (the result
file decides the kind: ``posterior.json``, ``fit.json`` or ``diagnosis.json``), re-reads and
verifies the logs and rebuilds the problem; :mod:`fitstiff.present.reopen` recomputes the model's
curves (a fit's exactly, checked against ``fit.json``; a posterior's median and 90 % predictive band
from ``predictive.npz``, its per-term forces at the most probable draw of ``chain.h5``). This
package is presentation only: figures (:mod:`~fitstiff.present.report.figures`), tables and
words (:mod:`~fitstiff.present.report.text`), the sections of each kind
(:mod:`~fitstiff.present.report.kinds`, :mod:`~fitstiff.present.report.diagnosis`) and the page
(:mod:`~fitstiff.present.report.page`). A new kind adds an entry to
:data:`~fitstiff.present.reopen.RESULT_FILES` and a builder to ``page._BUILDERS``; the trace and
autocorrelation plots use the whole chain, the corner plot ``posterior.nc``.

**The page** is one self-contained HTML file: inline CSS, every image an embedded base64 PNG,
no script, no external reference; it opens offline. Every figure is also written as PNG and
SVG to ``figures/``. The report's own manifest is ``report.manifest.json`` (the run's
``manifest.json`` stays as it was).
"""

from __future__ import annotations

from fitstiff.present.reopen import RESULT_FILES, RunDirectory, open_run
from fitstiff.present.report.figures import ReportFigure
from fitstiff.present.report.page import FIGURES, PLANNED, REPORT, REPORT_MANIFEST, write_report

__all__ = ["FIGURES", "PLANNED", "REPORT", "REPORT_MANIFEST", "RESULT_FILES", "ReportFigure",
           "RunDirectory", "open_run", "write_report"]
