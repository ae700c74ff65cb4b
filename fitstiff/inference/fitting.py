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

import dataclasses
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np
import optimistix as optx

from fitstiff._jax import jax, jnp
from fitstiff.errors import InputError
from fitstiff.inference import lm
from fitstiff.inference.identifiability import (Identifiability, assess_identifiability,
                                                reversal_travel)
from fitstiff.inference.problem import NUISANCE_PARAMS, Problem, compiled_batch
from fitstiff.io.guards import check_finite
from fitstiff.io.log import Log
from fitstiff.physics.derived import DERIVED, derived_quantities, split_unit
from fitstiff.physics.derived import to_display as derived_display
from fitstiff.physics.model import Model
from fitstiff.physics.params import Parameterization, named_params, to_display, to_si
from fitstiff.physics.terms.base import FrictionBase, FrictionEstimate, Modifier
from fitstiff.signal.noise import marginal_scale
from fitstiff.signal.spikes import UNTRUSTED as _UNTRUSTED

__all__ = ["FitResult", "fit", "fit_problem", "fit_problems", "initial_guess", "SOLVERS",
           "LEAN_JACOBIAN_MB"]


class NormalEquationsLM(NamedTuple):
    """fitstiff's Levenberg-Marquardt in its normal-equations form
    (:func:`fitstiff.inference.lm.levenberg_marquardt` ``normal=True``): no Jacobian kept between
    steps. ``"lm"`` runs it when the Jacobian would exceed :data:`LEAN_JACOBIAN_MB`."""

    rtol: float
    atol: float


SOLVERS = {
    "lm": lambda rtol, atol: optx.LevenbergMarquardt(rtol=rtol, atol=atol),
    "lm-normal": NormalEquationsLM,
    "dogleg": lambda rtol, atol: optx.Dogleg(rtol=rtol, atol=atol),
    "gauss-newton": lambda rtol, atol: optx.GaussNewton(rtol=rtol, atol=atol),
    "bfgs": lambda rtol, atol: optx.BFGS(rtol=rtol, atol=atol),
}
#: ``"lm"`` switches to ``"lm-normal"`` when the Jacobian (residuals x entries, float64)
#: would exceed this: optimistix's Levenberg-Marquardt holds about four Jacobian-sized
#: arrays at once (the accepted point's, the trial point's, the damped operator and its QR;
#: XLA's buffer assignment), 1.2 GB peak for a 1 M-sample log with two pressure channels
#: (``benchmarks/fit_memory.py``); and the default covariance summary shares one vectorised
#: Jacobian between the covariance and the turning-point columns (:func:`_summary_evaluate`).
#: At 64 MB (the former threshold) that summary peaked 100 MB above the two it replaced
#: (518 001 samples: 932 against 832 MB). At 48 MB a default fit of 370 001 samples (a
#: 44 MB Jacobian) peaks at 794 MB, and a 444 001-sample log takes the lean path (652 MB,
#: 18.7 s, against 776 MB and 22.3 s on the default path before)
LEAN_JACOBIAN_MB = 48.0
_CORRELATION_WARNING = 0.95
_SINGULAR = 1e-7       # relative singular value below which a direction is undetermined
_AT_BOUND = 1e-3          # a parameter this close to a bound (share of its span) sits at it
_BREAKAWAY_EXCESS = 10.0  # breakaway above this many times the largest measured force
#: the pooled lag-1 autocorrelation of the residuals is clipped here (AR(1) factor 14.1)
_LAG1_CAP = 0.99
#: after the step budget ran out, :data:`_FLAT_STEPS` more steps: when the cost falls by less
#: than what moves the fit :data:`_FLAT_SD` of a standard error (``_FLAT_SD**2`` times the
#: residual variance, AR(1)-inflated as the standard errors are), the fit has converged as
#: far as its uncertainty can tell, and what still moves is a coordinate the data do not
#: determine (issue 17: on the O-ring logs LuGre's initial friction states walked for 3 000
#: steps at a cost change of 2e-6 relative, about 0.02 standard errors)
_FLAT_STEPS = 10
_FLAT_SD = 0.1
#: each fitted nuisance's fit.json ``per_log`` key (its name and display unit) and its
#: transform-layer entry, which converts the value
PER_LOG_NUISANCES = {name: (name if p.unit == "-" else f"{name}_{p.unit}", p)
                     for name, p in NUISANCE_PARAMS.items()}
_RESIDUAL_LIMIT = 1e100  # whitened residuals / Jacobian entries beyond this are refused


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


# -- starting values ----------------------------------------------------------------------
#: a chamber-only model's predicted force on a drive and its linearised stiffness, compiled
#: once per model structure (no data inside)
_chamber_start = jax.jit(lambda model, drive: (model.predict(drive),
                                               model.term("chamber").stiffness(drive)))


