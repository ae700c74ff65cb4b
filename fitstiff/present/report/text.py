"""The words and tables of the report pages: numbers formatted with their spread, HTML tables,
the verdicts of a fit and a posterior, the parameter and per-log tables, and the headline quote
of the pre-sliding slope and the breakaway."""

from __future__ import annotations

import dataclasses
import html
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from fitstiff.inference.posterior import PosteriorRecord
from fitstiff.inference.problem import Problem
from fitstiff.io.log import Log
from fitstiff.physics.derived import split_unit, to_display as derived_display
from fitstiff.present.reopen import Z90, Curves, RunDirectory

__all__ = ["fmt", "fmt_to", "paragraph", "html_table", "Verdict", "per_log_noise", "fit_verdict",
           "not_identifiable", "posterior_verdict", "entries", "center", "fit_tables",
           "posterior_tables", "value_pm", "log_table", "pressure_cell", "inputs_table", "quote",
           "DEFINITIONS"]



_POSTERIOR_RMS_EXCESS = 0.10    # median curve worse than least squares by more: say so


# -- tables and words -----------------------------------------------------------------------
def fmt(value: float | None, digits: int = 5) -> str:
    if value is None or not math.isfinite(value):
        return "n/a"
    return f"{value:.{digits}g}"


def fmt_to(value: float | None, spread: float | None) -> str:
    """``value`` with the decimals that give ``spread`` (its uncertainty) two significant
    digits: 1.4000 for n = 1.40004 +/- 0.0026, not 1.4."""
    if value is None or spread is None or not (math.isfinite(spread) and spread > 0):
        return fmt(value)
    return f"{value:.{max(0, 1 - math.floor(math.log10(spread)))}f}"


def paragraph(text: str) -> str:
    return f"<p>{html.escape(text)}</p>"


