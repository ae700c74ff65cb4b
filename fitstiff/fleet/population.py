"""The population of a fleet: random-effects estimates, outliers and drift (issue 34).

Per quantity (by default the derived quantities of fit.json that describe a cylinder,
:data:`QUANTITIES`), on the log scale (every one is positive; a spread in per cent is a
spread of logs), with ``y_cr`` the estimate of cylinder ``c`` in run ``r`` and ``s_cr`` its
standard error (delta method, ``stderr / value``)::

    y_cr = mu + u_c + w_cr + e_cr,   u_c ~ N(0, tau^2),  w_cr ~ N(0, omega^2),  e_cr ~ N(0, s_cr^2)

- ``omega`` (run-to-run scatter) from the cylinders with two runs or more: their residuals
  about their own straight line in the run index (about their mean with two runs), pooled,
  less the mean ``s^2`` (method of moments, at least 0). A drifting cylinder does not widen
  it: its trend is taken out.
- ``mu`` and ``tau`` (population mean and between-cylinder spread) by maximum likelihood from
  each cylinder's mean over its runs ``ybar_c`` with variance ``v_c = (mean s^2 + omega^2) /
  n_c``: the estimate **and** its standard error enter. Intervals: ``mu`` by its Wald interval
  at ``tau``'s estimate, ``tau`` by the profile likelihood (chi-square, 1 dof).
- **Outliers**: a cylinder's two-sided predictive tail probability ``p = 2 Phi(-|ybar_c - mu|
  / sqrt(tau^2 + v_c))``; Benjamini-Hochberg over every (cylinder, quantity) of the fleet at
  ``q``. The first round's population is the median and a MAD-based spread, which the
  outliers do not widen (with :data:`_ROBUST_MIN` cylinders or more; below, in every round
  each cylinder against the ML population of the others, Student t; below
  :data:`_MIN_TESTED`, none is tested); then the population is refitted by ML without the flagged cylinders
  until the flags settle (with them, planted outliers widen ``tau`` and hide themselves).
- **Drift**: for a cylinder with :data:`MIN_DRIFT_RUNS` runs or more, the weighted slope of
  ``y`` against the run index (weights ``1 / (s^2 + omega^2)``), its z against its standard
  error, two-sided; Benjamini-Hochberg over every (cylinder, quantity) tested, at ``q``.
  ``drift_per_run`` is the slope as a fraction per run (``exp(b) - 1``).

The fleet's rows are sorted by cylinder and run first: the result depends on the rows, not on
the order the workers returned them in.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import numpy as np
import pandas as pd
from scipy import stats

__all__ = ["Population", "population", "QUANTITIES", "DEFAULT_Q", "MIN_DRIFT_RUNS",
           "benjamini_hochberg"]

#: the quantities a population is estimated for (fit.json's derived quantities)
QUANTITIES = ("presliding_slope_N_per_mm", "breakaway_N", "presliding_range_mm",
              "chamber_stiffness_N_per_mm")
#: the false-discovery rate of the outlier and drift flags
DEFAULT_Q = 0.01
#: runs a cylinder needs for its drift to be tested
MIN_DRIFT_RUNS = 3
_Z95 = stats.norm.ppf(0.975)
_CHI2_95 = stats.chi2.ppf(0.95, 1)
_MAX_ROUNDS = 20
#: cylinders a quantity needs before the first round's population is the median and MAD:
#: in fewer the MAD can come out near 0 by chance, every cylinder then looks far off and
#: the flagged ones never return to the fit that judges them (5 cylinders: a slope spread of
#: 0 % and a cylinder 4.5 % off flagged at q = 3e-12); there the first round is ML on all
_ROBUST_MIN = 20
#: cylinders a quantity needs before any of them is tested as an outlier (with fewer, the
#: others say too little about the population's spread)
_MIN_TESTED = 5


def benjamini_hochberg(p: np.ndarray) -> np.ndarray:
    """Benjamini-Hochberg adjusted p-values (q-values): ``p`` flagged at level ``q`` where
    the result is at most ``q``."""
    p = np.asarray(p, dtype=float)
    m = p.size
    if not m:
        return p
    order = np.argsort(p, kind="stable")
    ranked = p[order] * m / np.arange(1, m + 1)
    adjusted = np.minimum.accumulate(ranked[::-1])[::-1]
    out = np.empty(m)
    out[order] = np.clip(adjusted, 0.0, 1.0)
    return out


@dataclasses.dataclass(frozen=True)
class Population:
    """The population fit of a fleet (``population.json``) and the rows' flags.

    Attributes:
        q: the false-discovery rate of the flags.
        quantities: per quantity the estimates (see :meth:`to_dict`).
        flags: per row of the sorted table (cylinder, run): ``outlier``,
            ``outlier_quantities``, ``outlier_size``, ``outlier_q``, ``drift``,
            ``drift_quantities``, ``drift_per_run``, ``drift_q``.
    """

    q: float
    quantities: Mapping[str, Mapping[str, object]]
    outliers: tuple[Mapping[str, object], ...]
    drifts: tuple[Mapping[str, object], ...]
    flags: pd.DataFrame

    def to_dict(self) -> dict[str, object]:
        return {"q": self.q, "scale": "log", "model": (
                    "y_cr = mu + u_c + w_cr + e_cr on the log scale: u_c ~ N(0, tau^2) "
                    "between cylinders, w_cr ~ N(0, omega^2) run to run, e_cr ~ N(0, s_cr^2) "
                    "each fit's own error"),
                "quantities": dict(self.quantities), "outliers": list(self.outliers),
                "drift": list(self.drifts)}


def _run_scatter(groups: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> float | None:
    """omega^2 by moments from cylinders with two runs or more (detrended with three or
    more), or None when no cylinder has two runs."""
    ss, dof, s2 = 0.0, 0, []
    for runs, y, s in groups:
        n = y.size
        if n < 2:
            continue
        if n >= 3:
            coef = np.polyfit(runs, y, 1)
            res = y - np.polyval(coef, runs)
            dof += n - 2
        else:
            res = y - y.mean()
            dof += n - 1
        ss += float(res @ res)
        s2.extend(s**2)
    if dof == 0:
        return None
    return max(ss / dof - float(np.mean(s2)), 0.0)


def _profile(ybar: np.ndarray, v: np.ndarray, tau2: float) -> tuple[float, float]:
    """(mu(tau), log-likelihood) of the cylinders' means at between-cylinder variance tau2."""
    w = 1.0 / (tau2 + v)
    mu = float(np.sum(w * ybar) / np.sum(w))
    ll = -0.5 * float(np.sum(np.log(2 * np.pi / w) + w * (ybar - mu) ** 2))
    return mu, ll


