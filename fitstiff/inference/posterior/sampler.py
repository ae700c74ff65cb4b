"""The emcee driver: :func:`sample_posterior` starts the walkers around the least-squares
optimum, runs the chain in chunks until it has converged, and collects the samples, derived
quantities and predictive draws."""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence

import emcee
import numpy as np

from fitstiff._jax import jax, jnp, release_compiled
from fitstiff.errors import InputError
from fitstiff.inference import likelihood
from fitstiff.inference.fitting import FitResult, fit_problem
from fitstiff.inference.likelihood import Layout, NoiseModel
from fitstiff.inference.posterior.chain import ChainStore, signature
from fitstiff.inference.posterior.convergence import Check, run_chunks
from fitstiff.inference.posterior.density import (DEFAULT_NOISE_MODEL, DERIVED_BATCH,
                                                  Coordinates, LogPosterior, batched,
                                                  derived_rows, force_rows, integrated_entries,
                                                  physical_rows, prepared_noise, residuals_at)
from fitstiff.inference.posterior.result import DEFAULT_MOVES, Diagnostics, Posterior
from fitstiff.inference.priors import Prior, Priors
from fitstiff.inference.problem import Problem
from fitstiff.inference.selection import Selection
from fitstiff.io.guards import nonfinite_error
from fitstiff.io.log import Log
from fitstiff.physics.derived import DERIVED
from fitstiff.physics.model import Model

__all__ = ["MOVES", "sample_posterior", "disagreements"]

#: emcee proposals (``moves``): name -> factory of emcee's ``moves`` argument
MOVES: dict[str, Callable[[], list]] = {
    "de": lambda: [(emcee.moves.DEMove(), 1.0)],
    "de+snooker": lambda: [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)],
    "stretch": lambda: [(emcee.moves.StretchMove(), 1.0)],
}
_BALL = 0.1                 # start ball: this times the Laplace standard deviations
_BALL_FLOOR = 1e-4          # ... and at least this in theta units (undetermined directions)
_BURN_IN_TAUS = 5.0
_DISAGREEMENT = 4.0         # posterior median vs least squares, in combined standard deviations
_PREDICTIVE_BATCH = 25
_PREDICTIVE_POINTS = 2000   # at most this many samples per log in the predictive file


