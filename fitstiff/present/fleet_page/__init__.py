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

The parts, one concept a module: ``_read`` (the fleet directory), ``_numbers`` (each
cylinder's estimate, the typical cylinder), ``_text`` (labels and numbers as written),
``_figures`` (each figure on a given Axes), ``_sections`` (distributions, outliers, drift),
``_summary`` (the verdict, the table of units), ``_page`` (the page) and ``_cylinder`` (a
unit's report on demand).
"""

from __future__ import annotations

from fitstiff.present.fleet_page._cylinder import cylinder_report
from fitstiff.present.fleet_page._figures import plot_distribution, plot_drift, plot_loops
from fitstiff.present.fleet_page._page import write_fleet_report
from fitstiff.present.fleet_page._read import cylinder_dir
from fitstiff.present.fleet_page._sections import MAX_OUTLIERS_SHOWN

__all__ = ["write_fleet_report", "cylinder_report", "cylinder_dir", "plot_distribution",
           "plot_loops", "plot_drift", "MAX_OUTLIERS_SHOWN"]
