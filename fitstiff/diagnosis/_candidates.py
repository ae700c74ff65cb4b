"""The :class:`~fitstiff.diagnosis.result.Candidate` record of each screened effect: built from
its screen (and held-out refit, where it had one) in each round, and, for the accepted ones,
the fitted values with their standard errors and intervals.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from fitstiff.diagnosis._refit import Tried
from fitstiff.diagnosis.result import Candidate
from fitstiff.diagnosis.screen import Score
from fitstiff.diagnosis.select import HeldOut
from fitstiff.diagnosis.supermodel import SuperProblem
from fitstiff.physics.params import to_display

__all__ = ["refitted", "screened", "parameter_entries", "improved_regions", "fitted_sizes"]

_IMPROVED = 0.95      # a region improved when its held-out RMS fell below 95 % of before
_REGIONS = ("presliding", "sliding", "dwell", "standstill", "stroke_end")


def refitted(sp: SuperProblem, s: Score, t: Tried, *, current: HeldOut, noise, masks,
             round_: int) -> Candidate:
    """The record of a candidate refitted in round ``round_`` (``t``: its refit and the rule's
    verdict; ``current``: the held-out figure of the model it was refitted on)."""
    return Candidate(
        effect=s.effect, score=s.statistic, dof=s.dof, p_value=s.p_value,
        log_p_value=s.log_p,
        testable=s.testable, heldout_rms_before_N=current.rms_N,
        heldout_rms_after_N=t.heldout.rms_N, shrink=t.shrink,
        converged=t.heldout.converged,
        regions_improved=improved_regions(sp, noise, masks, current, t.heldout),
        parameters=parameter_entries(sp, s.one_step, "one_step"), round=round_,
        why=t.why, determined_by=t.determined_by, outdone_by=t.outdone_by)


def screened(sp: SuperProblem, s: Score, *, round_: int, alpha: float, m: int) -> Candidate:
    """The record of a candidate screened in round ``round_`` and not refitted, with why
    (``m`` candidates: the screen's Bonferroni level ``alpha / m``)."""
    why = (f"not testable: {s.reason}" if s.reason else
           "significant, but a stronger candidate passed in this round (it is "
           "screened again on the enlarged model)" if s.testable
           and s.p_value * m < alpha else
           f"score not significant (p = {s.p_value:.2g}, needs < {alpha / m:.2g})")
    return Candidate(
        effect=s.effect, score=s.statistic, dof=s.dof, p_value=s.p_value,
        log_p_value=s.log_p,
        testable=s.testable, round=round_, why=why,
        parameters=parameter_entries(sp, s.one_step, "one_step"))


def parameter_entries(sp: SuperProblem, values, kind: str) -> dict[str, dict[str, object]]:
    """``Candidate.parameters``: each value (SI, by parameter name) in display units, with
    its unit and ``kind`` (``one_step`` or ``fit``)."""
    return {name: {"value": value, "unit": sp.units[name], "kind": kind}
            for name, value in to_display(sp.problem.model, values).items()}


def improved_regions(sp, noise, masks, before, after) -> tuple[str, ...]:
    """Motion regions whose held-out RMS fell below 95 % of before."""
    out = []
    for region in _REGIONS:
        b = a = 0.0
        n = 0
        for i, seg in enumerate(sp.problem.segmentations):
            if region not in seg.available_regions:
                continue
            keep = seg.mask(region) & masks[i]
            b += float(np.sum(before.residuals[i][keep] ** 2))
            a += float(np.sum(after.residuals[i][keep] ** 2))
            n += int(keep.sum())
        if n >= 10 and a < _IMPROVED**2 * b:
            out.append(region)
    return tuple(out)


def fitted_sizes(sp: SuperProblem, theta, hold, active, weights,
                 effects: Sequence[str]) -> dict[str, dict[str, object]]:
    """Standard error and 95 % interval (display units) of every fitted parameter of
    ``effects`` in the final full-data fit: the Gauss-Newton covariance over the free model
    entries and nuisances, ``s^2 (J^T J)^-1`` with ``s^2`` the residual variance, widened by
    the residuals' AR(1) factor ``(1 + rho) / (1 - rho)`` (the fit's rule for correlated
    noise). A parameter the data leave undetermined gets no interval."""
    if not effects:
        return {}
    free = sp.model_mask(active)
    x = np.asarray(sp.physical(theta, hold, free))
    r, jac = sp.jacobian(x, theta)
    keep = np.asarray(weights) > 0
    cols = np.concatenate([np.flatnonzero(free),
                           sp.n_model + np.flatnonzero(sp.nuisance_mask())])
    rf, jf = r[keep], jac[keep][:, cols]
    dof = max(rf.size - cols.size, 1)
    rho = float(np.clip(np.corrcoef(rf[:-1], rf[1:])[0, 1], 0.0, 0.99)) if rf.size > 2 else 0.0
    scale = float(rf @ rf) / dof * (1.0 + rho) / (1.0 - rho)
    # a column with a non-finite entry (a parameter at the edge of its law: Dahl's sigma0 /
    # Fc with Fc near 0 once a Maxwell-slip law has taken the friction over) determines
    # nothing; without it the SVD did not converge (withheld law/maxwell_slip/3)
    finite = np.all(np.isfinite(jf), axis=0)
    cols = cols[finite]
    jf = jf[:, finite]
    cov = scale * np.linalg.pinv(jf.T @ jf)
    position = {int(c): j for j, c in enumerate(cols)}
    par, out = sp.problem.par, {}
    for effect in effects:
        for k in sp.elements(effect, fitted=True):
            if int(k) not in position:
                continue
            var = cov[position[int(k)], position[int(k)]]
            if not (np.isfinite(var) and var > 0):
                continue
            name, se = par.names[k], math.sqrt(var)
            shown = to_display(sp.problem.model, {name: x[k]})[name]
            se_shown = abs(float(to_display(sp.problem.model, {name: se})[name]))
            out[name] = {"stderr": se_shown,
                         "interval_95": [float(shown) - 1.96 * se_shown,
                                         float(shown) + 1.96 * se_shown]}
    return out
