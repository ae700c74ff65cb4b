"""The greedy search of :func:`~fitstiff.diagnosis.diagnose.diagnose` (DESIGN §6, steps 3-4).

Each round screens the candidates not yet accepted on the current model
(:func:`~fitstiff.diagnosis.screen.screen`), refits the significant ones on held-out data in
batches of :data:`~fitstiff.diagnosis._choice.MAX_REFITS` (:mod:`fitstiff.diagnosis._refit`),
records every candidate (:mod:`fitstiff.diagnosis._candidates`) and accepts the best that
passes (:func:`~fitstiff.diagnosis._choice.choose`), or two together when none passes alone
(:func:`~fitstiff.diagnosis._choice.pair`). After the last round, accepted effects that the
others made redundant are dropped (:func:`~fitstiff.diagnosis.prune.prune`).

**An effect must do as well as a description.** A candidate (or pair) that passes the rule is
still refused when a description of the same held-out residual that names no physics
(:func:`~fitstiff.diagnosis.structure.passing_descriptions`, :class:`Rival`) leaves a
held-out RMS lower than the candidate's by more than ``MIN_GAIN`` of the noise floor: the
gap then follows a shape the effect does not have, and naming the effect would name a
lookalike. The description is held out as the candidate's refit is (each log left out in
turn; blocks of one log's loops for one log): held out by blocks within each log it learns
each log's own friction level, and on the real O-ring logs a smooth curve of the force so
held out (0.737 N) beat pressure friction's leave-one-log-out 1.09 N. A description with
the candidate's own shape (:data:`~fitstiff.diagnosis.structure.LOOKALIKES`) is no rival of
it: the same O-ring's transition scaled by the pressure (0.946 N) is pressure friction with
a freer shape. Measured on the withheld benchmark (docs/diagnosis_heldout.md, session of
2026-11-30 04:16): a load cell's hysteresis named Maxwell-slip (0.262 N) against a
hysteresis in the force (0.209 N), a friction drifting with time named pressure friction
(0.184 N) against a transition scaled by the time (0.172 N).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import time
from collections import Counter
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from fitstiff.diagnosis._candidates import (improved_regions, parameter_entries, refitted,
                                            screened)
from fitstiff.diagnosis._choice import MAX_REFITS, choose, pair
from fitstiff.diagnosis._refit import FoldStarts, Tried, fold_fits, judge
from fitstiff.diagnosis.prune import prune
from fitstiff.diagnosis.result import Candidate
from fitstiff.diagnosis.screen import Score, screen
from fitstiff.diagnosis.select import (MIN_GAIN, Fold, FoldFit, HeldOut, Job,
                                      held_out_batch)
from fitstiff.diagnosis.structure import Passing, Structure, passing_descriptions
from fitstiff.diagnosis.supermodel import SuperProblem
from fitstiff.signal.noise import NoiseFloor

__all__ = ["MAX_ACCEPT", "Setting", "Search", "Rival", "outdone", "phase", "run_rounds",
           "prune_accepted"]

#: most rounds of the search (each accepts one effect, or a pair)
MAX_ACCEPT = 4


@contextlib.contextmanager
def phase(spent: Counter, name: str):
    """Add the wall time of the block to ``spent[name]``."""
    start = time.perf_counter()
    try:
        yield
    finally:
        spent[name] += time.perf_counter() - start


@dataclasses.dataclass(frozen=True, eq=False)
class Setting:
    """What the rounds do not change: the super-model and its folds, the candidates
    (``names``), each log's noise floor and the pooled one, the samples that count
    (``masks``), the full-data run-time ``weights``, the rule's ``alpha`` and ``min_shrink``,
    and ``spent``: seconds per phase of the selection (``timing_s``)."""

    sp: SuperProblem
    folds: Sequence[Fold]
    names: Sequence[str]
    noise: Sequence[NoiseFloor]
    noise_pooled: float
    masks: Sequence[np.ndarray]
    weights: np.ndarray
    alpha: float
    min_shrink: float
    spent: Counter


@dataclasses.dataclass(eq=False)
class Search:
    """The state the rounds update: the full-data fit of the current model (``theta``,
    ``hold``) and its terms (``active``), its held-out figure (``current``) and each fold's
    training fit of it (``fits``: where the next refits start); every candidate's first screen
    (``first``) and record (``decided``), the accepted effects in order, and the last round's
    screen (``scores``)."""

    theta: np.ndarray
    hold: np.ndarray
    active: list[str]
    current: HeldOut
    fits: list[FoldFit]
    first: dict[str, Score] = dataclasses.field(default_factory=dict)
    decided: dict[str, Candidate] = dataclasses.field(default_factory=dict)
    accepted: list[str] = dataclasses.field(default_factory=list)
    scores: list[Score] = dataclasses.field(default_factory=list)


class _Step(NamedTuple):
    """What a round accepts: the effects (one, or a pair) and their held-out refit."""

    effects: list[str]
    heldout: HeldOut


def run_rounds(st: Setting, s: Search) -> None:
    """Up to :data:`MAX_ACCEPT` rounds, until no candidate is left or none passes."""
    for round_ in range(1, MAX_ACCEPT + 1):
        if not _round(st, s, round_):
            break


class Rival:
    """The descriptions of the current model's held-out residual that pass the rule
    (:func:`~fitstiff.diagnosis.structure.passing_descriptions`, each log held out as the
    effects' refits hold it out; with one log, blocks), worked out when a round first needs
    them: a candidate that leaves more than the best of them that does not have its own
    shape (by ``MIN_GAIN`` of the noise floor) is refused (the module docstring)."""

    def __init__(self, st: Setting, current: HeldOut):
        self._st, self._current = st, current

    @functools.cached_property
    def passing(self) -> list[Passing]:
        st = self._st
        problem = st.sp.problem
        with phase(st.spent, "rivals"):
            return passing_descriptions(
                problem.logs, problem.segmentations, self._current.residuals, st.masks,
                st.noise_pooled, hold_out="logs" if problem.n_logs > 1 else "blocks")

    def outdoes(self, effects: Sequence[str], rms_N: float) -> tuple[str, str]:
        """The description (``"<form> in <variable>"``) and why ``effects`` (one, or a pair)
        whose held-out RMS is ``rms_N`` are refused for it, or ``("", "")``."""
        others = [p.structure for p in self.passing
                  if not set(effects) & set(p.lookalike_of)]
        return outdone(others[0] if others else None, rms_N, self._st.noise_pooled)


def outdone(best: Structure | None, rms_N: float, noise_N: float) -> tuple[str, str]:
    """:meth:`Rival.outdoes` for the description ``best`` (None: no description passed) and
    the pooled noise floor ``noise_N``."""
    if best is None or best.heldout_rms_after_N >= rms_N - MIN_GAIN * noise_N:
        return "", ""
    name = f"{best.form} in {best.variable}"
    return name, (f"a description that names no physics explains the gap better held out "
                  f"({name}: {best.heldout_rms_after_N:.3g} N against {rms_N:.3g} N; an "
                  f"effect must come within {MIN_GAIN:.0%} of the noise floor, "
                  f"{MIN_GAIN * noise_N:.2g} N, of it): the gap follows a shape this effect "
                  "does not have")


def _round(st: Setting, s: Search, round_: int) -> bool:
    """One round of the search; False when it ends the search."""
    remaining = [c for c in st.names if c not in s.accepted]
    if not remaining:
        return False
    with phase(st.spent, "screens"):
        s.scores, s.hold = screen(st.sp, s.theta, s.hold, active=s.active,
                                  candidates=remaining, noise=st.noise, weights=st.weights,
                                  alpha=st.alpha, min_gain=MIN_GAIN)
    for score in s.scores:
        s.first.setdefault(score.effect, score)
    starts = FoldStarts(st.sp, st.folds, s.fits, s.active, noise=st.noise, alpha=st.alpha)
    rival = Rival(st, s.current)
    tried = _refits(st, s, starts, rival)
    _record(st, s, tried, round_)
    passing = [v for v in tried.values() if v.passes]
    step = (_accept_one(st, s, passing) if passing
            else _accept_pair(st, s, tried, starts, rival))
    if step is None:
        return False
    _take(st, s, step)
    return True


def _refits(st: Setting, s: Search, starts: FoldStarts, rival: Rival) -> dict[str, Tried]:
    """Held-out refits of the round's significant candidates, judged by the rule and against
    the ``rival`` description: in batches of ``MAX_REFITS``, strongest score first, the next
    batch only when none of the previous passed, so no significant candidate stays
    untried."""
    m = len(st.names)
    promising = sorted((x for x in s.scores if x.testable and x.p_value * m < st.alpha),
                       key=lambda x: x.log_p)
    tried: dict[str, Tried] = {}
    for b in range(0, len(promising), MAX_REFITS):
        if b and any(v.passes for v in tried.values()):
            break
        batch = promising[b:b + MAX_REFITS]
        names = [x.effect for x in batch]
        with phase(st.spent, "refits"):
            fold_start = [starts.of(x.effect, batch=names) for x in batch]
            # the batch's folds share the fold threads (held_out_batch)
            heldout = held_out_batch(st.sp, st.folds, [
                Job(f, s.active, st.sp.elements(x.effect, fitted=True))
                for x, f in zip(batch, fold_start)])
            for score, ho, f in zip(batch, heldout, fold_start):
                tried[score.effect] = judge(st.sp, score, ho, f, current=s.current,
                                            noise=st.noise_pooled, min_shrink=st.min_shrink)
            _refine_shapes(st, s, tried, names)
        for e in names:
            by, why = (rival.outdoes([e], tried[e].heldout.rms_N) if tried[e].passes
                       else ("", ""))
            if by:
                tried[e] = dataclasses.replace(tried[e], passes=False, why=why, outdone_by=by)
    return tried


def _refine_shapes(st: Setting, s: Search, tried: dict[str, Tried],
                   effects: Sequence[str]) -> None:
    """A passing candidate whose shape was held on its grid
    (:data:`~fitstiff.diagnosis.supermodel.FIXED_SHAPE`: Maxwell-slip's slip displacements)
    is refitted once more with its shape free, each fold from its own refit (its training
    fit: nothing of its held-out part); that refit is the candidate's when it converged.
    Only a candidate that explains the gap on its grid is refined: on the real-size speed
    set the refits that free the slip displacements of a Maxwell-slip that does not pass took
    296 and 366 trial steps (62 and 83 s of solves, issue 31's 90 s target), and on a load
    cell's hysteresis the freed law fitted the sensor's lag (``ool/load_cell_hysteresis/4``)."""
    sp = st.sp
    shaped = [e for e in effects if e in tried and tried[e].passes
              and sp.own(e).size > sp.elements(e, fitted=True).size]
    if not shaped:
        return
    jobs = [Job([FoldFit(sp.to_theta(fit.theta, fit.hold, sp.own(e)), fit.hold)
                 for fit in tried[e].heldout.fits], s.active, sp.own(e)) for e in shaped]
    for e, job, ho in zip(shaped, jobs, held_out_batch(sp, st.folds, jobs)):
        if ho.converged:
            tried[e] = judge(sp, tried[e].score, ho, job.starts, current=s.current,
                             noise=st.noise_pooled, min_shrink=st.min_shrink)


def _record(st: Setting, s: Search, tried: dict[str, Tried], round_: int) -> None:
    """Every screened candidate's record of this round; a tie of an earlier round stays on
    the record, with why it lost and its BIC gap (the loser is screened again, and once the
    effect it tied with is in the model it explains nothing more: that is no reason)."""
    tied = {e: c for e, c in s.decided.items() if c.tied_with}
    for score in s.scores:
        if score.effect in tried:
            record = refitted(st.sp, score, tried[score.effect], current=s.current,
                              noise=st.noise, masks=st.masks, round_=round_)
        else:
            record = screened(st.sp, score, round_=round_, alpha=st.alpha, m=len(st.names))
        tie = tied.get(score.effect)
        if tie is not None:
            # refitted again, it keeps that refit's own verdict beside the tie's
            why = (f"{tie.why}; round {round_}: {record.why}"
                   if score.effect in tried and record.why else tie.why)
            record = dataclasses.replace(record, tied_with=tie.tied_with,
                                         tie_bic_gap=tie.tie_bic_gap, why=why)
        s.decided[score.effect] = record


def _accept_one(st: Setting, s: Search, passing: list[Tried]) -> _Step:
    """The passing candidate to accept (:func:`~fitstiff.diagnosis._choice.choose`); the
    full-data fit goes on from its fit, and each tied candidate's record says why it lost."""
    choice = choose(st.sp, passing, s.theta, s.hold, s.active, st.weights, st.noise_pooled)
    s.theta, s.hold = choice.theta, choice.hold
    for effect, lost in choice.losers.items():
        rec = s.decided[effect]
        s.decided[effect] = dataclasses.replace(rec, why=f"round {rec.round}: {lost.why}",
                                                tied_with=choice.chosen.effect,
                                                tie_bic_gap=lost.bic_gap)
    return _Step([choice.chosen.effect], choice.chosen.heldout)


def _accept_pair(st: Setting, s: Search, tried: dict[str, Tried],
                 starts: FoldStarts, rival: Rival) -> _Step | None:
    """Two effects to accept together when none passes alone
    (:func:`~fitstiff.diagnosis._choice.pair`) and the ``rival`` description does not explain
    more, or None: the search ends."""
    with phase(st.spent, "refits"):
        found = pair(st.sp, st.folds, tried, starts, s.theta, s.hold, s.active, st.weights,
                     current=s.current, noise=st.noise_pooled, min_shrink=st.min_shrink)
    if found is None:
        return None
    by, why = rival.outdoes(found.effects, found.heldout.rms_N)
    if by:
        for effect in found.effects:
            rec = s.decided[effect]
            s.decided[effect] = dataclasses.replace(
                rec, outdone_by=by,
                why=f"{rec.why}; with {' and '.join(found.effects)} together: {why}")
        return None
    free = st.sp.fitting(s.active, found.effects)
    s.theta, _, _, _ = st.sp.solve(found.theta, found.hold, free, st.sp.nuisance_mask(),
                                   st.weights)
    # the pair's own shape entries stay where this fit put them
    s.hold = np.asarray(st.sp.physical(s.theta, found.hold, free))
    improved = improved_regions(st.sp, st.noise, st.masks, s.current, found.heldout)
    for effect in found.effects:
        s.decided[effect] = dataclasses.replace(
            s.decided[effect], heldout_rms_after_N=found.heldout.rms_N, shrink=found.shrink,
            converged=found.heldout.converged, regions_improved=improved,
            together=tuple(found.effects))
    return _Step(found.effects, found.heldout)


def _take(st: Setting, s: Search, step: _Step) -> None:
    """Add the accepted effects to the model, with their fitted values on the record. The
    accepted model's held-out figure is its refit's, and each fold goes on from its own
    training fit of it: never a figure chosen by its held-out value."""
    s.active += step.effects
    x = np.asarray(st.sp.physical(s.theta, s.hold, st.sp.model_mask(s.active)))
    for effect in step.effects:
        values = {st.sp.owners[k].name: float(x[k]) for k in st.sp.elements(effect)}
        s.decided[effect] = dataclasses.replace(
            s.decided[effect], accepted=True, why="",
            parameters=parameter_entries(st.sp, values, "fit"),
            reading=st.sp.problem.model.term(effect).reading(),
            lookalike=st.sp.problem.model.term(effect).lookalike)
        s.accepted.append(effect)
    s.current = step.heldout
    s.fits = fold_fits(st.sp, s.current, s.active)


def prune_accepted(st: Setting, s: Search) -> None:
    """Drop the accepted effects that the others made redundant
    (:func:`~fitstiff.diagnosis.prune.prune`), with why on their records."""
    with phase(st.spent, "refits"):
        pruned = prune(st.sp, st.folds, [s.decided[e].together or (e,) for e in s.accepted],
                       s.current, s.theta, s.hold, s.active, st.weights,
                       noise=st.noise_pooled, min_shrink=st.min_shrink)
    s.current, s.theta, s.hold, s.active = (pruned.current, pruned.theta, pruned.hold,
                                            pruned.active)
    for unit, why in pruned.dropped.items():
        for effect in unit:
            s.decided[effect] = dataclasses.replace(s.decided[effect], accepted=False,
                                                    why=why)
            s.accepted.remove(effect)
