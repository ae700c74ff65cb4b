"""Held-out figures that never see the held-out data (issue 31).

Every held-out figure the diagnosis reports is checked against an independent path made of
plain public calls (:mod:`fitstiff._testing.heldout`: ``fit`` on the training part, the
held-out part predicted with the model held and only its own nuisances fitted), per log or
per block within 2 %; and a fold's held-out RMS does not depend on where its solve starts.
The real O-ring set has the same checks in tests/test_realdata.py.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from fitstiff._testing.heldout import blocks_of, leave_one_block_out, leave_one_log_out, pooled
from fitstiff.io.log import Rig
from fitstiff.physics.programs import Concat, TriangleCycles
from fitstiff.physics.simulate import Noise, simulate

RIG = Rig(bore=0.032, rod=0.0, stroke=0.7, start_position=0.35, supply_pressure=6e5)
CANDIDATES = "viscous,asymmetry,force_drift"
TRUTH = {"n": 1.4, "sigma0": 40, "Fc": 18, "c": 150}


def _logs(spec, params, *, rates, amplitudes=(0.3, 1.0), seed=0):
    return [simulate(spec, TriangleCycles(amplitudes_mm=amplitudes, rate_mm_s=rate, cycles=1),
                     rig=RIG, params=params, rate_hz=200.0 if rate < 5 else 500.0,
                     seed=seed + j, name=f"log{j}",
                     noise=Noise(force_N=0.2, displacement_um=0.5, pressure_mbar=2.0)).log
            for j, rate in enumerate(rates)]


def _per_log_rms(residuals):
    return [float(np.sqrt(np.mean(np.square(r)))) for r in residuals]


@pytest.fixture(scope="module")
def one_effect():
    from fitstiff.diagnosis import diagnose

    logs = _logs("chamber+dahl+viscous", TRUTH, rates=(2.0, 10.0))
    return logs, diagnose(logs, candidates=CANDIDATES)


@pytest.fixture(scope="module")
def two_effects():
    from fitstiff.diagnosis import diagnose

    logs = _logs("chamber+dahl+viscous+asymmetry", TRUTH | {"level_asym": 0.15},
                 rates=(2.0, 10.0))
    return logs, diagnose(logs, candidates=CANDIDATES)


def _check_against_plain_fits(logs, d):
    """Baseline, final model and every refitted candidate of the first round, per log."""
    counts = [len(log) for log in logs]
    plain = functools.cache(lambda spec: leave_one_log_out(logs, spec))
    assert d.gap["heldout_rms_per_log_N"] == pytest.approx(plain(d.baseline), rel=0.02)
    assert d.gap["final_heldout_rms_per_log_N"] == pytest.approx(plain(d.final_model),
                                                                 rel=0.02)
    assert _per_log_rms(d.heldout["after"]) == pytest.approx(
        d.gap["final_heldout_rms_per_log_N"], rel=1e-12)
    for c in d.candidates:
        if c.heldout_rms_after_N is None or c.together:
            continue
        spec = "+".join([d.baseline, *d.accepted[:c.round - 1], c.effect])
        assert c.heldout_rms_after_N == pytest.approx(pooled(plain(spec), counts),
                                                      rel=0.02), c.effect
        assert c.heldout_rms_before_N == pytest.approx(
            pooled(plain("+".join([d.baseline, *d.accepted[:c.round - 1]])), counts),
            rel=0.02), c.effect


def test_every_heldout_figure_of_one_accepted_effect_equals_plain_fits(one_effect):
    logs, d = one_effect
    assert d.accepted == ("viscous",)
    assert not [line for line in d.verdict if line.startswith("one log")]
    _check_against_plain_fits(logs, d)


def test_every_heldout_figure_of_two_accepted_effects_equals_plain_fits(two_effects):
    """The leak began with the second round: its "before" and its refits are checked too."""
    logs, d = two_effects
    assert set(d.accepted) == {"viscous", "asymmetry"}, d.verdict
    second = d.candidate(d.accepted[1])
    assert second.round == 2
    _check_against_plain_fits(logs, d)


def test_leave_one_block_out_equals_plain_fits_of_the_rest_of_the_log():
    """One log, two loops at 2 mm/s then two at 10 mm/s, viscous withheld: per block, the
    baseline's and the final model's held-out residuals, and the accepted candidate's before
    and after (the other candidates' refits are checked on logs, above: each block costs a
    plain fit)."""
    from fitstiff.diagnosis import diagnose

    program = Concat(parts=(TriangleCycles(amplitudes_mm=(0.3, 1.0), rate_mm_s=2.0),
                            TriangleCycles(amplitudes_mm=(0.6, 1.2), rate_mm_s=10.0)))
    log = simulate("chamber+dahl+viscous", program, rig=RIG, params=TRUTH, rate_hz=500.0,
                   seed=3, name="one", noise=Noise(force_N=0.2, displacement_um=0.5,
                                                   pressure_mbar=2.0)).log
    d = diagnose([log], candidates=CANDIDATES)
    assert d.accepted == ("viscous",), d.verdict
    # what is accepted on one log rests on that log alone, and the verdict says so
    assert [line for line in d.verdict if line.startswith("one log (one): its blocks")]
    blocks = blocks_of(d.folds)
    assert len(blocks) >= 3 and blocks[0][0] == 0 and blocks[-1][1] == len(log)
    plain = functools.cache(lambda spec: leave_one_block_out(log, spec, blocks))
    for spec, residual in ((d.baseline, d.heldout["before"][0]),
                           (d.final_model, d.heldout["after"][0])):
        for a, b in blocks:
            assert np.sqrt(np.mean(residual[a:b] ** 2)) == pytest.approx(
                np.sqrt(np.mean(plain(spec)[a:b] ** 2)), rel=0.02), (spec, a, b)
    accepted = d.candidate("viscous")
    assert accepted.heldout_rms_before_N == pytest.approx(
        np.sqrt(np.mean(plain(d.baseline) ** 2)), rel=0.02)
    assert accepted.heldout_rms_after_N == pytest.approx(
        np.sqrt(np.mean(plain(d.final_model) ** 2)), rel=0.02)


def test_a_folds_heldout_rms_does_not_depend_on_its_start(one_effect):
    """The final model's folds started from the baseline's cold fold starts (the effect at a
    value off its fit) and from those starts moved by 0.3 in every free unconstrained entry:
    the held-out RMS of each log agrees to 1 %."""
    from fitstiff.diagnosis.select import FoldFit, fold_starts, folds_for, held_out
    from fitstiff.diagnosis.supermodel import SuperProblem

    logs, d = one_effect
    sp = SuperProblem(logs, d.baseline, list(d.settings["candidates"]))
    folds = folds_for(sp)
    active = [*sp.baseline_terms, *d.accepted]
    k = sp.problem.par.names.index("c")
    starts = []
    for f in fold_starts(sp, folds):
        hold = f.hold.copy()
        hold[k] = 60.0                                     # N s/m, the truth is 150
        starts.append(FoldFit(sp.to_theta(f.theta, hold, np.array([k])), hold))
    rng = np.random.default_rng(1)
    free = np.flatnonzero(sp.model_mask(active))
    moved = [FoldFit(f.theta + np.isin(np.arange(f.theta.size), free)
                     * rng.choice([-0.3, 0.3], f.theta.size), f.hold) for f in starts]
    a = held_out(sp, folds, starts, active)
    b = held_out(sp, folds, moved, active)
    assert a.converged and b.converged
    assert a.rms_per_log_N == pytest.approx(b.rms_per_log_N, rel=0.01)
    assert a.rms_per_log_N == pytest.approx(d.gap["final_heldout_rms_per_log_N"], rel=0.01)


def test_a_batch_of_models_held_out_together_gives_each_ones_own_figures(one_effect):
    """Speed (issue 31): a round's candidates share the fold threads
    (:func:`~fitstiff.diagnosis.select.held_out_batch`). Each model's held-out residuals,
    steps and fold fits are those of its own :func:`held_out`, to the bit, whatever the
    batch holds and in which order."""
    from fitstiff.diagnosis.select import (FoldFit, Job, fold_starts, folds_for, held_out,
                                           held_out_batch)
    from fitstiff.diagnosis.supermodel import SuperProblem

    logs, d = one_effect
    sp = SuperProblem(logs, d.baseline, list(d.settings["candidates"]))
    folds = folds_for(sp)
    base = list(sp.baseline_terms)
    cold = fold_starts(sp, folds)
    k = sp.problem.par.names.index("c")
    starts = []
    for f in cold:
        hold = f.hold.copy()
        hold[k] = 60.0
        starts.append(FoldFit(sp.to_theta(f.theta, hold, np.array([k])), hold))
    jobs = [Job(cold, base), Job(starts, base, sp.elements("viscous", fitted=True)),
            Job(cold, base, sp.elements("force_drift", fitted=True))]
    alone = [held_out(sp, folds, j.starts, j.active, extra=j.extra) for j in jobs]
    for order in ([0, 1, 2], [2, 0, 1]):
        together = held_out_batch(sp, folds, [jobs[i] for i in order])
        for i, ho in zip(order, together):
            a = alone[i]
            assert ho.rms_N == a.rms_N and ho.steps == a.steps
            assert ho.converged == a.converged
            for r, s in zip(ho.residuals, a.residuals):
                np.testing.assert_array_equal(r, s)
            for f, g in zip(ho.fits, a.fits):
                np.testing.assert_array_equal(f.theta, g.theta)
                np.testing.assert_array_equal(f.hold, g.hold)
    # the viscous refit is the one that moves the held-out RMS
    assert alone[1].rms_N < alone[0].rms_N
    # a fold with a second start (a handover) solves from both as separate tasks and keeps
    # the better: the same start twice gives the one start's figures, with twice the
    # training steps
    twice = Job([FoldFit(f.theta, f.hold, (FoldFit(f.theta, f.hold),)) for f in starts],
                base, sp.elements("viscous", fitted=True))
    ho = held_out_batch(sp, folds, [jobs[0], twice])[1]
    for r, s in zip(ho.residuals, alone[1].residuals):
        np.testing.assert_array_equal(r, s)
    assert alone[1].steps < ho.steps < 2 * alone[1].steps


def test_a_held_out_blocks_own_nuisances_start_from_its_own_data():
    """The fold rule for a held-out block that starts its log: its initial friction state
    is fitted to the block alone, so no training step may move it. The slow log of
    withheld ``single/stribeck/4`` alone: the Stribeck screen's joint step, computed on the
    other blocks (which the state barely touches), put it at -449 in the solver's
    coordinates (saturated: the block's own solve could not leave it) and the refit
    predicted that block at 2.7 N against the baseline's 0.18 N. Every refit start keeps the
    fold's own value, and the Stribeck refit predicts every block better than the baseline."""
    from fitstiff._testing.withheld import make_dataset
    from fitstiff.diagnosis._refit import FoldStarts, fold_fits
    from fitstiff.diagnosis.diagnose import baseline_fit, noise_floors
    from fitstiff.diagnosis.select import Job, fold_starts, folds_for, held_out, held_out_batch
    from fitstiff.diagnosis.supermodel import SuperProblem

    logs, truth = make_dataset("single/stribeck/4")
    sp = SuperProblem([logs[0]], truth["baseline"], ["stribeck"])
    folds = folds_for(sp)
    assert len(folds) == 4 and folds[0].samples[1][0]
    active = list(sp.baseline_terms)
    current = held_out(sp, folds, fold_starts(sp, folds), active)
    fits = fold_fits(sp, current, active)
    noise, _ = noise_floors(sp, baseline_fit(sp))
    starts = FoldStarts(sp, folds, fits, active, noise=noise, alpha=0.05).of("stribeck")
    for fold, fit, start in zip(folds, fits, starts):
        own = sp.n_model + np.flatnonzero(fold.nuisances(sp)[1])
        for s in (start, *start.also):
            np.testing.assert_array_equal(s.theta[own], fit.theta[own])
    assert np.flatnonzero(folds[0].nuisances(sp)[1]).size == 1
    ho = held_out_batch(sp, folds, [Job(starts, active, sp.elements("stribeck", fitted=True))])[0]
    assert ho.converged
    for fold in folds:
        mask = fold.samples[1]
        before, after = (float(np.sqrt(np.mean(r[0][mask] ** 2)))
                         for r in (current.residuals, ho.residuals))
        assert after < before, (np.flatnonzero(mask)[[0, -1]], before, after)