def initial_guess(problem: Problem, *, bases: Sequence[str] | None = None,
                  samples: Sequence[np.ndarray | None] | None = None
                  ) -> tuple[Model, dict[str, np.ndarray]]:
    """Starting values from the data: levels from the sliding plateaus, slope from the samples
    right after reversals, offsets from the plateau midlines, the chamber from geometry.

    Each friction base starts from :meth:`~fitstiff.physics.terms.base.Term.start` with an equal
    share of the estimate; ``bases`` names the bases that share it (default: all; the
    diagnosis gives the baseline's, its candidate Maxwell-slip starts at its null).
    Fixed parameters keep their values; parameters the data do not inform keep the model's.

    ``samples`` (the diagnosis' folds) restricts what informs the shared estimates: per log, a
    boolean mask of the samples that may (default: all), or ``None`` for a log that informs
    only its own nuisances (a held-out log, whose offset and initial state are fitted to it
    alone). Each log's offset comes from the samples it may use, its initial friction state
    from its first sample (a held-out part's own nuisance, as a left-out log's is).
    """
    model = problem.model
    chamber_only = [Model((model.term("chamber"),))] if model.has("chamber") else []
    if samples is None:
        samples = [np.ones(len(log), dtype=bool) for log in problem.logs]
    levels, offsets, slopes, states = [], [], [], []
    for log, seg, drive, seen in zip(problem.logs, problem.segmentations, problem.drives,
                                     samples):
        shared = seen is not None
        seen = np.ones(len(log), dtype=bool) if seen is None else np.asarray(seen, dtype=bool)
        force = np.asarray(log.force)
        k_chamber = 0.0
        if chamber_only:
            chamber_force, stiffness = _chamber_start(chamber_only[0], drive)
            force = force - np.asarray(chamber_force)
            k_chamber = float(stiffness)
            k_chamber = k_chamber if math.isfinite(k_chamber) else 0.0
        sliding = seg.mask("sliding") & seen
        pool = force[sliding] if sliding.sum() > 20 else force[seen]
        lo, hi = np.percentile(pool, [5, 95])
        level, offset = max((hi - lo) / 2, 1e-3), (hi + lo) / 2
        offsets.append(offset)
        states.append(float(np.clip((force[0] - offset) / level, -0.9, 0.9)))
        if not shared:
            continue
        levels.append(level)
        x = np.asarray(drive.displacement)
        for r in seg.reversals[seen[seg.reversals]]:
            window = 0.1 * level / 40e3
            after = np.flatnonzero(np.abs(x[r:r + 2000] - x[r]) <= window)
            after = after[after == np.arange(after.size)] + r   # contiguous from r
            if after.size < 4 or np.ptp(x[after]) <= 0:
                continue
            slope = np.polyfit(x[after], force[after], 1)[0] - k_chamber
            rel = min(abs(force[r] - offset) / level, 1.0)
            slopes.append((abs(slope), rel))
    estimate = FrictionEstimate(
        level=float(np.median(levels)),
        tangent=float(np.median([s for s, _ in slopes])) if slopes else None,
        reversal_state=float(np.median([r for _, r in slopes])) if slopes else 1.0)
    bases = [t.name for t in model.terms_of(FrictionBase) if bases is None or t.name in bases]
    terms = [t.start(estimate, share=1.0 / len(bases)) if t.name in bases else t
             for t in model.terms]
    guess = model.with_terms(tuple(terms))
    # restore anything the user fixed
    par_all = Parameterization(model)
    keep = {n: v for n, v in par_all.values(model).items() if n in problem.par_fixed}
    if keep:
        guess = Parameterization(guess).with_values(guess, keep)
    return guess, {"offset": np.asarray(offsets), "friction_state0": np.asarray(states),
                   "closing_pressure": problem.closing_pressure_start()}


# -- the fit --------------------------------------------------------------------------------
def fit(logs: Sequence[Log], model: Model | str, *, fix: Mapping[str, float] | Iterable[str] = (),
        solver: str = "lm", starts: int = 1, seed: int = 0, max_steps: int = 400,
        rtol: float = 1e-5, atol: float = 1e-5, denoise: bool | str = "auto",
        sample_range: tuple[int | None, int | None] | None = None,
        weights: Mapping[str, float] | None = None, skip: int = 0,
        free: Iterable[str] = (), exclude: Sequence[tuple[int, int]] = ()) -> FitResult:
    """Fit ``model`` jointly to ``logs`` by nonlinear least squares.

    Args:
        logs: loaded logs (:func:`fitstiff.io.loading.load_logs`); seal and chamber parameters
            are shared, each log has its own force offset and initial friction state.
        model: spec string (``"chamber+dahl"``) or a built model (its values start the fit).
        fix: names to hold (``["n"]``) or names with values (``{"n": 1.4}``, SI units).
        solver: one of :data:`SOLVERS` (optimistix's Levenberg-Marquardt by default; for
            a Jacobian beyond :data:`LEAN_JACOBIAN_MB` fitstiff's normal-equations form,
            ``"lm-normal"``, which ``FitResult.solver`` then names).
        starts: number of starts; the first from :func:`initial_guess`, the others random
            perturbations of it (``seed``); the best converged run is kept.
        denoise, sample_range, weights, skip, free, exclude: see
            :class:`~fitstiff.inference.problem.Problem`
            (``free=["closing_pressure"]`` fits each log's closing pressure).

    Returns:
        A :class:`FitResult`; ``converged`` is False (with ``message``) when the solver did
        not converge - the result is never silently dropped or raised away.

    Example:
        >>> result = fit(logs, "chamber+dahl", fix={"n": 1.4})          # doctest: +SKIP
        >>> print(result.table())                                        # doctest: +SKIP
    """
    problem = Problem(logs, model, fix=fix, denoise=denoise, sample_range=sample_range,
                      weights=weights, skip=skip, free=free, exclude=exclude)
    return fit_problem(problem, solver=solver, starts=starts, seed=seed, max_steps=max_steps,
                       rtol=rtol, atol=atol)


