"""When an emcee chain has converged: the rules
:func:`fitstiff.inference.posterior.sample_posterior` stops by, and the chunked run that checks
them.

The chain runs in chunks of ``check_every`` steps (:func:`run_chunks`). After each chunk the
integrated autocorrelation time of every coordinate is estimated (emcee's estimator,
``tol=0`` so it never raises) and the run stops when all of (:func:`check_convergence`): the
chain is longer than ``tau_multiple`` times the largest time; every time changed since the
previous check by less than 5 % or three standard deviations of the estimate's change on a
stationary chain (:func:`tau_change_sd`); the mean acceptance fraction is at least 0.05 and no
walker accepts less than a fifth of the median walker. Checks fall on absolute step numbers,
so a resumed run stops where an uninterrupted one would.

A strict 5 % is below the estimator's noise at 50-90 times: on a stationary chain of the demo
logs (tau about 22, 32 walkers, seven coordinates) the change between checks 500 steps apart
(at 1 500 and 2 000 steps, 31 windows) had an rms of 6.7 % (5.6 % predicted by
:func:`tau_change_sd`); 5 % failed 90 % of these checks, two standard deviations 35 %, three
none.
"""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Callable, Sequence

import emcee
import numpy as np

from fitstiff.interrupts import deferred

__all__ = ["Check", "check_convergence", "integrated_time", "run_chunks", "tau_change_sd"]

_TAU_STABLE = 0.05          # the autocorrelation times may change by this between checks,
_TAU_NOISE_SDS = 3.0        # ... or by this many standard deviations of the estimate's change
_MIN_ACCEPTANCE = 0.05
_STUCK_FRACTION = 0.2


@dataclasses.dataclass(frozen=True)
class Check:
    converged: bool
    reason: str
    tau: np.ndarray
    steps: int


def run_chunks(sampler: emcee.EnsembleSampler, state, *, names: Sequence[str], steps: int,
                tau_multiple: float, check_every: int, progress: bool,
                interrupted: Callable[[], bool] | None = None) -> Check:
    """Run until the convergence rules hold or ``steps`` is reached; checks at multiples of
    ``check_every`` (absolute step numbers, so a resumed run stops where an uninterrupted
    one would). ``interrupted`` is asked after every step; ``True`` raises
    :class:`KeyboardInterrupt` there (the steps so far are in the sampler's backend)."""
    from tqdm.auto import tqdm

    done = sampler.iteration
    check = check_convergence(sampler, names, tau_multiple, check_every) if done else None
    # under the command line a signal is only recorded here, and ``interrupted`` reports it
    # after the step: raised inside the log-posterior, emcee printed its traceback
    with deferred(), tqdm(total=steps, initial=done, disable=not progress, desc="posterior",
                          unit="step", file=sys.stderr) as bar:
        while not (check and check.converged) and done < steps:
            stop = min(steps, (done // check_every + 1) * check_every)
            for latest in sampler.sample(state, iterations=stop - done, store=True):
                bar.update(1)
                if interrupted is not None and interrupted():
                    raise KeyboardInterrupt
            state = latest
            done = stop
            check = check_convergence(sampler, names, tau_multiple, check_every)
            bar.set_postfix_str(f"need {tau_multiple:g} tau = "
                                f"{tau_multiple * np.nanmax(check.tau):.0f} steps")
    if not check.converged and done >= steps:
        check = dataclasses.replace(check, reason=f"reached the step cap (--steps {steps}): "
                                                  f"{check.reason}")
    return check


def integrated_time(chain: np.ndarray) -> np.ndarray:
    """emcee's autocorrelation time per coordinate; NaN (without numpy's 0/0 warning) for a
    coordinate that never moved, which :func:`check_convergence` reports."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return emcee.autocorr.integrated_time(chain, tol=0, quiet=True)


def check_convergence(sampler: emcee.EnsembleSampler, names: Sequence[str], tau_multiple: float,
                 check_every: int) -> Check:
    chain = sampler.get_chain()
    n = chain.shape[0]
    tau = integrated_time(chain)
    worst = int(np.nanargmax(tau)) if np.isfinite(tau).any() else 0
    tau_max = float(tau[worst])
    if not np.isfinite(tau_max):
        return Check(False, "the autocorrelation time is not finite (a coordinate never "
                             "moved)", tau, n)
    if n < tau_multiple * tau_max:
        return Check(False, f"{n} steps < {tau_multiple:g} x tau = "
                             f"{tau_multiple * tau_max:.0f} (tau {tau_max:.1f} for "
                             f"{names[worst]})", tau, n)
    previous = ((n - 1) // check_every) * check_every
    if previous <= 0:
        return Check(False, "one check only: the autocorrelation times are not yet known to "
                             "be stable", tau, n)
    before = integrated_time(chain[:previous])
    allowed = np.maximum(_TAU_STABLE, _TAU_NOISE_SDS * tau_change_sd(tau, chain.shape[1],
                                                                       previous, n))
    with np.errstate(invalid="ignore", divide="ignore"):
        change = np.abs(tau - before) / tau
    if np.nanmax(change - allowed) > 0:
        k = int(np.nanargmax(change - allowed))
        return Check(False, f"the autocorrelation time of {names[k]} changed by "
                             f"{100 * change[k]:.0f} % since step {previous} (more than "
                             f"{100 * allowed[k]:.0f} %)", tau, n)
    acceptance = sampler.acceptance_fraction
    if np.mean(acceptance) < _MIN_ACCEPTANCE:
        return Check(False, f"mean acceptance fraction {np.mean(acceptance):.3f} < "
                             f"{_MIN_ACCEPTANCE}: the walkers barely move", tau, n)
    stuck = acceptance < _STUCK_FRACTION * np.median(acceptance)
    if stuck.any():
        return Check(False, f"{int(stuck.sum())} walkers accept less than "
                             f"{_STUCK_FRACTION:g} x the median walker (stuck, or the "
                             "posterior has separate modes)", tau, n)
    return Check(True, f"{n} steps >= {tau_multiple:g} x tau = {tau_multiple * tau_max:.0f} "
                        f"(tau {tau_max:.1f} for {names[worst]}), autocorrelation times stable "
                        f"within {100 * float(np.max(allowed)):.0f} %", tau, n)


def tau_change_sd(tau: np.ndarray, walkers: int, previous: int, n: int) -> np.ndarray:
    """Relative standard deviation of the change of an autocorrelation-time estimate between
    ``previous`` and ``n`` steps of a stationary chain: Sokal's variance of the estimate,
    ``2 (2 M + 1) tau**2 / N`` for a window ``M = 5 tau`` (emcee's), averaged over the
    walkers; the later estimate contains the earlier data, so the variance of the difference
    is the difference of the variances."""
    window = 5.0 * tau
    return np.sqrt(2.0 * (2.0 * window + 1.0) / walkers * (1.0 / previous - 1.0 / n))
