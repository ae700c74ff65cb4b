"""Starting values from the data: the chamber's closing pressures and each friction base's own
start (:meth:`FrictionBase.start`), before any solver runs (:func:`initial_guess`)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from fitstiff._jax import jax
from fitstiff.inference.problem import Problem
from fitstiff.physics.model import Model
from fitstiff.physics.params import Parameterization
from fitstiff.physics.terms.base import FrictionBase, FrictionEstimate


__all__ = ["initial_guess"]


# -- starting values ----------------------------------------------------------------------
#: a chamber-only model's predicted force on a drive and its linearised stiffness, compiled
#: once per model structure (no data inside)
_chamber_start = jax.jit(lambda model, drive: (model.predict(drive),
                                               model.term("chamber").stiffness(drive)))


def initial_guess(problem: Problem, *, bases: Sequence[str] | None = None,
                  samples: Sequence[np.ndarray | None] | None = None
                  ) -> tuple[Model, dict[str, np.ndarray]]:
    """Starting values from the data: levels from the sliding plateaus, slope from the samples
    right after reversals, offsets from the plateau midlines, the chamber from geometry.

    Each friction base starts from :meth:`~fitstiff.physics.terms.base.Term.start` with an equal
    share of the estimate; ``bases`` names the bases that share it (default: all; the
    diagnosis gives the baseline's, its candidate Maxwell-slip starts at its null).
    Fixed parameters keep their values; parameters the data do not inform keep the model's.

    ``samples`` (the diagnosis' folds) restricts what informs the shared estimates: per log, a
    boolean mask of the samples that may (default: all), or ``None`` for a log that informs
    only its own nuisances (a held-out log, whose offset and initial state are fitted to it
    alone). Each log's offset comes from the samples it may use, its initial friction state
    from its first sample (a held-out part's own nuisance, as a left-out log's is).
    """
    model = problem.model
    chamber_only = [Model((model.term("chamber"),))] if model.has("chamber") else []
    if samples is None:
        samples = [np.ones(len(log), dtype=bool) for log in problem.logs]
    levels, offsets, slopes, states = [], [], [], []
    for log, seg, drive, seen in zip(problem.logs, problem.segmentations, problem.drives,
                                     samples):
        shared = seen is not None
        seen = np.ones(len(log), dtype=bool) if seen is None else np.asarray(seen, dtype=bool)
        force = np.asarray(log.force)
        k_chamber = 0.0
        if chamber_only:
            chamber_force, stiffness = _chamber_start(chamber_only[0], drive)
            force = force - np.asarray(chamber_force)
            k_chamber = float(stiffness)
            k_chamber = k_chamber if math.isfinite(k_chamber) else 0.0
        sliding = seg.mask("sliding") & seen
        pool = force[sliding] if sliding.sum() > 20 else force[seen]
        lo, hi = np.percentile(pool, [5, 95])
        level, offset = max((hi - lo) / 2, 1e-3), (hi + lo) / 2
        offsets.append(offset)
        states.append(float(np.clip((force[0] - offset) / level, -0.9, 0.9)))
        if not shared:
            continue
        levels.append(level)
        x = np.asarray(drive.displacement)
        for r in seg.reversals[seen[seg.reversals]]:
            window = 0.1 * level / 40e3
            after = np.flatnonzero(np.abs(x[r:r + 2000] - x[r]) <= window)
            after = after[after == np.arange(after.size)] + r   # contiguous from r
            if after.size < 4 or np.ptp(x[after]) <= 0:
                continue
            slope = np.polyfit(x[after], force[after], 1)[0] - k_chamber
            rel = min(abs(force[r] - offset) / level, 1.0)
            slopes.append((abs(slope), rel))
    estimate = FrictionEstimate(
        level=float(np.median(levels)),
        tangent=float(np.median([s for s, _ in slopes])) if slopes else None,
        reversal_state=float(np.median([r for _, r in slopes])) if slopes else 1.0)
    bases = [t.name for t in model.terms_of(FrictionBase) if bases is None or t.name in bases]
    terms = [t.start(estimate, share=1.0 / len(bases)) if t.name in bases else t
             for t in model.terms]
    guess = model.with_terms(tuple(terms))
    # restore anything the user fixed
    par_all = Parameterization(model)
    keep = {n: v for n, v in par_all.values(model).items() if n in problem.par_fixed}
    if keep:
        guess = Parameterization(guess).with_values(guess, keep)
    return guess, {"offset": np.asarray(offsets), "friction_state0": np.asarray(states),
                   "closing_pressure": problem.closing_pressure_start()}