class _Run(NamedTuple):
    """One solve's outcome, whichever solver ran."""

    theta: jax.Array
    converged: bool        # the solver's verdict
    out_of_steps: bool     # its step budget ran out
    message: str           # the solver's status in words
    steps: int
    cost: float


def _solve(p: Problem, theta0, *, solver: str, rtol: float, atol: float, max_steps: int):
    """The least-squares solve from ``theta0``: ``(theta, status, steps, cost)``
    (compiled by :meth:`~fitstiff.inference.problem.Problem.compiled`)."""
    method = SOLVERS[solver](rtol, atol)
    if isinstance(method, NormalEquationsLM):
        sol = lm.levenberg_marquardt(p.residuals, theta0, rtol=rtol, atol=atol,
                                     max_steps=max_steps, normal=True)
        return sol.value, sol.status, sol.steps, sol.cost
    residuals = materialised_jacobian(p.residuals)
    sol = optx.least_squares(lambda theta, _: residuals(theta), method, theta0,
                             max_steps=max_steps, throw=False)
    r = p.residuals(sol.value)
    return sol.value, sol.result, sol.stats["num_steps"], jnp.sum(r**2)


def _solver(problem: Problem, solver: str, rtol: float, atol: float, max_steps: int):
    """The least-squares solve of ``problem``, ``theta0 -> _Run``, compiled once per
    settings and reused across starts and calls."""
    own = SOLVERS[solver] is NormalEquationsLM
    compiled = problem.compiled(_solve, solver=solver, rtol=rtol, atol=atol,
                                max_steps=max_steps)

    def run(theta0) -> _Run:
        return _as_run(own, *compiled(theta0))

    return run


def _as_run(own: bool, theta, status, steps, cost) -> _Run:
    """A :func:`_solve`'s outputs as a :class:`_Run` (``own``: fitstiff's LM ran, whose
    status codes are :mod:`fitstiff.inference.lm`'s; else optimistix's)."""
    if own:
        code = int(status)
        return _Run(theta, code == lm.CONVERGED, code == lm.MAX_STEPS, lm.STATUS[code],
                    int(steps), float(cost))
    return _Run(theta, bool(status == optx.RESULTS.successful), _out_of_steps(status),
                str(optx.RESULTS[status]), int(steps), float(cost))


def _is_lean(problem: Problem) -> bool:
    """Whether ``problem``'s Jacobian (residuals x entries, float64) exceeds
    :data:`LEAN_JACOBIAN_MB`: then the fit takes the memory-lean paths (the normal-equations
    solve, a Jacobian built one column at a time in the summary)."""
    rows = max(s.span.stop for s in problem.residual_series())
    return rows * problem.size * 8 > LEAN_JACOBIAN_MB * 2**20


def _lean(problem: Problem, solver: str) -> str:
    """``solver``, or ``"lm-normal"`` for ``"lm"`` on a lean problem (:func:`_is_lean`)."""
    return "lm-normal" if solver == "lm" and _is_lean(problem) else solver


def materialised_jacobian(f):
    """``f`` whose JVP multiplies by a Jacobian built once per point with ``jacfwd``.

    The solvers linearise the residual function and then apply the linear map once per
    parameter (to materialise it) and again in the linear solves; replaying the linearised
    hysteresis scan each time costs several times one forward-mode Jacobian. With this rule
    the scan runs once per point, carrying all parameter tangents together.
    """

    @jax.custom_jvp
    def wrapped(theta):
        return f(theta)

    @wrapped.defjvp
    def _jvp(primals, tangents):
        (theta,), (tangent,) = primals, tangents
        jac, value = jax.jacfwd(lambda th: (f(th), f(th)), has_aux=True)(theta)
        return value, jac @ tangent

    return wrapped


def fit_problem(problem: Problem, *, solver: str = "lm", starts: int = 1, seed: int = 0,
                max_steps: int = 400, rtol: float = 1e-5, atol: float = 1e-5,
                initial: tuple[Model, Mapping[str, np.ndarray]] | None = None) -> FitResult:
    """Fit a prepared :class:`~fitstiff.inference.problem.Problem` (see :func:`fit`)."""
    if solver not in SOLVERS:
        raise InputError(None, f"--solver {solver}", "unknown solver",
                         f"use one of: {', '.join(SOLVERS)}")
    if starts < 1:
        raise InputError(None, f"--starts {starts}", "must be at least 1", "give 1 or more")
    model0, nuis0 = initial or initial_guess(problem)
    theta0 = problem.pack(model0, nuis0)
    solver = _lean(problem, solver)
    run = _solver(problem, solver, rtol, atol, max_steps)
    rng = np.random.default_rng(seed)
    runs = []
    for k in range(starts):
        start = np.array(theta0)
        if k:
            start[:problem.par.size] += rng.normal(scale=0.5, size=problem.par.size)
        runs.append(_judged(problem, run(jnp.asarray(start)), solver=solver, rtol=rtol,
                            atol=atol))
    return _best_of(problem, runs, solver=solver, starts=starts)


