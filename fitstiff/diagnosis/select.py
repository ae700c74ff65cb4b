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
to a few per cent); and (4) it removes at least ``min_shrink`` of the gap above the noise floor,
``shrink = (before - after) / (before - noise)``. Among the candidates that pass, the one with
the lowest held-out RMS is accepted; the screen is then repeated on the enlarged model, until
none passes. Condition (1) bounds the false-alarm rate on data with no missing effect by
``alpha`` as long as the AR(1) noise model holds; (4) keeps a partial mimic of an effect
outside the library from being named. Both thresholds are measured in the withheld-effect
benchmark (``benchmarks/withheld.py``).
"""

from __future__ import annotations

import dataclasses
import math
import os
from concurrent.futures import ThreadPoolExecutor
from collections.abc import Sequence

import numpy as np

from fitstiff.diagnosis.supermodel import SuperProblem
from fitstiff.errors import InputError

__all__ = ["Fold", "HeldOut", "folds_for", "held_out"]

MAX_LOOP_FOLDS = 4
_WORKERS = min(2, os.cpu_count() or 1)


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
    """Held-out predictions of one model: per log, model - measured force at every sample."""

    residuals: tuple[np.ndarray, ...]
    rms_N: float
    rms_per_log_N: tuple[float, ...]
    converged: bool
    steps: int


def held_out(sp: SuperProblem, folds: Sequence[Fold], theta: np.ndarray, hold: np.ndarray,
             active: Sequence[str], *, extra: np.ndarray = np.zeros(0, int)) -> HeldOut:
    """Held-out residuals of the model made of the ``active`` terms (plus the model entries
    ``extra``), starting every fold from ``(theta, hold)``."""
    p = sp.problem
    free_model = sp.model_mask(active)
    free_model[extra] = True
    none = np.zeros(sp.n_model, dtype=bool)

    def one(fold: Fold):
        """``(log, sample mask or None, residual, converged, steps)`` of one fold."""
        if fold.log is not None:
            others = [i for i in range(p.n_logs) if i != fold.log]
            th, ok1, s1, _ = sp.solve(theta, hold, free_model, sp.nuisance_mask(others),
                                      sp.entry_weights(logs=others))
            # the trained model held (in physical values), only the log's nuisances fitted
            x = np.asarray(sp.physical(th, hold, free_model))
            th, ok2, s2, _ = sp.solve(th, x, none, sp.nuisance_mask([fold.log]),
                                      sp.entry_weights(logs=[fold.log]))
            force = sp.forces(x, th)[fold.log]
            return (fold.log, None, force - np.asarray(p.logs[fold.log].force), ok1 and ok2,
                    s1 + s2)
        i, mask = fold.samples
        th, ok, s1, _ = sp.solve(theta, hold, free_model, sp.nuisance_mask(),
                                 sp.entry_weights(samples={i: ~mask}))
        x = np.asarray(sp.physical(th, hold, free_model))
        force = sp.forces(x, th)[i]
        return i, mask, force - np.asarray(p.logs[i].force), ok, s1

    # the folds are independent: two at a time on two cores (the compiled scan runs on one
    # core and releases the GIL); the results do not depend on the order
    with ThreadPoolExecutor(max_workers=_WORKERS) as pool:
        done = list(pool.map(one, folds))
    residuals = [np.zeros(len(log)) for log in p.logs]
    converged, steps = True, 0
    for i, mask, res, ok, s in done:
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
                   bool(converged), steps)
