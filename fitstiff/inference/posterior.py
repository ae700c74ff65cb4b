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

**Convergence** (:mod:`fitstiff.inference.convergence`): the chain runs in chunks of ``check_every``
steps and stops when it is longer than ``tau_multiple`` autocorrelation times, the times are
stable between checks and the walkers move. Otherwise it stops at ``steps`` with ``converged``
False and the reason; it is never dropped. ``discard`` = 5 times the largest time (at most
half the chain), ``thin`` = half of it unless given; effective samples = walkers x kept steps /
tau.

**Resume** (:mod:`fitstiff.inference.chain`): with ``backend`` (a path) the chain goes to an HDF5
file (an emcee backend with fitstiff's own layout) with a signature of the problem;
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

import dataclasses
import math
import os
import sys
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import emcee
import numpy as np

from fitstiff._jax import computed_apart, jax, jnp, release_compiled
from fitstiff.errors import InputError
from fitstiff.inference import likelihood
from fitstiff.inference.chain import CHAIN, KEPT, ChainStore, fixed_values, signature
from fitstiff.inference.closed_series import ClosedFormLikelihood
from fitstiff.inference.convergence import Check, run_chunks
from fitstiff.inference.fitting import FitResult, fit_problem
from fitstiff.inference.likelihood import (Layout, LinearNuisances, NoiseModel, TurningPoints,
                                           noise_from_dict)
from fitstiff.inference.priors import Prior, Priors
from fitstiff.inference.problem import PROBLEM_OPTIONS, Problem
from fitstiff.io.guards import nonfinite_error
from fitstiff.io.log import Log
from fitstiff.physics.derived import DERIVED, derived_quantities, split_unit
from fitstiff.physics.model import Model
from fitstiff.physics.params import to_display

__all__ = [
    "CALIBRATION_NOTE",
    "CHAIN",
    "DEFAULT_MOVES",
    "DEFAULT_NOISE_MODEL",
    "INFERENCE_DATA",
    "KEPT",
    "PREDICTIVE",
    "Diagnostics",
    "LogPosterior",
    "MOVES",
    "Posterior",
    "PosteriorRecord",
    "log_posterior",
    "sample_posterior",
]

DEFAULT_NOISE_MODEL = "ar1"
#: the files a posterior run writes next to ``posterior.json`` (``fitstiff posterior``)
INFERENCE_DATA = "posterior.nc"     # ArviZ InferenceData (netCDF)
PREDICTIVE = "predictive.npz"       # model-force draws, their median and spread (the report)
#: measured 90 % interval coverage (``python -m benchmarks.calibration --datasets 50 --steps
#: 12000 --noise-models ar1``: benchmarks/results/calibration_50_de.json; the white-noise
#: figures from an older run, benchmarks/results/calibration_50.json)
CALIBRATION_NOTE = ("50 synthetic datasets: ar1 (default) covered the slope in 78 % and the "
                    "breakaway in 88 % (least squares 78 % and 90 %); white gaussian 54 % and "
                    "60 % in an older run")
#: emcee proposals (``moves``): name -> factory of emcee's ``moves`` argument
MOVES: dict[str, Callable[[], list]] = {
    "de": lambda: [(emcee.moves.DEMove(), 1.0)],
    "de+snooker": lambda: [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)],
    "stretch": lambda: [(emcee.moves.StretchMove(), 1.0)],
}
DEFAULT_MOVES = "de"
_BALL = 0.1                 # start ball: this times the Laplace standard deviations
_BALL_FLOOR = 1e-4          # ... and at least this in theta units (undetermined directions)
_BURN_IN_TAUS = 5.0
_DISAGREEMENT = 4.0         # posterior median vs least squares, in combined standard deviations
_DERIVED_BATCH = 256
_PREDICTIVE_BATCH = 25
_PREDICTIVE_POINTS = 2000   # at most this many samples per log in the predictive file
_QUANTILES = (("q05", 5.0), ("q50", 50.0), ("q95", 95.0))