def fit_problems(problems: Sequence[Problem], *, solver: str = "lm", max_steps: int = 400,
                 rtol: float = 1e-5, atol: float = 1e-5, lanes: int = 8) -> list[FitResult]:
    """Fit many prepared problems, one start each: :func:`fit_problem` of each, with the
    solves of problems of one structure (:meth:`~fitstiff.inference.problem.Problem.structure_key`)
    run ``lanes`` at a time as one ``vmap``-ed call
    (:func:`~fitstiff.inference.problem.compiled_batch`: one compilation per structure, and a lane's
    result does not depend on its neighbours). What follows a solve (the flat-cost check, the
    covariance summary) is each problem's own. A fleet's cylinders go through here
    (:mod:`fitstiff.fleet`)."""
    if solver not in SOLVERS:
        raise InputError(None, f"--solver {solver}", "unknown solver",
                         f"use one of: {', '.join(SOLVERS)}")
    if lanes < 1:
        raise InputError(None, f"lanes {lanes}", "must be at least 1", "give 1 or more")
    groups: dict[object, list[int]] = {}
    for i, problem in enumerate(problems):
        key = problem.structure_key()
        groups.setdefault(("alone", i) if key is None else key, []).append(i)
    results: list[FitResult | None] = [None] * len(problems)
    for index in groups.values():
        chosen = _lean(problems[index[0]], solver)
        own = SOLVERS[chosen] is NormalEquationsLM
        for at in range(0, len(index), lanes):
            chunk = [problems[i] for i in index[at:at + lanes]]
            theta0 = jnp.stack([p.pack(*initial_guess(p)) for p in chunk])
            solve = compiled_batch(chunk, _solve, lanes=lanes, solver=chosen, rtol=rtol,
                                   atol=atol, max_steps=max_steps)
            outs = jax.tree.map(np.asarray, solve(theta0))    # the status: a pytree
            for k, (i, problem) in enumerate(zip(index[at:at + lanes], chunk)):
                lane = jax.tree.map(lambda x: x[k], outs)
                out = _as_run(own, jnp.asarray(lane[0]), *lane[1:])
                judged = _judged(problem, out, solver=chosen, rtol=rtol, atol=atol)
                results[i] = _best_of(problem, [judged], solver=chosen, starts=1)
    return results


def _judged(problem: Problem, out: _Run, *, solver: str, rtol: float, atol: float):
    """One start's ``(ok, cost, theta, run, walk)``: a run whose step budget ran out is
    taken as converged when the cost is flat on the scale of its standard errors
    (:func:`_flat_walk`; ``walk`` names what still moves)."""
    theta, cost = out.theta, out.cost
    ok = out.converged and bool(np.isfinite(cost))
    walk = None
    if out.out_of_steps and np.isfinite(cost):
        theta, cost, walk = _flat_walk(problem, theta, cost, solver=solver,
                                       rtol=rtol, atol=atol)
        ok = walk is not None
    return ok, float(cost), np.asarray(theta), out, walk


def _best_of(problem: Problem, runs, *, solver: str, starts: int) -> FitResult:
    """The :class:`FitResult` of the best converged start (else the best start)."""
    converged_runs = [r for r in runs if r[0]]
    best = min(converged_runs or runs, key=lambda r: r[1] if np.isfinite(r[1]) else np.inf)
    agreed = sum(1 for r in converged_runs
                 if r is best or abs(r[1] - best[1]) <= 1e-6 * max(best[1], 1.0)
                 and np.allclose(problem.par.physical(jnp.asarray(r[2][:problem.par.size])),
                                 problem.par.physical(jnp.asarray(best[2][:problem.par.size])),
                                 rtol=1e-3, atol=1e-9))
    ok, cost, theta, out, walk = best
    message = "converged" if ok else (out.message if not out.converged else "non-finite cost")
    notes = []
    if walk is not None:
        message = "converged (the cost is flat on the scale of its standard errors)"
        moving = (f"; what still moves most: {', '.join(walk)}, which the data hardly "
                  "determine near the optimum (e.g. a transformed coordinate walking towards "
                  "its bound)") if walk else ""
        notes.append(f"the step budget ran out with the cost flat: {_FLAT_STEPS} more steps "
                     f"lowered it by less than a move of {_FLAT_SD:g} standard error would"
                     f"{moving}; the fit is taken as converged")
    return _summarise(problem, jnp.asarray(theta), converged=ok, message=str(message),
                      steps=out.steps, solver=solver,
                      starts={"requested": starts, "converged": len(converged_runs),
                              "agreed": agreed}, notes=notes)


def _out_of_steps(result) -> bool:
    return bool(result == optx.RESULTS.nonlinear_max_steps_reached) or bool(
        result == optx.RESULTS.max_steps_reached)