def _leave_one_out(ybar: np.ndarray, v: np.ndarray, excluded: np.ndarray) -> np.ndarray:
    """Each cylinder's predictive tail probability under the population fitted to the others
    that are not ``excluded`` (flagged; its mean's uncertainty included): a small fleet's
    test, where one outlier widens a population fitted with it enough to hide itself. Fewer
    than :data:`_MIN_TESTED` cylinders: no test (1)."""
    n = ybar.size
    if n < _MIN_TESTED:
        return np.ones(n)
    out = np.empty(n)
    for i in range(n):
        others = (np.arange(n) != i) & ~excluded
        m = int(others.sum())
        if m < _MIN_TESTED - 1:
            out[i] = 1.0
            continue
        fit = _random_effects(ybar[others], v[others])
        # a spread from m cylinders: ML's m-divisor undone, and Student's t with m - 1
        # degrees of freedom for its uncertainty (with the normal, a clean fleet of six
        # flagged a cylinder 10 % off at q = 0.004)
        tau2 = 0.0 if math.isnan(fit["tau"]) else fit["tau"] ** 2 * m / (m - 1)
        scale = math.sqrt(tau2 + float(v[i]) + fit["mu_se"] ** 2)
        out[i] = 2 * stats.t.sf(abs(float(ybar[i]) - fit["mu"]) / scale, df=m - 1)
    return out


