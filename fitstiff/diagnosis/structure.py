"""What the unexplained gap follows: descriptions of the held-out residual (issue 32).

When the library's effects are exhausted (:func:`~fitstiff.diagnosis.diagnose.diagnose`'s greedy
acceptance), the final model's **held-out** residual ``r`` (model - measured, N; every sample
predicted by a fit that never saw it, :mod:`fitstiff.diagnosis.select`) may still follow
something. This module tries small regularised models ``d(v)`` of ``r`` in one variable ``v``
of a fixed vocabulary (:data:`VARIABLES`), and names the one that holds on held-out data.

**Descriptions.** For each variable: ``linear`` (one column), ``smooth`` (hat functions at
``KNOTS`` quantiles of ``v``, of each log's own for the position, a second-difference penalty
chosen by generalised cross-validation), ``periodic`` (a sine and a cosine whose period is
scanned, their phase and amplitude shared by the logs that travel one stretch of the stroke;
position only), ``step`` (one level per log, or per direction) and, for the force,
``hysteresis`` (smooth in the force's change since it last turned, times the direction of its
change), each either **even** (the same in both directions of motion) or **sign-dependent**
(times the direction of the last motion, held through a stop: a friction-like force, which
keeps its sign while the piston stands). Two forms follow how a friction change shows in a
seal's force: a change of its level or its presliding stiffness is felt through the
transition after each reversal, so ``transition`` is a smooth curve of the travel since the
reversal plus a second one times the time, the supply pressure or the log of the leg's
speed (a friction warming up, a pressure law beyond the library's, a rate-dependent
presliding stiffness), and ``gated`` is a smooth curve of the position times
``1 - exp(-travel / s0)``, ``s0`` chosen on the training folds (a friction level along the
bore: a tight spot). A transition in the time or the speed carries a friction level of each
log's own beside its shape: what the physics fit of the other logs leaves in a log's
friction level is no shape of the variable. Every column is
centred per log, so no description can take over a log's force offset (a nuisance the fit
already owns).

**Held out twice.** The residual is already held out from the physics; a description is held
out from itself too: each log's samples are cut into ``BLOCKS`` consecutive blocks, block
``b`` belongs to fold ``b mod FOLDS``, the description is fitted on the other folds (its
knots, penalty and period included) and predicts the fold. No physics model is refitted.
With ``hold_out="logs"`` each log is a fold instead (what a library effect's refit faces
when the diagnosis leaves one log out: :class:`~fitstiff.diagnosis._rounds.Rival` holds a
passing effect against such a description); a log's own columns (its level, its phase)
then predict nothing of it.

**The rule** (the library's, :mod:`fitstiff.diagnosis.select`, on the description): the
gap must exist (held-out RMS above the pooled noise floor); the description's held-out
gain ``sum(r^2) - sum((r - d)^2)`` per block is positive by a one-sided t-test over the blocks
at ``alpha`` family-wise over the descriptions tried (:func:`max_t_threshold`: the blocks'
signs flipped together, so correlated descriptions are not counted as independent tries);
the held-out RMS falls by at
least ``MIN_GAIN`` of the noise floor; and the fall is at least ``min_shrink`` of the gap
above the noise. Among the descriptions that pass, the lowest held-out RMS wins (within
``TIE`` of the noise floor: fewer parameters, then the vocabulary's order); its held-out
prediction is taken off the residual and the rest is described again, up to
``MAX_ACCEPT`` descriptions. Descriptions of other variables that do about as well (a tie,
or passing with at least ``RIVAL_GAIN`` of the winner's held-out gain) and predict the same
thing (correlation above ``CONFOUNDED``) are its ``confounded_with``: the logs cannot tell
those variables apart; so are ``log``, and any variable with one level per log (a supply
pressure each), for a curve of a variable whose ranges in the logs do not overlap, for
a period whose phase is every log's own, and for a transition scaled by a variable with one
level per log (each is as well a shape per log).

The rates are measured in the withheld-effect benchmark (``benchmarks/withheld.py``: nulls,
datasets whose in-library effect was accepted, and the out-of-library family).

This module holds the rounds and the rule; the variables and the forms they can take are in
:mod:`fitstiff.diagnosis._structure_forms`, the columns and the penalised fit of one form
(``KNOTS``) in :mod:`fitstiff.diagnosis._structure_basis`, and what a description's record
says and the shape its plot draws in :mod:`fitstiff.diagnosis._structure_record`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import numpy as np

from fitstiff.diagnosis._structure_basis import Design, fit_predict
from fitstiff.diagnosis._structure_forms import (VARIABLES, Candidate, candidates, disjoint,
                                                 one_level_per_log, phase_per_log,
                                                 structure_variables)
from fitstiff.diagnosis._structure_record import LOOKALIKES, Structure, Trial, record, shown
from fitstiff.inference.comparison import TIE
from fitstiff.io.log import Log
from fitstiff.segments.segmentation import Segmentation

__all__ = ["VARIABLES", "LOOKALIKES", "Described", "Passing", "Structure",
           "accepted_descriptions", "describe_structure", "passing_descriptions",
           "structure_variables",
           "STRUCTURE_ALPHA", "STRUCTURE_MIN_SHRINK"]

#: family-wise level of the descriptions' test in each round
STRUCTURE_ALPHA = 0.05
#: share of the gap above the noise floor a description must remove on held-out data
STRUCTURE_MIN_SHRINK = 0.2
#: least fall of the held-out RMS, as a share of the noise floor (as the library's MIN_GAIN)
MIN_GAIN = 0.05
MAX_ACCEPT = 3
FOLDS = 4
BLOCKS = 16
#: descriptions of two variables whose held-out predictions correlate above this, and whose
#: held-out gains are within a tie or the rival's at least RIVAL_GAIN of the chosen one's
#: (passing the rule itself), are one: the logs cannot tell the variables apart
CONFOUNDED = 0.8
RIVAL_GAIN = 0.8


@dataclasses.dataclass(frozen=True)
class Described:
    """An accepted description with what its plot needs, all samples of all logs
    concatenated: ``values`` of its variable, the ``sign`` that multiplies it (ones for an
    even form), the residual it described (``residual``: after the descriptions accepted
    before it) and its own held-out prediction."""

    structure: Structure
    values: np.ndarray
    sign: np.ndarray
    residual: np.ndarray
    prediction: np.ndarray


def describe_structure(logs: Sequence[Log], segmentations: Sequence[Segmentation],
                       residuals: Sequence[np.ndarray], masks: Sequence[np.ndarray],
                       noise_N: float, *, alpha: float = STRUCTURE_ALPHA,
                       min_shrink: float = STRUCTURE_MIN_SHRINK,
                       max_accept: int = MAX_ACCEPT,
                       library: Mapping[str, str] | None = None,
                       hold_out: str = "blocks") -> tuple[Structure, ...]:
    """Describe what the held-out residual follows (see the module docstring).

    Args:
        logs, segmentations: the diagnosed logs and their segmentations.
        residuals: per log, the final model's held-out residual (model - measured, N).
        masks: per log, the samples that count.
        noise_N: the pooled noise floor (N).
        library: the library effects tried and not accepted, with why (a description with
            one's shape says so, :data:`LOOKALIKES`).
        hold_out: ``"blocks"`` (folds of blocks within each log) or ``"logs"`` (each log a
            fold; two logs or more).

    Returns:
        The accepted descriptions in order, then the best description of every other
        variable tried in the last round (not accepted, with why), best first.
    """
    found = _describe(logs, segmentations, residuals, masks, noise_N, alpha=alpha,
                      min_shrink=min_shrink, max_accept=max_accept, library=library,
                      hold_out=hold_out)
    return tuple(d.structure for d in found.accepted) + tuple(found.rest)


def accepted_descriptions(logs: Sequence[Log], segmentations: Sequence[Segmentation],
                          residuals: Sequence[np.ndarray], masks: Sequence[np.ndarray],
                          noise_N: float, **rule) -> tuple[Described, ...]:
    """:func:`describe_structure`'s accepted descriptions with their data (for plots)."""
    return tuple(_describe(logs, segmentations, residuals, masks, noise_N, **rule).accepted)


class _Samples(NamedTuple):
    """All logs' samples one after another: the held-out ``residual`` (0 where a sample does
    not count), the ``weight`` of each and whether it counts, its log, its block
    (:func:`_blocks`; -1 where it does not count) and fold (-1 likewise), the number of
    blocks and of folds, the candidate descriptions, and whether the positions are
    ``relative`` to the start (a start position not known)."""

    residual: np.ndarray
    weight: np.ndarray
    counted: np.ndarray
    log_id: np.ndarray
    block: np.ndarray
    fold: np.ndarray
    n_blocks: int
    n_folds: int
    candidates: list[Candidate]
    relative: bool


class _Rule(NamedTuple):
    """The rule's settings: the pooled noise floor (N), the level and least share of the gap,
    and the library effects tried and not accepted (with why)."""

    noise: float
    alpha: float
    min_shrink: float
    library: Mapping[str, str]


class _Descriptions(NamedTuple):
    """The accepted descriptions in order, and the records of the last round's best
    description of every other variable (not accepted, with why)."""

    accepted: list[Described]
    rest: list[Structure]


class _Outcome(NamedTuple):
    """A round's outcome: the description it accepts, or None and the best description of
    each variable, not accepted, with why."""

    described: Described | None
    rest: list[Structure]


def _describe(logs, segmentations, residuals, masks, noise_N, *,
              alpha: float = STRUCTURE_ALPHA, min_shrink: float = STRUCTURE_MIN_SHRINK,
              max_accept: int = MAX_ACCEPT, library: Mapping[str, str] | None = None,
              hold_out: str = "blocks") -> _Descriptions:
    """The rounds: each accepts the best description that passes the rule and takes its
    held-out prediction off the residual, until none passes, no gap is left or
    ``max_accept`` are accepted."""
    data = _samples(logs, segmentations, residuals, masks, hold_out)
    if not _describable(data):
        return _Descriptions([], [])
    designs = [Design(c, data.log_id, data.weight) for c in data.candidates]
    rule = _Rule(noise_N, alpha, min_shrink, library or {})
    r = data.residual
    accepted: list[Described] = []
    last: list[Structure] = []
    for round_ in range(1, max_accept + 1):
        before = _rms(data, r)
        if before <= noise_N:
            why = (f"no gap left: held-out RMS {before:.3g} N is at the noise floor "
                   f"{noise_N:.3g} N")
            last = [dataclasses.replace(s, why=why) for s in last]
            break
        outcome = _round(data, designs, r, before, rule, round_)
        if outcome.described is None:
            last = outcome.rest
            break
        accepted.append(outcome.described)
        variable = outcome.described.structure.variable
        r = r - outcome.described.prediction
        designs = [d for d in designs if d.cand.variable != variable]
        last = []
        if not designs:
            break
    return _Descriptions(accepted, last)


def _describable(data: _Samples) -> bool:
    """Whether the samples can be described at all: a candidate description, four blocks or
    more to test it over, and samples that count."""
    return bool(data.candidates) and data.n_blocks >= 4 and bool(data.counted.any())


def _rms(data: _Samples, r: np.ndarray) -> float:
    """The weighted RMS of ``r`` over the counted samples (N)."""
    return math.sqrt(float(np.sum(data.weight * r**2) / data.weight.sum()))


def _samples(logs, segmentations, residuals, masks, hold_out: str = "blocks") -> _Samples:
    """The logs' samples, variables and candidate descriptions, all logs concatenated; the
    folds are blocks (``hold_out="blocks"``) or logs (``"logs"``)."""
    if hold_out not in ("blocks", "logs") or hold_out == "logs" and len(logs) < 2:
        raise ValueError(f"hold_out={hold_out!r}: give 'blocks', or 'logs' with two logs or "
                         f"more ({len(logs)} given)")
    r_logs = [np.asarray(r, float) for r in residuals]
    per_log = [structure_variables(log, seg, np.asarray(log.force) + r)
               for log, seg, r in zip(logs, segmentations, r_logs)]
    log_id = np.concatenate([np.full(len(r), k) for k, r in enumerate(r_logs)])
    weight = np.concatenate([np.asarray(m, float) for m in masks])
    r = np.concatenate(r_logs)
    r = np.where(weight > 0, r, 0.0)
    block = _blocks(log_id, weight)
    fold = np.where(block < 0, -1, block % FOLDS if hold_out == "blocks" else log_id)
    return _Samples(residual=r, weight=weight, counted=weight > 0, log_id=log_id,
                    block=block, fold=fold, n_blocks=int(block.max()) + 1,
                    n_folds=FOLDS if hold_out == "blocks" else len(logs),
                    candidates=candidates(per_log, log_id),
                    relative=any(log.rig.start_position is None for log in logs))


def _round(data: _Samples, designs: Sequence[Design], r: np.ndarray, before: float,
           rule: _Rule, round_: int) -> _Outcome:
    """Try every description on the residual ``r`` (held-out RMS ``before``) and accept the
    best that passes the rule (the module docstring), with the variables it is confounded
    with."""
    tried, t_needed, shrinks, passing = _tried(data, designs, r, before, rule)
    band = TIE * rule.noise
    best_by_var = _best_per_variable(tried, band)
    if not passing:
        return _Outcome(None, [
            record(x, data.relative, rule.noise, accepted=False, round_=round_,
                   t_needed=t_needed,
                   why=_why_not(x, t_needed, rule.noise, rule.min_shrink, shrinks[id(x)]))
            for x in sorted(best_by_var, key=lambda x: x.after)])
    best_after = min(x.after for x in passing)

    def order(x):
        return (round((x.after - best_after) / band) if band > 0 else x.after,
                x.dof, VARIABLES.index(x.cand.variable))

    chosen = min(passing, key=order)
    gain = chosen.before - chosen.after
    rivals = tuple(x.cand.variable for x in best_by_var
                   if x.cand.variable != chosen.cand.variable
                   and (x.after - best_after <= band or any(x is y for y in passing)
                        and x.before - x.after >= RIVAL_GAIN * gain)
                   and _corr(x.pred, chosen.pred, data.weight) > CONFOUNDED)
    apart: tuple[str, ...] = ()
    if (chosen.cand.form in ("linear", "smooth", "curved", "gated")
            and disjoint(chosen.cand.values, data.log_id, data.counted)
            or phase_per_log(chosen.cand, data.log_id, data.counted)
            or chosen.cand.form == "transition"
            and one_level_per_log(chosen.cand.scale, data.log_id, data.counted)):
        # a curve per log (or a phase per log) is as well a shape of each log's own, and of
        # any variable that has one level per log (a supply pressure each)
        apart = ("log", *dict.fromkeys(
            c.variable for c in data.candidates if c.variable not in ("log", chosen.cand.variable)
            and one_level_per_log(c.values, data.log_id, data.counted)))
    structure = record(chosen, data.relative, rule.noise, accepted=True, round_=round_,
                       t_needed=t_needed, rivals=rivals, apart=apart, library=rule.library)
    return _Outcome(Described(structure, chosen.shown, chosen.cand.sign, r, chosen.pred), [])


def _tried(data: _Samples, designs: Sequence[Design], r: np.ndarray, before: float,
           rule: _Rule) -> tuple[list[Trial], float, dict[int, float], list[Trial]]:
    """Every description tried on ``r``, the t its gain must exceed, each one's shrink (by
    ``id``) and those that pass the rule."""
    tried = [_trial(design, r, before, data) for design in designs]
    t_needed = max_t_threshold(np.array([x.gains for x in tried]), rule.alpha)
    shrinks = {id(x): (x.before - x.after) / (x.before - rule.noise) for x in tried}
    passing = [x for x in tried
               if x.t > t_needed and x.before - x.after >= MIN_GAIN * rule.noise
               and shrinks[id(x)] >= rule.min_shrink]
    return tried, t_needed, shrinks, passing


class Passing(NamedTuple):
    """A description that passes the rule (:func:`passing_descriptions`) and the library
    effects whose shape it has (:data:`LOOKALIKES`)."""

    structure: Structure
    lookalike_of: tuple[str, ...]


def passing_descriptions(logs: Sequence[Log], segmentations: Sequence[Segmentation],
                         residuals: Sequence[np.ndarray], masks: Sequence[np.ndarray],
                         noise_N: float, *, alpha: float = STRUCTURE_ALPHA,
                         min_shrink: float = STRUCTURE_MIN_SHRINK,
                         hold_out: str = "blocks") -> list[Passing]:
    """One round of :func:`describe_structure`'s rule on the residual, without accepting:
    per variable, its best description that passes, lowest held-out RMS first (the same
    arguments). What a library effect is held against
    (:class:`~fitstiff.diagnosis._rounds.Rival`)."""
    data = _samples(logs, segmentations, residuals, masks, hold_out)
    r = data.residual
    if not _describable(data) or (before := _rms(data, r)) <= noise_N:
        return []
    designs = [Design(c, data.log_id, data.weight) for c in data.candidates]
    rule = _Rule(noise_N, alpha, min_shrink, {})
    _, t_needed, _, passing = _tried(data, designs, r, before, rule)
    best = sorted(_best_per_variable(passing, TIE * noise_N), key=lambda x: x.after)
    return [Passing(record(x, data.relative, noise_N, accepted=True, round_=1,
                           t_needed=t_needed),
                    LOOKALIKES.get((x.cand.variable, x.cand.signed), ())) for x in best]


def _trial(design: Design, r: np.ndarray, before: float, data: _Samples) -> Trial:
    """One description tried on the residual ``r``: held out from itself (fitted on the
    other folds, predicting each fold), the t statistic of its held-out gain over the
    blocks, and its fit to all counted samples."""
    pred = np.zeros_like(r)
    for f in range(data.n_folds):
        test = data.fold == f
        pred[test] = fit_predict(design, r, (data.fold >= 0) & ~test, data.weight).pred[test]
    counted = data.counted
    gains = np.bincount(data.block[counted], weights=(data.weight * (r**2 - (r - pred) ** 2))
                        [counted], minlength=data.n_blocks)
    sd = float(np.std(gains, ddof=1))
    t = float(np.mean(gains) / (sd / math.sqrt(data.n_blocks))) if sd > 0 else 0.0
    after = math.sqrt(float(np.sum(data.weight * (r - pred) ** 2) / data.weight.sum()))
    full = fit_predict(design, r, data.fold >= 0, data.weight)
    plot = shown(design.cand, data.log_id, counted, full.pred, full.period)
    return Trial(design.cand, pred, full.pred, full.period, full.dof, t, before, after,
                 plot.values, plot.axis, gains)


#: sign flips drawn for :func:`max_t_threshold` (its seed fixed: the same data, the same
#: threshold)
FLIPS = 2000


def max_t_threshold(gains: np.ndarray, alpha: float) -> float:
    """The t a description's held-out gain must exceed, family-wise at ``alpha`` over the
    descriptions tried (``gains``: one row of block gains per description): the
    ``1 - alpha`` quantile of the largest t over the descriptions when every block's gains
    change sign together (Westfall and Young's max-T). Under no structure a held-out
    block gain is a term symmetric about 0 less the square of an independent prediction,
    so flipping signs is conservative; flipping all descriptions' gains of a block alike
    keeps their correlation (transitions of the time, the pressure and the speed predict
    much the same), which a Bonferroni bound over the descriptions ignores."""
    g = np.asarray(gains, float)
    n = g.shape[1]
    rng = np.random.default_rng(0)
    flips = rng.choice((-1.0, 1.0), size=(FLIPS, n))
    means = flips @ g.T / n                                   # (flips, descriptions)
    ss = np.sum(g * g, axis=1)
    var = np.maximum((ss[None, :] - n * means**2) / (n - 1), 1e-300)
    t = means / np.sqrt(var / n)
    t = np.where(ss[None, :] > 0, t, 0.0)
    return float(np.quantile(t.max(axis=1), 1 - alpha))


def _blocks(log_id: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Per sample its block (``BLOCKS`` consecutive blocks of counted samples per log),
    numbered over the logs; -1 for samples that do not count."""
    out = np.full(log_id.size, -1, dtype=np.int64)
    offset = 0
    for k in np.unique(log_id):
        idx = np.flatnonzero((log_id == k) & (weight > 0))
        if idx.size == 0:
            continue
        parts = np.array_split(idx, BLOCKS)
        for b, part in enumerate(parts):
            out[part] = offset + b
        offset += BLOCKS
    return out


def _best_per_variable(tried: Sequence[Trial], band: float) -> list[Trial]:
    """The best description of each variable: the lowest held-out RMS, within ``band`` the
    fewer parameters."""
    best: dict[str, Trial] = {}
    for x in tried:
        cur = best.get(x.cand.variable)
        if cur is None or x.after < cur.after - band or (
                abs(x.after - cur.after) <= band and x.dof < cur.dof):
            best[x.cand.variable] = x
    return list(best.values())


def _corr(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> float:
    """The weighted correlation of two predictions."""
    a, b = a - np.average(a, weights=w), b - np.average(b, weights=w)
    den = math.sqrt(float(np.sum(w * a * a) * np.sum(w * b * b)))
    return float(np.sum(w * a * b)) / den if den > 0 else 0.0


def _why_not(x: Trial, t_needed: float, noise: float, min_shrink: float,
             shrink: float) -> str:
    """Why a description does not pass the rule."""
    if x.t <= t_needed:
        return f"not significant on held-out blocks (t = {x.t:.2g}, needs > {t_needed:.2g})"
    if x.before - x.after < MIN_GAIN * noise:
        return (f"held-out RMS falls by {x.before - x.after:.2g} N, less than "
                f"{MIN_GAIN:.0%} of the noise floor")
    return f"removes {shrink:.0%} of the gap above the noise, needs {min_shrink:.0%}"