# -- results --------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Diagnostics:
    """Sampler diagnostics (``posterior.json`` ``diagnostics``; :meth:`from_dict` reads them
    back).

    Attributes:
        acceptance_fraction: the fraction of accepted proposals, mean over the walkers.
        acceptance_fraction_min: the lowest walker's (a stuck walker shows here).
        autocorr_time: integrated autocorrelation time (steps) per sampled coordinate (NaN
            where not estimated: a coordinate that never moved).
        effective_samples: walkers x kept steps / autocorrelation time, per name.
        converged, reason: the verdict of the convergence rules and why.
        steps, walkers, discard, thin: chain length, ensemble size, burn-in and thinning used.
        tau_multiple: the required chain length in autocorrelation times.
        noise_model: the noise model's name.
        integrated: names integrated out analytically instead of sampled (the force offsets;
            no autocorrelation time: each kept step holds an exact conditional draw).
        moves: the emcee proposal (a key of :data:`MOVES`).
    """

    acceptance_fraction: float
    acceptance_fraction_min: float
    autocorr_time: Mapping[str, float]
    effective_samples: Mapping[str, float]
    converged: bool
    reason: str
    steps: int
    walkers: int
    discard: int
    thin: int
    tau_multiple: float
    noise_model: str
    integrated: tuple[str, ...] = ()
    moves: str = DEFAULT_MOVES

    def to_dict(self) -> dict[str, object]:
        return {"acceptance_fraction": self.acceptance_fraction,
                "acceptance_fraction_min": self.acceptance_fraction_min,
                # None where not estimated (a coordinate that never moved: see reason)
                "autocorr_time": {k: _or_none(v) for k, v in self.autocorr_time.items()},
                "effective_samples": {k: _or_none(v) for k, v in self.effective_samples.items()},
                "converged": self.converged, "reason": self.reason, "steps": self.steps,
                "walkers": self.walkers, "discard": self.discard, "thin": self.thin,
                "tau_multiple": self.tau_multiple, "noise_model": self.noise_model,
                "integrated": list(self.integrated), "moves": self.moves}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Diagnostics:
        """Read back what :meth:`to_dict` wrote. A file from before the force offsets could be
        integrated out (no ``integrated``, ``moves``) sampled every coordinate with the stretch
        move."""
        return cls(acceptance_fraction=float(data["acceptance_fraction"]),
                   acceptance_fraction_min=float(data["acceptance_fraction_min"]),
                   autocorr_time=_nan_for_none(data["autocorr_time"]),
                   effective_samples=_nan_for_none(data["effective_samples"]),
                   converged=bool(data["converged"]), reason=str(data["reason"]),
                   steps=int(data["steps"]), walkers=int(data["walkers"]),
                   discard=int(data["discard"]), thin=int(data["thin"]),
                   tau_multiple=float(data["tau_multiple"]),
                   noise_model=str(data["noise_model"]),
                   integrated=tuple(data.get("integrated", ())),
                   moves=str(data.get("moves", "stretch")))


