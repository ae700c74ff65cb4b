"""How far the gap shrinks: held-out refits and greedy acceptance.

Every decision is taken on held-out data. With two logs or more the folds leave one log out:
the shared parameters are fitted on the others, then only the left-out log's own nuisances
(force offset, initial friction state) are fitted to it and its force is predicted. With one
log the folds are blocks of consecutive loops (blocked in time): the model is fitted with the
block's samples weighted 0 and the block is predicted. Every sample is predicted exactly once,
so the held-out residual covers the whole data set (:mod:`fitstiff.diagnosis.gap` tabulates
it).

A candidate is **accepted** when (1) its score p-value, Bonferroni-corrected over the
candidates, is below ``alpha``; (2) every refit converged; (3) its held-out RMS is below the
current model's by at least 5 % of the noise floor (``MIN_GAIN``: the floor itself is known
to a few per cent); (4) it removes at least ``min_shrink`` of the gap above the noise floor,
``shrink = (before - after) / (before - noise)``; and (5) an effect the logs test only against
each other (``Score.between_logs``) predicts no left-out log worse by ``MIN_GAIN`` of the noise
floor or more (:func:`~fitstiff.diagnosis._refit.worse_log`). Among the candidates that
pass, the one with the lowest held-out RMS is accepted; the screen is then repeated on the
enlarged model, until none passes. Then each accepted effect is judged as if it had been
added last (the final model without it against with it, by conditions (3) and (4)) and
dropped if it fails: a later effect can leave an earlier one nothing of its own
(:func:`~fitstiff.diagnosis.prune.prune`). Condition (1) bounds the false-alarm rate on
data with no missing effect by ``alpha`` as long as the AR(1) noise model holds; (4) keeps a
partial mimic of an effect outside the library from being named. Both thresholds are
measured in the withheld-effect benchmark (``benchmarks/withheld.py``).

**The fold rule.** No fold ever starts from, or is tuned by, anything fitted on its held-out
part. Each fold carries its own fit (:class:`FoldFit`) from round to round: the baseline's
starts from :meth:`~fitstiff.diagnosis.supermodel.SuperProblem.start` on the fold's training
samples alone; a candidate's refit starts from the fold's fit of the current model with the
candidate's one-step values computed on the fold's training data (the score screen with the
fold's weights; its joint step moves only what the fold's training solve frees); an
accepted effect's fold fits become the next round's starts. The full-data fit only
screens, breaks ties (BIC) and reports the parameters. A fold's solve is checked with
the tolerances of a cold fit. A left-out log's own nuisances (force offset, initial friction
state) are fitted to it alone with the trained model held, and start from that log's own data;
a held-out block that starts its log owns the log's initial friction state the same way (the
rest of the log does not inform it), the offset stays the training part's.
Before this rule, folds restarted from full-data fits, whose solves could stop on a flat
direction with the held-out data's imprint (issue 31: second-round "held-out" RMS equal to the
in-sample fit's to three digits).
"""

from __future__ import annotations

import dataclasses
import math
import os
from concurrent.futures import ThreadPoolExecutor
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from fitstiff.diagnosis.supermodel import SuperProblem, best_solve
from fitstiff.errors import InputError

__all__ = ["FOLD_THREADS", "Fold", "FoldFit", "HeldOut", "Job", "MIN_GAIN", "fold_starts",
           "folds_for", "held_out", "held_out_batch"]

#: least fall of the held-out RMS, as a share of the noise floor: the floor is estimated to a
#: few per cent, so a smaller fall cannot be told from its error (on the stribeck set a time
#: delay of -0.18 ms "removed 30 %" of a 7 mN gap left once stribeck was fitted)
MIN_GAIN = 0.05

MAX_LOOP_FOLDS = 4
#: the nuisances a held-out block that starts a log owns (fitted to the block alone)
_BLOCK_OWN = ("friction_state0",)
#: folds solved (and screened) at a time, each on a thread: the compiled scans release the GIL
FOLD_THREADS = min(2, os.cpu_count() or 1)