# -- the sampler ------------------------------------------------------------------------------
# long: its docstring documents its 20 options; the body is the sampler's phases in order
def sample_posterior(logs_or_fit: Sequence[Log] | FitResult, model: Model | str | None = None,
                     *, fix: Mapping[str, float | None] | Iterable[str] = (),
                     fit_options: Mapping[str, object] | None = None,
                     noise_model: str | NoiseModel = DEFAULT_NOISE_MODEL,
                     priors: Mapping[str, Prior | Mapping[str, object]] | str | os.PathLike
                     | None = None,
                     walkers: int = 32, steps: int = 20_000, tau_multiple: float = 50.0,
                     check_every: int = 500, thin: int | None = None, seed: int = 0,
                     backend: str | os.PathLike | None = None, resume: bool = False,
                     progress: bool | None = None, draws: int = 200,
                     moves: str = DEFAULT_MOVES, integrate_offsets: bool = True,
                     release: bool = False,
                     interrupted: Callable[[], bool] | None = None) -> Posterior:
    """Sample the posterior of ``model`` given ``logs`` with emcee.

    Args:
        logs_or_fit: loaded logs (then ``model`` is required and least squares runs first),
            or a :class:`~fitstiff.inference.fitting.FitResult` to start from (its problem is
            sampled).
        model: spec string or built model (with logs).
        fix: parameters to hold, as in :func:`~fitstiff.inference.fitting.fit`.
        fit_options: keyword arguments of :func:`~fitstiff.inference.fitting.fit` (the problem's
            :class:`~fitstiff.inference.selection.Selection`'s fields and solver options).
        noise_model: ``"ar1"`` (default), ``"gaussian"``, ``"student_t"`` or an instance
            from :mod:`fitstiff.inference.likelihood`.
        priors: overrides of the default priors (:mod:`fitstiff.inference.priors`): a mapping or the
            path of a JSON file.
        walkers: ensemble size, at least twice the number of sampled coordinates.
        steps: the step cap (total, including steps of a resumed run).
        tau_multiple: required chain length in autocorrelation times.
        check_every: steps between convergence checks.
        thin: keep every ``thin``-th step (default: half the largest autocorrelation time).
        seed: seeds the start ball, the sampler and the choice of predictive draws.
        backend: HDF5 file for the chain
            (:class:`~fitstiff.inference.posterior.chain.ChainBackend`); ``None`` keeps it in
            memory.
        resume: continue the chain stored in ``backend``.
        progress: progress bar on stderr; ``None``: when stderr is a terminal.
        draws: number of posterior draws of the model force kept for the report.
        moves: emcee proposal, a key of :data:`MOVES` (``"de"``: differential evolution,
            the default; ``"stretch"``: emcee's default stretch move).
        integrate_offsets: integrate the per-log force offsets out analytically instead of
            sampling them (``gaussian`` and ``ar1`` noise, flat offset priors; otherwise they
            are sampled). Their samples are then exact draws from their conditional
            posterior given each sampled step.
        release: free JAX's compiled functions between the phases (fit, noise settings,
            sampling, summaries; :func:`fitstiff._jax.release_compiled`): each phase's
            compilations are needed in it alone, and kept they add up (the default 4-log
            posterior: 985 MB peak resident kept, 563-585 MB released). Every jitted
            function of the process is traced and compiled again on its next call, which
            without a persistent compilation cache costs seconds (``fitstiff posterior``
            releases; it has the cache).
        interrupted: asked after every step; ``True`` stops the run with
            :class:`KeyboardInterrupt`, the chain so far kept in ``backend`` (the command
            line's signal handlers: a signal's exception raised while a garbage-collection
            callback runs is dropped by Python, and the run went on).

    Returns:
        A :class:`Posterior`; ``diagnostics.converged`` is False (with the reason) when the
        convergence rules were not met within ``steps``.
    """
    _check_options(walkers=walkers, steps=steps, tau_multiple=tau_multiple,
                   check_every=check_every, thin=thin, draws=draws)
    if resume and backend is None:
        raise InputError(None, "resume", "needs a chain file", "give backend (--out DIR)")
    problem, fit_result = _problem(logs_or_fit, model, fix, fit_options or {})
    noise = likelihood.noise_model(noise_model)
    prior_set = Priors(problem, priors)
    if moves not in MOVES:
        raise InputError(None, f"--moves {moves}", "unknown proposal",
                         f"use one of: {', '.join(MOVES)}")
    layout = Layout.from_problem(problem)
    integrated = integrated_entries(problem, noise, prior_set, integrate_offsets)
    sampled = [n for i, n in enumerate(problem.names) if i not in set(integrated)]
    if walkers < 2 * len(sampled):
        raise InputError(None, f"--walkers {walkers}",
                         f"fewer than twice the {len(sampled)} sampled coordinates "
                         f"({', '.join(sampled)})",
                         f"give --walkers {2 * len(sampled) + 2} or more")
    stored_as = signature(problem, noise, prior_set, walkers) | {
        "moves": moves, "integrated": [problem.names[i] for i in integrated]}
    store = ChainStore(backend) if backend is not None else None
    seeds = np.random.SeedSequence(seed).spawn(3)
    warnings: list[str] = []

    if resume:
        noise, theta_start = store.resume(stored_as)
        fit_result = None
    else:
        if fit_result is None:
            fit_result = fit_problem(problem, **_solver_options(fit_options or {}))
            if release:
                release_compiled()
        warnings += _start_warnings(fit_result)
        theta_start = np.asarray(fit_result.theta)
    coordinates = Coordinates.of(problem, theta_start, integrated, layout)
    noise, turning = prepared_noise(problem, noise, theta_start, layout, linear=coordinates.linear)
    if release:
        release_compiled()
    if turning.columns.shape[1] and getattr(noise, "marginal", None) is None:
        warnings.append(f"the {noise.name} noise model leaves the displacement errors at the "
                        "turning points out: intervals may be too narrow")
    log_prob = LogPosterior(problem, noise, prior_set, batch=(walkers + 1) // 2,
                            coordinates=coordinates, centre=theta_start)
    emcee_backend = store.backend if store else emcee.backends.Backend()
    if not resume:
        emcee_backend.reset(walkers, coordinates.sampled.size)
        if store:
            store.write_settings(stored_as, settings=noise, theta_start=theta_start)
    sampler = emcee.EnsembleSampler(walkers, coordinates.sampled.size,
                                    log_prob.rows if log_prob.blobs else log_prob,
                                    vectorize=True, backend=emcee_backend,
                                    moves=MOVES[moves]())
    state = (sampler.get_last_sample() if resume else
             _start_state(fit_result, problem, log_prob, walkers, prior_set, seeds))
    try:
        check = run_chunks(sampler, state, names=coordinates.names(problem), steps=steps,
                            tau_multiple=tau_multiple, check_every=check_every,
                            progress=sys.stderr.isatty() if progress is None else progress,
                            interrupted=interrupted)
    finally:
        if store:
            store.backend.flush()      # also when interrupted: no sampled step is lost
    if release:
        release_compiled()
    return _collect(problem, sampler, check, noise=noise, layout=layout, priors=prior_set,
                    coordinates=coordinates, fit=fit_result, thin=thin, draws=draws,
                    tau_multiple=tau_multiple, moves=moves,
                    rng=np.random.default_rng(seeds[2]), warnings=warnings, store=store)