def html_table(headers: Sequence[str], rows: Sequence[Sequence[str]], *,
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
class Verdict:
    status: str                  # "ok", "caution" or "bad"
    headline: str
    details: tuple[str, ...]


def per_log_noise(noise: Mapping[str, float], *, what: str = "force noise estimate") -> str:
    """``a force noise estimate of 0.2 N`` for one log; for several, every log's own (a mean
    would hide a log whose noise differs)."""
    if len(noise) == 1:
        return f"a {what} of {next(iter(noise.values())):.3g} N"
    return (f"{what}s of " + ", ".join(f"{v:.3g} N ({k})" for k, v in noise.items()))


def fit_verdict(result: Mapping[str, Any]) -> Verdict:
    rms = result["rms_N"]
    noise = per_log_noise({p.get("name", f"log {i + 1}"): p["force_noise_N"]
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
        headline = not_identifiable(result.get("identifiable_reason"),
                                     result.get("identifiability"))
        status = "bad"
    return Verdict(status, headline, warnings_)


def not_identifiable(reason: str | None, details: Mapping[str, Any] | None) -> str:
    """The red headline of a fit (or the fit a posterior started from) whose data do not
    separate the seal parameters (:mod:`fitstiff.inference.identifiability`): its
    ``identifiable_reason`` and ``identifiability``."""
    details = details or {}
    withheld = list(details.get("parameters", [])) + [
        split_unit(d)[0] for d in details.get("derived", [])]
    return ("The data do NOT identify the seal parameters: "
            f"{reason} No standard error is given for "
            f"{', '.join(withheld) or 'the affected quantities'}; do not quote them.")


def posterior_verdict(record: PosteriorRecord, curves_rms: float) -> Verdict:
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
        headline = not_identifiable(record.identifiable_reason, record.identifiability)
        status = "bad"
    return Verdict(status, headline, tuple(details + cautions))


def entries(parameters: Mapping[str, Mapping[str, Any]],
             derived: Mapping[str, Mapping[str, Any]]) -> list[tuple[str, str, Mapping[str, Any]]]:
    """``(name, label, entry)`` of the parameters, then the derived quantities (their entries
    given a ``unit``)."""
    out = [(name, name, p) for name, p in parameters.items()]
    for name, d in derived.items():
        label, unit = split_unit(name)
        # a derived quantity that is a parameter of the model (Dahl's sigma0 is its pre-sliding
        # slope, Fc its breakaway) says so instead of reading as a second estimate
        same = next((n for n, p in parameters.items() if p.get("unit") == unit
                     and center(p) is not None and center(d) is not None
                     and math.isclose(center(p), center(d), rel_tol=1e-9)), None)
        out.append((name, f"{label} (= {same})" if same else label, {"unit": unit} | d))
    return out


def center(entry: Mapping[str, Any]) -> float | None:
    """A fit entry's value or a posterior entry's median."""
    value = entry.get("value", entry.get("q50"))
    return None if value is None else float(value)


def fit_tables(run: RunDirectory, truth: Mapping[str, float]) -> str:
    rows = []
    for name, label, e in entries(run.result["parameters"], run.result["derived"]):
        value, stderr = e["value"], e.get("stderr")
        if e.get("fixed"):
            spread, interval = "fixed", ""
        elif stderr is None:
            spread, interval = "n/a", "n/a (not determined)"
        else:
            spread = fmt_to(stderr, stderr)
            interval = (f"{fmt_to(value - Z90 * stderr, stderr)} to "
                        f"{fmt_to(value + Z90 * stderr, stderr)}")
        rows.append([label, fmt_to(value, stderr), spread, interval, e["unit"],
                     fmt(truth.get(name))])
    return html_table(["quantity", "estimate", "standard error", "90 % interval", "unit", "truth"],
                  rows)


def posterior_tables(run: RunDirectory, truth: Mapping[str, float]) -> str:
    record = run.posterior
    fit = record.fit or {}
    least_squares = {**fit.get("parameters", {}), **fit.get("derived", {})}
    rows = []
    for name, label, e in entries(record.parameters, record.derived):
        if e.get("fixed"):
            rows.append([label, fmt(e["value"]), "fixed", "", e["unit"], "",
                         fmt(truth.get(name))])
            continue
        std, ls = e["std"], least_squares.get(name)
        rows.append([label, fmt_to(e["q50"], std), fmt_to(std, std),
                     f"{fmt_to(e['q05'], std)} to {fmt_to(e['q95'], std)}", e["unit"],
                     value_pm(ls),
                     fmt(truth.get(name))])
    return html_table(["quantity", "median", "std", "90 % interval (5-95 %)", "unit",
                   "least squares ± stderr", "truth"], rows)


def value_pm(entry: Mapping[str, object] | None) -> str:
    """``value ± stderr`` of a least-squares entry; the value alone where it has no stderr."""
    if entry is None or entry.get("value") is None:
        return ""
    value, stderr = entry["value"], entry.get("stderr")
    if stderr is None:
        return fmt(value)
    return f"{fmt_to(value, stderr)} ± {fmt_to(stderr, stderr)}"


def log_table(problem: Problem, curves: Curves, offsets: Sequence[float | None]) -> str:
    """Per log: size, pressure, the point model's chamber stiffness at its start, fit quality."""
    model = curves.model
    rows = []
    for i, log in enumerate(problem.logs):
        supply = log.rig.supply_pressure
        k_chamber = (derived_display("chamber_stiffness_N_per_mm",
                                     float(model.term("chamber").stiffness(problem.drives[i])))
                     if model.has("chamber") else None)
        rows.append([log.name, str(len(log)), pressure_cell(log, supply), fmt(k_chamber, 4),
                     fmt(curves.rms(problem, i), 3), fmt(problem.force_noise[i], 3),
                     fmt(offsets[i], 3), "yes" if problem.denoised[i] else "no"])
    return html_table(["log", "samples", "supply [bar gauge]", "chamber stiffness [N/mm]",
                   "RMS residual [N]", "force noise estimate [N]", "force offset [N]",
                   "displacement denoised"], rows)


def pressure_cell(log: Log, supply: float | None) -> str:
    """The supply pressure, else the mean logged chamber pressure (regulated), else n/a."""
    if supply is not None:
        return fmt(supply / 1e5, 3)
    logged = [(c.upper(), float(np.mean(g)) / 1e5) for c in "ab"
              if getattr(log, f"pressure_{c}") is not None
              and (g := log.gauge(c)) is not None]
    if not logged:
        return "n/a"
    return "regulated " + " / ".join(f"{c} {fmt(v, 3)}" for c, v in logged)


def inputs_table(run: RunDirectory) -> str:
    rows = [[str(path), f"{digest[:16]}...", "unchanged since the run"]
            for path, digest in run.inputs]
    return html_table(["input file", "sha256", "check"], rows, numeric_from=3)


DEFINITIONS = paragraph(
    "presliding_slope: the seal's stiffness at zero friction force (Dahl, LuGre: sigma0; right "
    "after a reversal from saturation these models start about twice as steep); breakaway: the "
    "largest friction force before gross sliding; presliding_range: travel after a reversal "
    "until the friction force has made 95 % of its swing; chamber_stiffness: linearised "
    "stiffness of the closed chambers at the first log's start (every log's in the table "
    "below); total_stiffness: their sum.")


#: the quantities of the report's first line: (derived name, label)
_QUOTED = (("presliding_slope_N_per_mm", "pre-sliding slope"), ("breakaway_N", "breakaway"))


def quote(entries: Mapping[str, Mapping[str, Any]], *, posterior: bool) -> str:
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
            parts.append(f"{label} {fmt(value)} {unit} (not determined)")
        else:
            parts.append(f"{label} {fmt_to(value, spread)} {unit} "
                         f"[{fmt_to(low, spread)}, {fmt_to(high, spread)}]")
    text = ", ".join(parts)
    return f"{text[:1].upper()}{text[1:]} (90 % intervals)" if parts else ""