@dataclasses.dataclass(frozen=True)
class Fold:
    """One fold: ``log`` left out (all its samples), or ``samples`` of one log held out."""

    log: int | None
    samples: tuple[int, np.ndarray] | None = None

    def describe(self, names: Sequence[str]) -> str:
        if self.log is not None:
            return f"leave out log {names[self.log]}"
        i, mask = self.samples
        idx = np.flatnonzero(mask)
        return f"leave out samples {idx[0]}-{idx[-1]} of log {names[i]}"

    def training(self, sp: SuperProblem) -> np.ndarray:
        """Run-time weights of the residual entries the fold trains on (its held-out part 0)."""
        if self.log is not None:
            return sp.entry_weights(logs=[i for i in range(sp.problem.n_logs) if i != self.log])
        i, mask = self.samples
        return sp.entry_weights(samples={i: ~mask})

    def nuisances(self, sp: SuperProblem) -> tuple[np.ndarray, np.ndarray]:
        """Masks over the nuisance entries: those the fold's training solve frees, and those
        only its held-out part owns (a left-out log's; the initial friction state of a
        held-out block that starts its log, which the rest of the log does not inform), fitted
        to that part alone with the trained model held and never moved by a training step."""
        if self.log is not None:
            others = [i for i in range(sp.problem.n_logs) if i != self.log]
            return sp.nuisance_mask(others), sp.nuisance_mask([self.log])
        i, mask = self.samples
        own = (sp.nuisance_mask([i], names=_BLOCK_OWN) if mask[0]
               else np.zeros(sp.size - sp.n_model, dtype=bool))
        return sp.nuisance_mask() & ~own, own

    def seen(self, n_samples: Sequence[int]) -> list[np.ndarray | None]:
        """Per log, the samples the training part holds (``None``: the left-out log), for
        :func:`~fitstiff.inference.fitting.initial_guess`."""
        out: list[np.ndarray | None] = [np.ones(n, dtype=bool) for n in n_samples]
        if self.log is not None:
            out[self.log] = None
        else:
            i, mask = self.samples
            out[i] = ~np.asarray(mask)
        return out


@dataclasses.dataclass(frozen=True)
class FoldFit:
    """A fold's model fitted to its training part: ``theta`` (its left-out log's nuisances
    as they were at the start: never fitted to that log here) and ``hold`` (physical values of
    the model entries that are not free). As a start, ``also``: other starts of the same
    solve (from the same training data); :func:`held_out` solves from each and keeps the
    lowest training cost."""

    theta: np.ndarray
    hold: np.ndarray
    also: tuple[FoldFit, ...] = ()


def fold_starts(sp: SuperProblem, folds: Sequence[Fold]) -> list[FoldFit]:
    """The baseline's start of every fold, from the fold's training samples alone."""
    n = [len(log) for log in sp.problem.logs]
    return [FoldFit(*sp.start(samples=f.seen(n))) for f in folds]


def folds_for(sp: SuperProblem) -> list[Fold]:
    """Leave-one-log-out with two logs or more, else blocks of loops of the single log."""
    p = sp.problem
    if p.n_logs >= 2:
        return [Fold(i) for i in range(p.n_logs)]
    seg = p.segmentations[0]
    n = len(p.logs[0])
    loops = seg.loops
    if len(loops) < 2:
        raise InputError(p.logs[0].name, "a single log",
                         f"holds {len(loops)} full loop(s): too short to hold out a loop",
                         "give two logs or more, or a log with at least two full loops")
    k = min(MAX_LOOP_FOLDS, len(loops))
    groups = np.array_split(np.arange(len(loops)), k)
    edges = [int(loops[g[0], 0]) for g in groups] + [n]
    edges[0] = 0
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        mask = np.zeros(n, dtype=bool)
        mask[a:b] = True
        out.append(Fold(None, (0, mask)))
    return out


@dataclasses.dataclass(frozen=True)
class HeldOut:
    """Held-out predictions of one model: per log, model - measured force at every sample;
    ``fits``: each fold's training fit (where the next round's folds start)."""

    residuals: tuple[np.ndarray, ...]
    rms_N: float
    rms_per_log_N: tuple[float, ...]
    converged: bool
    steps: int
    fits: tuple[FoldFit, ...] = ()


def held_out(sp: SuperProblem, folds: Sequence[Fold], starts: Sequence[FoldFit],
             active: Sequence[str], *, extra: np.ndarray = np.zeros(0, int)) -> HeldOut:
    """Held-out residuals of the model made of the ``active`` terms (plus the model entries
    ``extra``), every fold from its own start (``starts``, one per fold: see the fold rule in
    the module docstring)."""
    return held_out_batch(sp, folds, [Job(starts, active, extra)])[0]


class Job(NamedTuple):
    """One model to hold out (:func:`held_out_batch`): each fold's start, the ``active``
    terms and the ``extra`` model entries freed beside them (a candidate's)."""

    starts: Sequence[FoldFit]
    active: Sequence[str]
    extra: np.ndarray = np.zeros(0, int)