def _robust(ybar: np.ndarray, v: np.ndarray) -> dict[str, float]:
    """The first round's population: the median and the MAD-based spread (less the median
    of the cylinders' own variances), which the outliers it is to find do not widen (an ML
    fit with 3 % of cylinders 30 % off widens a 6 % spread to 6.7 %, and hides most of
    them)."""
    mu = float(np.median(ybar))
    mad = 1.4826 * float(np.median(np.abs(ybar - mu)))
    return {"mu": mu, "tau": math.sqrt(max(mad**2 - float(np.median(v)), 0.0))}


def _random_effects(ybar: np.ndarray, v: np.ndarray) -> dict[str, float]:
    """ML mu and tau with intervals (see the module docstring)."""
    if ybar.size == 1:
        return {"mu": float(ybar[0]), "mu_se": math.sqrt(float(v[0])), "tau": math.nan,
                "tau_low": math.nan, "tau_high": math.nan}
    spread = float(np.var(ybar)) + float(np.max(v))
    grid = np.concatenate([[0.0], np.geomspace(1e-8 * max(spread, 1e-300), 4 * spread, 400)])
    lls = np.array([_profile(ybar, v, t)[1] for t in grid])
    k = int(np.argmax(lls))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]
    for _ in range(60):          # golden-section refinement inside the bracket
        a, b = lo + 0.382 * (hi - lo), lo + 0.618 * (hi - lo)
        if _profile(ybar, v, a)[1] >= _profile(ybar, v, b)[1]:
            hi = b
        else:
            lo = a
    tau2 = 0.5 * (lo + hi)
    mu, best = _profile(ybar, v, tau2)
    if best < lls[k]:
        tau2, (mu, best) = float(grid[k]), _profile(ybar, v, float(grid[k]))
    inside = grid[2 * (best - lls) <= _CHI2_95]
    w = 1.0 / (tau2 + v)
    return {"mu": mu, "mu_se": math.sqrt(1.0 / float(np.sum(w))), "tau": math.sqrt(tau2),
            "tau_low": math.sqrt(float(inside.min())), "tau_high": math.sqrt(float(inside.max()))}


def population(table: pd.DataFrame, *, q: float = DEFAULT_Q,
               quantities: Sequence[str] = QUANTITIES) -> Population:
    """The population model, outliers and drift of a fleet table (``fleet.parquet``'s rows,
    any order). Rows with an error, not converged or not identifiable, or without a positive
    value and a finite standard error of a quantity do not enter that quantity."""
    if not 0 < q < 1:
        raise ValueError(f"q={q} must lie strictly between 0 and 1")
    table = table.sort_values(["cylinder", "run_index"], kind="stable").reset_index(drop=True)
    per_quantity = _quantities(table, quantities)
    outliers = _outliers(per_quantity, q)
    drifts = _drifts(per_quantity, q)
    summaries = {name: _summary(d, outliers.fits[name], outliers.excluded[name])
                 for name, d in per_quantity.items()}
    return Population(q=q, quantities=summaries, outliers=_ranked(outliers.rows, "size"),
                      drifts=_ranked(drifts, "per_run"),
                      flags=_flags(table, outliers.rows, drifts))


class _Quantity(NamedTuple):
    """One quantity's data on the log scale, per cylinder with a usable run."""

    names: list[str]         # the cylinders
    ybar: np.ndarray         # each one's mean over its runs
    v: np.ndarray            # the variance of that mean: (mean s^2 + omega^2) / runs
    omega2: float | None     # the run-to-run variance (None: no cylinder has two runs)
    groups: dict             # per cylinder (run indices, y, s, rows of the table)


#: per cylinder its flags of one kind: (quantity, size or drift per run, q-value)
_Rows = dict[str, list[tuple[str, float, float]]]


