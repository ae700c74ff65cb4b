"""Fitting one candidate description of the held-out residual
(:mod:`fitstiff.diagnosis.structure`): its columns (:class:`Design`; hat functions at
``KNOTS`` quantiles for a smooth one, times ``1 - exp(-travel / s0)`` for a gated one, and
beside them the same times the variable for a transition; a sine and a cosine per stretch
of the stroke for a periodic one; a friction level per log beside a transition in the time or
the speed), the
penalised least squares with the penalty chosen by generalised cross-validation
(:func:`ridge`), and the fit on training samples that predicts every sample
(:func:`fit_predict`, the period scanned for a periodic one).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from fitstiff.diagnosis._structure_forms import Candidate, one_level_per_log, periods

__all__ = ["KNOTS", "Design", "Fit", "fit_predict", "gate", "hats", "ridge"]

KNOTS = 8
#: penalty weights tried by generalised cross-validation, in units of the columns' scale
_LAMBDAS = 10.0 ** np.arange(-4.0, 4.5, 1.0)


def hats(v: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """Piecewise-linear hat functions at ``knots`` (constant beyond the ends)."""
    x = np.clip(v, knots[0], knots[-1])
    cols = np.zeros((v.size, knots.size))
    idx = np.clip(np.searchsorted(knots, x, side="right") - 1, 0, knots.size - 2)
    w = (x - knots[idx]) / (knots[idx + 1] - knots[idx])
    rows = np.arange(v.size)
    cols[rows, idx] = 1.0 - w
    cols[rows, idx + 1] += w
    return cols


class Design:
    """The columns of one candidate given the training samples (knots, period), centred per
    log over all samples (the centring uses no residual)."""

    def __init__(self, cand: Candidate, log_id: np.ndarray, weight: np.ndarray):
        self.cand, self.log_id, self.weight = cand, log_id, weight
        self.n_logs = int(log_id.max()) + 1
        self.own = (log_id[:, None] == np.arange(self.n_logs)[None, :]).astype(float)
        # a periodic description's phase groups (logs on one stretch of the stroke): per
        # sample its group's column, and per group the logs in it (a log each by default)
        self.phase, self._group_logs = self.own, np.eye(self.n_logs)
        if cand.groups is not None:
            n_groups = int(cand.groups.max()) + 1
            self.phase = (cand.groups[:, None] == np.arange(n_groups)[None, :]).astype(float)
            group_of_log = np.zeros(self.n_logs, dtype=np.int64)
            group_of_log[log_id] = cand.groups
            self._group_logs = (np.arange(n_groups)[:, None]
                                == group_of_log[None, :]).astype(float)
        # a transition scaled by a variable that varies within the logs (the time, the
        # speed) carries a friction level per log (the ``log`` description's columns): what
        # the physics fit of the other logs leaves in a log's level is no shape of it
        self._levels = (cand.form == "transition" and self.n_logs > 1
                        and not one_level_per_log(cand.scale, log_id, weight > 0))
        # the logs lie one after another: per-log sums are sums over these runs of rows
        self._starts = np.flatnonzero(np.r_[True, np.diff(log_id) != 0])
        total = self._per_log(weight)
        self._total = np.where(total > 0, total, 1.0)

    def columns(self, train: np.ndarray, shape: float | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
        """The columns and their penalty; ``shape``: a periodic description's period, a
        gated one's travel ``s0`` (mm) over which it grows in after a reversal."""
        c = self.cand
        v = c.values
        if c.form in ("linear", "curved"):
            # a law a + b z (+ c z^2) of the variable; centring each log takes the constant
            # off an even law, but a signed one keeps it (a friction level times the
            # direction): where its zero lies is fitted, not fixed at the training mean
            z = v - np.mean(v[train])
            base = np.column_stack(([np.ones_like(z)] if c.signed else [])
                                   + [z] + ([z**2] if c.form == "curved" else []))
            pen = np.zeros((base.shape[1], base.shape[1]))
        elif c.form == "step":
            base = v[:, None] if c.variable == "direction" else self.own
            pen = np.zeros((base.shape[1], base.shape[1]))
        elif c.form == "periodic":
            # one period, a phase and an amplitude per stretch of the stroke
            # (:func:`~fitstiff.diagnosis._structure_forms.stretches`)
            phase = 2 * np.pi * v / shape
            base = np.concatenate([self.phase * np.sin(phase)[:, None],
                                   self.phase * np.cos(phase)[:, None]], axis=1)
            pen = np.zeros((base.shape[1], base.shape[1]))
        else:                       # smooth; a hysteresis is smooth in the force's travel
            knots = self._knots(v, train)
            if knots.size < 3:
                knots = np.linspace(v[train].min(), v[train].max() + 1e-12, 3)
            base = hats(v, knots)
            if c.form == "gated":        # a level that grows in as the seal slides
                base = base * -np.expm1(-c.scale / shape)[:, None]
            d2 = np.diff(np.eye(knots.size), 2, axis=0)
            pen = d2.T @ d2
            if c.form == "transition":
                # the transition's shape, and a second one times the variable (centred)
                z = (c.scale - np.mean(c.scale[train]))[:, None]
                zero = np.zeros_like(pen)
                base = np.concatenate([base, base * z], axis=1)
                pen = np.block([[pen, zero], [zero, pen]])
        x = base * c.sign[:, None]
        if self._levels:
            # a friction level of each log's own beside the shape (unpenalised)
            lv = self.own * c.sign[:, None]
            x = np.concatenate([x, lv], axis=1)
            pen = np.block([[pen, np.zeros((pen.shape[0], lv.shape[1]))],
                            [np.zeros((lv.shape[1], pen.shape[0] + lv.shape[1]))]])
        return self._centre(x), pen

    def _knots(self, v: np.ndarray, train: np.ndarray) -> np.ndarray:
        """``KNOTS`` quantiles of the training values; of each log's own for the position
        (logs far apart along the stroke would otherwise share a handful of knots)."""
        q = np.linspace(0, 1, KNOTS)
        if self.cand.variable != "position":
            return np.unique(np.quantile(v[train], q))
        return np.unique(np.concatenate([np.quantile(v[train & (self.log_id == k)], q)
                                         for k in range(self.n_logs)
                                         if np.any(train & (self.log_id == k))]))

    def _per_log(self, x: np.ndarray) -> np.ndarray:
        """Sums over each log's samples (rows), one row per log."""
        return np.add.reduceat(x, self._starts, axis=0)

    def _centre(self, x: np.ndarray) -> np.ndarray:
        """Each column less its weighted mean over each log's samples."""
        w = self.weight if x.ndim == 1 else self.weight[:, None]
        means = self._per_log(w * x) / (self._total if x.ndim == 1 else self._total[:, None])
        return x - means[self.log_id]

    def period_rss(self, r: np.ndarray, wt: np.ndarray, periods: np.ndarray) -> np.ndarray:
        """The training RSS of the periodic description at each of ``periods`` at once:
        its columns are a sine and a cosine per stretch of the stroke, so the least squares
        fall apart into a 2 x 2 system per stretch and period (what :meth:`columns` and
        :func:`ridge` give one period at a time)."""
        phase = 2 * np.pi * self.cand.values[:, None] / periods[None, :]
        sign = self.cand.sign[:, None]
        sin, cos = self._centre(sign * np.sin(phase)), self._centre(sign * np.cos(phase))
        ws, wc = wt[:, None] * sin, wt[:, None] * cos

        def per_group(x):
            return self._group_logs @ self._per_log(x)

        ss, cc, sc = per_group(ws * sin), per_group(wc * cos), per_group(ws * cos)
        rs, rc = per_group(r[:, None] * ws), per_group(r[:, None] * wc)
        det = ss * cc - sc**2
        ok = det > 1e-12 * np.maximum(ss * cc, 1e-300)
        safe = np.where(ok, det, 1.0)
        a, b = (cc * rs - sc * rc) / safe, (ss * rc - sc * rs) / safe
        explained = np.where(ok, a * rs + b * rc, 0.0).sum(axis=0)
        return float(np.sum(wt * r**2)) - explained