@dataclasses.dataclass(frozen=True)
class PosteriorRecord:
    """What ``posterior.json`` holds (:meth:`Posterior.to_dict`), read back by
    :meth:`Posterior.from_dict`: a posterior's summaries in display units and its diagnostics,
    without the samples (those are in ``chain.h5`` and ``posterior.nc``).

    Attributes:
        model: the model spec.
        parameters: per model parameter its summary (``q05``, ``q50``, ``q95``, ``mean``,
            ``std``, ``unit``: :meth:`Posterior.summary`), or ``value``, ``unit`` and
            ``fixed: True`` for one held fixed.
        derived: per DESIGN §1.2 quantity its summary (the numbers None where the model does
            not define it).
        nuisances: per sampled nuisance (``offset[log]``, ``friction_state0[log]``) its
            summary.
        diagnostics: see :class:`Diagnostics`.
        noise: the noise model with its estimated settings.
        noise_scale: per series (``force[log]``, ``pressure_a[log]`` ...) the errors' standard
            deviation and its unit at the most probable sample.
        priors: the priors' settings (:meth:`fitstiff.inference.priors.Priors.to_dict`).
        samples: the number of kept samples.
        warnings: what the run warned of.
        files: the logs' paths (their names where they have none).
        fit: the least-squares start (``converged``, ``rms_N``, ``parameters`` and ``derived``
            of its ``fit.json``); ``None`` for a resumed run, which has none.
        identifiable, identifiable_reason, identifiability: the start's identifiability
            verdict (as in ``fit.json``; ``None`` without a start).

    The command line adds ``outputs`` (the files written beside it) to ``posterior.json``;
    that is not part of the record.
    """

    model: str
    parameters: Mapping[str, Mapping[str, Any]]
    derived: Mapping[str, Mapping[str, Any]]
    nuisances: Mapping[str, Mapping[str, Any]]
    diagnostics: Diagnostics
    noise: NoiseModel
    noise_scale: Mapping[str, tuple[float, str]]
    priors: Mapping[str, Any]
    samples: int
    warnings: tuple[str, ...]
    files: tuple[str, ...]
    fit: Mapping[str, Any] | None = None
    identifiable: bool | None = None
    identifiable_reason: str | None = None
    identifiability: Mapping[str, Any] | None = None

    @property
    def free_parameters(self) -> tuple[str, ...]:
        """The model parameters that were sampled (not held fixed), in the problem's order."""
        return tuple(n for n, p in self.parameters.items() if not p.get("fixed"))

    @property
    def names(self) -> tuple[str, ...]:
        """The problem's names: the free model parameters, then the nuisances (sampled or
        integrated out)."""
        return self.free_parameters + tuple(self.nuisances)

    def to_dict(self) -> dict[str, object]:
        """The ``posterior.json`` content (DESIGN §5)."""
        out: dict[str, object] = {
            "model": self.model,
            "parameters": {k: dict(v) for k, v in self.parameters.items()},
            "derived": {k: dict(v) for k, v in self.derived.items()},
            "nuisances": {k: dict(v) for k, v in self.nuisances.items()},
            "diagnostics": self.diagnostics.to_dict(),
            "noise": {"model": self.noise.to_dict(),
                      "scale": {label: {"sd": sd, "unit": unit}
                                for label, (sd, unit) in self.noise_scale.items()}},
            "priors": dict(self.priors),
            "samples": self.samples,
            "warnings": list(self.warnings),
            "files": list(self.files),
        }
        if self.fit is not None:
            out["fit"] = dict(self.fit)
            out |= {"identifiable": self.identifiable,
                    "identifiable_reason": self.identifiable_reason,
                    "identifiability": self.identifiability}
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> PosteriorRecord:
        """Read back what :meth:`to_dict` wrote (``posterior.json``)."""
        noise = data["noise"]
        return cls(model=str(data["model"]), parameters=data["parameters"],
                   derived=data["derived"], nuisances=data["nuisances"],
                   diagnostics=Diagnostics.from_dict(data["diagnostics"]),
                   noise=noise_from_dict(noise["model"]),
                   noise_scale={label: (s["sd"], s["unit"])
                                for label, s in noise["scale"].items()},
                   priors=data["priors"], samples=int(data["samples"]),
                   warnings=tuple(data["warnings"]), files=tuple(data["files"]),
                   fit=data.get("fit"), identifiable=data.get("identifiable"),
                   identifiable_reason=data.get("identifiable_reason"),
                   identifiability=data.get("identifiability"))


