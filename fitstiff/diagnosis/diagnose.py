""":func:`diagnose`: where the baseline misses, which effect explains it, how far the gap shrinks.

The steps (DESIGN §6):

1. build the baseline and every candidate as one compiled super-model
   (:class:`~fitstiff.diagnosis.supermodel.SuperProblem`), fit the baseline, estimate each
   log's noise floor from the high-frequency part of the data and of the baseline's residual
   (:func:`~fitstiff.signal.noise.noise_floor`);
2. **where**: the baseline's held-out residuals per cell (:mod:`fitstiff.diagnosis.gap`);
3. **which**: score statistics of every candidate at its null
   (:mod:`fitstiff.diagnosis.screen`), then held-out refits of the promising ones;
4. **how far**: greedy acceptance by the rule of :mod:`fitstiff.diagnosis.select`; what stays
   above the noise floor is reported as unexplained. Each candidate's detectability comes from
   the first screen;
5. **what the rest follows**: the final model's held-out residual described by one variable
   at a time (:mod:`fitstiff.diagnosis.structure`), accepted by the same kind of held-out rule.

Steps 3 and 4 are the rounds of :mod:`fitstiff.diagnosis._rounds` (a candidate's held-out
refit: :mod:`fitstiff.diagnosis._refit`; ties and pairs: :mod:`fitstiff.diagnosis._choice`;
the backward check: :mod:`fitstiff.diagnosis.prune`); this module sets them up and assembles
the result (its records: :mod:`fitstiff.diagnosis._candidates`; its words:
:mod:`fitstiff.diagnosis._verdict`).
"""

from __future__ import annotations

import dataclasses
import time
from collections import Counter
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import pandas as pd

from fitstiff.diagnosis._candidates import fitted_sizes
from fitstiff.diagnosis._choice import tie_order
from fitstiff.diagnosis._refit import fold_fits, maxwell_shape
from fitstiff.diagnosis._rounds import Search, Setting, phase, prune_accepted, run_rounds
from fitstiff.diagnosis._verdict import cell, region_records, verdict
from fitstiff.diagnosis.gap import above_floor, region_table
from fitstiff.diagnosis.result import Candidate, Diagnosis
from fitstiff.diagnosis.screen import detectability
from fitstiff.diagnosis.select import MIN_GAIN, HeldOut, fold_starts, folds_for, held_out
from fitstiff.diagnosis.structure import (STRUCTURE_ALPHA, STRUCTURE_MIN_SHRINK,
                                          describe_structure)
from fitstiff.diagnosis.supermodel import SuperProblem, candidate_names
from fitstiff.errors import InputError
from fitstiff.inference.selection import Selection
from fitstiff.io.log import Log
from fitstiff.physics.model import DEFAULT_MODEL
from fitstiff.signal.noise import pooled_noise_floor

__all__ = ["diagnose", "ALPHA", "MIN_GAIN", "MIN_SHRINK"]

#: family-wise level of the score screen (Bonferroni over the candidates)
ALPHA = 0.05
#: share of the gap above the noise floor an effect must remove on held-out data
MIN_SHRINK = 0.3


def diagnose(logs: Sequence[Log], *, baseline: str = DEFAULT_MODEL,
             candidates: str | Sequence[str] = "all", alpha: float = ALPHA,
             min_shrink: float = MIN_SHRINK, structure: bool = True,
             selection: Selection | None = None, **options) -> Diagnosis:
    """Diagnose the gap between ``baseline`` and the logs.

    Args:
        logs: loaded logs (two or more: leave-one-log-out; one: leave-one-block-of-loops-out).
        baseline: the model spec whose gap is diagnosed.
        candidates: ``"all"`` (every DESIGN §3 effect not in the baseline that applies) or
            effect names (a list or a comma-separated string).
        alpha: family-wise level of the score screen.
        min_shrink: share of the gap above the noise that an accepted effect must remove.
        structure: describe what the unexplained held-out residual follows
            (:mod:`fitstiff.diagnosis.structure`; ``Diagnosis.unexplained_structure``).
        selection: the data options (:class:`~fitstiff.inference.selection.Selection`:
            ``denoise``, ``sample_range``, ``weights``, ``skip``, ...), or its fields as
            keywords.

    Returns:
        The :class:`~fitstiff.diagnosis.result.Diagnosis`.
    """
    _check(logs, alpha, min_shrink)
    clock = {"start": time.perf_counter()}
    names, skipped = candidate_names(baseline, candidates, logs=logs)
    sp = SuperProblem(logs, baseline, names, selection=Selection.given(selection, options))
    clock["setup"] = time.perf_counter()
    fit = baseline_fit(sp)
    st = _setting(sp, names, fit, alpha=alpha, min_shrink=min_shrink)
    base = _baseline(st, fit)
    search = base.search
    clock["baseline"] = time.perf_counter()
    run_rounds(st, search)
    prune_accepted(st, search)
    _add_sizes(st, search)
    clock["select"] = time.perf_counter()
    tables = _tables(st, base, search)
    problem = st.sp.problem
    described = (describe_structure(problem.logs, problem.segmentations,
                                    search.current.residuals, st.masks, st.noise_pooled,
                                    library={e: c.why for e, c in search.decided.items()
                                             if not c.accepted})
                 if structure else ())
    clock["structure"] = time.perf_counter()
    return _diagnosis(st, search, base, tables, baseline=baseline, skipped=skipped,
                      described=described, structure=structure, clock=clock)


