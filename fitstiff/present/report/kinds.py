"""What the page of each kind of run holds: a fit's and a posterior's sections (figures, tables,
verdict), as a :class:`Report` the page writer renders."""

from __future__ import annotations

import dataclasses
import math


from fitstiff.present.reopen import RunDirectory, fit_curves, posterior_curves, read_chain
from fitstiff.present.report.figures import (Section, chain_figures, corner_figure, model_sections,
                                             truth_of)
from fitstiff.present.report.text import (DEFINITIONS, Verdict, fit_tables, fit_verdict, log_table,
                                          paragraph, posterior_tables, posterior_verdict, quote)

__all__ = ["Report", "fit_report", "posterior_report"]



# -- the two kinds --------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Report:
    title: str
    verdict: Verdict
    summary: str                       # HTML
    sections: tuple[Section, ...]
    summary_title: str = "Estimates"
    #: the numbers engineers quote, in one line at the top (:func:`quote`); empty for none
    numbers: str = ""


def fit_report(run: RunDirectory, *, draws: int) -> Report:
    del draws                          # a fit has no posterior draws
    curves = fit_curves(run)
    truth = truth_of(run.problem.logs)
    offsets = [p["offset_N"] for p in run.result["per_log"]]
    summary = (fit_tables(run, truth)
               + paragraph("Standard errors from the Laplace covariance, inflated for "
                           "autocorrelated residuals; the 90 % interval is estimate ± 1.645 "
                           "standard errors.")
               + DEFINITIONS
               + log_table(run.problem, curves, offsets))
    return Report(f"Fit report: {run.result['model']}", fit_verdict(run.result), summary,
                   tuple(model_sections(run.problem, curves)),
                   numbers=quote(run.result["derived"], posterior=False))


def posterior_report(run: RunDirectory, *, draws: int) -> Report:
    chain = read_chain(run)
    curves = posterior_curves(run, chain, draws=draws)
    problem = run.problem
    truth = truth_of(problem.logs)
    rms = math.sqrt(sum(curves.rms(problem, i) ** 2 * len(log)
                        for i, log in enumerate(problem.logs))
                    / sum(len(log) for log in problem.logs))
    nuisances = run.posterior.nuisances
    offsets = [nuisances.get(f"offset[{log.name}]", {}).get("q50") for log in problem.logs]
    summary = (posterior_tables(run, truth)
               + paragraph("Posterior medians, standard deviations and central 90 % intervals. The "
                    "least-squares column is the fit the walkers started from.")
               + DEFINITIONS
               + log_table(problem, curves, offsets))
    sections = model_sections(problem, curves) + [
        Section("Posterior", figures=(corner_figure(run, truth),)),
        Section("Chains: trace and autocorrelation time",
                 html=paragraph("Model parameters only; the per-log offsets and initial friction "
                         "states are in chain.h5 and posterior.nc."),
                 figures=tuple(chain_figures(run, chain))),
    ]
    return Report(f"Posterior report: {run.posterior.model}",
                   posterior_verdict(run.posterior, rms), summary, tuple(sections),
                   numbers=quote(run.posterior.derived, posterior=True))