@dataclasses.dataclass(frozen=True, eq=False)
class Posterior:
    """Posterior samples of a model given logs. SI inside, display units at the edges.

    Attributes:
        problem: the :class:`~fitstiff.inference.problem.Problem` sampled.
        names: names of the sampled entries (``problem.names``).
        samples: ``(draws, walkers, len(names))`` physical SI values, after burn-in and
            thinning.
        log_prob: ``(draws, walkers)`` log-posterior of ``samples``.
        derived: DESIGN §1.2 name -> ``(draws, walkers)`` in engineering units.
        noise: the noise model with its estimated settings.
        noise_scale: per series (``noise.layout`` labels) the errors' standard deviation in
            channel units (N, Pa) at the most probable sample.
        priors: the priors used.
        diagnostics: see :class:`Diagnostics`.
        predictive: arrays for the report (see :meth:`predictive_arrays`).
        fit: the least-squares fit the walkers started from (``None`` when resumed).
        warnings: things the user should know (unconverged fit, no convergence ...).
    """

    problem: Problem
    names: tuple[str, ...]
    samples: np.ndarray
    log_prob: np.ndarray
    derived: Mapping[str, np.ndarray]
    noise: NoiseModel
    noise_scale: Mapping[str, tuple[float, str]]
    priors: Priors
    diagnostics: Diagnostics
    predictive: Mapping[str, np.ndarray]
    fit: FitResult | None
    warnings: tuple[str, ...]

    @property
    def model_names(self) -> tuple[str, ...]:
        return tuple(self.problem.par.names)

    def flat(self, name: str) -> np.ndarray:
        """All kept samples of a sampled name (SI) or a derived quantity (its unit), flat."""
        if name in self.derived:
            return np.asarray(self.derived[name]).ravel()
        return self.samples[..., self.names.index(name)].ravel()

    def summary(self, name: str) -> dict[str, object]:
        """``{q05, q50, q95, mean, std, unit}`` of a sampled name or derived quantity, in
        display units."""
        if name in self.derived:
            return _summary(self.flat(name), unit=split_unit(name)[1])
        i = self.names.index(name)
        return _summary(self.priors.to_display(self.flat(name), i), unit=self.priors.units[name])

    def _defined_summary(self, name: str) -> dict[str, object]:
        """:meth:`summary`, with None for the numbers of a quantity the model does not define
        (NaN in every sample, e.g. the breakaway of a model without friction)."""
        summary = self.summary(name)
        if np.isfinite(self.flat(name)).any():
            return summary
        return {k: (None if k != "unit" else v) for k, v in summary.items()}

    def interval(self, name: str) -> tuple[float, float]:
        """The central 90 % interval ``(q05, q95)`` in display units."""
        s = self.summary(name)
        return s["q05"], s["q95"]

    def to_record(self) -> PosteriorRecord:
        """What ``posterior.json`` keeps of this posterior: the summaries, not the samples."""
        problem = self.problem
        parameters: dict[str, Mapping[str, Any]] = {n: self.summary(n)
                                                     for n in self.model_names}
        for name, value in to_display(problem.model, fixed_values(problem)).items():
            parameters[name] = {"value": value, "unit": problem.par_unit(name), "fixed": True}
        start: dict[str, Any] = {}
        if self.fit is not None:
            fit_dict = self.fit.to_dict()
            start = {key: fit_dict[key] for key in ("identifiable", "identifiable_reason",
                                                     "identifiability")}
            start["fit"] = {k: fit_dict[k] for k in ("converged", "rms_N", "parameters",
                                                     "derived")}
        return PosteriorRecord(
            model=problem.model.spec, parameters=parameters,
            derived={k: self._defined_summary(k) for k in self.derived},
            nuisances={n: self.summary(n) for n in self.names[len(self.model_names):]},
            diagnostics=self.diagnostics, noise=self.noise, noise_scale=dict(self.noise_scale),
            priors=self.priors.to_dict(),
            samples=int(self.samples.shape[0] * self.samples.shape[1]),
            warnings=tuple(self.warnings),
            files=tuple(str(log.path) if log.path else log.name for log in problem.logs),
            **start)

    def to_dict(self) -> dict[str, object]:
        """The ``posterior.json`` content (DESIGN §5); :meth:`from_dict` reads it back."""
        return self.to_record().to_dict()

    @staticmethod
    def from_dict(data: Mapping[str, Any]) -> PosteriorRecord:
        """``posterior.json`` read back. It holds the summaries and diagnostics, not the samples
        (those are in ``chain.h5``), so what comes back is a :class:`PosteriorRecord`, whose
        :meth:`~PosteriorRecord.to_dict` gives ``data`` again."""
        return PosteriorRecord.from_dict(data)

    def table(self) -> str:
        """A readable summary with units."""
        d = self.diagnostics
        verdict = "converged" if d.converged else "NOT CONVERGED"
        head = (f"model {self.problem.model.spec}, noise {d.noise_model}: {verdict} "
                f"({d.reason}); {d.steps} steps x {d.walkers} walkers, acceptance "
                f"{d.acceptance_fraction:.2f}")
        lines = [head, f"  {'':<28}{'q50':>11}{'q05':>11}{'q95':>11}  unit"]
        defined = [k for k, v in self.derived.items() if np.isfinite(v).any()]
        for name in list(self.model_names) + defined:
            s = self.summary(name)
            lines.append(f"  {name:<28}{s['q50']:>11.5g}{s['q05']:>11.5g}{s['q95']:>11.5g}"
                         f"  {s['unit']}")
        lines += [f"  warning: {w}" for w in self.warnings]
        return "\n".join(lines)

    def to_inference_data(self):
        """An :class:`arviz.InferenceData` (chains = walkers) in display units: the model
        parameters, ``offset`` / ``friction_state0`` over the ``log`` dimension, the derived
        quantities; ``sample_stats.lp`` the log-posterior."""
        import arviz as az

        posterior: dict[str, np.ndarray] = {}
        units: dict[str, str] = {}
        by_walker = np.swapaxes(self.samples, 0, 1)
        for i, name in enumerate(self.model_names):
            posterior[name] = self.priors.to_display(by_walker[..., i], i)
            units[name] = self.priors.units[name]
        logs = [log.name for log in self.problem.logs]
        for nuisance in self.problem.nuisance_names:
            idx = [self.names.index(f"{nuisance}[{n}]") for n in logs]
            posterior[nuisance] = self.priors.to_display(by_walker[..., idx], idx)
            units[nuisance] = self.priors.units[self.names[idx[0]]]
        for name, values in self.derived.items():
            posterior[name] = np.swapaxes(np.asarray(values), 0, 1)
            units[name] = split_unit(name)[1]
        d = self.diagnostics
        with warnings.catch_warnings():
            # the axes are (walker, draw) on purpose: emcee runs many walkers on short thinned
            # chains, so ArviZ's "more chains than draws" shape guess does not apply
            warnings.filterwarnings("ignore", message="More chains", category=UserWarning)
            idata = az.from_dict(
                posterior=posterior, sample_stats={"lp": np.swapaxes(self.log_prob, 0, 1)},
                coords={"log": logs}, dims={n: ["log"] for n in self.problem.nuisance_names},
                attrs={"model": self.problem.model.spec, "noise_model": d.noise_model,
                       "converged": int(d.converged), "reason": d.reason, "steps": d.steps,
                       "discard": d.discard, "thin": d.thin,
                       "inference_library": f"emcee {emcee.__version__}"})
        for name, unit in units.items():
            idata.posterior[name].attrs["unit"] = unit
        return idata