def _flat_walk(problem: Problem, theta, cost: float, *, solver: str, rtol: float,
               atol: float) -> tuple[jax.Array, float, list[str] | None]:
    """After the step budget ran out: :data:`_FLAT_STEPS` more steps from ``theta``. Returns
    their end, its cost and the names of the entries that still moved when the cost fell by
    less than ``_FLAT_SD**2`` residual variances (AR(1)-inflated): converged on the scale of
    the standard errors; else ``theta``, ``cost`` and ``None`` (not converged)."""
    probe = _solver(problem, solver, rtol, atol, _FLAT_STEPS)(theta)
    after, cost_after = probe.theta, probe.cost
    if not np.isfinite(cost_after):
        return theta, cost, None
    rho = _lag1(problem, problem.per_log(after))
    inflation = (1 + rho) / (1 - rho) if rho > 0 else 1.0
    variance = cost_after / max(problem.n_data - problem.size, 1) * inflation
    if cost - cost_after > _FLAT_SD**2 * variance:
        return theta, cost, None
    before, after_np = np.asarray(theta), np.asarray(after)
    change = np.abs(after_np - before)
    moved = (change > atol + rtol * np.abs(before)) & (change >= 0.1 * change.max())
    return after, cost_after, [n for n, m in zip(problem.names, moved) if m]


def _summarise(problem: Problem, theta, *, converged: bool, message: str, steps: int,
               solver: str, starts: Mapping[str, int], notes: Sequence[str] = ()) -> FitResult:
    lean = _is_lean(problem)
    spans = tuple(tuple((s.span.start, s.span.stop) for s in problem.residual_series()
                        if s.log == i) for i in range(problem.n_logs))
    ev = problem.compiled(_summary_evaluate, spans=spans, sequential=lean)
    summary = jax.tree.map(np.asarray, ev(theta))
    if lean:    # apart: the two working sets of a long log do not add up
        summary = summary._replace(eiv_gram=np.asarray(
            problem.compiled(_eiv_gram)(theta)))
    check_finite(problem.logs, "the fit's whitened residuals and Jacobian", summary.largest,
                 limit=_RESIDUAL_LIMIT)
    check_finite(problem.logs, "the fitted parameter values", summary.values, summary.dphys)
    values, dphys, d0, g0 = summary.values, summary.dphys, summary.derived, summary.gradient
    n_data, n_par = problem.n_data, problem.size
    cost = float(summary.cost)
    s2 = cost / max(n_data - n_par, 1)
    per_log_pred = [{"force": f} for f in problem.unpad(summary.force)]
    rho = _lag1(problem, per_log_pred)
    inflation = (1 + rho) / (1 - rho) if rho > 0 else 1.0

    # covariance in theta, via the SVD of J's triangular factor (J's singular values and
    # directions); undetermined directions named, not inverted
    _, sv, vt = np.linalg.svd(summary.r_factor, full_matrices=False)
    keep = sv > _SINGULAR * sv[0] if sv.size else np.zeros(0, bool)
    inv = np.where(keep, 1.0 / np.where(keep, sv, 1.0) ** 2, 0.0)
    jtj_inv = (vt.T * inv) @ vt
    # force noise (AR(1)-inflated) + turning-point errors propagated through the scan
    cov_theta = jtj_inv * s2 * inflation + jtj_inv @ summary.eiv_gram @ jtj_inv
    names = problem.names
    warnings = []
    undetermined = np.zeros(n_par, dtype=bool)
    for j in np.flatnonzero(~keep):
        involved = np.flatnonzero(np.abs(vt[j]) > 0.3)
        undetermined[involved] = True
        combo = " + ".join(f"{vt[j][i]:+.2f} {names[i]}" for i in involved)
        warnings.append(f"the data do not determine the combination {combo}; their standard "
                        "errors are not reported (fix one of them or add excitation)")

    # physical values and their covariance (delta method through the transforms)
    cov = dphys @ cov_theta @ dphys.T
    check_finite(problem.logs, "the fit's covariance", cov)
    stderr = np.sqrt(np.clip(np.diag(cov), 0, None))
    stderr[undetermined] = np.nan
    corr = _correlation(cov[:problem.par.size, :problem.par.size])
    model_names = problem.par.names
    for i in range(len(model_names)):
        for j in range(i + 1, len(model_names)):
            if abs(corr[i, j]) > _CORRELATION_WARNING and not (undetermined[i] or undetermined[j]):
                warnings.append(
                    f"{model_names[i]} and {model_names[j]} are strongly correlated "
                    f"(r = {corr[i, j]:+.3f}): the data determine mainly a combination of "
                    "them, so their separate values are uncertain")
    if rho >= _LAG1_CAP:
        warnings.append(f"the residuals follow a slow systematic misfit, not noise (lag-1 r "
                        f"at its cap {_LAG1_CAP}): the standard errors carry the capped AR(1) "
                        f"factor {math.sqrt(inflation):.1f}, a lower bound, and do not measure "
                        "the uncertainty; the model misses an effect (see fitstiff diagnose)")
    elif rho > 0.5:
        warnings.append(f"residuals are strongly autocorrelated (lag-1 r = {rho:.2f}): "
                        "standard errors are inflated by the AR(1) factor "
                        f"{math.sqrt(inflation):.2f}; the model may miss an effect "
                        "(see fitstiff diagnose)")
    if not converged:
        warnings.insert(0, f"the solver did not converge: {message}")
    warnings.extend(notes)
    # what the loader found in a log (spikes, a force scale no cylinder has) stays beside
    # the fit that went through it
    warnings.extend(f"{log.name}: {note}" for log in problem.logs for note in log.notes
                    if note.endswith(_UNTRUSTED))

    # derived quantities at the first log's operating point (per-log chamber stiffness below)
    var0 = np.einsum("ij,jk,ik->i", g0, cov_theta, g0)
    derived = {}
    for k, name in enumerate(DERIVED):
        err = math.sqrt(max(var0[k], 0.0))
        if np.any(undetermined & (np.abs(g0[k]) > 0)):
            err = float("nan")
        derived[name] = (float(d0[k]), err)

    warnings += _implausible(problem, values, derived)
    identifiability = _identifiability(problem, summary,
                                       {k: v for k, (v, _) in derived.items()})
    withheld = set(identifiability.parameters)
    stderr[[i for i, n in enumerate(names) if n in withheld]] = np.nan
    for name in identifiability.derived:
        derived[name] = (derived[name][0], float("nan"))

    model, nuis = problem.unpack_physical(values)
    per_log = []
    raw_sq, raw_n = 0.0, 0
    for i, (log, pred) in enumerate(zip(problem.logs, per_log_pred)):
        w = problem.sample_weights[i] > 0
        res = (pred["force"] - np.asarray(log.force))[w]
        raw_sq += float(res @ res)
        raw_n += res.size
        k_ch = (derived_display("chamber_stiffness_N_per_mm",
                                float(summary.chamber_stiffness[i]))
                if model.has("chamber") else 0.0)
        entry = {"name": log.name, "file": str(log.path) if log.path else None,
                 "samples": len(log), "rms_N": math.sqrt(float(res @ res) / max(res.size, 1)),
                 "offset_N": 0.0, "friction_state0": None,
                 "chamber_stiffness_N_per_mm": _finite(k_ch),
                 "closing_pressure_bar": (NUISANCE_PARAMS["closing_pressure"].to_display(
                     log.rig.supply_pressure) if log.rig.supply_pressure is not None else None),
                 "force_noise_N": problem.force_noise[i],
                 # the marginal level: read as white, correlated noise looks smaller
                 "displacement_noise_um": (problem.displacement_noise[i]
                                           * marginal_scale(problem.displacement_rho[i]) * 1e6),
                 "displacement_noise_rho": problem.displacement_rho[i],
                 "denoised_displacement": problem.denoised[i]}
        entry |= {key: p.to_display(float(nuis[name][i]))
                  for name, (key, p) in PER_LOG_NUISANCES.items() if name in nuis}
        per_log.append(entry)
    k = n_par
    n = max(n_data, 1)
    aic = n * math.log(max(cost, 1e-300) / n) + 2 * k
    bic = n * math.log(max(cost, 1e-300) / n) + k * math.log(n)
    fixed = {name: v for name, v in Parameterization(problem.model).values(model).items()
             if name in problem.par_fixed}
    return FitResult(
        model=model, names=tuple(names), values=values, stderr=stderr, covariance=cov,
        units=problem.par.units(),
        fixed=fixed, derived=derived, per_log=per_log, converged=converged, message=message,
        steps=steps, solver=solver, rms_N=math.sqrt(raw_sq / max(raw_n, 1)), cost=cost,
        n_data=n_data, n_params=n_par, aic=aic, bic=bic, residual_autocorrelation=rho,
        warnings=tuple(warnings), identifiability=identifiability,
        files=tuple(str(log.path) if log.path else log.name for log in problem.logs),
        starts=starts, theta=np.asarray(theta), problem=problem)


