"""Least-squares identification with optimistix: :func:`fit` -> :class:`FitResult`.

>>> from fitstiff.io.loading import load_logs
>>> from fitstiff.inference.fitting import fit
>>> logs = load_logs(["data/synthetic/fig4/osp32_mid_6bar.csv"])        # doctest: +SKIP
>>> result = fit(logs, "chamber+dahl")                                   # doctest: +SKIP
>>> result.converged, result.derived["breakaway_N"]                      # doctest: +SKIP
(True, (18.02, 0.03))

The solver works on the flat unconstrained vector of :class:`~fitstiff.inference.problem.Problem`
(model parameters through their transforms, per-log offsets and initial friction states) with
exact Jacobians through the hysteresis scan (forward-mode autodiff). Starting values come from
the data (:func:`initial_guess`); ``starts > 1`` adds random restarts around them and keeps
the best converged run.

Uncertainty is the Gauss-Newton (Laplace) covariance ``s^2 (J^T J)^-1`` at the optimum, with
``s^2`` the residual variance, inflated by ``(1 + rho) / (1 - rho)`` for the lag-1
autocorrelation ``rho`` of the residuals (an AR(1) effective sample size). Directions of
``J^T J`` that the data do not determine are named in ``warnings`` and their parameters get no
standard error instead of a meaningless one.
"""

from __future__ import annotations

from fitstiff.inference.fitting.result import FitResult
from fitstiff.inference.fitting.solve import fit, fit_problem, fit_problems, SOLVERS
from fitstiff.inference.fitting.start import initial_guess
from fitstiff.inference.fitting.summary import LEAN_JACOBIAN_MB

__all__ = ["FitResult", "fit", "fit_problem", "fit_problems", "initial_guess", "SOLVERS",
           "LEAN_JACOBIAN_MB"]
