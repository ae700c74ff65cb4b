"""The log-posterior that emcee samples: residuals of a problem's rows, the noise model's
likelihood with the linear nuisances integrated out, and the priors, batched over walkers
(:class:`LogPosterior`, :func:`log_posterior`)."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from fitstiff._jax import computed_apart, jax, jnp
from fitstiff.inference import likelihood
from fitstiff.inference.closed_series import ClosedFormLikelihood
from fitstiff.inference.fitting import FitResult
from fitstiff.inference.likelihood import Layout, LinearNuisances, NoiseModel, TurningPoints
from fitstiff.inference.priors import Prior, Priors
from fitstiff.inference.problem import Problem
from fitstiff.physics.derived import DERIVED, derived_quantities


__all__ = ["DEFAULT_NOISE_MODEL", "LogPosterior", "log_posterior", "Coordinates",
           "prepared_noise", "integrated_entries", "residuals_at", "physical_rows",
           "derived_rows", "force_rows", "batched", "DERIVED_BATCH"]

DEFAULT_NOISE_MODEL = "ar1"
#: rows per compiled call of the derived quantities and predictions of kept draws
DERIVED_BATCH = 256


def log_posterior(fit: FitResult, *, noise_model: str | NoiseModel = DEFAULT_NOISE_MODEL,
                  priors: Mapping[str, Prior | Mapping[str, object]] | str | os.PathLike
                  | None = None, batch: int = 16) -> LogPosterior:
    """The log-posterior of a fit's problem, for other samplers and benchmarks.

    Args:
        fit: the least-squares fit; its residuals give the noise settings (and its optimum
            the turning-point columns).
        noise_model, priors: as in :func:`sample_posterior`.
        batch: rows per compiled call of the returned :class:`LogPosterior`.
    """
    problem = fit.problem
    layout = Layout.from_problem(problem)
    noise, _ = prepared_noise(problem, likelihood.noise_model(noise_model), fit.theta, layout)
    return LogPosterior(problem, noise, Priors(problem, priors), batch=batch,
                        centre=np.asarray(fit.theta))


def prepared_noise(problem: Problem, noise: NoiseModel, theta: np.ndarray, layout: Layout, *,
              linear: LinearNuisances | None = None) -> tuple[NoiseModel, TurningPoints]:
    """``noise`` with its settings, the turning-point errors at ``theta`` and the ``linear``
    nuisances integrated out."""
    turning = TurningPoints.at(problem, jnp.asarray(theta), layout)
    return noise.prepared(residuals_at(problem, theta), layout, turning_points=turning,
                          linear=linear), turning


def integrated_entries(problem: Problem, noise: NoiseModel, priors: Priors,
                       wanted: bool) -> list[int]:
    """Positions in ``theta`` of the entries to integrate out: the problem's linear entries
    (force offsets) with flat priors, when the noise model can."""
    if not (wanted and noise.integrates_linear):
        return []
    return [i for i in problem.linear_entries()
            if priors.priors[problem.names[i]].dist == "flat"]


@dataclasses.dataclass(frozen=True, eq=False)
class Coordinates:
    """What the walkers move in: ``theta`` less the entries integrated out analytically.

    Attributes:
        base: a full ``theta``; the integrated entries keep its values in the likelihood.
        sampled: positions in ``theta`` of the sampled coordinates.
        linear: the integrated entries' columns (``None`` when none is integrated).
    """

    base: np.ndarray
    sampled: np.ndarray
    linear: LinearNuisances | None

    @classmethod
    def of(cls, problem: Problem, theta: np.ndarray, integrated: Sequence[int],
           layout: Layout) -> Coordinates:
        base = np.asarray(theta, dtype=float)
        sampled = np.setdiff1d(np.arange(base.size), np.asarray(integrated, dtype=int))
        linear = (LinearNuisances.at(problem, base, layout, integrated) if len(integrated)
                  else None)
        return cls(base, sampled, linear)

    def names(self, problem: Problem) -> list[str]:
        return [problem.names[i] for i in self.sampled]

    def full(self, coords):
        """The full ``theta`` of sampled coordinates (JAX; one row)."""
        return jnp.asarray(self.base).at[self.sampled].set(coords)


class LogPosterior:
    """Rows of sampled coordinates -> log-posteriors (emcee's ``log_prob_fn`` with
    ``vectorize=True``): ``theta``, or with ``coordinates`` its sampled entries (the others
    integrated out by the prepared ``noise``).

    ``one(coords)`` is the JAX function of one row's log-posterior; calls compute the same
    as two ``vmap``-ed, compiled functions (the residuals, then likelihood and priors) for
    ``batch`` rows (half the ensemble: emcee's red-blue moves), padding the last chunk, so
    they compile once. Compilations are shared by every instance for the same problem, noise
    model, priors, batch and coordinates. A call returns the log-posteriors; :meth:`rows`
    also the statistics (emcee's blobs).

    Args:
        problem: the problem sampled.
        noise: a prepared noise model (:meth:`~fitstiff.inference.likelihood.NoiseModel.prepared`).
        priors: the priors.
        batch: rows per compiled call.
        coordinates: the sampled coordinates (default: all of ``theta``).
        centre: the ``theta`` ``noise`` was prepared at (the least-squares optimum). Given,
            the pressure series of a closed-form chamber are evaluated as polynomials in
            ``n`` around it (:class:`~fitstiff.inference.closed_series.ClosedFormLikelihood`, when
            the model and the noise model allow): the same values to rounding, only the force
            residuals computed per row. None: every series from the residuals.

    Attributes:
        blobs: the number of statistics per row after its log-posterior: with linear
            nuisances integrated out (``coordinates.linear``), ``k + S``, their
            :meth:`~fitstiff.inference.likelihood._Quadratic.linear_statistics` (what their
            conditional draws need); else 0.
    """

    def __init__(self, problem: Problem, noise: NoiseModel, priors: Priors, *, batch: int,
                 coordinates: Coordinates | None = None, centre: np.ndarray | None = None):
        layout = Layout.from_problem(problem)
        self.problem, self.noise, self.priors, self.batch = problem, noise, priors, batch
        self.coordinates = coordinates
        self.closed = (None if centre is None
                       else ClosedFormLikelihood.of(problem, noise, centre, layout))
        self.blobs = (0 if coordinates is None or coordinates.linear is None
                      else coordinates.linear.index.size + len(layout.series))

        options = dict(noise=noise, priors=priors, layout=layout, coordinates=coordinates,
                       closed=self.closed)

        def one(coords):
            return _given(problem, _row_residuals(problem, coords, **options), coords,
                          **options)[0]

        self.one = one
        self._fn = problem.compiled(_log_posterior_rows, **options)

    def __call__(self, coords: np.ndarray) -> np.ndarray:
        return self.rows(coords)[:, 0]

    def rows(self, coords: np.ndarray) -> np.ndarray:
        """``(rows, 1 + blobs)``: each row's log-posterior, then its :attr:`blobs`
        statistics (emcee's ``log_prob_fn`` returning blobs)."""
        return batched(self._fn, np.asarray(coords, dtype=float), batch=self.batch)


def _full(coordinates: Coordinates | None, coords):
    return coords if coordinates is None else coordinates.full(coords)


def _row_residuals(p: Problem, coords, *, coordinates: Coordinates | None,
                   closed: ClosedFormLikelihood | None, **_):
    """The residuals the log-posterior of one row needs: all, or with ``closed`` those of
    its channels computed from the model."""
    theta = _full(coordinates, coords)
    return p.residuals(theta) if closed is None else p.residuals(theta, channels=closed.channels)


def _given(p: Problem, residuals, coords, *, noise: NoiseModel, priors: Priors,
           layout: Layout, coordinates: Coordinates | None,
           closed: ClosedFormLikelihood | None):
    """``[log-posterior, statistics...]`` of one row of sampled coordinates, given its
    :func:`_row_residuals` (the statistics: :attr:`LogPosterior.blobs`)."""
    theta = _full(coordinates, coords)
    linear = coordinates is not None and coordinates.linear is not None
    if closed is not None:
        likelihood, statistics = closed.solved_likelihood(p, residuals, theta)
    elif linear:
        likelihood, statistics = noise.solved_likelihood(residuals, layout)
    else:
        likelihood = noise.log_likelihood(residuals, layout)
    lp = likelihood + priors.log_density(p.physical(theta)) + p.log_jacobian(theta)
    lp = jnp.where(jnp.isnan(lp), -jnp.inf, lp)
    return jnp.concatenate([lp[None], statistics]) if linear else lp[None]


def _log_posterior_rows(p: Problem, rows, **options):
    """Log-posteriors of rows of sampled coordinates: the residuals of every row, then the
    likelihood and priors. The residuals are computed apart (:func:`~fitstiff._jax.computed_apart`):
    fused into the likelihood they cost twice the time of the two apart (four logs of
    35 000 samples, 16 rows: 24 ms fused, 5.9 + 5.1 ms apart; the force residuals of one
    4 000-sample log with its pressures in closed form, 32 rows: 2.0 against 0.6 ms); one
    compiled call instead of two saves a dispatch per step."""
    residuals = computed_apart(jax.vmap(lambda c: _row_residuals(p, c, **options))(rows))
    return jax.vmap(lambda r, c: _given(p, r, c, **options))(residuals, rows)


def physical_rows(p: Problem, rows):
    """SI values of every entry for each row of ``theta`` (``rows``: one per draw)."""
    return jax.vmap(p.physical)(rows)


def derived_rows(p: Problem, rows):
    """The derived quantities (:data:`~fitstiff.physics.derived.DERIVED`, in order) of each
    row of ``theta``."""
    return jax.vmap(lambda th: jnp.stack([_derived(p, th)[k] for k in DERIVED]))(rows)


def force_rows(p: Problem, rows):
    """The predicted force of every group's logs, flattened, for each row of ``theta``."""
    return jax.vmap(lambda theta: jnp.concatenate(
        [pred.force.ravel() for pred in p.predictions(theta)]))(rows)


def batched(fn: Callable, rows: np.ndarray, *, batch: int) -> np.ndarray:
    """``fn`` (compiled for ``batch`` rows) over all ``rows``, padding the last chunk."""
    n = rows.shape[0]
    if n == batch:                     # a sampler's call: no copies
        return np.asarray(fn(rows))
    padded = np.concatenate([rows, np.repeat(rows[-1:], (-n) % batch, axis=0)])
    out = [np.asarray(fn(padded[i:i + batch]))
           for i in range(0, padded.shape[0], batch)]
    return np.concatenate(out)[:n]


def residuals_at(problem: Problem, theta: np.ndarray) -> np.ndarray:
    """The problem's whitened residuals at ``theta`` (its compiled function), as NumPy."""
    fn = problem.compiled(Problem.residuals)
    return np.asarray(fn(jnp.asarray(theta)))


def _derived(problem: Problem, theta) -> dict[str, jnp.ndarray]:
    model, _ = problem.unpack(theta)
    return derived_quantities(model, problem.drives[0])