def _identifiability(problem: Problem, summary: _Summary,
                     derived: Mapping[str, float]) -> Identifiability:
    """:func:`~fitstiff.inference.identifiability.assess_identifiability` of a fit: the data checks
    on the (denoised) drives, the null-direction check on ``J^T J`` in physical coordinates."""
    names = problem.names
    dphys, g0 = summary.dphys, summary.gradient
    kinds = {}
    for i, p, flat in named_params(problem.model):
        term = problem.model.terms[i]
        is_seal = isinstance(term, FrictionBase) or (isinstance(term, Modifier)
                                                     and term.targets is FrictionBase)
        for n in flat:
            kinds[n] = (is_seal, p.unit)
    seal = [n for n in problem.par.names if kinds[n][0]]
    states = [j for j, n in enumerate(names) if n.startswith("friction_state0[")]
    if seal:
        seal += [names[j] for j in states]
    # physical coordinates: A = d(theta)/d(physical); a state's column comes from its JVP
    d = np.array(dphys, dtype=float)
    d[states, states] = 1.0
    a = np.linalg.pinv(d)
    gram = a.T @ (summary.r_factor.T @ summary.r_factor) @ a
    for j, i in zip(states, range(problem.n_logs)):
        gram[:, j] = gram[j, :] = a.T @ summary.state_cross[i]
        gram[j, j] = float(summary.state_norm2[i])
    gradient = g0 @ a
    breakaway = gradient[DERIVED.index("breakaway_N")]
    levels = [n for j, n in enumerate(names) if n in seal and not n.startswith("friction_state0[")
              and (kinds[n][1] == "N" or abs(breakaway[j]) > 0)]
    n_rev, travel = reversal_travel([np.asarray(dr.displacement) for dr in problem.drives],
                                    [s.reversals for s in problem.segmentations],
                                    problem.sample_weights)
    return assess_identifiability(names=names, seal=seal, levels=levels, reversals=n_rev,
                                  longest_travel_m=travel, derived=derived, gram=gram,
                                  derived_gradient=gradient, derived_names=DERIVED)


