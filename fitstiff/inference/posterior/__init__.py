"""Bayesian posteriors with emcee: :func:`sample_posterior` -> :class:`Posterior`.

>>> from fitstiff.io.loading import load_logs
>>> from fitstiff.inference.posterior import sample_posterior
>>> logs = load_logs(["data/synthetic/fig4/p6bar_x350mm.csv"])           # doctest: +SKIP
>>> post = sample_posterior(logs, "chamber+dahl", seed=1)                 # doctest: +SKIP
>>> post.diagnostics.converged, post.summary("breakaway_N")["q50"]        # doctest: +SKIP
(True, 18.01)

**Coordinates.** The walkers move in the unconstrained vector ``theta`` of
:class:`~fitstiff.inference.problem.Problem` (model parameters through their transforms, then each
log's force offset and initial friction state), the same coordinates as least squares, less the
force offsets: they enter the residuals linearly and, under their flat priors, are integrated
out exactly by the ``gaussian`` and ``ar1`` likelihoods (:mod:`fitstiff.inference.likelihood`), then
drawn from their conditional posterior for every kept step (``integrate_offsets=False``
samples them). What those draws need of a step (the offsets' most probable corrections and
the per-series sums of squares) comes out of its log-posterior evaluation as emcee blobs,
so no model runs again after sampling. The log-posterior is

    log p(theta | data) = log L(residuals(theta)) + sum_i log prior_i(x_i(theta))
                          + log |d x / d theta|

with ``x(theta)`` the physical values, so the priors (:mod:`fitstiff.inference.priors`) are
densities of physical quantities whatever the transform. It is two ``jit``-compiled JAX functions
(residuals; likelihood and priors) ``vmap``-ed over walkers; emcee calls them with
``vectorize=True`` on half of the ensemble at a time (its red-blue moves), padded to one
shape so they compile once.

**Proposal.** emcee's differential-evolution move (:data:`MOVES`, ``moves="de"``): on the
demo logs its autocorrelation time was 39 steps against 118 for the stretch move (4 000
steps x 32 walkers, offsets sampled), 22 with the offsets integrated out.

**Noise model** (:mod:`fitstiff.inference.likelihood`): ``ar1`` by default: per log and channel,
stationary AR(1) errors with the lag-1 coefficient estimated at the least-squares optimum and the
scale integrated out. Evidence: hysteresis-fit residuals are autocorrelated (a friction model is
never exact and force channels are low-pass filtered), and independent-error likelihoods then
treat thousands of correlated samples as independent. On the calibration benchmark
(``benchmarks/calibration.py``: synthetic ``chamber+dahl`` datasets drawn over realistic
seal, pressure and sensor ranges, force noise with lag-1 correlation 0-0.9) the 90 % intervals
of the pre-sliding slope and the breakaway force covered the truth in 78 % and 88 % of 50
datasets with ``ar1`` on the current code (least squares on the same fits: 78 % and 90 %;
an older run: 86 % and 92 %), in 54 % and 60 % with white ``gaussian`` noise in that older run
(:data:`CALIBRATION_NOTE`; white noise under-covers the more, the more correlated the
residuals are). ``gaussian`` is
there for white residuals and ``student_t`` for outliers.

**Start.** Least squares first (:func:`fitstiff.inference.fitting.fit`, or a given
:class:`~fitstiff.inference.fitting.FitResult`); the walkers start in a Gaussian ball around its
optimum with 0.1 times its Laplace covariance (mapped to ``theta``).

**Convergence** (:mod:`fitstiff.inference.posterior.convergence`): the chain runs in chunks of
``check_every`` steps and stops when it is longer than ``tau_multiple`` autocorrelation times, the
times are stable between checks and the walkers move. Otherwise it stops at ``steps`` with
``converged`` False and the reason; it is never dropped. ``discard`` = 5 times the largest time (at
most half the chain), ``thin`` = half of it unless given; effective samples = walkers x kept steps /
tau.

**Resume** (:mod:`fitstiff.inference.posterior.chain`): with ``backend`` (a path) the chain goes to
an HDF5 file (an emcee backend with fitstiff's own layout) with a signature of the problem;
``resume=True`` checks it and continues from the last stored step, giving the same chain as
an uninterrupted run.

**Outputs.** :class:`Posterior`: thinned samples in SI, quantiles (``q05``, ``q50``, ``q95``,
``mean``, ``std``) of the parameters and of the derived quantities of DESIGN §1.2 (computed by a
``vmap``-ed JAX function over the thinned samples, at the first log's operating point as in
fit.json), draws of the model force for the report, ``posterior.json`` content
(:meth:`Posterior.to_dict`; :meth:`Posterior.from_dict` reads it back as a
:class:`PosteriorRecord`, the summaries without the samples) and an ArviZ ``InferenceData``
(:meth:`Posterior.to_inference_data`).
"""

from __future__ import annotations

from fitstiff.inference.posterior.chain import CHAIN, KEPT
from fitstiff.inference.posterior.density import DEFAULT_NOISE_MODEL, LogPosterior, log_posterior
from fitstiff.inference.posterior.result import (CALIBRATION_NOTE, DEFAULT_MOVES, INFERENCE_DATA,
                                                 PREDICTIVE, Diagnostics, Posterior,
                                                 PosteriorRecord)
from fitstiff.inference.posterior.sampler import MOVES, sample_posterior

__all__ = ["CALIBRATION_NOTE", "CHAIN", "DEFAULT_MOVES", "DEFAULT_NOISE_MODEL",
           "INFERENCE_DATA", "KEPT", "PREDICTIVE", "Diagnostics", "LogPosterior", "MOVES",
           "Posterior", "PosteriorRecord", "log_posterior", "sample_posterior"]