def _start_warnings(fit_result: FitResult) -> list[str]:
    """What a posterior started from ``fit_result`` must say about its start."""
    warnings = []
    if not fit_result.converged:
        warnings.append(f"the least-squares start did not converge "
                        f"({fit_result.message}); the burn-in may be long")
    if not fit_result.identifiability.identifiable:
        ident = fit_result.identifiability
        warnings.append(f"the data do not identify the seal: {ident.reason} The posterior "
                        f"of {', '.join(ident.parameters + ident.derived)} reflects the "
                        "prior and the model's assumptions, not a measurement")
    return warnings


def _start_state(fit_result: FitResult, problem: Problem, log_prob: LogPosterior, walkers: int,
                 prior_set: Priors, seeds) -> emcee.State:
    """The walkers' start around the fit (``seeds[0]`` draws the ball, ``seeds[1]`` seeds
    the sampler), with their log-posteriors and blobs."""
    coords, rows = _start(fit_result, problem, log_prob, walkers,
                          np.random.default_rng(seeds[0]), prior_set)
    return emcee.State(coords, log_prob=rows[:, 0],
                       blobs=rows[:, 1:] if log_prob.blobs else None,
                       random_state=np.random.RandomState(
                           np.random.MT19937(seeds[1])).get_state())


def _check_options(**options) -> None:
    flags = {"walkers": "--walkers", "steps": "--steps", "tau_multiple": "--tau-multiple",
             "check_every": "--check-every", "thin": "--thin", "draws": "--draws"}
    for key, value in options.items():
        if value is None and key == "thin":
            continue
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 1):
            raise InputError(None, f"{flags[key]} {value}", "must be at least 1",
                             "give a positive number")


def _problem(logs_or_fit, model, fix, fit_options) -> tuple[Problem, FitResult | None]:
    if isinstance(logs_or_fit, FitResult):
        if model is not None or fix or fit_options:
            raise InputError(None, "model, fix, fit_options",
                             "are given with a fit, which has them already",
                             "pass the fit alone, or the logs with these options")
        return logs_or_fit.problem, logs_or_fit
    if model is None:
        raise InputError(None, "model", "none given", "give a spec such as 'chamber+dahl'")
    selection, _ = Selection.pick(fit_options)
    return Problem(list(logs_or_fit), model, fix=fix, selection=selection), None


def _solver_options(fit_options: Mapping[str, object]) -> dict[str, object]:
    return Selection.pick(fit_options)[1]


def _start(fit: FitResult, problem: Problem, log_prob: LogPosterior, walkers: int,
           rng: np.random.Generator, priors: Priors) -> tuple[np.ndarray, np.ndarray]:
    """Walkers in a ball around the least-squares optimum (0.1 x its Laplace covariance),
    in the sampled coordinates of ``log_prob``, and their :meth:`LogPosterior.rows`."""
    theta = np.asarray(fit.theta, dtype=float)
    sampled = (np.arange(theta.size) if log_prob.coordinates is None
               else log_prob.coordinates.sampled)
    if not np.isfinite(log_prob(theta[None, sampled])[0]):
        density = np.asarray(priors.log_densities(problem.physical(jnp.asarray(theta))))
        outside = [n for n, d in zip(problem.names, density) if not np.isfinite(d)]
        if outside:
            raise InputError(None, "--priors", "the least-squares optimum has zero prior "
                             f"density in {', '.join(outside)}", "widen those priors")
        raise nonfinite_error(problem.logs, "the log-posterior at the least-squares optimum")
    jac = np.asarray(jax.jacfwd(problem.physical)(jnp.asarray(theta)))
    cov = np.nan_to_num(np.asarray(fit.covariance, dtype=float))
    inv = np.linalg.pinv(jac)
    cov_theta = (inv @ cov @ inv.T)[np.ix_(sampled, sampled)]
    w, v = np.linalg.eigh(0.5 * (cov_theta + cov_theta.T))
    root = v * np.sqrt(np.clip(w, 0.0, None))
    sd_floor = _BALL_FLOOR / _BALL
    theta = theta[sampled]
    coords = np.empty((walkers, theta.size))
    rows = np.full((walkers, 1 + log_prob.blobs), -np.inf)
    for _ in range(100):
        bad = ~np.isfinite(rows[:, 0])
        if not bad.any():
            return coords, rows
        z = rng.standard_normal((int(bad.sum()), theta.size))
        coords[bad] = theta + _BALL * (z @ root.T + sd_floor * rng.standard_normal(z.shape))
        rows[bad] = log_prob.rows(coords[bad])
    raise nonfinite_error(problem.logs, "the log-posterior around the least-squares optimum "
                          "(no place for the walkers)")


