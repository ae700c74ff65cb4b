"""Which effect: score (Lagrange-multiplier) statistics of every candidate at its null value.

At the current model's least-squares fit, the residuals ``r`` and their Jacobian ``J`` are
taken with respect to every model parameter **in physical coordinates** (several nulls sit on
a bound of the transform layer, where the unconstrained derivative vanishes) and every
nuisance, through the hysteresis scan (:meth:`SuperProblem.jacobian`). Both are filtered with
each log's AR(1) noise coefficient (``e_t - rho e_{t-1}``, scaled to unit variance), so that
under the null hypothesis the filtered residuals are white. With ``B`` the columns of the
current model's free parameters and nuisances and ``G`` the candidate's tested columns,
projected off ``B`` (``G_perp``, ``r_perp``):

    g = G_perp^T r_perp,   I = G_perp^T G_perp,   LM = g^T I^+ g / s^2   ~ chi2(k)

with ``s^2`` the filtered residual variance. A one-parameter effect whose null is a lower
bound (``c >= 0``, ``mass >= 0``) is tested one-sided with ``z = -g / sqrt(I s^2)``. Shape
parameters that the null leaves undetermined (Stribeck velocity, dwell growth time and decay
travel) are scanned on a small grid; the p-value is Bonferroni-corrected over the grid.

The same quantities give the **detectability**: along the candidate's main direction ``d``,
the size ``(z_a + z_0.8) s / sqrt(d^T I d)`` is the effect that these logs would detect at
80 % power with the screen's level ``a``. Detected is not accepted: the acceptance rule also
wants the effect to lower the held-out force RMS by ``min_gain`` of the noise floor, so its
force (projected off the baseline, unfiltered, over the ``n_f`` force samples) must reach an
RMS of ``sqrt((1 + min_gain)^2 - 1) s``: the size ``sqrt(((1 + min_gain)^2 - 1) n_f s^2 /
|G_perp d|^2)``. The reported detectable size is the larger of the two (on the withheld-effect
benchmark the score's size alone was 5-10 times below what was accepted: 36 of 63 effects
above it were found). Where ``G`` lies in the span of ``B`` (no pauses for dwell stiction, one
pressure for pressure friction) the candidate is not testable.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence

import numpy as np
from scipy import stats

from fitstiff.diagnosis.supermodel import SuperProblem
from fitstiff.errors import FitstiffError
from fitstiff.physics.params import Param
from fitstiff.physics.terms import TERMS
from fitstiff.signal.noise import NoiseFloor, noise_floor

__all__ = ["Score", "screen", "collinear_groups", "detectability", "SHAPE_GRIDS", "POWER",
           "COLLINEAR_TIE", "chi2_logsf"]

POWER = 0.8
#: shape parameters scanned by the screen (SI); the first value starts the model
SHAPE_GRIDS: dict[str, dict[str, tuple[float, ...]]] = {
    "stribeck": {"stribeck_vs": (0.5e-3, 2e-3, 8e-3)},
    "dwell_stiction": {"dwell_tau": (0.3, 3.0), "dwell_decay": (0.05e-3, 0.2e-3)},
}
_COLLINEAR = 1e-6    # share of a candidate column left after projection: not testable
#: share of a candidate's column left within a log after projection on the current model's
#: columns there, below which that log cannot test it alone (:func:`_between_logs`)
_BETWEEN = 1e-6
#: correlation of two candidates' projected columns above which the screen cannot order them
COLLINEAR_TIE = 0.999


@dataclasses.dataclass(frozen=True)
class Score:
    """The screen's verdict on one candidate."""

    effect: str
    statistic: float               # LM statistic (chi2 scale; z**2 for one-sided)
    dof: int
    p_value: float                 # after the grid correction
    log_p: float                   # its natural log, from the log survival function: strong
                                   # effects' p-values underflow to 0, and a tie at 0 would be
                                   # broken by the order of the candidate list
    direction: float               # sign of the one-step estimate along the main direction
    testable: bool
    reason: str | None             # why not testable
    detectable: float | None       # SI, along the main direction (see ``parameter``)
    parameter: str                 # main parameter the detectable size refers to
    param: Param                   # its metadata (display unit, conversion)
    one_step: Mapping[str, float]  # SI start values of the candidate's parameters
    shape: Mapping[str, float]     # shape values of the best grid point (SI)
    #: its main direction's filtered column projected off the current model, unit length
    #: (what :func:`collinear_groups` compares); None when not testable
    column: np.ndarray | None = dataclasses.field(default=None, repr=False, compare=False)
    #: the joint Gauss-Newton step's move of the current model's free entries that goes with
    #: ``one_step`` (``base_cols`` index -> change; physical units for model parameters, the
    #: nuisances' own coordinates): ``-B^+ G step``, the baseline parameters the effect was
    #: projected off taking up what the effect no longer needs them for (a series compliance
    #: leaves the pre-sliding slope it softened)
    base_step: Mapping[int, float] = dataclasses.field(default_factory=dict, repr=False,
                                                      compare=False)
    #: whether the logs test it only against each other: within every log alone its main
    #: column is one of the current model's (pressure-dependent friction with one pressure
    #: per log is each log's own friction level), so its evidence is the differences
    #: between the logs (:func:`_between_logs`)
    between_logs: bool = False


