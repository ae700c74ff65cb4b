"""A candidate's held-out refit: where each fold's refit starts, and what the acceptance rule
(:mod:`fitstiff.diagnosis.select`) says of it.

Used by the rounds of :func:`~fitstiff.diagnosis.diagnose.diagnose`
(:mod:`fitstiff.diagnosis._rounds`), the choice among passing candidates
(:mod:`fitstiff.diagnosis._choice`) and the backward check (:mod:`fitstiff.diagnosis.prune`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numpy as np
from scipy.optimize import nnls

from fitstiff.diagnosis.screen import Score, screen
from fitstiff.diagnosis.select import FOLD_THREADS, MIN_GAIN, FoldFit, HeldOut
from fitstiff.diagnosis.supermodel import SuperProblem
from fitstiff.physics.params import to_display
from fitstiff.physics.terms import TERMS, FrictionBase, MaxwellSlip

__all__ = ["Start", "Tried", "FoldStarts", "judge", "lone_log", "on_bound", "worse_log",
           "refit_start", "maxwell_shape", "fold_fits", "at_null"]

_MAXWELL_SHAPE = (0.25, 0.5, 1.0, 2.0)   # slip displacements, multiples of breakaway / slope
_PAPER_BREAKAWAY, _PAPER_SLOPE = 18.0, 40e3     # N, N/m: the paper's seal
#: the share of its force the friction base keeps in a friction law's handover start
#: (:func:`_handover`)
_HANDOVER = 0.05
#: longer one-step moves a refit may start from (:func:`refit_start`)
_STEP_FACTORS = (4.0, 16.0, 64.0)
#: a fitted parameter within this share of its range (or of its size, for a one-sided
#: range) from a bound that is not its null rests on the bound (:func:`on_bound`)
_BOUND = 1e-3
#: a fold whose estimate of the effect is within this share of the nearest other fold's
#: distance from the null has not found it (:func:`lone_log`)
_LONE = 0.25


class Start(NamedTuple):
    """Where a fit starts: ``theta`` (the solver's coordinates of the free entries and
    nuisances) and ``hold`` (physical values of the model entries); ``also``: other starts
    the held-out refit solves from too, keeping the lowest training cost (:func:`refit_start`)."""

    theta: np.ndarray
    hold: np.ndarray
    also: tuple = ()


@dataclasses.dataclass(frozen=True)
class Tried:
    """A refitted candidate: its screen, held-out refit, the rule's verdict and the fold
    starts its refit used."""

    score: Score
    heldout: HeldOut
    shrink: float
    passes: bool
    why: str
    starts: tuple[FoldFit, ...]
    #: the log that alone determines the effect, where :func:`lone_log` found one
    determined_by: str = ""
    #: the description that explained the gap better (:class:`~fitstiff.diagnosis._rounds.Rival`)
    outdone_by: str = ""

    @property
    def effect(self) -> str:
        return self.score.effect


def judge(sp: SuperProblem, s: Score, ho: HeldOut, starts, *, current: HeldOut,
          noise: float, min_shrink: float, effects: Sequence[str] | None = None) -> Tried:
    """The acceptance rule (:mod:`fitstiff.diagnosis.select`) on one held-out refit of
    ``effects`` (default: ``s.effect``), whose fold fits must also keep every fitted parameter
    of them off the bounds of its range (:func:`on_bound`)."""
    gap = current.rms_N - noise
    shrink = (current.rms_N - ho.rms_N) / gap if gap > 0 else float("nan")
    gain = current.rms_N - ho.rms_N
    bound = on_bound(sp, ho, effects or [s.effect])
    worse = worse_log(sp, s, ho, current, noise)
    passes = (ho.converged and gain >= MIN_GAIN * noise
              and math.isfinite(shrink) and shrink >= min_shrink and bound is None
              and worse is None)
    why = ("" if passes else "a refit did not converge" if not ho.converged
           else "held-out RMS did not fall" if gain <= 0
           else f"lowers the held-out RMS by only {gain:.2g} N (needs "
                f"{MIN_GAIN:.0%} of the noise floor, {MIN_GAIN * noise:.2g} N)"
           if gain < MIN_GAIN * noise
           else f"removes only {shrink:.0%} of the gap above the noise "
                f"(needs {min_shrink:.0%})" if shrink < min_shrink
           else bound if bound is not None else worse)
    lone = lone_log(sp, s, ho) if not passes and ho.converged and gain > 0 else None
    if lone is not None:
        why += "; " + lone[1]
    return Tried(s, ho, shrink, passes, why, tuple(starts), lone[0] if lone else "")


def lone_log(sp: SuperProblem, s: Score, ho: HeldOut) -> tuple[str, str] | None:
    """Why a candidate's held-out refit gains little when one log alone determines it: every
    fold that trains on that log finds the effect (its main parameter off its null, on one
    side), and the fold that leaves it out does not (within :data:`_LONE` of the nearest
    one's distance from the null, or on a bound of its range): the other logs cannot pin
    it, so that log, held out, is predicted without it: that log's name and the sentence
    that says so; or None. Leave-one-log-out with three logs or more.

    Seen on the withheld Stribeck sets whose Stribeck velocity is 1.1-1.4 mm/s: the slow log
    (1.4 mm/s) shows the friction's rise, the faster ones (5-30 mm/s) only at their reversal
    samples, where level and velocity trade off. Fitted to the two fast logs of
    ``single/stribeck/4`` the ratio went to 4.99 (its bound) at 0.12 mm/s; with the slow log
    1.03-1.06 at 1.4-2.6 mm/s (truth 1.059 at 1.34 mm/s), and the held-out refit removed 22 %
    of the gap although the score test found it at log p -395."""
    n = sp.problem.n_logs
    par = sp.problem.par
    if n < 3 or len(ho.fits) != n or s.parameter not in par.names:
        return None
    # only an effect whose force, fitted to all the logs, would clear the rule's least gain:
    # its score (the fall of the squared residual in units of the noise variance, to first
    # order) at least ((1 + MIN_GAIN)**2 - 1) per sample; a weak later-round candidate (a
    # force drift at log p -16 that lowers the held-out RMS by 0.3 mN) is no experiment's
    # worth
    if s.statistic < ((1.0 + MIN_GAIN) ** 2 - 1.0) * sum(len(log) for log in sp.problem.logs):
        return None
    k = par.names.index(s.parameter)
    null = sp.owners[k].null
    # with two logs or more the folds leave out one log each, in the logs' order (folds_for)
    values = np.array([float(f.hold[k]) for f in ho.fits])
    p = par.entries[k].param
    away = values - null
    for j in range(n):
        others = np.delete(away, j)
        if not (np.all(others > 0) or np.all(others < 0)):
            continue
        bound = any(math.isfinite(b) and b != null and abs(values[j] - b) <= _BOUND * (
                        p.upper - p.lower if math.isfinite(p.upper - p.lower)
                        else max(abs(b), abs(values[j]), 1e-300))
                    for b in (p.lower, p.upper))   # as on_bound reads a bound
        if bound or abs(away[j]) <= _LONE * float(np.min(np.abs(others))):
            others = np.delete(values, j)
            shown = [next(iter(to_display(sp.problem.model, {s.parameter: v}).values()))
                     for v in (values[j], others.min(), others.max())]
            unit = "" if sp.units[s.parameter] == "-" else " " + sp.units[s.parameter]
            name = sp.problem.logs[j].name
            return name, (f"the fold that leaves out log {name} finds {s.parameter} "
                          f"{shown[0]:.4g}{unit}, the folds that train on it "
                          f"{shown[1]:.4g}-{shown[2]:.4g}{unit}: log {name} alone determines "
                          "it, and held out it is predicted from logs that cannot; record a "
                          f"second log that excites it ({TERMS[s.effect].excitation})")
    return None


def worse_log(sp: SuperProblem, s: Score, ho: HeldOut, current: HeldOut,
              noise: float) -> str | None:
    """Why an effect the logs test only against each other (``s.between_logs``: friction
    growing with the pressure, on logs at one pressure each) cannot be accepted: a left-out
    log it predicts worse than the current model, by at least ``MIN_GAIN`` of the noise
    floor; or None. Its evidence is the logs' differences alone, so it must hold on each
    log left out, not on their pooled RMS only: a level that differs between three logs for
    another reason (a ripple, friction drifting over a log) lines up with their pressures
    one time in three, and one log's large gain then hides another's loss."""
    if not s.between_logs or len(ho.rms_per_log_N) != len(current.rms_per_log_N):
        return None
    for i, (before, after) in enumerate(zip(current.rms_per_log_N, ho.rms_per_log_N)):
        if after - before >= MIN_GAIN * noise:
            return (f"the logs test it only against each other, and held out it predicts "
                    f"log {sp.problem.logs[i].name} worse ({before:.3g} -> {after:.3g} N)")
    return None


def on_bound(sp: SuperProblem, ho: HeldOut, effects: Sequence[str]) -> str | None:
    """Why the held-out refit of ``effects`` cannot be accepted because a fold put one of
    their fitted parameters on a bound of its range that is not its null (the data pushing
    it beyond what the term can be: the level asymmetry of a seal read at +-0.9), or None."""
    par = sp.problem.par
    for effect in effects:
        for k in sp.elements(effect, fitted=True):
            p, null = par.entries[k].param, sp.owners[k].null
            for j, fit in enumerate(ho.fits):
                v = float(fit.hold[k])
                for b in (p.lower, p.upper):
                    if not math.isfinite(b) or b == null:
                        continue
                    span = (p.upper - p.lower if math.isfinite(p.upper - p.lower)
                            else max(abs(b), abs(v), 1e-300))
                    if abs(v - b) <= _BOUND * span:
                        value = to_display(sp.problem.model, {par.names[k]: v})
                        shown = next(iter(value.values()))
                        return (f"its refit puts {par.names[k]} on the bound of its range "
                                f"({shown:.3g} {sp.units[par.names[k]]}) in fold {j + 1}: the "
                                "data push it beyond what the term can be")
    return None


class FoldStarts:
    """Where each fold's refit of a candidate starts: the fold's fit of the current model with
    the candidate's one-step values from the score screen on the fold's training data
    (:func:`refit_start` with the fold's weights). The screens run once per fold for a batch
    of candidates, when the first of them is refitted."""

    def __init__(self, sp: SuperProblem, folds, fits, active, *, noise, alpha):
        self.sp, self.folds, self.fits, self.active = sp, folds, fits, list(active)
        self.noise, self.alpha = noise, alpha
        self.scores: list[dict[str, Score]] = [{} for _ in folds]
        self.holds = [f.hold for f in fits]

    def score(self, k: int, effect: str, batch: Sequence[str] = ()) -> Score:
        """The candidate's screen on fold ``k``'s training data (with ``batch``, once)."""
        if effect not in self.scores[k]:
            wanted = [e for e in dict.fromkeys([effect, *batch]) if e not in self.scores[k]]
            fit = self.fits[k]
            found, self.holds[k] = screen(
                self.sp, fit.theta, self.holds[k], active=self.active, candidates=wanted,
                noise=self.noise, weights=self.folds[k].training(self.sp), alpha=self.alpha,
                min_gain=MIN_GAIN)
            self.scores[k].update({s.effect: s for s in found})
        return self.scores[k][effect]

    def of(self, effect: str, *, batch: Sequence[str] = (),
           on: Sequence[FoldFit] | None = None) -> list[FoldFit]:
        """Every fold's start for ``effect`` on top of the current model's fold fits, or on
        top of ``on`` (a partner's refit starts, for a pair)."""
        waiting = [k for k in range(len(self.folds)) if effect not in self.scores[k]]
        if len(waiting) > 1:        # the folds' screens are independent: two at a time
            with ThreadPoolExecutor(max_workers=FOLD_THREADS) as pool:
                list(pool.map(lambda k: self.score(k, effect, batch), waiting))
        out = []
        for k, fold in enumerate(self.folds):
            s = self.score(k, effect, batch)
            base = (on[k] if on is not None
                    else FoldFit(self.fits[k].theta, self.holds[k]))
            if not s.testable:         # nothing to step along on this fold: from the null
                out.append(base)
                continue
            start = refit_start(self.sp, s, base.theta, base.hold, self.active,
                                fold.training(self.sp), nuisances=fold.nuisances(self.sp)[0])
            out.append(FoldFit(start.theta, start.hold,
                               tuple(FoldFit(a.theta, a.hold) for a in start.also)))
        return out


def refit_start(sp: SuperProblem, s: Score, theta, hold, active, weights, *,
                nuisances: np.ndarray | None = None) -> Start:
    """Where a refit of ``s.effect`` on the model ``active`` starts: the
    effect's one-step values, and the current model's free entries either where they are or
    moved by the joint Gauss-Newton step (:attr:`~fitstiff.diagnosis.screen.Score.base_step`,
    entries it would take out of their bounds left where they are), whichever fits all the
    data better. The first is the right start where the effect is orthogonal to the model;
    where the model's parameters absorbed part of it, they start where the effect leaves them
    (withheld ``rig_compliance+dwell_stiction/1`` with the level law of dwell stiction it had
    before issue 31: the baseline's pre-sliding slope is 23 N/mm,
    the truth 44; the joint step starts the compliance's refit at 39 N/mm). Measured on the
    withheld benchmark: with it, heat exchange is found under Maxwell-slip elements in both
    such pairs (once read as leakage, once missed before).

    The one-step values are the linearised effect's; where the effect enters strongly
    nonlinearly (rates, time constants) they fall far short of it (a leak of time constant
    4 s: one step 0.0075 /s), so the step is also tried :data:`_STEP_FACTORS` times longer
    along its own direction. The start that fits the given ``weights`` best is kept (one
    residual evaluation each, no solve). A friction law may also start where it has taken
    over the base's friction (:func:`_handover`): when that start fits better than the best
    of the others, the refit solves from both (``also``) and keeps the lower training cost.

    ``nuisances``: a mask over the nuisance entries the refit's solve frees (default all,
    a full-data fit). The joint step moves no other: a fold's held-out part owns its
    nuisances and they start from its own data (the fold rule,
    :mod:`fitstiff.diagnosis.select`). A held-out block's initial friction state barely
    touches the training samples after it, so the step's least-squares shift for it is
    huge and says nothing: on the first block of ``single/stribeck/4``'s slow log it put
    the state at -449 in the solver's coordinates (saturated, a flat direction the
    held-out part's own solve could not leave), and Stribeck friction that lowers the other
    blocks' held-out RMS from 0.20 to 0.13 N predicted that block at 2.72 N against 0.18."""
    par = sp.problem.par
    free = sp.model_mask(active)
    entries = sp.own(s.effect)
    x = np.array(sp.physical(theta, hold, free))
    for name, value in s.one_step.items():
        x[par.names.index(name)] = value
    starts = [Start(np.array(theta, dtype=float), x)]
    for factor in _STEP_FACTORS:
        x_f = x.copy()
        for name, value in s.one_step.items():
            k = par.names.index(name)
            v = sp.owners[k].null + factor * (value - sp.owners[k].null)
            lo, hi = par.entries[k].param.lower, par.entries[k].param.upper
            x_f[k] = min(max(v, lo), hi) if lo < v < hi else x_f[k]
        if not np.array_equal(x_f, x):
            starts.append(Start(np.array(theta, dtype=float), x_f))
    handover = _handover(sp, x, active, s.effect)
    if s.base_step:
        theta_j, x_j = np.array(theta, dtype=float), x.copy()
        for k, change in s.base_step.items():
            if k >= sp.n_model:
                if nuisances is None or nuisances[k - sp.n_model]:
                    theta_j[k] += change
                continue
            lo, hi = par.entries[k].param.lower, par.entries[k].param.upper
            if lo < x[k] + change < hi:
                x_j[k] = x[k] + change
        starts.append(Start(theta_j, x_j))
    moved = np.concatenate([np.flatnonzero(free), entries])
    w = np.asarray(weights)

    def cost(start: Start) -> float:
        r = sp.residuals(start.hold, start.theta)
        c = float(np.sum((r * w) ** 2))
        return c if math.isfinite(c) else math.inf

    best = min(starts, key=cost)
    out = Start(sp.to_theta(best.theta, best.hold, moved), best.hold)
    if handover is not None:
        taken = Start(np.array(theta, dtype=float), handover)
        if cost(taken) < cost(best):
            # the law fits the start better: solved from both, the lower training cost kept
            # (from the handover alone, the soft long-slip law/maxwell_slip/1, short logs,
            # ended 1.07 N held out, from the one-step values 0.31 N)
            out = Start(sp.to_theta(taken.theta, taken.hold, moved), taken.hold, (out,))
    return out


def _handover(sp: SuperProblem, x: np.ndarray, active, effect: str) -> np.ndarray | None:
    """A start where the friction law ``effect`` takes over the model's friction base:
    ``x`` (physical values) with the candidate's fitted entries drawing the base's virgin
    curve ``B (1 - exp(-S u / B))`` (breakaway ``B``, slope ``S``) on their fixed shape, a
    non-negative least-squares fit, and the base's force-scaled entries (those in N, N/mm, N
    s/m ...) at :data:`_HANDOVER` of theirs, so the two together still draw the curve.
    ``None`` when ``effect`` is not Maxwell-slip (the one friction law among the
    candidates) or the model has no friction base.

    The one-step values grow the candidate beside a base that already carries the friction:
    on a seal whose whole friction is a Maxwell-slip law the refit then stayed near the base
    (withheld ``law`` family, issue 31: held-out 2.47 -> 1.53 N against a 0.24 N floor, or
    nothing accepted); the law it names must be able to become the friction."""
    if not any(t.name == effect and isinstance(t, MaxwellSlip) for t in sp.problem.model.terms):
        return None
    par = sp.problem.par
    model = par.physical_to_model(x, sp.problem.model)
    base = next((t for t in model.terms_of(FrictionBase)
                 if t.name in active and t.name != effect), None)
    if base is None:
        return None
    level, slope = float(base.breakaway()), float(base.presliding_slope())
    if not (level > 0 and slope > 0):
        return None
    k_entries = sp.elements(effect, tested=True)
    delta = x[sp.elements(effect, tested=False)]
    u = np.linspace(0.0, 4.0 * level / slope, 200)
    curve = (1.0 - _HANDOVER) * level * (1.0 - np.exp(-slope * u / level))
    k, _ = nnls(np.minimum(u[:, None], delta[None, :]), curve)
    out = np.array(x, dtype=float)
    out[k_entries] = k
    for i, o in enumerate(sp.owners):
        if o.term == base.name and "N" in par.entries[i].param.unit:
            out[i] *= _HANDOVER
    return out


def maxwell_shape(sp: SuperProblem, theta, hold, active) -> np.ndarray:
    """Slip displacements of the Maxwell-slip candidate from the baseline's Fc / sigma0.
    Once accepted (in ``active``), its slip displacements stay those its stiffnesses were
    fitted with: after a handover (:func:`_handover`) the base's Fc / sigma0 no longer
    describe the seal, and a grid drawn from them put the next round's refits at 12-15 N
    held out against 0.54 N (withheld ``law/maxwell_slip/2``)."""
    entries = sp.elements("maxwell_slip", tested=False)
    if entries.size == 0 or "maxwell_slip" in active:
        return hold
    x = np.asarray(sp.physical(theta, hold, sp.model_mask(active)))
    model = sp.problem.par.physical_to_model(x, sp.problem.model)
    # the baseline's own seal answers: its breakaway (N) and pre-sliding slope (N/m); without
    # a friction base, the paper's seal
    base = next((t for t in model.terms_of(FrictionBase) if not isinstance(t, MaxwellSlip)),
                None)
    breakaway, slope = ((float(base.breakaway()), float(base.presliding_slope()))
                        if base is not None else (_PAPER_BREAKAWAY, _PAPER_SLOPE))
    hold = np.array(hold)
    hold[entries] = np.asarray(_MAXWELL_SHAPE) * breakaway / slope
    return hold


def fold_fits(sp: SuperProblem, ho: HeldOut, active) -> list[FoldFit]:
    """The folds' training fits of the current model, Maxwell-slip's shape from each fold's
    own fit."""
    return [FoldFit(f.theta, maxwell_shape(sp, f.theta, f.hold, active)) for f in ho.fits]


def at_null(sp: SuperProblem, hold, effects: Sequence[str]) -> np.ndarray:
    """``hold`` with the tested parameters of ``effects`` at their null."""
    hold = np.array(hold, dtype=float)
    for effect in effects:
        for k in sp.elements(effect, tested=True):
            hold[k] = sp.owners[k].null
    return hold
