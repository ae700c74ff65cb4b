"""Noise models: the likelihood of the whitened residuals of a
:class:`~fitstiff.inference.problem.Problem`.

The residual vector is cut into **series**, one per log and observed channel (force, and the
pressure of each closed chamber whose pressure is logged), each in time order
(:meth:`Problem.residual_series <fitstiff.inference.problem.Problem.residual_series>`). Samples with
weight 0 (padding, ``--skip``, ``--range``) are not data: they enter no likelihood. Every
series has its own noise level and, for :class:`AR1`, its own correlation.

=============== ========================================================================
``gaussian``    independent Gaussian errors. ``sigma=None`` (default): one unknown scale
                per series, integrated out under the Jeffreys prior ``p(s) ~ 1/s``, so the
                series contributes ``-(n/2) log(sum r**2)`` (a Student-t marginal);
                ``sigma=1.0``: the per-log noise estimates used for whitening are taken as
                exact.
``student_t``   independent Student-t errors with ``nu`` degrees of freedom (default 4),
                robust to outliers. The scale of each series is estimated once, from the
                median absolute residual at the least-squares optimum.
``ar1``         stationary AR(1) errors ``e_k = phi e_(k-1) + s w_k`` per series, exact
                likelihood: each run of consecutive weighted samples starts from the
                stationary law and continues with the one-step conditionals (runs
                separated by zero-weight samples are independent). ``phi`` is
                estimated once per series at the least-squares optimum (from thousands of
                samples its uncertainty is ~ ``sqrt((1 - phi**2) / n)``, about 0.01, far below
                anything it influences), the innovation scale ``s`` is integrated out as for
                ``gaussian``: ``-(n/2) log(sum_first (1 - phi**2) r**2 + sum (r_k - phi
                r_(k-1))**2)``.
=============== ========================================================================

``ar1`` is the default of :func:`fitstiff.inference.posterior.sample_posterior`; see that module for
the evidence.

**Turning points** (``gaussian`` and ``ar1``). A displacement error at a reversal shifts the
whole branch after it (the denoiser keeps every sample between reversals on a monotone
estimate, but the extremum itself carries the sensor noise); least squares adds this
errors-in-variables term to its covariance (:mod:`fitstiff.inference.fitting`), and so does the
likelihood: :class:`TurningPoints` holds, per reversal sample ``k`` of each log, the column
``u_k = (d r / d x_k) sigma_x`` (the log's displacement noise) of the whitened force
residuals at the least-squares optimum, and the errors ``delta ~ N(0, I)`` along them are
integrated out: the covariance of a series is ``s**2 (C + W W')`` with ``C`` the noise
model's correlation and ``W = C^(-1/2) U / s_hat`` (``s_hat`` the noise scale at the optimum),
so with ``e = C^(-1/2) r``, ``v = W' e`` and ``M = (I + W'W)^-1`` the sum of squares above
becomes ``e'e - v'M v`` (Woodbury). The pressure channels' sensitivity to a micrometre at a
reversal (a few Pa against hundreds) is left out. ``student_t`` has no such closed form and
leaves the turning points out.

**Linear nuisances** (``gaussian`` and ``ar1``). The per-log force offsets enter the residuals
linearly (``r = r_0 + a c``), so under their flat priors they are integrated out exactly
instead of sampled (:class:`LinearNuisances`): their whitened columns ``G`` join ``W`` with
prior precision 0, ``A = [W, G]``, ``P = diag(1 (turning points), 0 (offsets))``, ``b = A'e``,
the sum of squares becomes ``q = e'e - b'(P + A'A)^-1 b`` and each series contributes
``-((n - k)/2) log q`` with ``k`` its flat columns (the Jeffreys-scale marginal loses one
degree of freedom per flat column). Sampling is then in fewer, better-conditioned coordinates;
:meth:`_Quadratic.linear_draws` draws the offsets from their exact conditional afterwards.

A noise model is a small frozen dataclass. :meth:`~NoiseModel.prepared` fills in what it
estimates from the least-squares residuals (returning a new instance);
:meth:`~NoiseModel.log_likelihood` is a pure JAX function of the residual vector (``jit`` /
``vmap`` friendly).

The parts, one concept a module: :mod:`~fitstiff.inference.likelihood.layout` (the series),
:mod:`~fitstiff.inference.likelihood.columns` (the turning-point and linear-nuisance columns),
:mod:`~fitstiff.inference.likelihood.base` (the interface), ``_quadratic`` (what ``gaussian``
and ``ar1`` share: whitening, the scale and the columns integrated out) and
:mod:`~fitstiff.inference.likelihood.models` (the models by name).
"""

from __future__ import annotations

from fitstiff.inference.likelihood._quadratic import _Quadratic  # noqa: F401 (closed_series)
from fitstiff.inference.likelihood.base import NoiseModel
from fitstiff.inference.likelihood.columns import LinearNuisances, TurningPoints
from fitstiff.inference.likelihood.layout import Layout
from fitstiff.inference.likelihood.models import (AR1, NOISE_MODELS, Gaussian, StudentT,
                                                  noise_from_dict, noise_model)

__all__ = [
    "AR1",
    "NOISE_MODELS",
    "Gaussian",
    "Layout",
    "LinearNuisances",
    "NoiseModel",
    "StudentT",
    "TurningPoints",
    "noise_from_dict",
    "noise_model",
]