def _check(logs: Sequence[Log], alpha: float, min_shrink: float) -> None:
    """Refuse what cannot be diagnosed: no logs, a level or share out of range."""
    if not logs:
        raise InputError(None, "logs", "none given", "name at least one CSV log")
    if not (0 < alpha < 1):
        raise InputError(None, f"--alpha {alpha}", "must lie strictly between 0 and 1",
                         "give e.g. 0.05")
    if not (0 <= min_shrink < 1):
        raise InputError(None, f"--min-shrink {min_shrink}", "must lie in [0, 1)",
                         "give e.g. 0.3")


class _FullFit(NamedTuple):
    """The baseline fitted to all the data: the solver's ``theta``, ``hold`` and whether the
    solve converged."""

    theta: np.ndarray
    hold: np.ndarray
    converged: bool


def baseline_fit(sp: SuperProblem) -> _FullFit:
    """The baseline fitted to all the data. It screens, breaks ties and reports (the folds fit
    their own training parts), and its prediction lets the noise floors set aside the signal's
    curvature (:func:`noise_floors`)."""
    active = list(sp.baseline_terms)
    theta, hold = sp.start()
    theta, converged, _, _ = sp.solve(theta, hold, sp.model_mask(active), sp.nuisance_mask(),
                                      sp.entry_weights())
    return _FullFit(theta, maxwell_shape(sp, theta, hold, active), converged)


def _setting(sp: SuperProblem, names, fit: _FullFit, *, alpha: float,
             min_shrink: float) -> Setting:
    """The folds, each log's noise floor and the weights of the search. A floor is read from
    the second differences of the log's force and of the baseline's full-data residual, the
    smaller per lag (:func:`~fitstiff.signal.noise.noise_floor` with a ``reference``): the
    differences of a fast log's pre-sliding curves are not noise; a missing effect's slow
    misfit cancels in them."""
    masks = [w > 0 for w in sp.problem.sample_weights]
    noise, noise_pooled = noise_floors(sp, fit)
    return Setting(sp=sp, folds=folds_for(sp), names=names, noise=noise,
                   noise_pooled=noise_pooled, masks=masks, weights=sp.entry_weights(),
                   alpha=alpha, min_shrink=min_shrink, spent=Counter())


def noise_floors(sp: SuperProblem, fit: _FullFit):
    """Each log's noise floor and the pooled one (:func:`pooled_noise_floor`), read with the
    baseline's full-data prediction as the reference (see :func:`_setting`)."""
    masks = [w > 0 for w in sp.problem.sample_weights]
    x = np.asarray(sp.physical(fit.theta, fit.hold, sp.model_mask(sp.baseline_terms)))
    return pooled_noise_floor(sp.problem.logs, masks, references=sp.forces(x, fit.theta))


class _Baseline(NamedTuple):
    """The baseline fitted: the search's start, whether the full-data solve converged and
    its held-out figure."""

    search: Search
    converged: bool
    heldout: HeldOut


def _baseline(st: Setting, fit: _FullFit) -> _Baseline:
    """The baseline's search start: its full-data ``fit``, and the folds fitting their own
    training parts from starts of their own (the fold rule,
    :mod:`fitstiff.diagnosis.select`)."""
    sp = st.sp
    active = list(sp.baseline_terms)
    theta, hold, converged = fit
    with phase(st.spent, "baseline_folds"):
        current = held_out(sp, st.folds, fold_starts(sp, st.folds), active)
    fits = fold_fits(sp, current, active)
    return _Baseline(Search(theta, hold, active, current, fits), converged, current)


def _add_sizes(st: Setting, s: Search) -> None:
    """Each accepted effect's fitted parameters with their standard errors and intervals."""
    sizes = fitted_sizes(st.sp, s.theta, s.hold, s.active, st.weights, s.accepted)
    for effect in s.accepted:
        s.decided[effect] = dataclasses.replace(s.decided[effect], parameters={
            name: dict(entry) | sizes.get(name, {})
            for name, entry in s.decided[effect].parameters.items()})


