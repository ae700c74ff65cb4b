"""After a solve: the Gauss-Newton covariance (widened for autocorrelated residuals and the
turning points' errors), the derived quantities with their standard errors, identifiability,
plausibility warnings and the fit's record (:func:`_summarise`)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import numpy as np

from fitstiff._jax import jax, jnp
from fitstiff.inference import lm
from fitstiff.inference.fitting.result import FitResult, PER_LOG_NUISANCES, _correlation, _finite
from fitstiff.inference.identifiability import (Identifiability, assess_identifiability,
                                                reversal_travel)
from fitstiff.inference.nuisances import NUISANCE_PARAMS
from fitstiff.inference.problem import Problem
from fitstiff.io.guards import check_finite
from fitstiff.physics.derived import DERIVED, derived_quantities
from fitstiff.physics.derived import to_display as derived_display
from fitstiff.physics.params import Parameterization, named_params
from fitstiff.physics.terms.base import FrictionBase, Modifier
from fitstiff.signal.noise import marginal_scale
from fitstiff.signal.spikes import UNTRUSTED as _UNTRUSTED

__all__ = ["LEAN_JACOBIAN_MB", "summary_evaluate", "summary_spans", "errors_in_variables_gram",
           "implausible"]

#: ``"lm"`` switches to ``"lm-normal"`` when the Jacobian (residuals x entries, float64)
#: would exceed this: optimistix's Levenberg-Marquardt holds about four Jacobian-sized
#: arrays at once (the accepted point's, the trial point's, the damped operator and its QR;
#: XLA's buffer assignment), 1.2 GB peak for a 1 M-sample log with two pressure channels
#: (``benchmarks/fit_memory.py``); and the default covariance summary shares one vectorised
#: Jacobian between the covariance and the turning-point columns (:func:`summary_evaluate`).
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
_RESIDUAL_LIMIT = 1e100  # whitened residuals / Jacobian entries beyond this are refused


def _is_lean(problem: Problem) -> bool:
    """Whether ``problem``'s Jacobian (residuals x entries, float64) exceeds
    :data:`LEAN_JACOBIAN_MB`: then the fit takes the memory-lean paths (the normal-equations
    solve, a Jacobian built one column at a time in the summary)."""
    rows = max(s.span.stop for s in problem.residual_series())
    return rows * problem.size * 8 > LEAN_JACOBIAN_MB * 2**20


def summary_spans(problem: Problem) -> tuple[tuple[tuple[int, int], ...], ...]:
    """Per log, the ``(start, stop)`` entries of its residual series (:func:`summary_evaluate`'s
    ``spans``)."""
    return tuple(tuple((s.span.start, s.span.stop) for s in problem.residual_series()
                       if s.log == i) for i in range(problem.n_logs))


def _summarise(problem: Problem, theta, *, converged: bool, message: str, steps: int,
               solver: str, starts: Mapping[str, int], notes: Sequence[str] = (),
               evaluated: _Summary | None = None) -> FitResult:
    """The fit's record at ``theta``; ``evaluated``: :func:`summary_evaluate` at ``theta``
    already computed (the batched fits of a fleet compute it for many problems in one call;
    never on the lean path)."""
    # the memory-lean summary where the solve was lean: for a long log, or when asked for
    lean = solver == "lm-normal" or _is_lean(problem)
    if problem.chunked:
        summary = _window_summary(problem, theta)
    elif evaluated is not None and not lean:
        summary = jax.tree.map(np.asarray, evaluated)
    else:
        ev = problem.compiled(summary_evaluate, spans=summary_spans(problem), sequential=lean)
        summary = jax.tree.map(np.asarray, ev(theta))
    if lean and not problem.chunked:    # apart: the two working sets do not add up
        summary = summary._replace(eiv_gram=np.asarray(
            problem.compiled(errors_in_variables_gram)(theta)))
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

    names = problem.names
    cov_theta, undetermined, warnings = _theta_covariance(summary, names, s2, inflation)

    # physical values and their covariance (delta method through the transforms)
    cov = dphys @ cov_theta @ dphys.T
    check_finite(problem.logs, "the fit's covariance", cov)
    stderr = np.sqrt(np.clip(np.diag(cov), 0, None))
    stderr[undetermined] = np.nan
    warnings += _correlation_warnings(cov[:problem.par.size, :problem.par.size],
                                      problem.par.names, undetermined)
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
    derived = {name: (float(d0[k]), float("nan") if np.any(undetermined & (np.abs(g0[k]) > 0))
                      else math.sqrt(max(var0[k], 0.0)))
               for k, name in enumerate(DERIVED)}

    warnings += implausible(problem, values, derived)
    identifiability = _identifiability(problem, summary,
                                       {k: v for k, (v, _) in derived.items()})
    withheld = set(identifiability.parameters)
    stderr[[i for i, n in enumerate(names) if n in withheld]] = np.nan
    for name in identifiability.derived:
        derived[name] = (derived[name][0], float("nan"))

    model, nuis = problem.unpack_physical(values)
    per_log, raw_sq, raw_n = _per_log(problem, per_log_pred, summary, model, nuis)
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


def _theta_covariance(summary: _Summary, names: Sequence[str], s2: float, inflation: float
                      ) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The covariance of ``theta`` (the residual variance ``s2`` times its AR(1)
    ``inflation`` times ``(J^T J)^-1``, plus the
    turning-point errors propagated through the scan) from the SVD of ``J``'s triangular
    factor, the entries it leaves undetermined, and a warning naming each undetermined
    combination (its directions are not inverted)."""
    _, sv, vt = np.linalg.svd(summary.r_factor, full_matrices=False)
    keep = sv > _SINGULAR * sv[0] if sv.size else np.zeros(0, bool)
    inv = np.where(keep, 1.0 / np.where(keep, sv, 1.0) ** 2, 0.0)
    jtj_inv = (vt.T * inv) @ vt
    cov_theta = jtj_inv * s2 * inflation + jtj_inv @ summary.eiv_gram @ jtj_inv
    warnings = []
    undetermined = np.zeros(len(names), dtype=bool)
    for j in np.flatnonzero(~keep):
        involved = np.flatnonzero(np.abs(vt[j]) > 0.3)
        undetermined[involved] = True
        combo = " + ".join(f"{vt[j][i]:+.2f} {names[i]}" for i in involved)
        warnings.append(f"the data do not determine the combination {combo}; their standard "
                        "errors are not reported (fix one of them or add excitation)")
    return cov_theta, undetermined, warnings


