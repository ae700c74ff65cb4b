"""An effect that one log alone determines, judged on held-out blocks of that log.

Leave-one-log-out asks every log to be predicted from the others. When one log alone excites
an effect, the folds that train on it find the effect and the fold that leaves it out does
not (:func:`~fitstiff.diagnosis._refit.lone_log`), so that log, held out, is predicted
without it and the refit gains too little by the rule, however clear the effect is in that
log (withheld ``single/stribeck/4``: only the slow log shows the Stribeck rise with its
whole sliding; the fast logs see it at their reversals alone, where its level and velocity
trade off). Its evidence lives in that log, so it is judged as a single log is: blocks of
that log's loops held out in turn, every other log in each fold's training part
(:func:`~fitstiff.diagnosis.select.blocks`), the current model and the enlarged one each
from the folds' own starts (the fold rule of :mod:`fitstiff.diagnosis.select`), by the
acceptance rule on that log's held-out RMS and noise floor. The leave-one-log-out refit must
still have converged, lowered the pooled held-out RMS and predicted no left-out log worse by
``MIN_GAIN`` of the noise floor: the other logs cannot pin the effect, but they must not
contradict it. The record and the verdict say that the effect rests on one log and what to
record to confirm it across logs.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

from fitstiff.diagnosis._refit import FoldStarts, Tried, fold_fits, on_bound
from fitstiff.diagnosis.select import (MIN_GAIN, HeldOut, Job, blocks, fold_starts, held_out,
                                       held_out_batch)
from fitstiff.diagnosis.supermodel import SuperProblem
from fitstiff.signal.noise import NoiseFloor

__all__ = ["BlockCheck", "on_blocks", "confirm"]


@dataclasses.dataclass(frozen=True)
class BlockCheck:
    """The acceptance rule on held-out blocks of one log: its held-out RMS without and with
    the effect (N), its noise floor, the share of its gap removed, and whether it passes
    (else ``why``)."""

    log: str
    before_N: float
    after_N: float
    noise_N: float
    shrink: float
    passes: bool
    why: str = ""

    def to_dict(self) -> dict[str, object]:
        return {"log": self.log, "heldout_rms_before_N": self.before_N,
                "heldout_rms_after_N": self.after_N, "noise_N": self.noise_N,
                "shrink": self.shrink}


def on_blocks(sp: SuperProblem, effect: str, log: int, active: Sequence[str], *,
              noise: Sequence[NoiseFloor], alpha: float, min_shrink: float) -> BlockCheck:
    """The acceptance rule for ``effect`` on top of the model ``active``, on held-out blocks
    of log ``log`` (every other log in each fold's training part): the current model from
    the folds' cold starts, the enlarged one from each fold's fit of it with the effect's
    one-step values screened on the fold's training data."""
    folds = blocks(sp, log)
    base = held_out(sp, folds, fold_starts(sp, folds), active)
    starts = FoldStarts(sp, folds, fold_fits(sp, base, active), active, noise=noise,
                        alpha=alpha).of(effect)
    ho = held_out_batch(sp, folds, [Job(starts, active, sp.elements(effect, fitted=True))])[0]
    name = sp.problem.logs[log].name
    before, after, floor = base.rms_per_log_N[log], ho.rms_per_log_N[log], noise[log].sigma
    gain = before - after
    shrink = gain / (before - floor) if before > floor else float("nan")
    bound = on_bound(sp, ho, [effect])
    why = ("a refit on its blocks did not converge" if not (base.converged and ho.converged)
           else "its held-out RMS did not fall" if gain <= 0
           else f"it lowers its held-out RMS by only {gain:.2g} N (needs {MIN_GAIN:.0%} of "
                f"its noise floor, {MIN_GAIN * floor:.2g} N)" if gain < MIN_GAIN * floor
           else f"it removes only {shrink:.0%} of its gap above the noise (needs "
                f"{min_shrink:.0%})" if not (math.isfinite(shrink) and shrink >= min_shrink)
           else bound or "")
    return BlockCheck(name, before, after, floor, shrink, not why, why)


def confirm(sp: SuperProblem, t: Tried, active: Sequence[str], *, current: HeldOut,
            noise: Sequence[NoiseFloor], noise_pooled: float, alpha: float,
            min_shrink: float) -> Tried:
    """``t`` judged on held-out blocks of the log that alone determines it
    (``t.determined_by``, set by :func:`~fitstiff.diagnosis._refit.lone_log` on a converged
    refit that gained too little): it passes when its leave-one-log-out refit predicts no
    left-out log worse than ``current`` by ``MIN_GAIN`` of the noise floor and
    :func:`on_blocks` passes; else ``t`` with why the blocks do not confirm it."""
    names = [log.name for log in sp.problem.logs]
    if t.passes or not t.determined_by or t.determined_by not in names:
        return t
    for name, b, a in zip(names, current.rms_per_log_N, t.heldout.rms_per_log_N):
        if a - b >= MIN_GAIN * noise_pooled:
            return dataclasses.replace(t, why=f"{t.why}; held out across the logs it predicts "
                                              f"log {name} worse ({b:.3g} -> {a:.3g} N)")
    check = on_blocks(sp, t.effect, names.index(t.determined_by), active, noise=noise,
                      alpha=alpha, min_shrink=min_shrink)
    if check.passes:
        return dataclasses.replace(t, passes=True, why="", blocks=check)
    return dataclasses.replace(t, why=f"{t.why}; on held-out blocks of log {check.log} "
                                      f"{check.why}", blocks=check)
