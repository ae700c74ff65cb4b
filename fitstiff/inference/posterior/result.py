"""What a posterior run returns: its convergence diagnostics, the record written to
posterior.json, and the in-memory :class:`Posterior` with summaries of every parameter and
derived quantity."""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Mapping
from typing import Any

import emcee
import numpy as np

from fitstiff.inference.fitting import FitResult
from fitstiff.inference.likelihood import NoiseModel, noise_from_dict
from fitstiff.inference.posterior.chain import fixed_values
from fitstiff.inference.priors import Priors
from fitstiff.inference.problem import Problem
from fitstiff.physics.derived import split_unit
from fitstiff.physics.params import to_display


__all__ = ["CALIBRATION_NOTE", "DEFAULT_MOVES", "INFERENCE_DATA", "PREDICTIVE", "Diagnostics",
           "Posterior", "PosteriorRecord"]

#: the files a posterior run writes next to ``posterior.json`` (``fitstiff posterior``)
INFERENCE_DATA = "posterior.nc"     # ArviZ InferenceData (netCDF)
PREDICTIVE = "predictive.npz"       # model-force draws, their median and spread (the report)
#: measured 90 % interval coverage (``python -m benchmarks.calibration --datasets 50 --steps
#: 12000 --noise-models ar1``: benchmarks/results/calibration_50_de.json; the white-noise
#: figures from an older run, benchmarks/results/calibration_50.json)
CALIBRATION_NOTE = ("50 synthetic datasets: ar1 (default) covered the slope in 78 % and the "
                    "breakaway in 88 % (least squares 78 % and 90 %); white gaussian 54 % and "
                    "60 % in an older run")
DEFAULT_MOVES = "de"
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