def _correlation_warnings(cov: np.ndarray, names: Sequence[str],
                          undetermined: np.ndarray) -> list[str]:
    """A warning for each pair of determined model parameters correlated beyond
    :data:`_CORRELATION_WARNING` (``cov``: the model parameters' covariance)."""
    corr = _correlation(cov)
    return [f"{names[i]} and {names[j]} are strongly correlated (r = {corr[i, j]:+.3f}): the "
            "data determine mainly a combination of them, so their separate values are "
            "uncertain"
            for i in range(len(names)) for j in range(i + 1, len(names))
            if abs(corr[i, j]) > _CORRELATION_WARNING and not (undetermined[i]
                                                                or undetermined[j])]


def _per_log(problem: Problem, predictions, summary: _Summary, model, nuisances
             ) -> tuple[list[dict[str, object]], float, int]:
    """fit.json's ``per_log`` entries, and the sum of squared force residuals (N^2) over the
    fitted samples of all logs with their count."""
    per_log = []
    raw_sq, raw_n = 0.0, 0
    for i, (log, pred) in enumerate(zip(problem.logs, predictions)):
        res = _fitted_residuals(problem, i, pred["force"])
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
        entry |= {key: p.to_display(float(nuisances[name][i]))
                  for name, (key, p) in PER_LOG_NUISANCES.items() if name in nuisances}
        per_log.append(entry)
    return per_log, raw_sq, raw_n


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
    the optimum, reduced inside one compiled function (:func:`summary_evaluate`; on a lean
    problem, two: :func:`errors_in_variables_gram` apart, so that their working sets do not
    add up): no ``(residuals, parameters)`` array leaves them (a 1 M-sample log's ``J`` and
    its copies are hundreds of MB, ``benchmarks/fit_memory.py``)."""

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
    #: from :func:`errors_in_variables_gram`)
    eiv_gram: jax.Array | None


def summary_evaluate(problem: Problem, theta, *, spans: tuple[tuple[tuple[int, int], ...], ...],
                     sequential: bool) -> _Summary:
    """The :class:`_Summary` at ``theta`` (compiled by
    :meth:`~fitstiff.inference.problem.Problem.compiled`); ``spans``: per log, its ``(start, stop)``
    entries of the residual vector; ``sequential``: build ``J`` one column at a time
    (:func:`fitstiff.inference.lm.jacobian_rows`) and leave ``eiv_gram`` to
    :func:`errors_in_variables_gram`.

    Otherwise one compiled function shares ``J`` between the covariance and the
    turning-point columns (``C^T = J^T B S``: a VJP per row of ``J^T``), and the predicted
    force comes out of the residuals' own forward pass. On the benchmark log of
    ``benchmarks/fit_speed.py`` a cold ``fitstiff fit`` took a median 12.6 s (15.9 s of
    CPU) against 13.6 s (17.1 s) with the two functions and the predictions compiled apart
    (five alternating runs each, a slow host), with the same fit.json to 1e-14; building
    ``C^T`` one row at a time (``lax.map``, no extra memory) gained about half of that.
    """

    def derived_vec(th):
        return _derived_vector(problem, th, problem.drives[0])

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


def _derived_vector(problem: Problem, theta, drive):
    """The derived quantities at ``theta`` in :data:`DERIVED` order (``drive``: the operating
    point of the chamber stiffness)."""
    d = derived_quantities(problem.unpack(theta)[0], drive)
    return jnp.stack([d[k] for k in DERIVED])


def _window_summary(problem: Problem, theta) -> _Summary:
    """:func:`summary_evaluate` of a chunked problem: the reductions over its windows
    (:class:`~fitstiff.inference.chunks.Windows`), the turning points' errors by a backward
    sweep, the parameters' part compiled on its own (no per-sample array enters it)."""
    windows = problem.windows
    problem.reversal_noise()        # before the summary's own arrays: its working set apart
    w = windows.summary(theta)
    start = problem.drives[0].window(0, 1)        # the operating point: rig values only

    def parameters(th):
        def derived(t):
            return _derived_vector(problem, t, start)

        return (problem.physical(th), jax.jacfwd(problem.physical)(th), derived(th),
                jax.jacfwd(derived)(th))

    values, dphys, derived, gradient = jax.tree.map(np.asarray, jax.jit(parameters)(theta))
    model = problem.unpack(theta)[0]
    force = []
    for g in problem.groups:
        n = g.force.shape[1]
        rows = [w.force[i] if len(w.force[i]) == n else
                np.pad(w.force[i], (0, n - len(w.force[i])), mode="edge") for i in g.index]
        force.append(rows[0][None] if len(rows) == 1 else np.stack(rows))
    return _Summary(
        cost=w.cost, largest=w.largest, r_factor=w.r_factor, values=values, dphys=dphys,
        derived=derived, gradient=gradient, state_cross=w.state_cross,
        state_norm2=w.state_norm2, force=tuple(force),
        chamber_stiffness=np.asarray(_chamber_stiffness(problem, model)),
        eiv_gram=windows.errors_in_variables_gram(theta, w.starts))


