"""Pressure series in closed form: the posterior's likelihood with the closed chambers'
pressures as polynomials in ``n`` equals the one from the residuals."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from fitstiff._testing.speed import make_log
from fitstiff.inference.closed_series import (MAX_TERMS, ClosedFormLikelihood,
                                              pressure_closed_forms, taylor_terms)
from fitstiff.inference.fitting import fit_problem
from fitstiff.inference.likelihood import AR1, Gaussian, Layout, StudentT, TurningPoints
from fitstiff.inference.posterior import LogPosterior
from fitstiff.inference.posterior.density import Coordinates, integrated_entries, prepared_noise
from fitstiff.inference.priors import Priors
from fitstiff.inference.problem import Problem, ResidualSeries


@pytest.fixture(scope="module")
def bench_log():
    return make_log()


def _start(problem):
    return np.asarray(problem.pack(problem.model))


def test_taylor_terms_are_exact_to_double_precision():
    assert taylor_terms(0.0) == 0
    assert taylor_terms(1e3) is None
    for bound in (1e-6, 2.0**-8 * 0.67, 0.05, 0.5):
        k = taylor_terms(bound)
        assert k is not None and k <= MAX_TERMS
        u = np.linspace(-bound, bound, 2001)
        poly = sum(u**j / math.factorial(j) for j in range(k + 1))
        # truncation below 2**-53, the rest the rounding of the sum
        assert np.max(np.abs(poly / np.exp(u) - 1)) <= 8 * 2.0**-53
        if k:       # one term fewer is not exact
            short = poly - u**k / math.factorial(k)
            assert np.max(np.abs(short / np.exp(u) - 1)) > 2.0**-53


def _pair(problem, noise, theta, *, integrate, walkers=8):
    """The log-posterior with the pressures in closed form and from the residuals."""
    layout = Layout.from_problem(problem)
    priors = Priors(problem, None)
    integrated = integrated_entries(problem, noise, priors, integrate)
    coordinates = Coordinates.of(problem, theta, integrated, layout)
    noise, _ = prepared_noise(problem, noise, theta, layout, linear=coordinates.linear)
    closed = LogPosterior(problem, noise, priors, batch=walkers, coordinates=coordinates,
                          centre=theta)
    plain = LogPosterior(problem, noise, priors, batch=walkers, coordinates=coordinates)
    return closed, plain, coordinates


def _agree(closed, plain, coordinates, *, seed=0, walkers=8):
    assert closed.closed is not None and plain.closed is None
    rng = np.random.default_rng(seed)
    centre = coordinates.base[coordinates.sampled]
    for scale in (0.0, 1e-3, 0.1, 1.0, 4.0):     # 4: n near its bounds
        rows = centre + scale * rng.standard_normal((walkers, centre.size))
        a, b = closed(rows), plain(rows)
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=0)
        # and so do the statistics the integrated offsets' draws take (emcee's blobs)
        a, b = closed.rows(rows), plain.rows(rows)
        assert a.shape == b.shape == (walkers, 1 + closed.blobs)
        finite = np.isfinite(a[:, 0])
        scale = np.max(np.abs(b[finite]), axis=0)
        np.testing.assert_array_less(np.abs(a[finite] - b[finite]),
                                     1e-12 * (np.abs(b[finite]) + scale) + 1e-300)


@pytest.mark.parametrize("noise", [AR1(), Gaussian()], ids=["ar1", "gaussian"])
@pytest.mark.parametrize("integrate", [True, False], ids=["offset-integrated", "offset-sampled"])
def test_closed_form_likelihood_equals_the_residuals_one(bench_log, noise, integrate):
    """Two logs of different lengths in one padded stack, turning points integrated out,
    walkers from the optimum to far off it."""
    logs = [bench_log, bench_log.slice(0, 3200)]
    problem = Problem(logs, "chamber+dahl")
    fit = fit_problem(problem)
    closed, plain, coordinates = _pair(problem, noise, np.asarray(fit.theta),
                                       integrate=integrate)
    assert len(problem.groups) == 1 and closed.closed.expansion.series.size == 4
    # with the offsets integrated out: theirs and every series' sum of squares
    assert closed.blobs == (2 + 6 if integrate else 0)
    _agree(closed, plain, coordinates)


def test_closing_pressure_nuisance_enters_the_coefficients(bench_log):
    problem = Problem([bench_log.slice(0, 2500)], "chamber+dahl", free=["closing_pressure"])
    fit = fit_problem(problem)
    closed, plain, coordinates = _pair(problem, AR1(), np.asarray(fit.theta), integrate=True)
    _agree(closed, plain, coordinates, seed=1)


def test_fixed_exponent_needs_no_polynomial(bench_log):
    problem = Problem([bench_log.slice(0, 2500)], "chamber+dahl", fix=["n"])
    fit = fit_problem(problem)
    closed, plain, coordinates = _pair(problem, AR1(), np.asarray(fit.theta), integrate=True)
    assert closed.closed.expansion.terms == 0
    _agree(closed, plain, coordinates, seed=2)


@pytest.mark.parametrize("spec", ["chamber+dahl+heat_transfer", "chamber+dahl+time_delay", "chamber+dahl+rig_compliance"])
def test_models_without_the_closed_form_keep_the_residuals(bench_log, spec):
    problem = Problem([bench_log.slice(0, 1500)], spec)
    assert problem.model.closed_form_chamber() is None
    assert pressure_closed_forms(problem) == []
    layout = Layout.from_problem(problem)
    noise = AR1().prepared(np.asarray(problem.residuals(_start(problem))), layout)
    assert ClosedFormLikelihood.of(problem, noise, _start(problem), layout) is None


def test_student_t_keeps_the_residuals(bench_log):
    problem = Problem([bench_log.slice(0, 1500)], "chamber+dahl")
    layout = Layout.from_problem(problem)
    noise = StudentT().prepared(np.asarray(problem.residuals(_start(problem))), layout)
    assert ClosedFormLikelihood.of(problem, noise, _start(problem), layout) is None


def test_exponent_beyond_its_bounds_gives_nan(bench_log):
    problem = Problem([bench_log.slice(0, 1500)], "chamber+dahl")
    layout = Layout.from_problem(problem)
    noise = AR1().prepared(np.asarray(problem.residuals(_start(problem))), layout)
    closed = ClosedFormLikelihood.of(problem, noise, _start(problem), layout)
    narrow = dataclasses.replace(closed.expansion, max_shift=1e-9)
    theta = _start(problem).copy()
    theta[problem.names.index("n")] += 0.5
    assert np.all(np.isnan(np.asarray(narrow.coefficients(problem, theta))[:, 2:]))
    assert np.all(np.isfinite(np.asarray(closed.expansion.coefficients(problem, theta))))


def _two_series_layout(n):
    series = [ResidualSeries(0, "force", slice(0, n), np.ones(n, bool)),
              ResidualSeries(0, "pressure_a", slice(n, 2 * n), np.arange(n) < n - 3)]
    return Layout.from_series(series, ["force[x]", "pressure_a[x]"])


def test_gram_and_restriction_reproduce_the_sums_of_squares():
    """``c' G c`` is the series' sum of squares with its integrated columns reduced; the
    noise model restricted to one series gives that series' terms."""
    rng = np.random.default_rng(4)
    n = 40
    layout = _two_series_layout(n)
    columns = np.zeros((2 * n, 4))
    columns[:n, :2] = 0.3 * rng.standard_normal((n, 2))
    columns[n:, 2:] = 0.2 * rng.standard_normal((n, 2)) * layout.mask[n:, None]
    turning = TurningPoints(columns, np.array([0, 0, 1, 1]))
    r_hat = rng.standard_normal(2 * n) * layout.mask
    for model in (AR1(phi=(0.5, -0.3)), Gaussian()):
        noise = model.prepared(r_hat, layout, turning_points=turning)
        columns = rng.standard_normal((n, 3))
        c = rng.standard_normal(3)
        r = r_hat.copy()
        r[n:] = (columns @ c) * layout.mask[n:]
        q = np.asarray(noise.squares(r, layout))
        g = noise.gram(columns * layout.mask[n:, None], 1, layout)
        assert c @ g @ c == pytest.approx(q[1], rel=1e-12)
        sub = Layout.from_series([ResidualSeries(0, "force", slice(0, n), np.ones(n, bool))],
                                 ["force[x]"])
        alone = noise.restricted([0], layout, sub)
        assert float(alone.squares(r[:n], sub)[0]) == pytest.approx(q[0], rel=1e-12)
        assert alone.dof(sub).tolist() == noise.dof(layout)[:1].tolist()
