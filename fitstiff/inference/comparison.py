"""Model comparison: information criteria and held-out error over logs.

Held-out error (leave one log out): fit the shared parameters on every other log, then
predict the left-out log with them, fitting only that log's own nuisances (force offset and
initial friction state), and take the RMS force error. It rewards models that generalise
across logs, not models with more parameters.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from fitstiff.errors import InputError
from fitstiff.inference.fitting import FitResult, fit, fit_problem
from fitstiff.inference.problem import Problem
from fitstiff.inference.selection import Selection
from fitstiff.io.log import Log
from fitstiff.physics.model import Model
from fitstiff.physics.params import named_params
from fitstiff.signal.noise import noise_floor

__all__ = ["Comparison", "check_specs", "compare", "held_out_rms", "pooled_noise", "predict_held_out",
           "rank_held_out", "TIE"]


def predict_held_out(log: Log, model: Model, **problem_kw) -> tuple[float, FitResult]:
    """RMS force error (N) of ``model`` on ``log`` with only the log's nuisances fitted."""
    names = [n for _, _, ns in named_params(model) for n in ns]
    problem = Problem([log], model, fix=names, selection=Selection.pick(problem_kw)[0])
    result = fit_problem(problem)
    return result.rms_N, result


def held_out_rms(logs: Sequence[Log], model: Model | str, **fit_kw) -> list[float]:
    """Leave-one-log-out RMS force errors (N), one per log (needs two logs or more)."""
    if len(logs) < 2:
        raise InputError(None, "held-out error over logs", f"got {len(logs)} log",
                         "give two logs or more (or rank by BIC)")
    selection, _ = Selection.pick(fit_kw)
    out = []
    for i in range(len(logs)):
        train = [log for j, log in enumerate(logs) if j != i]
        trained = fit(train, model, **fit_kw)
        rms, _ = predict_held_out(logs[i], trained.model, selection=selection)
        out.append(rms)
    return out


@dataclasses.dataclass(frozen=True)
class Comparison:
    """Several models fitted to the same logs, ranked (best first)."""

    rows: tuple[dict[str, object], ...]
    ranked_by: str

    def to_dict(self) -> dict[str, object]:
        return {"ranked_by": self.ranked_by, "models": list(self.rows)}

    def table(self) -> str:
        lines = [f"{'model':<36}{'params':>7}{'rms N':>10}{'AIC':>14}{'BIC':>14}"
                 f"{'held-out N':>12}  converged"]
        for r in self.rows:
            held = r["heldout_rms_N"]
            lines.append(f"{r['spec']:<36}{r['n_params']:>7}{r['rms_N']:>10.4g}"
                         f"{r['aic']:>14.6g}{r['bic']:>14.6g}"
                         f"{'n/a' if held is None else f'{held:.4g}':>12}  {r['converged']}")
        lines.append(f"ranked by {self.ranked_by}" + (
            f" (values within {TIE:.0%} of the logs' noise floor are a tie: identifiable "
            "first, then BIC)" if self.ranked_by == "heldout_rms_N" else ""))
        return "\n".join(lines)


def check_specs(logs: Sequence[Log], specs: Sequence[str], **fit_kw) -> None:
    """Build every spec's problem on ``logs`` (raises the first spec's :class:`InputError`,
    e.g. a chamber term without ``bore_mm``), so that no fit runs before all can."""
    if not specs:
        raise InputError(None, "--compare", "names no model", "give SPEC,SPEC,...")
    selection, _ = Selection.pick(fit_kw)
    for spec in specs:
        try:
            Problem(list(logs), spec, selection=selection)
        except InputError as exc:
            raise InputError(None, f"--compare model '{spec}'", str(exc),
                             "drop it from --compare or give what it needs") from None


def compare(logs: Sequence[Log], specs: Sequence[str], **fit_kw) -> tuple[Comparison,
                                                                           list[FitResult]]:
    """Fit every spec to ``logs``; rank by held-out RMS (two logs or more; near-ties by
    identifiability, then BIC: :func:`rank_held_out`), else by BIC.
    Every spec is checked on the logs first (:func:`check_specs`). Each row holds the spec
    as given (``spec``, e.g. ``maxwell_slip:4``), the built model's spec (``model``), the
    fit's numbers and its ``parameters`` and ``derived`` values as in ``fit.json``."""
    check_specs(logs, specs, **fit_kw)
    results, rows = [], []
    for spec in specs:
        result = fit(logs, spec, **fit_kw)
        held = held_out_rms(logs, spec, **fit_kw) if len(logs) >= 2 else None
        results.append(result)
        summary = result.to_dict()
        rows.append({"spec": spec, "model": result.model.spec, "n_params": result.n_params,
                     "rms_N": result.rms_N, "aic": result.aic, "bic": result.bic,
                     "heldout_rms_N": (math.sqrt(float(np.mean(np.square(held))))
                                       if held else None),
                     "heldout_rms_per_log_N": held, "converged": result.converged,
                     "parameters": summary["parameters"], "derived": summary["derived"]})
    if len(logs) >= 2:
        key = "heldout_rms_N"
        best = min(results, key=lambda res: res.rms_N)      # the logs as its fit read them
        tie = TIE * pooled_noise(best.problem.logs, references=[
            np.asarray(one["force"]) for one in best.problem.per_log(best.theta)])
        order = rank_held_out([r["heldout_rms_N"] for r in rows], [r["bic"] for r in rows],
                              [res.identifiability.identifiable for res in results], tie=tie)
    else:
        key = "bic"
        order = sorted(range(len(rows)), key=lambda i: rows[i][key])
    for i in range(len(rows)):
        rows[i]["identifiable"] = bool(results[i].identifiability.identifiable)
    return (Comparison(tuple(rows[i] for i in order), key), [results[i] for i in order])


#: held-out RMS values within this share of the logs' noise floor are a tie, here and in the
#: diagnosis (:func:`fitstiff.diagnosis._choice.choose`): broken by identifiability (here)
#: or the fit to all the data (BIC)
TIE = 0.01


def pooled_noise(logs: Sequence[Log], *, references: Sequence[np.ndarray] | None = None
                 ) -> float:
    """The logs' force noise floor (N), pooled over their samples (:func:`noise_floor`;
    ``references``: per log, a fitted model's predicted force, as the diagnosis reads its
    floors with its baseline's)."""
    counts = np.array([len(log) for log in logs], dtype=float)
    refs = [None] * len(logs) if references is None else list(references)
    sigmas = np.array([noise_floor(np.asarray(log.force), reference=g).sigma
                       for log, g in zip(logs, refs)])
    return math.sqrt(float(np.sum(counts * sigmas**2) / counts.sum()))


def rank_held_out(heldout: Sequence[float], bic: Sequence[float],
                  identifiable: Sequence[bool], *, tie: float) -> list[int]:
    """Indices best first: by held-out RMS, except that models within ``tie`` (N) of each
    other are ranked identifiable first, then by BIC. A model that beats another by more
    than ``tie`` held out ranks above it whatever else; so an unidentifiable model never
    ranks above an identifiable one it does not beat clearly."""
    def before(i: int, j: int) -> bool:
        if abs(heldout[i] - heldout[j]) > tie:
            return heldout[i] < heldout[j]
        if bool(identifiable[i]) != bool(identifiable[j]):
            return bool(identifiable[i])
        return bic[i] < bic[j]

    order: list[int] = []
    for i in sorted(range(len(heldout)), key=lambda i: heldout[i]):
        at = len(order)
        while at > 0 and before(i, order[at - 1]):
            at -= 1
        order.insert(at, i)
    return order
