"""The backward check of :func:`~fitstiff.diagnosis.diagnose.diagnose`: accepted effects that
no longer pass the acceptance rule (:mod:`fitstiff.diagnosis.select`) once the others are in
the model are dropped (:func:`prune`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from fitstiff.diagnosis._refit import at_null
from fitstiff.diagnosis.select import MIN_GAIN, FoldFit, HeldOut, Job, held_out_batch
from fitstiff.diagnosis.supermodel import SuperProblem

__all__ = ["Pruned", "prune"]


class Pruned(NamedTuple):
    """The model left by :func:`prune`: its held-out figure (``current``), full-data fit
    (``theta``, ``hold``) and terms (``active``), and ``dropped``: each dropped unit (an
    effect, or a pair accepted together) mapped to why."""

    current: HeldOut
    theta: np.ndarray
    hold: np.ndarray
    active: list[str]
    dropped: dict[tuple[str, ...], str]


class _Removal(NamedTuple):
    """One unit taken out of the model: how much lower the held-out RMS is with it
    (``gain``, N) and that share of the gap above the noise (``shrink``), the held-out figure
    without it, and the terms left."""

    unit: tuple[str, ...]
    gain: float
    shrink: float
    heldout: HeldOut
    rest: list[str]


def prune(sp: SuperProblem, folds, units: list[tuple[str, ...]], current: HeldOut, theta,
          hold, active, weights, *, noise: float, min_shrink: float) -> Pruned:
    """Accepted effects that no longer pass the rule once the others are in the model,
    dropped.

    Greedy acceptance takes the best effect of each round; a later one can explain the gap
    better and leave an earlier one with nothing of its own (a time delay accepted first
    because its steep force change mimics a junction's rise, the junction accepted next).
    The tests build such a case (a viscous term forced in beside dwell stiction on the
    junction set); on the benchmark and independent sets measured so far the check has not
    dropped anything. So, with two units or more, each unit is judged by the acceptance rule
    as if it were added last: the held-out RMS of the final model without it (each fold from
    its own fit of the final model with the unit at its null: the fold rule) against the
    final model's. The unit that fails by the most is dropped and the check repeats on what
    is left; a removal whose refit does not converge is not judged.

    Args:
        sp, folds: the super-model and its folds.
        units: the accepted effects, each a tuple (two for a pair accepted together).
        current: the held-out figure of the model ``active`` (with every unit).
        theta, hold: its full-data fit.
        active: its terms.
        weights: the full-data run-time weights.
        noise: the pooled noise floor (N).
        min_shrink: the acceptance rule's least share of the gap above the noise.

    Returns:
        The :class:`Pruned` model.
    """
    dropped: dict[tuple[str, ...], str] = {}
    units = list(units)
    while len(units) >= 2:
        worst = None
        jobs = [Job([FoldFit(f.theta, at_null(sp, f.hold, unit)) for f in current.fits],
                    [t for t in active if t not in unit]) for unit in units]
        # the units' folds share the fold threads (held_out_batch)
        for unit, job, ho in zip(units, jobs, held_out_batch(sp, folds, jobs)):
            rest = list(job.active)
            gain = ho.rms_N - current.rms_N
            shrink = gain / (ho.rms_N - noise) if ho.rms_N > noise else float("nan")
            keeps = gain >= MIN_GAIN * noise and math.isfinite(shrink) and shrink >= min_shrink
            if ho.converged and not keeps and (worst is None or gain < worst.gain):
                worst = _Removal(unit, gain, shrink, ho, rest)
        if worst is None:
            break
        others = " and ".join(e for u in units if u != worst.unit for e in u)
        dropped[worst.unit] = (
            f"accepted in an earlier round, but with {others} in the model it lowers the "
            f"held-out RMS by only {worst.gain:.2g} N ({worst.heldout.rms_N:.3g} -> "
            f"{current.rms_N:.3g} N, {worst.shrink:.0%} of the gap above the noise; needs "
            f"{min_shrink:.0%} and {MIN_GAIN * noise:.2g} N): dropped")
        units.remove(worst.unit)
        active, current = worst.rest, worst.heldout
        hold = at_null(sp, hold, worst.unit)
        theta, _, _, _ = sp.solve(theta, hold, sp.model_mask(active), sp.nuisance_mask(),
                                  weights)
    return Pruned(current, theta, hold, active, dropped)