def _or_none(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _nan_for_none(values: Mapping[str, float | None]) -> dict[str, float]:
    """The inverse of :func:`_or_none` over a mapping."""
    return {k: math.nan if v is None else float(v) for k, v in values.items()}


def _summary(values: np.ndarray, *, unit: str) -> dict[str, object]:
    values = np.asarray(values, dtype=float)
    out: dict[str, object] = {k: float(np.percentile(values, q)) for k, q in _QUANTILES}
    out |= {"mean": float(np.mean(values)), "std": float(np.std(values, ddof=1)), "unit": unit}
    return out


# -- the sampler ------------------------------------------------------------------------------
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
            :data:`~fitstiff.inference.problem.PROBLEM_OPTIONS` and solver options).
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
        backend: HDF5 file for the chain (:class:`~fitstiff.inference.chain.ChainBackend`); ``None``
            keeps it in memory.
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
    integrated = _integrated(problem, noise, prior_set, integrate_offsets)
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
        if not fit_result.converged:
            warnings.append(f"the least-squares start did not converge "
                            f"({fit_result.message}); the burn-in may be long")
        if not fit_result.identifiability.identifiable:
            ident = fit_result.identifiability
            warnings.append(f"the data do not identify the seal: {ident.reason} The posterior "
                            f"of {', '.join(ident.parameters + ident.derived)} reflects the "
                            "prior and the model's assumptions, not a measurement")
        theta_start = np.asarray(fit_result.theta)
    coordinates = _Coordinates.of(problem, theta_start, integrated, layout)
    noise, turning = _prepared(problem, noise, theta_start, layout, linear=coordinates.linear)
    if release:
        release_compiled()
    if turning.columns.shape[1] and getattr(noise, "marginal", None) is None:
        warnings.append(f"the {noise.name} noise model leaves the displacement errors at the "
                        "turning points out: intervals may be too narrow")
    log_prob = LogPosterior(problem, noise, prior_set, batch=(walkers + 1) // 2,
                            coordinates=coordinates, centre=theta_start)
    ndim = coordinates.sampled.size
    emcee_backend = store.backend if store else emcee.backends.Backend()
    if not resume:
        emcee_backend.reset(walkers, ndim)
        if store:
            store.write_settings(stored_as, settings=noise, theta_start=theta_start)
    sampler = emcee.EnsembleSampler(walkers, ndim,
                                    log_prob.rows if log_prob.blobs else log_prob,
                                    vectorize=True, backend=emcee_backend,
                                    moves=MOVES[moves]())
    if resume:
        state = sampler.get_last_sample()
    else:
        coords, rows = _start(fit_result, problem, log_prob, walkers,
                              np.random.default_rng(seeds[0]), prior_set)
        state = emcee.State(coords, log_prob=rows[:, 0],
                            blobs=rows[:, 1:] if log_prob.blobs else None,
                            random_state=np.random.RandomState(
                                np.random.MT19937(seeds[1])).get_state())
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
    options = {k: v for k, v in fit_options.items() if k in PROBLEM_OPTIONS}
    return Problem(list(logs_or_fit), model, fix=fix, **options), None