def errors_in_variables_gram(problem: Problem, theta):
    """``C^T C`` of the errors in variables at the turning points, ``C = S B^T J`` with
    ``B = d(residuals)/d(displacement)`` and ``S`` the turning points' errors at their
    samples (0 elsewhere), for a lean problem: a JVP and a VJP per parameter, one parameter
    at a time, so no ``J`` is built (:func:`summary_evaluate` does it from its ``J``)."""
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


def implausible(problem: Problem, values: np.ndarray,
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
    model, _ = problem.unpack_physical(values)
    for term in model.terms_of(FrictionBase):       # the seal's own physics (LuGre: Fs >= Fc)
        out += term.implausible()
    if math.isfinite(breakaway) and abs(breakaway) > _BREAKAWAY_EXCESS * largest:
        out.append(f"the breakaway force {breakaway:.4g} N is more than {_BREAKAWAY_EXCESS:g} "
                   f"times the largest measured force ({largest:.4g} N): the logs do not "
                   "reach breakaway, so it is the model's extrapolation, not a measurement "
                   "(record a log that slides)")
    return out


def _fitted_residuals(problem: Problem, i: int, force) -> np.ndarray:
    """Log ``i``'s force residuals (N) at its fitted samples, a new array (one copy of the
    channel at most: a long log's)."""
    res = np.subtract(force, problem.logs[i].force)
    fitted = problem.sample_weights[i] > 0
    return res if fitted.all() else res[fitted]


def _lag1(problem: Problem, per_log_pred) -> float:
    """Pooled lag-1 autocorrelation of the force residuals over the weighted samples."""
    num = den = 0.0
    for i, pred in enumerate(per_log_pred):
        res = _fitted_residuals(problem, i, pred["force"])
        res -= res.mean()
        num += float(res[1:] @ res[:-1])
        den += float(res @ res)
    return float(np.clip(num / den, -_LAG1_CAP, _LAG1_CAP)) if den > 0 else 0.0