def _ar1_filter(a: np.ndarray, series, rhos) -> np.ndarray:
    """Apply each series' AR(1) prewhitening along axis 0 (residuals or Jacobian columns)."""
    out = np.array(a, dtype=float, copy=True)
    for s, rho in zip(series, rhos):
        if rho == 0.0:
            continue
        block = a[s.span]
        filtered = (block[1:] - rho * block[:-1]) / math.sqrt(1.0 - rho**2)
        out[s.span.start + 1:s.span.stop] = filtered
    return out


def _series_rhos(sp: SuperProblem, noise: Sequence[NoiseFloor]) -> list[float]:
    """AR(1) coefficient per residual series: the log's force noise, or its pressure noise."""
    out = []
    for s in sp.series:
        if s.channel == "force":
            out.append(min(max(noise[s.log].rho, 0.0), 0.95))
        else:
            log = sp.problem.logs[s.log]
            p = log.pressure_a if s.channel == "pressure_a" else log.pressure_b
            out.append(min(max(noise_floor(p).rho, 0.0), 0.95) if p is not None else 0.0)
    return out


def _orthonormal(b: np.ndarray) -> np.ndarray:
    norms = np.linalg.norm(b, axis=0)
    b = b[:, norms > 0] / norms[norms > 0]
    if b.shape[1] == 0:
        return b
    u, sv, _ = np.linalg.svd(b, full_matrices=False)
    return u[:, sv > 1e-10 * sv[0]]


def _check_finite(sp: SuperProblem, r: np.ndarray, base: np.ndarray, cols: np.ndarray) -> None:
    """The current fit's residuals and its own columns must be finite: the screen's
    projections are meaningless otherwise (a candidate's column that is not finite makes
    that candidate untestable instead, :func:`_score`)."""
    bad = [k for k, ok in zip(cols, np.isfinite(base).all(axis=0)) if not ok]
    if np.isfinite(r).all() and not bad:
        return
    names = sp.problem.par.names
    where = ", ".join(names[k] if k < sp.n_model else f"nuisance {k - sp.n_model}"
                      for k in bad[:8]) or "the residuals"
    raise FitstiffError(f"the diagnosis' screen: the current fit's derivatives are not finite "
                        f"({where}); the fit has left the model's valid range")


