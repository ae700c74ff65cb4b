"""Least squares: :func:`fit` and :func:`fit_problem` choose a solver (optimistix or fitstiff's
own Levenberg-Marquardt, the memory-lean form for long logs), run it from one or several starts,
judge its status (never dropped) and summarise the best; :func:`fit_problems` solves many
problems of one structure."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import NamedTuple

import numpy as np
import optimistix as optx

from fitstiff._jax import jax, jnp, on_host
from fitstiff.errors import InputError
from fitstiff.inference import lm
from fitstiff.inference.fitting.result import FitResult
from fitstiff.inference.fitting.start import initial_guess
from fitstiff.inference.fitting.summary import (_is_lean, _lag1, _summarise, summary_evaluate,
                                                summary_spans)
from fitstiff.inference.problem import Problem, compiled_batch
from fitstiff.inference.selection import Selection
from fitstiff.io.log import Log
from fitstiff.physics.model import Model

__all__ = ["fit", "fit_problem", "fit_problems", "SOLVERS"]


class _NormalEquationsLM(NamedTuple):
    """fitstiff's Levenberg-Marquardt in its normal-equations form
    (:func:`fitstiff.inference.lm.levenberg_marquardt` ``normal=True``): no Jacobian kept between
    steps. ``"lm"`` runs it when the Jacobian would exceed :data:`LEAN_JACOBIAN_MB`."""

    rtol: float
    atol: float


SOLVERS = {
    "lm": lambda rtol, atol: optx.LevenbergMarquardt(rtol=rtol, atol=atol),
    "lm-normal": _NormalEquationsLM,
    "dogleg": lambda rtol, atol: optx.Dogleg(rtol=rtol, atol=atol),
    "gauss-newton": lambda rtol, atol: optx.GaussNewton(rtol=rtol, atol=atol),
    "bfgs": lambda rtol, atol: optx.BFGS(rtol=rtol, atol=atol),
}
#: after the step budget ran out, :data:`_FLAT_STEPS` more steps: when the cost falls by less
#: than what moves the fit :data:`_FLAT_SD` of a standard error (``_FLAT_SD**2`` times the
#: residual variance, AR(1)-inflated as the standard errors are), the fit has converged as
#: far as its uncertainty can tell, and what still moves is a coordinate the data do not
#: determine (issue 17: on the O-ring logs LuGre's initial friction states walked for 3 000
#: steps at a cost change of 2e-6 relative, about 0.02 standard errors)
_FLAT_STEPS = 10
_FLAT_SD = 0.1


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
        denoise, sample_range, weights, skip, free, exclude: the data options, see
            :class:`~fitstiff.inference.selection.Selection`
            (``free=["closing_pressure"]`` fits each log's closing pressure).

    Returns:
        A :class:`FitResult`; ``converged`` is False (with ``message``) when the solver did
        not converge - the result is never silently dropped or raised away.

    Example:
        >>> result = fit(logs, "chamber+dahl", fix={"n": 1.4})          # doctest: +SKIP
        >>> print(result.table())                                        # doctest: +SKIP
    """
    selection = Selection(denoise=denoise, sample_range=sample_range, weights=weights,
                          skip=skip, free=free, exclude=exclude)
    problem = Problem(logs, model, fix=fix, selection=selection)
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
    if isinstance(method, _NormalEquationsLM):
        sol = lm.levenberg_marquardt(p.residuals, theta0, rtol=rtol, atol=atol,
                                     max_steps=max_steps, normal=True)
        return sol.value, sol.status, sol.steps, sol.cost
    residuals = _materialised_jacobian(p.residuals)
    sol = optx.least_squares(lambda theta, _: residuals(theta), method, theta0,
                             max_steps=max_steps, throw=False)
    r = p.residuals(sol.value)
    return sol.value, sol.result, sol.stats["num_steps"], jnp.sum(r**2)


def _solver(problem: Problem, solver: str, rtol: float, atol: float, max_steps: int):
    """The least-squares solve of ``problem``, ``theta0 -> _Run``, compiled once per
    settings and reused across starts and calls."""
    own = SOLVERS[solver] is _NormalEquationsLM
    if problem.chunked:         # the normal equations accumulated window by window
        windows = problem.windows

        def run_windows(theta0) -> _Run:
            sol = lm.levenberg_marquardt_reduced(windows.linearise, windows.cost, theta0,
                                                 rtol=rtol, atol=atol, max_steps=max_steps)
            return _as_run(True, sol.value, sol.status, sol.steps, sol.cost)

        return run_windows
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