def _solver_options(fit_options: Mapping[str, object]) -> dict[str, object]:
    return {k: v for k, v in fit_options.items() if k not in PROBLEM_OPTIONS}


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
    noise, _ = _prepared(problem, likelihood.noise_model(noise_model), fit.theta, layout)
    return LogPosterior(problem, noise, Priors(problem, priors), batch=batch,
                        centre=np.asarray(fit.theta))


def _prepared(problem: Problem, noise: NoiseModel, theta: np.ndarray, layout: Layout, *,
              linear: LinearNuisances | None = None) -> tuple[NoiseModel, TurningPoints]:
    """``noise`` with its settings, the turning-point errors at ``theta`` and the ``linear``
    nuisances integrated out."""
    turning = TurningPoints.at(problem, jnp.asarray(theta), layout)
    return noise.prepared(_residuals(problem, theta), layout, turning_points=turning,
                          linear=linear), turning


def _integrated(problem: Problem, noise: NoiseModel, priors: Priors, wanted: bool) -> list[int]:
    """Positions in ``theta`` of the entries to integrate out: the problem's linear entries
    (force offsets) with flat priors, when the noise model can."""
    if not (wanted and noise.integrates_linear):
        return []
    return [i for i in problem.linear_entries()
            if priors.priors[problem.names[i]].dist == "flat"]


@dataclasses.dataclass(frozen=True, eq=False)
class _Coordinates:
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
           layout: Layout) -> _Coordinates:
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
                 coordinates: _Coordinates | None = None, centre: np.ndarray | None = None):
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
        return _batched(self._fn, np.asarray(coords, dtype=float), batch=self.batch)


