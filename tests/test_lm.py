"""fitstiff.inference.lm's Levenberg-Marquardt, in its QR and its normal-equations form: solutions,
statuses, the bound walk."""

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

from fitstiff.inference.lm import (CONVERGED, MAX_STEPS, NONFINITE, STATUS, jacobian_rows,
                                   levenberg_marquardt, r_factor, wide_dot)

T = np.linspace(0.0, 4.0, 200)
TRUTH = np.array([2.5, -1.3, 0.7])
Y = TRUTH[0] * np.exp(TRUTH[1] * T) + TRUTH[2] + 0.01 * np.random.default_rng(0).normal(
    size=T.size)


def decay(z):
    return z[0] * jnp.exp(z[1] * T) + z[2] - Y


def rosenbrock(z):
    return jnp.array([10.0 * (z[1] - z[0] ** 2), 1.0 - z[0]])


FORMS = pytest.mark.parametrize("normal", [False, True], ids=["qr", "normal"])


@FORMS
@pytest.mark.parametrize("fn, z0", [(decay, [1.0, -0.5, 0.0]), (rosenbrock, [-1.2, 1.0])])
def test_it_finds_the_least_squares_solution_optimistix_finds(fn, z0, normal):
    ours = jax.jit(lambda z: levenberg_marquardt(fn, z, rtol=1e-10, atol=1e-10,
                                                 normal=normal))(jnp.asarray(z0))
    theirs = optx.least_squares(lambda z, _: fn(z), optx.LevenbergMarquardt(1e-10, 1e-10),
                                jnp.asarray(z0), max_steps=1000)
    assert int(ours.status) == CONVERGED
    np.testing.assert_allclose(ours.value, theirs.value, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(ours.cost, np.sum(np.asarray(fn(ours.value)) ** 2))


@FORMS
def test_the_decay_fit_recovers_the_truth_within_its_noise(normal):
    out = levenberg_marquardt(decay, jnp.array([1.0, -0.5, 0.0]), normal=normal)
    np.testing.assert_allclose(out.value, TRUTH, atol=0.02)
    assert 0 < int(out.steps) < 50


@FORMS
def test_a_step_budget_that_runs_out_is_reported(normal):
    out = levenberg_marquardt(rosenbrock, jnp.array([-1.2, 1.0]), max_steps=3,
                              normal=normal)
    assert int(out.status) == MAX_STEPS and int(out.steps) == 3
    assert STATUS[MAX_STEPS] == "the step budget ran out"


@FORMS
def test_a_start_with_nonfinite_residuals_is_reported_without_a_step(normal):
    out = levenberg_marquardt(lambda z: jnp.log(z) - 1.0, jnp.array([-1.0]), normal=normal)
    assert int(out.status) == NONFINITE and int(out.steps) == 0


@FORMS
def test_a_walk_towards_a_transform_bound_ends_converged(normal):
    """The best value of a non-negative stiffness k = exp(z) is 0: z walks to -inf while the
    cost stops changing; the ftol test ends it (the step test alone never would)."""
    x = np.linspace(-1.0, 1.0, 50)
    y = 0.3 - 0.1 * x + 0.01 * np.random.default_rng(1).normal(size=x.size)   # slope < 0

    def fn(z):
        return jnp.exp(z[0]) * x + z[1] - y

    out = levenberg_marquardt(fn, jnp.array([0.0, 0.0]), max_steps=200, normal=normal)
    assert int(out.status) == CONVERGED and int(out.steps) < 100
    assert float(jnp.exp(out.value[0])) < 1e-2
    np.testing.assert_allclose(out.value[1], np.mean(y), atol=1e-3)


@FORMS
def test_a_walk_towards_a_transform_bound_is_scaled_by_the_column_at_the_point(normal):
    """Started at k = exp(3), the stiffness whose best value is 0 reaches it in a few steps:
    the step's scale is its column at the point, which shrinks with k (down to a hundredth
    of its largest). Scaled by the running maximum of the column norms (Moré, MINPACK) the
    damping of k grew as k fell and the walk took 44 steps."""
    x = np.linspace(-1.0, 1.0, 50)
    y = 0.3 - 0.1 * x + 0.01 * np.random.default_rng(1).normal(size=x.size)

    def fn(z):
        return jnp.exp(z[0]) * x + z[1] - y

    out = levenberg_marquardt(fn, jnp.array([3.0, 0.0]), max_steps=200, normal=normal)
    assert int(out.status) == CONVERGED and int(out.steps) <= 12
    assert float(jnp.exp(out.value[0])) < 1e-6
    best = np.sum((np.mean(y) - y) ** 2)                 # k = 0, intercept the mean
    assert float(out.cost) <= best * (1 + 1e-5)


@FORMS
def test_a_padding_entry_with_a_zero_column_stays_put(normal):
    out = levenberg_marquardt(lambda z: decay(z[:3]), jnp.array([1.0, -0.5, 0.0, 7.0]),
                              normal=normal)
    assert int(out.status) == CONVERGED
    assert float(out.value[3]) == 7.0


def test_wide_dot_is_the_matrix_product():
    rng = np.random.default_rng(2)
    a, b = rng.normal(size=(4, 500)), rng.normal(size=(3, 500))
    np.testing.assert_allclose(wide_dot(jnp.asarray(a), jnp.asarray(b)), a @ b.T, rtol=1e-12)


@pytest.mark.parametrize("sequential", [False, True])
def test_jacobian_rows_is_the_transposed_jacobian(sequential):
    z = jnp.array([1.0, -0.5, 0.2])
    np.testing.assert_allclose(jacobian_rows(decay, z, sequential=sequential),
                               jax.jacfwd(decay)(z).T, rtol=1e-13)


@pytest.mark.parametrize("rows", [300, 4096, 4097 + 300])
def test_the_blocked_r_factor_is_the_qr_factor_up_to_row_signs(rows):
    """A tall-skinny QR over blocks (here of 1 024 rows) gives the R of one QR: the same
    R^T R, the same singular values, rows equal up to sign; also for an ill-conditioned J."""
    rng = np.random.default_rng(3)
    jac = rng.normal(size=(rows, 4)) * np.array([1.0, 1e-3, 1e3, 1.0])
    jac[:, 3] = jac[:, 0] + 1e-6 * jac[:, 3]
    ours = np.asarray(r_factor(jnp.asarray(jac.T), block=1024))
    theirs = np.linalg.qr(jac, mode="r")
    np.testing.assert_allclose(np.abs(ours), np.abs(theirs), rtol=1e-9, atol=1e-9 * 1e3)
    np.testing.assert_allclose(np.linalg.svd(ours, compute_uv=False),
                               np.linalg.svd(jac, compute_uv=False), rtol=1e-9)