def _quantities(table: pd.DataFrame, quantities: Sequence[str]) -> dict[str, _Quantity]:
    """The quantities of the (sorted) table that at least two cylinders have estimates of."""
    ok = (table["error"].fillna("") == "") & table["converged"].astype(bool) \
        & table["identifiable"].astype(bool)
    cylinders = list(dict.fromkeys(table["cylinder"]))
    per_quantity: dict[str, _Quantity] = {}
    for name in quantities:
        if name not in table:
            continue
        value = table[name].to_numpy(float)
        err = table[f"{name}_stderr"].to_numpy(float)
        use = ok.to_numpy() & np.isfinite(value) & (value > 0) & np.isfinite(err)
        y = np.where(use, np.log(np.where(use, value, 1.0)), np.nan)
        s = np.where(use, err / np.where(use, value, 1.0), np.nan)
        groups = {}
        for c in cylinders:
            rows = np.flatnonzero((table["cylinder"] == c).to_numpy() & use)
            if rows.size:
                groups[c] = (table["run_index"].to_numpy(float)[rows], y[rows], s[rows], rows)
        if len(groups) < 2:
            continue
        omega2 = _run_scatter([g[:3] for g in groups.values()])
        names = list(groups)
        ybar = np.array([groups[c][1].mean() for c in names])
        v = np.array([(np.mean(groups[c][2] ** 2) + (omega2 or 0.0)) / groups[c][1].size
                      for c in names])
        per_quantity[name] = _Quantity(names, ybar, v, omega2, groups)
    return per_quantity


class _Outliers(NamedTuple):
    """The outcome of the outlier rounds."""

    fits: dict[str, dict[str, float]]     # per quantity the population of the last round
    excluded: dict[str, np.ndarray]       # per quantity the cylinders left out of it
    rows: _Rows                           # per flagged cylinder (quantity, size, q-value)


class _Round(NamedTuple):
    """One round of the outlier test, over every quantity."""

    fits: dict[str, dict[str, float]]     # per quantity its population
    pvals: list[np.ndarray]               # per quantity each cylinder's tail probability
    index: list[tuple[str, int]]          # (quantity, cylinder position) of each p-value


def _outliers(per_quantity: Mapping[str, _Quantity], q: float) -> _Outliers:
    """Refit without the flagged cylinders until the flags settle (module docstring)."""
    excluded = {name: np.zeros(len(d.names), bool) for name, d in per_quantity.items()}
    for round_ in range(_MAX_ROUNDS):
        fits, pvals, index = _round(per_quantity, excluded, round_)
        qvals = benjamini_hochberg(np.concatenate(pvals)) if pvals else np.zeros(0)
        flagged = {name: np.zeros(len(d.names), bool) for name, d in per_quantity.items()}
        for (name, i), qv in zip(index, qvals):
            flagged[name][i] = qv <= q
        if round_ and all(np.array_equal(flagged[n], excluded[n]) for n in per_quantity):
            break           # (after one ML round at least: the population reported is ML's)
        excluded = flagged
    rows: _Rows = {}
    for (name, i), qv in zip(index, qvals):
        if qv <= q:
            d, fit = per_quantity[name], fits[name]
            size = math.exp(d.ybar[i] - fit["mu"]) - 1.0
            rows.setdefault(d.names[i], []).append((name, size, float(qv)))
    return _Outliers(fits, excluded, rows)


def _round(per_quantity: Mapping[str, _Quantity], excluded: Mapping[str, np.ndarray],
           round_: int) -> _Round:
    """The populations without the ``excluded`` cylinders, and every cylinder's p-value."""
    fits, pvals, index = {}, [], []
    for name, d in per_quantity.items():
        keep = ~excluded[name]
        if keep.sum() < 2:
            keep = np.ones_like(keep)
        n = len(d.names)
        if n < _ROBUST_MIN:        # every round: each against the others not flagged
            fits[name] = _random_effects(d.ybar[keep], d.v[keep])
            pvals.append(_leave_one_out(d.ybar, d.v, excluded[name]))
        else:
            fits[name] = fit = (_robust(d.ybar, d.v) if round_ == 0
                                else _random_effects(d.ybar[keep], d.v[keep]))
            tau2 = 0.0 if math.isnan(fit["tau"]) else fit["tau"] ** 2
            z = (d.ybar - fit["mu"]) / np.sqrt(tau2 + d.v)
            pvals.append(2 * stats.norm.sf(np.abs(z)) if n >= _MIN_TESTED
                         else np.ones(n))
        index += [(name, i) for i in range(len(d.names))]
    return _Round(fits, pvals, index)