def _full(coordinates: _Coordinates | None, coords):
    return coords if coordinates is None else coordinates.full(coords)


def _row_residuals(p: Problem, coords, *, coordinates: _Coordinates | None,
                   closed: ClosedFormLikelihood | None, **_):
    """The residuals the log-posterior of one row needs: all, or with ``closed`` those of
    its channels computed from the model."""
    theta = _full(coordinates, coords)
    return p.residuals(theta) if closed is None else p.residuals(theta, channels=closed.channels)


def _given(p: Problem, residuals, coords, *, noise: NoiseModel, priors: Priors,
           layout: Layout, coordinates: _Coordinates | None,
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


def _physical_rows(p: Problem, rows):
    return jax.vmap(p.physical)(rows)


def _derived_rows(p: Problem, rows):
    return jax.vmap(lambda th: jnp.stack([_derived(p, th)[k] for k in DERIVED]))(rows)


def _force_rows(p: Problem, rows):
    return jax.vmap(lambda theta: jnp.concatenate(
        [pred.force.ravel() for pred in p.predictions(theta)]))(rows)


def _batched(fn: Callable, rows: np.ndarray, *, batch: int) -> np.ndarray:
    """``fn`` (compiled for ``batch`` rows) over all ``rows``, padding the last chunk."""
    n = rows.shape[0]
    if n == batch:                     # a sampler's call: no copies
        return np.asarray(fn(rows))
    padded = np.concatenate([rows, np.repeat(rows[-1:], (-n) % batch, axis=0)])
    out = [np.asarray(fn(padded[i:i + batch]))
           for i in range(0, padded.shape[0], batch)]
    return np.concatenate(out)[:n]


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
             noise: NoiseModel, layout: Layout, priors: Priors, coordinates: _Coordinates,
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
    physical = problem.compiled(_physical_rows)
    samples = _batched(physical, flat, batch=_DERIVED_BATCH).reshape(thetas.shape)
    derived_fn = problem.compiled(_derived_rows)
    derived_values = _batched(derived_fn, flat, batch=_DERIVED_BATCH)
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
        warnings.extend(_disagreements(fit, derived, noise.name))
    if store is not None:
        store.write_kept(thetas)
    best = flat[int(np.argmax(log_prob.ravel()))]
    predictive, scale = _predictive(problem, noise, layout, flat, best, draws=draws, rng=rng)
    return Posterior(problem=problem, names=tuple(problem.names), samples=samples,
                     log_prob=log_prob, derived=derived, noise=noise, noise_scale=scale,
                     priors=priors, diagnostics=diagnostics, predictive=predictive, fit=fit,
                     warnings=tuple(warnings))


def _disagreements(fit: FitResult, derived: Mapping[str, np.ndarray],
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


def _full_thetas(noise: NoiseModel, layout: Layout, coordinates: _Coordinates,
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


def _residuals(problem: Problem, theta: np.ndarray) -> np.ndarray:
    fn = problem.compiled(Problem.residuals)
    return np.asarray(fn(jnp.asarray(theta)))


def _derived(problem: Problem, theta) -> dict[str, jnp.ndarray]:
    model, _ = problem.unpack(theta)
    return derived_quantities(model, problem.drives[0])


def _predictive(problem: Problem, noise: NoiseModel, layout: Layout, flat: np.ndarray,
                best: np.ndarray, *, draws: int, rng: np.random.Generator):
    """Model-force draws per log (thinned to at most ``_PREDICTIVE_POINTS`` samples), the
    median and spread of the draws at every sample, and the noise level per series at the
    most probable sample."""
    fn = problem.compiled(_force_rows)
    pick = rng.choice(flat.shape[0], size=min(draws, flat.shape[0]), replace=False)
    curves = _batched(fn, flat[np.sort(pick)], batch=_PREDICTIVE_BATCH)
    whitened = np.asarray(noise.series_scale(jnp.asarray(_residuals(problem, best)), layout))
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