class _Tables(NamedTuple):
    """The held-out residuals by motion-region cell (:func:`~fitstiff.diagnosis.gap.region_table`)
    of the baseline and of the final model, and the final model's cells above the noise floor."""

    base: pd.DataFrame
    final: pd.DataFrame
    still: pd.DataFrame


def _tables(st: Setting, base: _Baseline, s: Search) -> _Tables:
    segmentations = st.sp.problem.segmentations
    base_table = region_table(base.heldout.residuals, segmentations, st.noise, st.masks)
    final_table = region_table(s.current.residuals, segmentations, st.noise, st.masks)
    return _Tables(base_table, final_table, above_floor(final_table))


def _diagnosis(st: Setting, s: Search, base: _Baseline, tables: _Tables, *, baseline: str,
               skipped, described, structure: bool, clock: dict[str, float]) -> Diagnosis:
    """The :class:`~fitstiff.diagnosis.result.Diagnosis` of a finished search."""
    problem = st.sp.problem
    decided = {e: dataclasses.replace(c, first_p_value=s.first[e].p_value)
               for e, c in s.decided.items()}
    ranked = _ranked(st, s, decided)
    gap = {"heldout_rms_N": base.heldout.rms_N, "noise_N": st.noise_pooled,
           "heldout_rms_per_log_N": list(base.heldout.rms_per_log_N),
           "final_heldout_rms_N": s.current.rms_N,
           "final_heldout_rms_per_log_N": list(s.current.rms_per_log_N),
           "baseline_converged": bool(base.converged and base.heldout.converged),
           "regions": region_records(tables.base),
           "final_regions": region_records(tables.final)}
    clock["end"] = time.perf_counter()
    return Diagnosis(
        baseline=baseline, final_model="+".join([baseline] + s.accepted), gap=gap,
        candidates=tuple(ranked), accepted=tuple(s.accepted),
        unexplained=tuple(cell(row) for _, row in tables.still.head(20).iterrows()),
        unexplained_structure=described,
        noise_N={log.name: nf.to_dict() for log, nf in zip(problem.logs, st.noise)},
        detectability={name: detectability(s.first[name]) for name in st.names
                       if name in s.first},
        skipped=skipped,
        folds=tuple(f.describe([log.name for log in problem.logs]) for f in st.folds),
        settings=_settings(st, structure),
        verdict=tuple(verdict(baseline, s.accepted, decided, gap, tables.still,
                              st.noise_pooled, described,
                              one_log=problem.logs[0].name if problem.n_logs == 1
                              else None)),
        files=tuple(str(log.path) if log.path else log.name for log in problem.logs),
        timing_s=_timing(clock, st.spent),
        heldout={"before": base.heldout.residuals, "after": s.current.residuals})


def _ranked(st: Setting, s: Search, decided: dict[str, Candidate]) -> list[Candidate]:
    """The candidates in the order of the result: the accepted ones in the order of
    acceptance, then the others by their last screen's log p-value, ties within a group the
    screen cannot order broken by BIC (:func:`~fitstiff.diagnosis._choice.tie_order`)."""
    tie = tie_order(st.sp, s.scores, s.accepted, s.theta, s.hold, s.active, st.weights,
                    level=st.alpha / len(st.names))
    return sorted(decided.values(), key=lambda c: (not c.accepted,
                                                   s.accepted.index(c.effect) if c.accepted
                                                   else 0,
                                                   *tie.get(c.effect, (c.log_p_value, 0.0))))


def _settings(st: Setting, structure: bool) -> dict[str, object]:
    """``Diagnosis.settings``: the rule's levels, the candidates and the structure step's."""
    return {"alpha": st.alpha, "min_shrink": st.min_shrink, "min_gain": MIN_GAIN,
            "screen_level": st.alpha / len(st.names),
            "candidates": list(st.names), "structure": structure,
            "structure_alpha": STRUCTURE_ALPHA,
            "structure_min_shrink": STRUCTURE_MIN_SHRINK}


def _timing(clock: dict[str, float], spent: Counter) -> dict[str, float]:
    """``Diagnosis.timing_s``: wall seconds of each step and of the selection's parts."""
    return {"setup": clock["setup"] - clock["start"],
            "baseline": clock["baseline"] - clock["setup"],
            "select": clock["select"] - clock["baseline"],
            "structure": clock["structure"] - clock["select"],
            "total": clock["end"] - clock["start"],
            # parts: the baseline's held-out folds (in "baseline"), the screens on all
            # data, the candidates' held-out refits with their fold starts and the
            # descriptions they are held against (in "select"); compilation happens
            # inside whichever part first needs it
            **{name: float(spent[name])
               for name in ("baseline_folds", "screens", "refits", "rivals")}}
