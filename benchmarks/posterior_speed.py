"""Posterior speed: the vectorised JAX log-posterior against a NumPy one, in the same run.

The 4 000-sample ``chamber+dahl`` log of :mod:`fitstiff._testing.speed` (paper cylinder, 6 bar,
realistic noise), fitted by least squares, then:

- **fitstiff**: :class:`fitstiff.inference.posterior.LogPosterior` (default AR(1) noise model,
  default priors, transforms' log-Jacobians) evaluated on 32 walkers at once: one compiled,
  ``vmap``-ed call, the two pressure series in closed form (:mod:`fitstiff.inference.closed_series`:
  quadratic forms in the coefficients of their polynomials in ``n``), the force series from
  residuals. Each round times two blocks of ``--calls`` consecutive calls (per call: their mean)
  after the reference's block: the first block (``speedup_cold``) starts right after the
  reference's ~50 ms of single-threaded Python, the second (``speedup``) follows it, warm, as a
  sampler's calls follow each other. Timed one by one, the first calls after the reference
  took 1.8 ms falling to 1.2 ms by the 20th, against 0.9 ms warm (the second core idles during
  the reference and XLA splits the large loops over both; pinned to one core the first call
  took 1.8 ms and those from the third 1.25-1.3 ms), and inside ``sample_posterior`` the 16-walker calls took 0.58 ms
  (median of 6 000), the warm rate: the cold block measures the benchmark's alternation, not
  the sampler.
- **sampler**: emcee's ensemble sampler with fitstiff's moves
  (:data:`~fitstiff.inference.posterior.MOVES`) and
  :class:`~fitstiff.inference.posterior.LogPosterior` on half the ensemble per call, as
  :func:`~fitstiff.inference.posterior.sample_posterior` runs it, ``--sampler-steps`` steps timed:
  log-posterior evaluations per second of a running chain (the proposals and emcee's own
  work included), against the same reference rate (``sampler_speedup``).
- **reference**: the same log-posterior as a user would write it with NumPy: the per-sample
  loop of :func:`fitstiff._testing.speed.reference_residuals` (exact Dahl step, exact polytropic
  chamber) called once per walker, the same AR(1) likelihood with the turning-point errors
  integrated out, priors and Jacobians. Both give the same values up to one constant over the
  walkers (checked: the run stops if the difference varies by more than 1e-3). The two are
  timed in interleaved rounds and the speedup is the median of the rounds' ratios.
- **full run**: :func:`fitstiff.inference.posterior.sample_posterior` from the fit, 32 walkers x 5
  000 steps with an HDF5 chain (compilation, sampling, derived quantities and draws included).

    python benchmarks/posterior_speed.py [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import emcee
import numpy as np

from fitstiff._testing.speed import make_log, reference_log_posterior
from fitstiff.inference.fitting import fit_problem
from fitstiff.inference.posterior import DEFAULT_MOVES, MOVES, log_posterior, sample_posterior
from fitstiff.inference.problem import Problem

WALKERS = 32
REFERENCE_WALKERS = 8       # reference evaluations per round (scaled to WALKERS)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--steps", type=int, default=5000)
    parser.add_argument("--calls", type=int, default=20,
                        help="consecutive fitstiff calls per timed block (default 20)")
    parser.add_argument("--sampler-steps", type=int, default=1000,
                        help="emcee steps timed for the sampler's rate (default 1000)")
    parser.add_argument("--json", metavar="FILE")
    args = parser.parse_args()
    log = make_log()
    problem = Problem([log], "chamber+dahl")
    fit = fit_problem(problem)
    lp = log_posterior(fit, batch=WALKERS)
    rng = np.random.default_rng(0)
    coords = fit.theta + 1e-3 * rng.standard_normal((WALKERS, problem.size))
    t0 = time.perf_counter()
    jax_values = lp(coords)
    compile_s = time.perf_counter() - t0
    ref_values = np.array([reference_log_posterior(c, problem, lp.noise) for c in coords])
    # interleaved: each round times one fitstiff call on the 32 walkers and the reference on
    # REFERENCE_WALKERS of them (scaled to 32); the speedup is the median of the rounds'
    # ratios, so a change of the host's speed during the run (other tenants: the same
    # commit measured 9 000 to 16 000 fitstiff evaluations/s in sequential runs) cancels
    # fitstiff is timed in two blocks of --calls consecutive calls per round (per call:
    # their mean): right after the reference (cold) and then warm, as a sampler calls it
    cold_times, jax_times, ref_times = [], [], []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        for c in coords[:REFERENCE_WALKERS]:
            reference_log_posterior(c, problem, lp.noise)
        ref_times.append((time.perf_counter() - t0) * WALKERS / REFERENCE_WALKERS)
        for times in (cold_times, jax_times):
            t0 = time.perf_counter()
            for _ in range(args.calls):
                lp(coords)
            times.append((time.perf_counter() - t0) / args.calls)
    ratios = np.array(ref_times) / np.array(jax_times)
    cold_ratios = np.array(ref_times) / np.array(cold_times)
    jax_s, ref_s = float(np.median(jax_times)), float(np.median(ref_times))
    sampler_rate = _sampler_rate(fit, coords, steps=args.sampler_steps)
    # log-posteriors are defined up to a constant (both drop different normalisations):
    # the two must differ by the same constant for every walker
    difference = ref_values - np.asarray(jax_values)
    agree = float(np.ptp(difference))
    if not agree < 1e-3:
        raise SystemExit(f"the NumPy and JAX log-posteriors disagree: their difference varies "
                         f"by {agree:.3g} over the walkers (must be a constant)")
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        # one convergence check, at the end: the chain is exactly --steps long
        post = sample_posterior(fit, walkers=WALKERS, steps=args.steps, check_every=args.steps,
                                seed=1, progress=False, backend=Path(tmp) / "chain.h5")
        run_s = time.perf_counter() - t0
    report = {
        "samples": len(log),
        "walkers": WALKERS,
        "fitstiff_evals_per_s": WALKERS / jax_s,
        "reference_evals_per_s": WALKERS / ref_s,
        "speedup": float(np.median(ratios)),
        "speedup_rounds_q10_q90": [float(np.quantile(ratios, 0.1)),
                                   float(np.quantile(ratios, 0.9))],
        "speedup_cold": float(np.median(cold_ratios)),
        "speedup_cold_rounds_q10_q90": [float(np.quantile(cold_ratios, 0.1)),
                                        float(np.quantile(cold_ratios, 0.9))],
        "fitstiff_cold_evals_per_s": WALKERS / float(np.median(cold_times)),
        "sampler_evals_per_s": sampler_rate,
        "sampler_speedup": sampler_rate / (WALKERS / ref_s),
        "sampler_steps": args.sampler_steps,
        "rounds": args.repeats,
        "fitstiff_calls_per_block": args.calls,
        "difference_spread_log_posterior": agree,
        "fitstiff_first_call_s_incl_compile": compile_s,
        "full_run_steps": post.diagnostics.steps,
        "full_run_s": run_s,
        "full_run_ms_per_step": 1e3 * run_s / post.diagnostics.steps,
        "full_run_converged": post.diagnostics.converged,
        "full_run_reason": post.diagnostics.reason,
        "reference_full_run_s_estimate": args.steps * WALKERS / (WALKERS / ref_s),
    }
    for k, v in report.items():
        print(f"{k:36s} {v}")
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2))


def _sampler_rate(fit, coords: np.ndarray, *, steps: int) -> float:
    """Log-posterior evaluations per second of an emcee chain run as ``sample_posterior``
    runs it (fitstiff's moves, half the ensemble per call), from ``coords``."""
    half = log_posterior(fit, batch=WALKERS // 2)
    sampler = emcee.EnsembleSampler(WALKERS, coords.shape[1], half, vectorize=True,
                                    moves=MOVES[DEFAULT_MOVES]())
    sampler.run_mcmc(coords, 50, progress=False)              # compiled, warm
    t0 = time.perf_counter()
    sampler.run_mcmc(None, steps, progress=False)
    return WALKERS * steps / (time.perf_counter() - t0)


if __name__ == "__main__":
    main()