def ridge(x: np.ndarray, r: np.ndarray, pen: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Penalised least squares of ``r`` on ``x`` with weights ``w``; the penalty's weight by
    generalised cross-validation (a tiny ridge keeps flat columns harmless)."""
    xtw = x.T * w
    a = xtw @ x
    b = xtw @ r
    n = float(np.sum(w > 0))
    scale = max(float(np.trace(a)) / max(a.shape[0], 1), 1e-300)
    tiny = 1e-9 * scale * np.eye(a.shape[0])
    if not np.any(pen):
        return np.linalg.solve(a + tiny, b)
    best, beta_best = math.inf, None
    for lam in _LAMBDAS:
        m = a + lam * scale * pen + tiny
        try:
            beta = np.linalg.solve(m, b)
            dof = float(np.trace(np.linalg.solve(m, a)))
        except np.linalg.LinAlgError:
            continue
        rss = max(float(np.sum(w * r**2) - 2 * beta @ b + beta @ a @ beta), 0.0)
        gcv = rss / max(n * (1 - dof / n) ** 2, 1e-300)
        if gcv < best:
            best, beta_best = gcv, beta
    return beta_best


#: the travels (mm) over which a gated description may grow in after a reversal, chosen on
#: the training samples (a seal's presliding range is 0.05-1 mm)
_GATES = (0.03, 0.1, 0.3, 1.0)


def gate(design: Design, r: np.ndarray, train: np.ndarray, w: np.ndarray) -> float:
    """A gated description's travel ``s0`` (mm): of :data:`_GATES`, the one whose fit to
    the ``train`` samples leaves the least residual."""
    wt = w * train
    best, chosen = math.inf, _GATES[0]
    for s0 in _GATES:
        x, pen = design.columns(train, s0)
        rss = float(np.sum(wt * (r - x @ ridge(x, r, pen, wt)) ** 2))
        if rss < best:
            best, chosen = rss, s0
    return chosen


class Fit(NamedTuple):
    """A description fitted on training samples: its prediction of every sample, the period
    chosen (a periodic one; else None) and its number of columns (``dof``)."""

    pred: np.ndarray
    period: float | None
    dof: int


def fit_predict(design: Design, r: np.ndarray, train: np.ndarray, w: np.ndarray) -> Fit:
    """Fit on ``train`` (weights ``w``), predict every sample; the period chosen on
    ``train`` for a periodic candidate, the travel it grows in over for a gated one."""
    wt = w * train
    if design.cand.form == "gated":
        x, pen = design.columns(train, gate(design, r, train, w))
        return Fit(x @ ridge(x, r, pen, wt), None, x.shape[1])
    if design.cand.form != "periodic":
        x, pen = design.columns(train)
        beta = ridge(x, r, pen, wt)
        return Fit(x @ beta, None, x.shape[1])
    grid = periods(design.cand.values, design.log_id)
    k = int(np.argmin(design.period_rss(r, wt, grid)))
    # refine between the neighbours of the best grid period
    fine = np.geomspace(grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)], 21)
    period = float(fine[int(np.argmin(design.period_rss(r, wt, fine)))])
    x, pen = design.columns(train, period)
    beta = ridge(x, r, pen, wt)
    return Fit(x @ beta, float(period), x.shape[1])