def held_out_batch(sp: SuperProblem, folds: Sequence[Fold], jobs: Sequence[Job]
                   ) -> list[HeldOut]:
    """:func:`held_out` of several models (a round's batch of candidates) at once. Every
    training solve (each fold of each model, from each of its starts) is an independent
    task, and the tasks share :data:`FOLD_THREADS` threads, the largest training sets first;
    then each fold keeps its best training solve and predicts its held-out part. One model's
    folds alone keep a thread idle while the other finishes its longest fold (at real size a
    leave-one-log-out fold trains on 44 800 samples or 19 200, and a fold with a handover
    start solves twice); a batch's solves fill it. The results do not depend on the order."""
    p = sp.problem
    for job in jobs:
        if len(job.starts) != len(folds):
            raise ValueError(f"held_out: {len(job.starts)} starts for {len(folds)} folds")
    none = np.zeros(sp.n_model, dtype=bool)

    def free(job: Job) -> np.ndarray:
        out = sp.model_mask(job.active)
        out[job.extra] = True
        return out

    # per model its free entries, per fold its training weights and nuisance masks: once
    frees = [free(job) for job in jobs]
    training = [fold.training(sp) for fold in folds]
    masks = [fold.nuisances(sp) for fold in folds]

    def train(j: int, k: int, start: FoldFit):
        """One training solve: ``(theta, converged, steps, cost, hold)``."""
        return (*sp.solve(start.theta, start.hold, frees[j], masks[k][0], training[k]),
                start.hold)

    def predict(j: int, k: int, solves):
        """``(log, sample mask or None, residual, converged, steps, fit)`` of one fold from
        its training solves (the converged one of lowest training cost kept): the trained
        model held (in physical values), only the held-out part's own nuisances fitted."""
        fold, own = folds[k], masks[k][1]
        th, ok, steps, _, hold = best_solve(solves)
        x = np.asarray(sp.physical(th, hold, frees[j]))
        if fold.log is not None:
            i, mask, weights = fold.log, None, sp.entry_weights(logs=[fold.log])
        else:
            i, mask = fold.samples
            weights = sp.entry_weights(samples={i: mask})
        th_out, ok2, s2 = th, True, 0
        if own.any():
            th_out, ok2, s2, _ = sp.solve(th, x, none, own, weights)
        force = sp.forces(x, th_out)[i]
        return i, mask, force - np.asarray(p.logs[i].force), ok and ok2, steps + s2, FoldFit(th, x)

    # the solves are independent: two at a time on two cores (the compiled scans run on one
    # core and release the GIL), the largest training sets first
    size = [float(np.sum(w)) for w in training]
    tasks = sorted(((j, k, n) for j, job in enumerate(jobs) for k in range(len(folds))
                    for n in range(1 + len(job.starts[k].also))), key=lambda t: -size[t[1]])

    def start_of(j: int, k: int, n: int) -> FoldFit:
        first = jobs[j].starts[k]
        return first if n == 0 else first.also[n - 1]

    with ThreadPoolExecutor(max_workers=FOLD_THREADS) as pool:
        futures = {t: pool.submit(train, t[0], t[1], start_of(*t)) for t in tasks}
        solves = {t: f.result() for t, f in futures.items()}

        def fold_of(jk: tuple[int, int]):
            j, k = jk
            n_starts = 1 + len(jobs[j].starts[k].also)
            return predict(j, k, [solves[(j, k, n)] for n in range(n_starts)])

        pairs = [(j, k) for j in range(len(jobs)) for k in range(len(folds))]
        done = dict(zip(pairs, pool.map(fold_of, pairs)))
    return [_gather(p, [done[(j, k)] for k in range(len(folds))]) for j in range(len(jobs))]


def _gather(p, done) -> HeldOut:
    """One model's :class:`HeldOut` from its folds' results (in fold order)."""
    residuals = [np.zeros(len(log)) for log in p.logs]
    converged, steps = True, 0
    for i, mask, res, ok, s, _ in done:
        if mask is None:
            residuals[i] = res
        else:
            residuals[i][mask] = res[mask]
        converged &= bool(ok)
        steps += s
    sq, count, per_log = 0.0, 0, []
    for i, res in enumerate(residuals):
        keep = p.sample_weights[i] > 0
        r = res[keep]
        sq += float(r @ r)
        count += r.size
        per_log.append(math.sqrt(float(r @ r) / max(r.size, 1)))
    return HeldOut(tuple(residuals), math.sqrt(sq / max(count, 1)), tuple(per_log),
                   bool(converged), steps, tuple(d[5] for d in done))