def _drifts(per_quantity: Mapping[str, _Quantity], q: float) -> _Rows:
    """Per drifting cylinder (quantity, drift per run, q-value): a weighted slope per
    cylinder with enough runs (module docstring)."""
    tests = []
    for name, d in per_quantity.items():
        omega2 = d.omega2 or 0.0
        for c, (runs, y, s, _) in d.groups.items():
            if y.size < MIN_DRIFT_RUNS or np.ptp(runs) == 0:
                continue
            w = 1.0 / (s**2 + omega2)
            xm = float(np.sum(w * runs) / np.sum(w))
            sxx = float(np.sum(w * (runs - xm) ** 2))
            b = float(np.sum(w * (runs - xm) * y) / sxx)
            z = b * math.sqrt(sxx)
            tests.append((c, name, b, 2 * stats.norm.sf(abs(z))))
    drift_q = benjamini_hochberg(np.array([t[3] for t in tests])) if tests else np.zeros(0)
    drift_rows: _Rows = {}
    for (c, name, b, _), qv in zip(tests, drift_q):
        if qv <= q:
            drift_rows.setdefault(c, []).append((name, math.expm1(b), float(qv)))
    return drift_rows


def _summary(d: _Quantity, fit: Mapping[str, float], excluded: np.ndarray) -> dict:
    """One quantity's entry of ``population.json``."""
    mu, se = fit["mu"], fit["mu_se"]
    return {
        "cylinders": len(d.names), "used": int((~excluded).sum()),
        "mean": math.exp(mu), "mean_interval_95": [math.exp(mu - _Z95 * se),
                                                   math.exp(mu + _Z95 * se)],
        "spread_sd_log": _finite(fit["tau"]),
        "spread_interval_95": [_finite(fit["tau_low"]), _finite(fit["tau_high"])],
        "run_to_run_sd_log": (None if d.omega2 is None else math.sqrt(d.omega2)),
        "note": "spreads are standard deviations of the natural log: 0.08 is a spread "
                "of about 8 %"}


def _flags(table: pd.DataFrame, outlier_rows: _Rows, drift_rows: _Rows) -> pd.DataFrame:
    """The flag columns of every row of the (sorted) table (:class:`Population`)."""
    flags = pd.DataFrame({"cylinder": table["cylinder"], "run": table["run"]})
    flags["outlier"] = flags["cylinder"].map(lambda c: c in outlier_rows)
    flags["outlier_quantities"] = flags["cylinder"].map(
        lambda c: ",".join(n for n, _, _ in outlier_rows.get(c, ())))
    flags["outlier_size"] = flags["cylinder"].map(
        lambda c: ", ".join(f"{n} {100 * sz:+.1f} %" for n, sz, _ in outlier_rows.get(c, ())))
    flags["outlier_q"] = flags["cylinder"].map(
        lambda c: min((qv for _, _, qv in outlier_rows.get(c, ())), default=math.nan))
    flags["drift"] = flags["cylinder"].map(lambda c: c in drift_rows)
    flags["drift_quantities"] = flags["cylinder"].map(
        lambda c: ",".join(n for n, _, _ in drift_rows.get(c, ())))
    strongest = {c: min(items, key=lambda t: t[2]) for c, items in drift_rows.items()}
    flags["drift_per_run"] = flags["cylinder"].map(
        lambda c: strongest[c][1] if c in strongest else math.nan)
    flags["drift_q"] = flags["cylinder"].map(
        lambda c: strongest[c][2] if c in strongest else math.nan)
    return flags


def _ranked(rows: _Rows, key: str) -> tuple[dict[str, object], ...]:
    """The flagged cylinders of one kind, most significant first, as in ``population.json``
    (``key``: ``size`` for the outliers, ``per_run`` for the drifts)."""
    return tuple({"cylinder": c, "quantities": [n for n, _, _ in items],
                  key: {n: value for n, value, _ in items},
                  "q_value": min(qv for _, _, qv in items)}
                 for c, items in sorted(rows.items(), key=lambda kv: min(t[2] for t in kv[1])))


def _finite(v: float) -> float | None:
    return float(v) if v is not None and math.isfinite(v) else None
