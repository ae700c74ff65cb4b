"""What a least-squares fit returns: :class:`FitResult`, its fitted values with standard errors
and correlations, the derived quantities, the per-log nuisances and the solver's status, as
written to ``fit.json``."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from fitstiff._jax import jax
from fitstiff.inference.identifiability import Identifiability
from fitstiff.inference.nuisances import NUISANCE_PARAMS
from fitstiff.inference.problem import Problem
from fitstiff.physics.derived import split_unit
from fitstiff.physics.model import Model
from fitstiff.physics.params import to_display, to_si


__all__ = ["FitResult"]

#: each fitted nuisance's fit.json ``per_log`` key (its name and display unit) and its
#: transform-layer entry, which converts the value
PER_LOG_NUISANCES = {name: (name if p.unit == "-" else f"{name}_{p.unit}", p)
                     for name, p in NUISANCE_PARAMS.items()}


@dataclasses.dataclass(frozen=True, eq=False)
class FitResult:
    """The outcome of a least-squares fit. Values in SI inside, engineering units at the edges.

    Attributes:
        model: the fitted model.
        names: free model-parameter names (flat), then nuisance names ``offset[log]`` ...
        values: SI values of ``names`` (nuisances: N for offsets, fraction for states).
        stderr: standard errors (SI); NaN where the data do not determine the parameter.
        units: display unit of each free model parameter (conversions: ``problem.par``).
        covariance: covariance of ``values`` (SI), after the autocorrelation inflation.
        derived: name -> ``(value, stderr)`` in engineering units (DESIGN §1.2), at the first
            log's operating point; ``per_log`` holds each log's chamber stiffness.
        converged: the solver's verdict; ``message`` says why not.
        identifiability: whether the data separate the seal parameters
            (:mod:`fitstiff.inference.identifiability`); the parameters and derived quantities it
            names have NaN standard errors (``null`` in fit.json).
        rms_N: RMS force residual over the weighted samples of all logs.
    """

    model: Model
    names: tuple[str, ...]
    values: np.ndarray
    stderr: np.ndarray
    covariance: np.ndarray
    units: Mapping[str, str]
    fixed: Mapping[str, float]
    derived: Mapping[str, tuple[float, float]]
    per_log: Sequence[Mapping[str, object]]
    converged: bool
    message: str
    steps: int
    solver: str
    rms_N: float
    cost: float
    n_data: int
    n_params: int
    aic: float
    bic: float
    residual_autocorrelation: float
    warnings: tuple[str, ...]
    identifiability: Identifiability
    files: tuple[str, ...]
    starts: Mapping[str, int]
    theta: np.ndarray
    problem: Problem = dataclasses.field(repr=False)

    @property
    def n_model_params(self) -> int:
        return len(self.units)

    def value(self, name: str) -> float:
        """SI value of a parameter (free or fixed) by flat name."""
        if name in self.names:
            return float(self.values[self.names.index(name)])
        return float(self.fixed[name])

    def parameters(self) -> dict[str, dict[str, object]]:
        """``name -> {value, stderr, unit}`` in display units (fit.json ``parameters``)."""
        out = {}
        n = self.n_model_params
        values, stderr = (self.problem.par.to_display(x[:n]) for x in (self.values, self.stderr))
        for i, name in enumerate(self.names[:n]):
            out[name] = {"value": values[i], "stderr": _finite(stderr[i]),
                         "unit": self.units[name]}
        for name, value in to_display(self.problem.model, self.fixed).items():
            out[name] = {"value": value, "stderr": None,
                         "unit": self.problem.par_unit(name), "fixed": True}
        return out

    @staticmethod
    def theta_from_dict(problem: Problem, data: Mapping[str, Any], *,
                        where: str | None = None) -> jax.Array:
        """The fitted ``theta`` of ``problem`` from a :meth:`to_dict` (``fit.json``): its free
        parameters (display units) and each log's fitted nuisances (``per_log``), exactly.
        ``problem`` must be the fit's (same logs, model and fixed values)."""
        values = to_si(problem.model, {name: p["value"] for name, p in data["parameters"].items()
                                       if not p.get("fixed")}, where=where)
        model = problem.par.with_values(problem.model, values, where=where)
        nuisances = {name: [p.to_si(entry[key]) for entry in data["per_log"]]
                     for name, (key, p) in PER_LOG_NUISANCES.items()
                     if name in problem.nuisance_names}
        return problem.pack(model, nuisances)

    def to_dict(self) -> dict[str, object]:
        """The ``fit.json`` content (DESIGN §5); :meth:`theta_from_dict` reads it back."""
        n_model = self.n_model_params
        corr = _correlation(self.covariance[:n_model, :n_model])
        return {
            "model": self.model.spec,
            "parameters": self.parameters(),
            "settings": self.model.settings(),
            "derived": {k: {"value": _finite(v), "stderr": _finite(e)}
                        for k, (v, e) in self.derived.items()},
            "rms_N": self.rms_N,
            "converged": self.converged,
            "message": self.message,
            "identifiable": self.identifiability.identifiable,
            "identifiable_reason": self.identifiability.reason,
            "identifiability": self.identifiability.to_dict(),
            "solver": self.solver,
            "steps": self.steps,
            "files": list(self.files),
            "per_log": list(self.per_log),
            "n_data": self.n_data,
            "n_params": self.n_params,
            "aic": self.aic,
            "bic": self.bic,
            "residual_autocorrelation": self.residual_autocorrelation,
            "correlation": {"names": list(self.names[:n_model]),
                            "matrix": [[_finite(c) for c in row] for row in corr]},
            "warnings": list(self.warnings),
            "starts": dict(self.starts),
        }

    def table(self) -> str:
        """A readable table with units."""
        lines = [f"model {self.model.spec}: "
                 + ("converged" if self.converged else f"NOT CONVERGED ({self.message})")
                 + f" after {self.steps} steps; rms {self.rms_N:.4g} N over {self.n_data} data",
                 self.identifiability.line()]
        if self.starts.get("requested", 1) > 1:
            lines.insert(1, f"starts: {self.starts['requested']} requested, "
                            f"{self.starts['converged']} converged, {self.starts['agreed']} "
                            "agreed with the best (cost within 1e-6, parameters within 0.1 %)")
        lines.append(f"  {'parameter':<22}{'value':>14}{'stderr':>12}  unit")
        for name, p in self.parameters().items():
            err = "fixed" if p.get("fixed") else ("n/d" if p["stderr"] is None
                                                 else f"{p['stderr']:.4g}")
            lines.append(f"  {name:<22}{p['value']:>14.6g}{err:>12}  {p['unit']}")
        for term in self.model.terms:
            if term.reading():
                lines.append(f"  ({term.name}: {term.reading()})")
        lines.append(f"  {'derived':<22}")
        for name, (v, e) in self.derived.items():
            label, unit = split_unit(name)
            err = "n/d" if not np.isfinite(e) else f"{e:.4g}"
            lines.append(f"  {label:<22}{v:>14.6g}{err:>12}  {unit}")
        for log in self.per_log:
            lines.append(f"  log {log['name']}: rms {log['rms_N']:.4g} N, offset "
                         f"{log['offset_N']:.4g} N, chamber stiffness "
                         f"{_fmt(log['chamber_stiffness_N_per_mm'])} N/mm")
        for w in self.warnings:
            lines.append(f"  warning: {w}")
        return "\n".join(lines)


def _fmt(v) -> str:
    return "n/a" if v is None or not np.isfinite(v) else f"{v:.4g}"


def _finite(v):
    v = float(v)
    return v if math.isfinite(v) else None


def _correlation(cov: np.ndarray) -> np.ndarray:
    d = np.sqrt(np.diag(cov))
    with np.errstate(invalid="ignore", divide="ignore"):
        return cov / np.outer(d, d)