# -- after sampling ---------------------------------------------------------------------------
def _collect(problem: Problem, sampler: emcee.EnsembleSampler, check: Check, *,
             noise: NoiseModel, layout: Layout, priors: Priors, coordinates: Coordinates,
             fit: FitResult | None, thin: int | None, draws: int, tau_multiple: float,
             moves: str, rng: np.random.Generator, warnings: list[str],
             store: ChainStore | None) -> Posterior:
    n, walkers = check.steps, sampler.nwalkers
    tau_max = float(np.nanmax(check.tau)) if np.isfinite(check.tau).any() else float(n)
    discard = min(math.ceil(_BURN_IN_TAUS * tau_max), n // 2)
    kept = n - discard
    if thin is not None and thin > kept:
        raise InputError(None, f"--thin {thin}", f"keeps no step of the {kept} after the burn-in",
                         f"give --thin {kept} or less")
    thin = thin or max(1, int(tau_max // 2))
    coords = sampler.get_chain(discard=discard, thin=thin)
    log_prob = sampler.get_log_prob(discard=discard, thin=thin)
    blobs = sampler.get_blobs(discard=discard, thin=thin)
    flat = _full_thetas(noise, layout, coordinates, coords.reshape(-1, coords.shape[-1]),
                        None if blobs is None else blobs.reshape(-1, blobs.shape[-1]), rng)
    thetas = flat.reshape(coords.shape[:2] + flat.shape[-1:])
    physical = problem.compiled(physical_rows)
    samples = batched(physical, flat, batch=DERIVED_BATCH).reshape(thetas.shape)
    derived_fn = problem.compiled(derived_rows)
    derived_values = batched(derived_fn, flat, batch=DERIVED_BATCH)
    derived = {k: derived_values[:, i].reshape(thetas.shape[:2]) for i, k in enumerate(DERIVED)}
    tau = dict(zip(coordinates.names(problem), map(float, check.tau)))
    integrated = tuple(n for n in problem.names if n not in tau)
    acceptance = np.asarray(sampler.acceptance_fraction)
    diagnostics = Diagnostics(
        acceptance_fraction=float(np.mean(acceptance)),
        acceptance_fraction_min=float(np.min(acceptance)), autocorr_time=tau,
        effective_samples={k: walkers * kept / t for k, t in tau.items()},
        converged=check.converged, reason=check.reason, steps=n, walkers=walkers,
        discard=discard, thin=thin, tau_multiple=tau_multiple, noise_model=noise.name,
        integrated=integrated, moves=moves)
    if not check.converged:
        warnings.append(f"the chain did not converge: {check.reason}")
    if fit is not None and check.converged:
        warnings.extend(disagreements(fit, derived, noise.name))
    if store is not None:
        store.write_kept(thetas)
    best = flat[int(np.argmax(log_prob.ravel()))]
    predictive, scale = _predictive(problem, noise, layout, flat, best, draws=draws, rng=rng)
    return Posterior(problem=problem, names=tuple(problem.names), samples=samples,
                     log_prob=log_prob, derived=derived, noise=noise, noise_scale=scale,
                     priors=priors, diagnostics=diagnostics, predictive=predictive, fit=fit,
                     warnings=tuple(warnings))


def disagreements(fit: FitResult, derived: Mapping[str, np.ndarray],
                  noise_name: str) -> list[str]:
    """Where the converged posterior's median of the slope or the breakaway sits more than
    :data:`_DISAGREEMENT` combined standard deviations from the least-squares value: on
    misspecified data the estimate depends on how the residuals are weighted (the noise
    model's whitening against least squares' per-log noise), and neither interval covers
    that model error. Says so instead of offering two precise-looking answers."""
    out = []
    for key in ("presliding_slope_N_per_mm", "breakaway_N"):
        values = np.asarray(derived[key]).ravel()
        value, err = fit.derived.get(key, (math.nan, math.nan))
        if not (np.isfinite(values).any() and math.isfinite(value)):
            continue
        median, sd = float(np.nanmedian(values)), float(np.nanstd(values))
        scale = math.hypot(err if math.isfinite(err) else 0.0, sd)
        if scale > 0 and abs(median - value) > _DISAGREEMENT * scale:
            out.append(f"the posterior and least squares disagree on {key}: {median:.4g} "
                       f"(posterior median, {noise_name} noise) against {value:.4g} +- "
                       f"{err:.2g} ({abs(median - value) / scale:.0f} combined standard "
                       "deviations). The chain converged, so this is not the sampler: the "
                       "model does not describe these logs and its estimates depend on how "
                       "the residuals are weighted; quote neither interval, find the missing "
                       "effect with fitstiff diagnose")
    return out


def _full_thetas(noise: NoiseModel, layout: Layout, coordinates: Coordinates,
                 coords: np.ndarray, blobs: np.ndarray | None,
                 rng: np.random.Generator) -> np.ndarray:
    """Full ``theta`` rows of sampled ``coords``: the integrated entries drawn from their
    conditional posterior given each row
    (:meth:`~fitstiff.inference.likelihood._Quadratic.linear_draws`) from the row's ``blobs``
    (:attr:`LogPosterior.blobs`, stored by the sampler)."""
    full = np.repeat(coordinates.base[None], coords.shape[0], axis=0)
    full[:, coordinates.sampled] = coords
    linear = coordinates.linear
    if linear is None:
        return full
    dof = noise.dof(layout)
    normal = rng.standard_normal((coords.shape[0], noise.marginal.series.size))
    chi2 = rng.chisquare(np.maximum(dof, 1), size=(coords.shape[0], dof.size))
    full[:, linear.index] += noise.linear_draws(blobs, normal, chi2)
    return full


def _predictive(problem: Problem, noise: NoiseModel, layout: Layout, flat: np.ndarray,
                best: np.ndarray, *, draws: int, rng: np.random.Generator):
    """Model-force draws per log (thinned to at most ``_PREDICTIVE_POINTS`` samples), the
    median and spread of the draws at every sample, and the noise level per series at the
    most probable sample."""
    fn = problem.compiled(force_rows)
    pick = rng.choice(flat.shape[0], size=min(draws, flat.shape[0]), replace=False)
    curves = batched(fn, flat[np.sort(pick)], batch=_PREDICTIVE_BATCH)
    whitened = np.asarray(noise.series_scale(jnp.asarray(residuals_at(problem, best)), layout))
    arrays: dict[str, np.ndarray] = {"log_names": np.array([g.name for g in problem.logs])}
    scale: dict[str, tuple[float, str]] = {}
    offset = 0
    for s, entry in enumerate(layout.series):
        log = problem.logs[entry.log]
        if entry.channel != "force":
            sd = whitened[s] * problem.pressure_noise[entry.log][entry.channel[-1]]
            scale[layout.labels[s]] = (float(sd), "Pa")
            continue
        length = entry.span.stop - entry.span.start
        n = len(log)
        step = max(1, math.ceil(n / _PREDICTIVE_POINTS))
        sd = float(whitened[s] * problem.force_noise[entry.log])
        scale[layout.labels[s]] = (sd, "N")
        prefix = f"log{entry.log}_"
        arrays[prefix + "time_s"] = (np.asarray(log.time)[::step] if log.time is not None
                                     else np.arange(n)[::step].astype(float))
        arrays[prefix + "displacement_mm"] = np.asarray(log.displacement)[::step] * 1e3
        arrays[prefix + "model_displacement_mm"] = \
            np.asarray(problem.drives[entry.log].displacement)[::step] * 1e3
        arrays[prefix + "force_N"] = np.asarray(log.force)[::step]
        arrays[prefix + "model_force_draws_N"] = \
            curves[:, offset:offset + n][:, ::step].astype(np.float32)
        # every sample: the median model force over the draws and their spread (the report's
        # central curve and, with the noise level, its 90 % predictive band)
        arrays[prefix + "model_force_median_N"] = np.median(curves[:, offset:offset + n], axis=0)
        arrays[prefix + "model_force_spread_N"] = np.std(curves[:, offset:offset + n], axis=0)
        arrays[prefix + "noise_sd_N"] = np.asarray(sd)
        offset += length
    arrays["draw_index"] = np.sort(pick)
    return arrays, scale