def screen(sp: SuperProblem, theta: np.ndarray, hold: np.ndarray, *, active: Sequence[str],
           candidates: Sequence[str], noise: Sequence[NoiseFloor], weights: np.ndarray,
           alpha: float, min_gain: float) -> tuple[list[Score], np.ndarray]:
    """Score every candidate at the current fit ``(theta, hold)`` of the ``active`` terms;
    ``min_gain``: the acceptance rule's least held-out RMS fall, as a share of the noise floor
    (for the detectable size).

    Returns the scores (in the order of ``candidates``) and ``hold`` with the shape values of
    each candidate's best grid point (where the refit starts).
    """
    free_model = sp.model_mask(active)
    hold = np.array(hold, dtype=float)
    x = np.asarray(sp.physical(theta, hold, free_model))
    rhos = _series_rhos(sp, noise)
    r, jac = sp.jacobian(x, theta)
    w = np.asarray(weights)
    keep = w > 0
    rf = _ar1_filter(r * w, sp.series, rhos)[keep]
    jf = _ar1_filter(jac * w[:, None], sp.series, rhos)[keep]
    base_cols = np.concatenate([np.flatnonzero(free_model),
                                sp.n_model + np.arange(sp.size - sp.n_model)])
    base = jf[:, base_cols]
    _check_finite(sp, rf, base, base_cols)
    q = _orthonormal(base)
    r_perp = rf - q @ (q.T @ rf)
    dof = max(rf.size - q.shape[1], 1)
    s2 = float(r_perp @ r_perp) / dof
    # the unfiltered force rows, for the size the held-out rule can accept
    force = np.zeros(w.size, dtype=bool)
    for series in sp.series:
        if series.channel == "force":
            force[series.span] = True
    force = force[keep]
    row_log = np.zeros(w.size, dtype=int)
    for series in sp.series:
        row_log[series.span] = series.log
    row_log = row_log[keep]
    # the current model's columns within each log, orthonormal, once for every candidate
    per_log = {int(k): (row_log == k, _orthonormal(base[row_log == k]))
               for k in np.unique(row_log)}
    ju = (jac * w[:, None])[keep]
    q_raw = _orthonormal(ju[:, base_cols])
    accept = _AcceptSize(q_raw, force, ((1.0 + min_gain) ** 2 - 1.0) * s2)
    m = max(len(candidates), 1)
    out = []
    for effect in candidates:
        tested = sp.elements(effect, tested=True)
        grid = SHAPE_GRIDS.get(effect, {})
        points = _grid_points(grid)
        best = None
        for point in points:
            if point:
                x_p = x.copy()
                hold_p = hold.copy()
                for name, value in point.items():
                    k = sp.problem.par.names.index(name)
                    x_p[k] = hold_p[k] = value
                cols = []
                for k in tested:
                    tangent = np.zeros(sp.n_model)
                    tangent[k] = 1.0
                    _, col = sp.column(x_p, theta, tangent)
                    cols.append(col)
                g_cols = np.stack(cols, axis=1)
            else:
                g_cols = jac[:, tested]
            gf = _ar1_filter(g_cols * w[:, None], sp.series, rhos)[keep]
            score = _score(effect, sp, tested, gf, q, r_perp, s2, alpha / m, len(points),
                           accept=accept, unfiltered=(g_cols * w[:, None])[keep],
                           base=(base, base_cols), per_log=per_log)
            score = dataclasses.replace(score, shape=point)
            if best is None or score.log_p < best.log_p:
                best = score
        for name, value in best.shape.items():
            hold[sp.problem.par.names.index(name)] = value
        out.append(best)
    return out, hold


def collinear_groups(scores: Sequence[Score], *, threshold: float = COLLINEAR_TIE
                     ) -> list[list[Score]]:
    """Groups (two or more) of testable candidates whose projected main columns agree to
    ``|correlation| >= threshold``: the screen gives them the same statistic up to noise and
    cannot order them (leakage and heat exchange, to first order both an accumulated
    relaxation of the pressure a displacement built up, agree to 0.99997)."""
    testable = [s for s in scores if s.testable and s.column is not None]
    groups: list[list[Score]] = []
    for s in testable:
        for g in groups:
            if any(abs(float(s.column @ t.column)) >= threshold for t in g):
                g.append(s)
                break
        else:
            groups.append([s])
    return [g for g in groups if len(g) > 1]


def detectability(s: Score) -> dict[str, object]:
    """The DESIGN §5 ``detectability`` entry of one candidate's score (``Diagnosis.detectability``,
    from the first screen): the size the logs detect at 80 % power (for an effect of several
    like elements, the smallest total, put where the logs see it best), or ``testable:
    false`` with why and what to record. A size beyond the parameter's physical range (a
    Stribeck ratio of 51 where the term ends at 5, a pressure coefficient of 9.6 /bar on one
    pressure) is not testable on these logs either."""
    term = TERMS[s.effect]
    if not s.testable:
        return {"testable": False, "parameter": s.parameter, "reason": s.reason,
                "record": term.excitation}
    null = s.param.null if s.param.null is not None else 0.0
    reach = max(s.param.upper - null, null - s.param.lower)
    size = s.param.to_display(s.detectable)
    if math.isfinite(reach) and s.detectable > reach:
        unit = "" if s.param.unit == "-" else f" {s.param.unit}"
        return {"testable": False, "parameter": s.parameter,
                "reason": f"not detectable on these logs: {s.parameter} would have to move "
                          f"{size:.3g}{unit} from its null, beyond the term's range "
                          f"({s.param.to_display(reach):.3g}{unit})",
                "record": term.excitation}
    return {"testable": True, "parameter": s.parameter, "size": size,
            "unit": s.param.unit, "power": 0.8}