class _Summary(NamedTuple):
    """What the covariance summary needs of the residuals ``r`` and their Jacobian ``J`` at
    the optimum, reduced inside one compiled function (:func:`_summary_evaluate`; on a lean
    problem, two: :func:`_eiv_gram` apart, so that their working sets do not add up): no
    ``(residuals, parameters)`` array leaves them (a 1 M-sample log's ``J`` and its copies
    are hundreds of MB, ``benchmarks/fit_memory.py``)."""

    cost: jax.Array           # |r|^2
    largest: jax.Array        # max |entry| of r and J (NaN counts as infinite)
    r_factor: jax.Array       # R of J = QR: J's singular values and right vectors; J^T J = R^T R
    values: jax.Array         # physical values of theta
    dphys: jax.Array          # their Jacobian d(physical)/d(theta)
    derived: jax.Array        # derived quantities (first log), in DERIVED order
    gradient: jax.Array       # their gradient in theta
    state_cross: jax.Array    # (logs, size): J^T u_i, u_i the residuals' derivative by log i's
    state_norm2: jax.Array    # (logs,): |u_i|^2          initial friction state (physical)
    force: tuple              # per group: the predicted force (leading log axis, padded)
    chamber_stiffness: jax.Array  # (logs,): the chamber's at each log's start (N/m; none: 0)
    #: C^T C of the turning-point error columns C (errors in variables; on a lean problem
    #: from :func:`_eiv_gram`)
    eiv_gram: jax.Array | None


def _summary_evaluate(problem: Problem, theta, *, spans: tuple[tuple[tuple[int, int], ...], ...],
                      sequential: bool) -> _Summary:
    """The :class:`_Summary` at ``theta`` (compiled by
    :meth:`~fitstiff.inference.problem.Problem.compiled`); ``spans``: per log, its ``(start, stop)``
    entries of the residual vector; ``sequential``: build ``J`` one column at a time
    (:func:`fitstiff.inference.lm.jacobian_rows`) and leave ``eiv_gram`` to :func:`_eiv_gram`.

    Otherwise one compiled function shares ``J`` between the covariance and the
    turning-point columns (``C^T = J^T B S``: a VJP per row of ``J^T``), and the predicted
    force comes out of the residuals' own forward pass. On the benchmark log of
    ``benchmarks/fit_speed.py`` a cold ``fitstiff fit`` took a median 12.6 s (15.9 s of
    CPU) against 13.6 s (17.1 s) with the two functions and the predictions compiled apart
    (five alternating runs each, a slow host), with the same fit.json to 1e-14; building
    ``C^T`` one row at a time (``lax.map``, no extra memory) gained about half of that.
    """

    def derived_vec(th):
        d = derived_quantities(problem.unpack(th)[0], problem.drives[0])
        return jnp.stack([d[k] for k in DERIVED])

    model, nuisances = problem.unpack(theta)

    def residuals_and_force(xs):
        preds = problem.model_predictions(model, nuisances, xs)
        return problem.model_residuals(model, nuisances, xs, predictions=preds), tuple(
            p.force for p in preds)

    jt = lm.jacobian_rows(problem.residuals, theta, sequential=sequential)      # J^T
    if sequential:
        r, force = residuals_and_force(None)
        eiv_gram = None
    else:
        r, vjp, force = jax.vjp(residuals_and_force, problem.displacements(), has_aux=True)
        ct = jax.vmap(lambda j: _scaled_cotangent(problem, vjp(j)[0]))(jt)
        eiv_gram = lm.wide_dot(ct, ct)
    state = _state_columns(problem, theta)
    cross, norm2 = [], []
    if state.size:
        # each log's share of the state column, masked rather than sliced out of J^T
        # (a slice of J^T is a copy: +130 MB for a 1 M-sample log)
        # (the series tile the residual vector: each entry's log, in order of the spans)
        owner = jnp.concatenate([jnp.full(b - a, i) for a, b, i in sorted(
            (a, b, i) for i, log_spans in enumerate(spans) for a, b in log_spans)])
        for i in range(len(spans)):
            u = jnp.where(owner == i, state, 0.0)
            cross.append(jnp.sum(jt * u, axis=1))
            norm2.append(u @ u)
    size = theta.shape[0]

    def largest(a):         # max |entry|, infinite with a NaN (fused: no copy of J^T)
        return jnp.where(jnp.any(jnp.isnan(a)), jnp.inf, jnp.max(jnp.abs(a)))

    return _Summary(
        cost=r @ r,
        largest=jnp.maximum(largest(r), largest(jt)),
        r_factor=lm.r_factor(jt),
        values=problem.physical(theta), dphys=jax.jacfwd(problem.physical)(theta),
        derived=derived_vec(theta), gradient=jax.jacfwd(derived_vec)(theta),
        state_cross=jnp.stack(cross) if cross else jnp.zeros((0, size)),
        state_norm2=jnp.stack(norm2) if norm2 else jnp.zeros(0),
        force=force, chamber_stiffness=_chamber_stiffness(problem, model), eiv_gram=eiv_gram)