def _lean(problem: Problem, solver: str) -> str:
    """``solver``, or ``"lm-normal"`` for ``"lm"`` on a lean problem (:func:`_is_lean`) or a
    chunked one (the normal equations accumulated over its windows)."""
    return ("lm-normal" if solver == "lm" and (problem.chunked or _is_lean(problem))
            else solver)


def _materialised_jacobian(f):
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
    if problem.chunked and solver not in ("lm", "lm-normal"):
        raise InputError(None, f"--solver {solver}",
                         f"the logs ({sum(len(log) for log in problem.logs)} samples) are "
                         "fitted in windows, by fitstiff's Levenberg-Marquardt only",
                         "drop --solver, or fit a shorter stretch (--range)")
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
    result does not depend on its neighbours). The flat-cost check after a solve is each
    problem's own; the covariance summary's compiled part runs batched the same way (each
    problem's own where it takes the memory-lean path). A fleet's cylinders go through here
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
        own = SOLVERS[chosen] is _NormalEquationsLM
        for at in range(0, len(index), lanes):
            chunk = [problems[i] for i in index[at:at + lanes]]
            with on_host():
                theta0 = np.stack([np.asarray(p.pack(*initial_guess(p))) for p in chunk])
            solve = compiled_batch(chunk, _solve, lanes=lanes, solver=chosen, rtol=rtol,
                                   atol=atol, max_steps=max_steps)
            outs = jax.tree.map(np.asarray, solve(theta0))    # the status: a pytree
            judged = []
            with on_host():         # each lane's own steps: on the host, where a GPU batched
                for k, problem in enumerate(chunk):
                    lane = jax.tree.map(lambda x: x[k], outs)
                    out = _as_run(own, jnp.asarray(lane[0]), *lane[1:])
                    judged.append(_judged(problem, out, solver=chosen, rtol=rtol, atol=atol))
            evaluated = _batched_summaries(chunk, [j[2] for j in judged], lanes=lanes,
                                           solver=chosen)
            with on_host():
                for k, i in enumerate(index[at:at + lanes]):
                    results[i] = _best_of(problems[i], [judged[k]], solver=chosen, starts=1,
                                          evaluated=evaluated[k])
    return results


def _batched_summaries(chunk: Sequence[Problem], thetas, *, lanes: int, solver: str) -> list:
    """:func:`~fitstiff.inference.fitting.summary.summary_evaluate` of each problem of
    ``chunk`` at its ``theta``, as one ``vmap``-ed call (on a GPU, one call instead of one
    per problem); ``None`` for each where the summary takes the memory-lean path or the
    problems' residual layouts differ (then each is summarised on its own)."""
    spans = summary_spans(chunk[0])
    if (solver == "lm-normal" or any(_is_lean(p) for p in chunk)
            or any(summary_spans(p) != spans for p in chunk[1:])):
        return [None] * len(chunk)
    ev = compiled_batch(chunk, summary_evaluate, lanes=lanes, spans=spans, sequential=False)
    out = jax.tree.map(np.asarray, ev(np.stack([np.asarray(t) for t in thetas])))
    return [jax.tree.map(lambda x: x[k], out) for k in range(len(chunk))]


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


def _best_of(problem: Problem, runs, *, solver: str, starts: int,
             evaluated=None) -> FitResult:
    """The :class:`FitResult` of the best converged start (else the best start);
    ``evaluated``: the summary at that start's end, already computed (one start only)."""
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
                              "agreed": agreed}, notes=notes, evaluated=evaluated)


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
    rho = _lag1(problem, problem.per_log(after))     # a chunked problem's window by window
    inflation = (1 + rho) / (1 - rho) if rho > 0 else 1.0
    variance = cost_after / max(problem.n_data - problem.size, 1) * inflation
    if cost - cost_after > _FLAT_SD**2 * variance:
        return theta, cost, None
    before, after_np = np.asarray(theta), np.asarray(after)
    change = np.abs(after_np - before)
    moved = (change > atol + rtol * np.abs(before)) & (change >= 0.1 * change.max())
    return after, cost_after, [n for n, m in zip(problem.names, moved) if m]