def detectable_total(info: np.ndarray, z: float, direction: np.ndarray, accepted
                     ) -> tuple[float, float]:
    """The total size (summed over ``direction``'s entries) of an effect that the score
    test detects (``z``: the normal quantiles of the level and the power added), along the
    candidate's ``direction``; and the size reported as detectable: the larger of that and
    the size the held-out rule can accept (``accepted(d)``, per unit of ``d``), and for an
    effect of several like elements (Maxwell-slip's stiffnesses, the entries where
    ``direction`` is 1) the smallest such total, put where the logs see it best.

    ``info``: the information of the tested entries over the residual variance. The
    information a split of one total carries is a convex form of the split, largest at a
    corner of the simplex: one element alone.

    Both sizes are first-order, at the baseline's fit. Where an effect's refit moves the
    baseline far (Maxwell-slip elements that take Dahl's friction over) it can do better
    than that: on the withheld ``single/maxwell_slip`` sets the elements are seen nearly
    alike (correlations 0.94-0.999), the corners lower the size 5-10 % (to 19-24 N/mm), the
    held-out rule's size sets it (the score test's is 3.5 N/mm on ``/0``), and four of five
    are accepted at totals of 0.4-0.7 times it."""
    def along(d: np.ndarray) -> tuple[float, float]:
        info_d = float(d @ info @ d)
        by = z / math.sqrt(info_d) * d.sum() if info_d > 0 else math.inf
        return by, float(max(by, accepted(d) * d.sum()))

    by_score, detectable = along(direction)
    like = np.flatnonzero(direction)
    if like.size > 1:
        for k in like:
            detectable = min(detectable, along(np.eye(direction.size)[k])[1])
    return by_score, detectable


def _between_logs(column: np.ndarray, per_log: Mapping[int, tuple[np.ndarray, np.ndarray]]
                  ) -> bool:
    """Whether, within every log alone, ``column`` (a candidate's main column, whitened) lies
    in the span of the current model's columns restricted to that log's rows (``per_log``:
    per log, its rows and an orthonormal basis of those columns there): then no log tests
    the candidate on its own, only the differences between two logs or more do (friction
    that grows with the pressure, on logs at one pressure each: within a log it is that
    log's friction level)."""
    seen = 0
    for rows, q in per_log.values():
        c = column[rows]
        size = float(c @ c)
        if size == 0.0:
            continue
        seen += 1
        left = c - q @ (q.T @ c) if q.shape[1] else c
        if float(left @ left) >= _BETWEEN * size:
            return False
    return seen >= 2


def chi2_logsf(x: float, dof: int) -> float:
    """``log P(chi2_dof > x)``, finite far in the tail. ``scipy.stats.chi2.logsf`` takes the
    log of the survival function, which underflows to ``-inf`` beyond ``x`` of about 1 500
    (the strong effects of the withheld-effect benchmark score up to 10 000); there the
    asymptotic series of the regularised upper incomplete gamma function
    ``Q(a, z) = z**(a-1) exp(-z) / Gamma(a) * sum_j (a-1)...(a-j) / z**j`` (``a = dof/2``,
    ``z = x/2``) is used, whose terms for ``z`` in the hundreds and ``a`` of a few are
    below 1e-16 within ten."""
    value = float(stats.chi2.logsf(x, dof))
    if math.isfinite(value):
        return value
    a, z = 0.5 * dof, 0.5 * x
    term = total = 1.0
    for j in range(1, 11):
        term *= (a - j) / z
        total += term
    return (a - 1.0) * math.log(z) - z - math.lgamma(a) + math.log(total)


def _grid_points(grid: Mapping[str, Sequence[float]]) -> list[dict[str, float]]:
    points: list[dict[str, float]] = [{}]
    for name, values in grid.items():
        points = [dict(p, **{name: v}) for p in points for v in values]
    return points