def _eiv_gram(problem: Problem, theta):
    """``C^T C`` of the errors in variables at the turning points, ``C = S B^T J`` with
    ``B = d(residuals)/d(displacement)`` and ``S`` the turning points' errors at their
    samples (0 elsewhere), for a lean problem: a JVP and a VJP per parameter, one parameter
    at a time, so no ``J`` is built (:func:`_summary_evaluate` does it from its ``J``)."""
    _, vjp = jax.vjp(lambda xs: problem.residuals(theta, xs), problem.displacements())

    def column(e):
        j = jax.jvp(problem.residuals, (theta,), (e,))[1]
        return _scaled_cotangent(problem, vjp(j)[0])

    ct = jax.lax.map(column, jnp.eye(theta.shape[0], dtype=theta.dtype))      # C^T
    return lm.wide_dot(ct, ct)


def _chamber_stiffness(problem: Problem, model):
    """Each log's linearised chamber stiffness (N/m) at its start, 0 without a chamber."""
    if not model.has("chamber"):
        return jnp.zeros(problem.n_logs)
    return jnp.stack([jnp.asarray(model.term("chamber").stiffness(d), dtype=float)
                      for d in problem.drives])


def _scaled_cotangent(problem: Problem, cotangent):
    """A cotangent of the displacements (per group), times each sample's turning-point
    error (0 away from the turning points), flat: a row of ``C^T``."""
    return jnp.concatenate([(c * s).ravel() for c, s in zip(cotangent,
                                                             problem.reversal_noise())])


def _state_columns(problem: Problem, theta):
    """d(residuals)/d(initial friction state) in physical coordinates, summed over the logs
    (their rows are disjoint): the tanh transform flattens at saturation, where a fit
    without reversals ends, and hides the state's trade-off with the seal."""
    model, nuisances = problem.unpack(theta)
    if "friction_state0" not in nuisances:
        return jnp.zeros(0)
    z = nuisances["friction_state0"]
    _, column = jax.jvp(lambda zz: problem.model_residuals(
        model, {**nuisances, "friction_state0": zz}), (z,), (jnp.ones_like(z),))
    return column


def _implausible(problem: Problem, values: np.ndarray,
                 derived: Mapping[str, tuple[float, float]]) -> list[str]:
    """Warnings for estimates a converged fit should not be trusted on (issue 17): a
    parameter at a bound of its range (the data push it out of the model's range, or do not
    hold it), and a breakaway force far above every measured force (the logs never reach
    breakaway: the value is the model's extrapolation)."""
    out = []
    free = dict(zip(problem.par.names, values))
    for _, p, names in named_params(problem.model):
        for name in names:
            if name not in free:
                continue
            x = float(free[name])
            span = p.upper - p.lower if math.isfinite(p.upper - p.lower) else abs(x)
            near = _AT_BOUND * max(span, p.to_si(1.0))   # a share of the span, or of one unit
            for bound, side in ((p.lower, "lower"), (p.upper, "upper")):
                if p.null is not None and bound == p.null:
                    continue          # an effect at its null is simply absent
                if math.isfinite(bound) and abs(x - bound) <= near:
                    out.append(f"{name} sits at its {side} bound ({p.to_display(bound):.4g} "
                               f"{p.unit}): the logs do not hold it inside the model's range; "
                               "its value and standard error mean nothing (fix it, or record "
                               "the motion that determines it)")
    largest = max(float(np.max(np.abs(np.asarray(log.force)))) for log in problem.logs)
    breakaway = derived.get("breakaway_N", (math.nan, math.nan))[0]
    sliding, static = free.get("Fc"), free.get("Fs")
    if sliding is not None and static is not None and static < 0.9 * sliding:
        out.append(f"the static friction Fs {static:.4g} N (the breakaway) is below the "
                   f"sliding friction Fc {sliding:.4g} N: not seal physics; the logs do not "
                   "determine the friction near rest (record slow starts from standstill) or "
                   "the model does not fit them")
    if math.isfinite(breakaway) and abs(breakaway) > _BREAKAWAY_EXCESS * largest:
        out.append(f"the breakaway force {breakaway:.4g} N is more than {_BREAKAWAY_EXCESS:g} "
                   f"times the largest measured force ({largest:.4g} N): the logs do not "
                   "reach breakaway, so it is the model's extrapolation, not a measurement "
                   "(record a log that slides)")
    return out


def _lag1(problem: Problem, per_log_pred) -> float:
    """Pooled lag-1 autocorrelation of the force residuals over the weighted samples."""
    num = den = 0.0
    for i, (log, pred) in enumerate(zip(problem.logs, per_log_pred)):
        res = pred["force"] - np.asarray(log.force)
        res = res[problem.sample_weights[i] > 0]
        res = res - res.mean()
        num += float(res[1:] @ res[:-1])
        den += float(res @ res)
    return float(np.clip(num / den, -_LAG1_CAP, _LAG1_CAP)) if den > 0 else 0.0