@dataclasses.dataclass(frozen=True)
class _AcceptSize:
    """What the held-out rule needs: the baseline's unfiltered columns (orthonormal), the force
    rows, and the least mean square force an effect must add (whitened units)."""

    q: np.ndarray
    force: np.ndarray
    power: float

    def size(self, columns: np.ndarray, direction: np.ndarray) -> float:
        """Along ``direction`` (SI per unit), the size whose force reaches :attr:`power`;
        ``columns``: the candidate's unfiltered Jacobian columns."""
        signal = columns @ direction
        signal = (signal - self.q @ (self.q.T @ signal))[self.force]
        energy = float(signal @ signal)
        if energy <= 0:
            return math.inf
        return math.sqrt(self.power * self.force.sum() / energy)


def _score(effect: str, sp: SuperProblem, tested: np.ndarray, g_cols: np.ndarray,
           q: np.ndarray, r_perp: np.ndarray, s2: float, alpha: float,
           n_grid: int, *, accept: _AcceptSize, unfiltered: np.ndarray,
           base: tuple[np.ndarray, np.ndarray],
           per_log: Mapping[int, tuple[np.ndarray, np.ndarray]]) -> Score:
    owners = [sp.owners[k] for k in tested]
    main = owners[0].name.rsplit("_", 1)[0] if owners[0].name.endswith("_1") else owners[0].name
    direction_vec = np.array([1.0 if (o.name == main or o.name.rsplit("_", 1)[0] == main)
                              else 0.0 for o in owners])
    param = sp.problem.par.entries[tested[0]].param
    g_perp = g_cols - q @ (q.T @ g_cols)
    raw = np.linalg.norm(g_cols @ direction_vec)
    left = np.linalg.norm(g_perp @ direction_vec)
    lower_bounded = [sp.problem.par.entries[k].param.lower == sp.owners[k].null
                     for k in tested]
    if not np.isfinite(g_cols).all():
        bad = int((~np.isfinite(g_cols)).any(axis=1).sum())
        return Score(effect, 0.0, len(tested), 1.0, 0.0, 0.0, False,
                     f"its derivative is not finite at the current fit ({bad} of "
                     f"{g_cols.shape[0]} rows): it cannot be screened there", None, main,
                     param, {}, {})
    if raw == 0 or left**2 < _COLLINEAR * raw**2 or s2 <= 0:
        reason = ("the logs do not excite it (its effect on the force is zero)" if raw == 0
                  else "with these logs it cannot be told apart from the baseline's parameters")
        return Score(effect, 0.0, len(tested), 1.0, 0.0, 0.0, False, reason, None, main,
                     param, {}, {})
    g = g_perp.T @ r_perp
    info = g_perp.T @ g_perp
    pinv = np.linalg.pinv(info, rcond=1e-10)
    step = -pinv @ g                     # one Gauss-Newton step from the null (physical)
    if len(tested) == 1 and lower_bounded[0]:
        z = float(step[0] * math.sqrt(info[0, 0] / s2))
        statistic, dof = z * abs(z), 1
        log_p = float(stats.norm.logsf(z))
        z_a = stats.norm.isf(alpha)
    else:
        statistic = float(g @ pinv @ g / s2)
        dof = int(np.linalg.matrix_rank(info))
        log_p = chi2_logsf(statistic, dof)
        z_a = stats.norm.isf(alpha / 2)
    log_p = min(0.0, log_p + math.log(n_grid))
    p = math.exp(log_p)
    by_score, detectable = detectable_total(info / s2, z_a + stats.norm.ppf(POWER),
                                            direction_vec,
                                            lambda d: accept.size(unfiltered, d))
    one_step = {}
    for k, o, value in zip(tested, owners, step):
        v = o.null + float(value)
        lo = sp.problem.par.entries[k].param.lower
        hi = sp.problem.par.entries[k].param.upper
        tiny = 0.05 * by_score / max(direction_vec.sum(), 1.0)
        one_step[o.name] = float(np.clip(v, lo + tiny if lo == o.null else lo,
                                         hi - 1e-9 * abs(hi) if np.isfinite(hi) else np.inf))
    sign = float(np.sign(direction_vec @ step))
    column = g_perp @ direction_vec
    b, cols = base
    taken = np.array([one_step[o.name] - o.null for o in owners])   # the step, as clipped
    shift = np.linalg.lstsq(b, -(g_cols @ taken), rcond=None)[0] if b.shape[1] else []
    return Score(effect, statistic, dof, p, log_p, sign, True, None, detectable, main, param,
                 one_step, {}, column / np.linalg.norm(column),
                 {int(k): float(v) for k, v in zip(cols, shift)},
                 _between_logs(g_cols @ direction_vec, per_log))
