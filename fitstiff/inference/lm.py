"""Levenberg-Marquardt that builds one Jacobian per accepted point.

The diagnosis solves many small masked least-squares problems through the hysteresis scan
(held-out folds, candidate refits). There one forward-mode Jacobian of all free entries costs
about four residual evaluations, and the general solvers of optimistix linearise the
residuals at every trial point, accepted or not, and materialise that linearisation more
than once per step (measured: about 3.5 Jacobians per step on the diagnosis benchmark). This
loop evaluates only the residuals at a trial point and builds the Jacobian once a trial is
accepted, which is what pays when a step costs a scan.

The algorithm is the classic one (Marquardt's scaling, Nielsen 1999 damping update):

- at an accepted point ``z``: residuals ``r``, Jacobian ``J`` (one ``jacfwd``), thin QR
  ``J = QR``, column scales ``D`` (the column norms of ``J`` at ``z``, floored; below);
- a trial step solves ``min |J d + r|^2 + lam |D d|^2`` as the small stacked least squares
  ``[R; sqrt(lam) D] d = [-Q^T r; 0]``;
- the gain ratio ``rho`` (actual over predicted decrease) accepts the step when positive and
  updates ``lam`` by ``max(1/3, 1 - (2 rho - 1)^3)``; a rejected step multiplies it by
  ``nu`` (doubled each time);
- it has converged when an accepted step moved every entry by at most ``atol + rtol |z|``
  and the cost changed by at most ``atol + rtol cost`` (optimistix's Cauchy criterion), when
  the actual and the predicted decrease of the cost are both at most ``rtol cost`` (MINPACK's
  ``ftol`` test: a parameter walking towards a bound of the transform layer, e.g. a stiffness
  towards 0 through a log transform, moves without end but changes nothing), or
  when the gradient vanishes (every column of ``J`` orthogonal to ``r`` to 1e-12, or to 1e-6
  once no step decreases the cost any more, measured against the running maxima of the
  column norms).

The scales are the column norms at the point (Marquardt), floored at a hundredth of their
running maxima, not the running maxima themselves (Moré 1978, as MINPACK). A parameter
walking towards a bound of the transform layer (an element stiffness ``k = exp(z)`` whose
best value is 0) has a column that shrinks with ``k``; against the largest norm it ever
had, its damping grows as the column shrinks and every step moves ``z`` by about the same
small amount: 44 steps from ``k = exp(3)`` in ``tests/test_lm.py``, 8 now; the
Maxwell-slip refits of the diagnosis walked their element stiffnesses to zero over 30-40
steps per fold (``docs/diagnosis_heldout.md``, speed at real size: refits 82 -> 46 s).

The floor keeps what the running maxima were for. Without one a vanishing column lets one
step throw an entry to numerical infinity (``z = -7e5``: a Dahl ``sigma0`` of exactly 0,
whose derivatives are not finite), and a Maxwell-slip element whose column is small at the
start is driven to zero before the others have moved, where its log-transformed value can
never come back (withheld ``single/maxwell_slip/1``: the Maxwell-slip refit removed 59 % of
the gap with the running maxima, 18 % with a floor of 1e-3, and a compliance was named; 35 %
with 1e-2, and it is accepted: that refit has more than one minimum, and its start decides).

With ``normal=True`` the state keeps the Gram matrix ``J^T J`` instead of ``Q`` and ``R``
and a trial step solves the damped normal equations ``(J^T J + lam D^2) d = -J^T r``
(Cholesky). The Jacobian lives only while it is reduced at an accepted point, and it is
built one forward-mode column at a time (:func:`jacobian_rows` with ``sequential=True``: the
tangents of the hysteresis scan for one column alive at once, not for all of them), as
``J^T`` whose products ``J^T J``, ``J^T r`` are fused multiply-and-sums (:func:`wide_dot`).
That is the memory-lean form for long logs: one transient Jacobian and a few residual
vectors, where the QR form (and optimistix's solvers) hold several ``(residuals,
parameters)`` arrays at once (``benchmarks/fit_memory.py``). The normal equations square the
condition number of ``J``, which the damping and the column scaling bound; the fit's
covariance summary works on ``J``'s own QR either way (:func:`r_factor`).

The status is returned, never dropped: :data:`CONVERGED`, :data:`MAX_STEPS` (the step budget
ran out), :data:`NONFINITE` (the residuals at the start were not finite) or :data:`STALLED`
(no trial step decreased the cost even with the damping at its ceiling).
"""

from __future__ import annotations

from typing import Callable, NamedTuple

from jax import lax

from fitstiff._jax import jax, jnp

__all__ = ["levenberg_marquardt", "levenberg_marquardt_reduced", "Linearisation",
           "jacobian_rows", "wide_dot", "r_factor", "LMResult",
           "CONVERGED", "MAX_STEPS", "NONFINITE", "STALLED", "STATUS"]

CONVERGED, MAX_STEPS, NONFINITE, STALLED = 0, 1, 2, 3
#: readable status, by code
STATUS = {CONVERGED: "converged", MAX_STEPS: "the step budget ran out",
          NONFINITE: "the residuals at the start are not finite",
          STALLED: "no step decreased the cost (damping at its ceiling)"}
_LAM0 = 1e-3
_LAM_MAX = 1e16
_GTOL = 1e-12          # largest |cos(residual, column)| at which the gradient has vanished
_STALL_GTOL = 1e-6     # the same, accepted when no step decreases the cost any more
#: least column scale of a step, as a share of the column's running maximum norm
_SCALE_FLOOR = 1e-2


class LMResult(NamedTuple):
    """The solution, its status code, the number of trial steps and the cost ``|r|^2``."""

    value: jax.Array
    status: jax.Array
    steps: jax.Array
    cost: jax.Array


class _State(NamedTuple):
    z: jax.Array
    r: jax.Array
    q: jax.Array            # thin Q of J (normal form: empty)
    rr: jax.Array           # R of J (normal form: J^T J)
    g: jax.Array            # J^T r
    d: jax.Array            # running maxima of the column norms (the stall test)
    norms: jax.Array        # the column norms at the point (the step's scales)
    lam: jax.Array
    nu: jax.Array
    steps: jax.Array
    status: jax.Array       # -1 while running


def _jac_norms(jac):
    return jnp.linalg.norm(jac, axis=0)


def _cosine(g, norms, r_norm):
    """Largest cosine between the residual vector (of norm ``r_norm``) and a Jacobian column
    (0 for a column of zeros, e.g. a padding entry)."""
    denom = norms * r_norm
    return jnp.max(jnp.where(denom > 0, jnp.abs(g) / jnp.where(denom > 0, denom, 1.0), 0.0))


def _scales(norms, d):
    """The column scales of a step: the column norms at the point, at least
    :data:`_SCALE_FLOOR` of their running maxima ``d`` (and 1e-12 of the largest)."""
    floor = 1e-12 * jnp.maximum(jnp.max(d), 1e-300)
    return jnp.maximum(jnp.maximum(norms, _SCALE_FLOOR * d), floor)


def _normal_step(gram, g, lam, d):
    """The damped step of the normal equations ``(J^T J + lam D^2) d = -J^T r`` and the
    decrease of the cost the linear model predicts for it."""
    lhs = gram + lam * jnp.diag(d**2)
    step = jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(lhs), -g)
    return step, -(2.0 * step @ g + step @ (gram @ step))


def _gain(cost, cost_new, predicted):
    """The gain ratio ``rho`` and whether the trial is accepted."""
    rho = (cost - cost_new) / jnp.where(predicted > 0, predicted, jnp.inf)
    return rho, jnp.isfinite(cost_new) & (rho > 1e-4)


def _done(step, z_new, cost, cost_new, predicted, g, norms, r_norm, rtol, atol):
    """Whether an accepted step ends the solve (the tests of the module docstring)."""
    small_step = jnp.all(jnp.abs(step) <= atol + rtol * jnp.abs(z_new))
    small_cost = jnp.abs(cost - cost_new) <= atol + rtol * cost
    # MINPACK's ftol test: the actual and the predicted decrease both negligible
    # (ends a parameter's slow walk towards a bound in the transformed coordinates)
    flat = (jnp.abs(cost - cost_new) <= rtol * cost) & (predicted <= rtol * cost)
    return (small_step & small_cost) | flat | (_cosine(g, norms, r_norm) <= _GTOL)


def _damped(lam, rho):
    """The damping after an accepted step of gain ``rho`` (Nielsen)."""
    return lam * jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)


def jacobian_rows(fn: Callable[[jax.Array], jax.Array], z: jax.Array, *,
                  sequential: bool = False) -> jax.Array:
    """``J^T`` of ``fn`` at ``z``: row ``j`` is the derivative of the residuals by ``z[j]``.

    ``sequential=False`` is ``jax.jacfwd`` (all columns in one vectorised pass);
    ``sequential=True`` takes one forward-mode column at a time (``lax.map``), so only one
    column's tangents of the scan's intermediates are alive: for a 1 M-sample log (three
    channels, five entries) 165 MB above the data, where the vectorised pass needs 355 MB.
    """
    basis = jnp.eye(z.size, dtype=z.dtype)

    def column(e):
        return jax.jvp(fn, (z,), (e,))[1]

    return lax.map(column, basis) if sequential else jax.vmap(column)(basis)


def wide_dot(a: jax.Array, b: jax.Array) -> jax.Array:
    """``a b^T`` of two wide 2-d arrays (a row per parameter, a column per residual) as one
    fused multiply-and-sum. A matrix product packs a copy of its operands first: 190 MB
    more peak for ``J^T J`` of a 1 M-sample log's Jacobian (three channels, five entries)."""
    return jnp.sum(a[:, None, :] * b[None, :, :], axis=-1)


def r_factor(jt: jax.Array, *, block: int = 2**16) -> jax.Array:
    """The triangular factor ``R`` of ``J = QR`` from ``J^T`` (``jt``), by a QR of each block
    of ``block`` residuals and a QR of the stacked factors (the tall-skinny QR): as accurate
    as one QR of ``J``, whose LAPACK call would copy all of ``J`` first. ``R`` is unique up
    to the signs of its rows; ``R^T R = J^T J``."""
    n, m = jt.shape
    k = m // block
    rest = jt[:, k * block:].T
    if not k:
        return jnp.linalg.qr(rest, mode="r")
    blocks = lax.map(lambda i: jnp.linalg.qr(
        lax.dynamic_slice(jt, (0, i * block), (n, block)).T, mode="r"), jnp.arange(k))
    return jnp.linalg.qr(jnp.concatenate([blocks.reshape(-1, n), rest]), mode="r")


def _linearise(fn, z, normal: bool):
    """At ``z``: the residuals, the factors the steps use (``Q, R``, or an empty ``Q`` and
    ``J^T J``), ``J^T r``, the column norms of ``J`` and whether ``J`` is finite."""
    if normal:
        jt = jacobian_rows(fn, z, sequential=True)
        r = fn(z)
        return (r, jnp.zeros((0, z.size)), wide_dot(jt, jt), jnp.sum(jt * r, axis=1),
                jnp.sqrt(jnp.sum(jt**2, axis=1)), jnp.all(jnp.isfinite(jt)))
    jac, r = jax.jacfwd(lambda z: (fn(z), fn(z)), has_aux=True)(z)
    (q, rr), g = jnp.linalg.qr(jac, mode="reduced"), jac.T @ r
    return r, q, rr, g, _jac_norms(jac), jnp.all(jnp.isfinite(jac))


def levenberg_marquardt(fn: Callable[[jax.Array], jax.Array], z0: jax.Array, *,
                        rtol: float = 1e-6, atol: float = 1e-6,
                        max_steps: int | jax.Array = 200, normal: bool = False) -> LMResult:
    """Minimise ``|fn(z)|^2`` from ``z0`` (traceable: call it inside ``jax.jit``).

    Args:
        fn: residuals, a function of a 1-d array.
        z0: the start.
        rtol, atol: the convergence tolerances (see the module docstring).
        max_steps: trial steps allowed (accepted or rejected).
        normal: solve the damped normal equations, keeping no Jacobian between steps (the
            memory-lean form for long residual vectors; see the module docstring).
    """
    z0 = jnp.asarray(z0, dtype=float)
    r0, q0, rr0, g0, d0, jac_finite = _linearise(fn, z0, normal)
    finite = jnp.all(jnp.isfinite(r0)) & jac_finite
    status0 = jnp.where(~finite, NONFINITE, jnp.where(
        _cosine(g0, d0, jnp.linalg.norm(r0)) <= _GTOL, CONVERGED, -1))
    init = _State(z0, r0, q0, rr0, g0, d0, d0, jnp.asarray(_LAM0), jnp.asarray(2.0),
                  jnp.asarray(0), status0)
    n = z0.size

    def trial_step(s: _State, d):
        """The damped step and the decrease of the cost the linear model predicts for it."""
        if normal:
            return _normal_step(s.rr, s.g, s.lam, d)
        lhs = jnp.concatenate([s.rr, jnp.sqrt(s.lam) * jnp.diag(d)])
        rhs = jnp.concatenate([-(s.q.T @ s.r), jnp.zeros(n)])
        step = jnp.linalg.lstsq(lhs, rhs)[0]
        jd = s.q @ (s.rr @ step)
        return step, s.r @ s.r - (s.r + jd) @ (s.r + jd)

    def body(s: _State) -> _State:
        step, predicted = trial_step(s, _scales(s.norms, s.d))
        z_new = s.z + step
        r_new = fn(z_new)
        cost = s.r @ s.r
        cost_new = r_new @ r_new
        rho, ok = _gain(cost, cost_new, predicted)

        def accept(_):
            r, q, rr, g, norms, _ = _linearise(fn, z_new, normal)
            done = _done(step, z_new, cost, cost_new, predicted, g, norms,
                         jnp.linalg.norm(r), rtol, atol)
            return _State(z_new, r, q, rr, g, jnp.maximum(s.d, norms), norms,
                          _damped(s.lam, rho), jnp.asarray(2.0), s.steps + 1,
                          jnp.where(done, CONVERGED, -1))

        def reject(_):
            lam = s.lam * s.nu
            # no step of any length decreases the cost: a minimum if the gradient vanishes
            at_minimum = _cosine(s.g, s.d, jnp.linalg.norm(s.r)) <= _STALL_GTOL
            return s._replace(lam=lam, nu=s.nu * 2.0, steps=s.steps + 1,
                              status=jnp.where(lam > _LAM_MAX, jnp.where(
                                  at_minimum, CONVERGED, STALLED), -1))

        out = lax.cond(ok, accept, reject, None)
        return out._replace(status=jnp.where((out.status < 0) & (out.steps >= max_steps),
                                             MAX_STEPS, out.status))

    final = lax.while_loop(lambda s: s.status < 0, body, init)
    return LMResult(final.z, final.status, final.steps, final.r @ final.r)


class Linearisation(NamedTuple):
    """What the normal-equations form needs of the residuals ``r`` and their Jacobian ``J``
    at a point, reduced (:func:`levenberg_marquardt_reduced`)."""

    cost: jax.Array         # |r|^2
    gram: jax.Array         # J^T J
    gradient: jax.Array     # J^T r
    norms: jax.Array        # the column norms of J
    finite: jax.Array       # r and J finite


def levenberg_marquardt_reduced(linearise: Callable[[jax.Array], Linearisation],
                                cost: Callable[[jax.Array], jax.Array], z0, *,
                                rtol: float = 1e-6, atol: float = 1e-6,
                                max_steps: int = 200) -> LMResult:
    """:func:`levenberg_marquardt` with ``normal=True``, step for step, driven from Python
    over reductions of the residuals instead of the residual vector: ``linearise(z)`` gives
    the :class:`Linearisation` at ``z``, ``cost(z)`` the cost ``|r(z)|^2`` at a trial point.
    For residuals that are never whole at once: a long log's, accumulated window by window
    (:mod:`fitstiff.inference.chunks`). The same steps, tests and status codes."""
    z = jnp.asarray(z0, dtype=float)
    lin = linearise(z)
    if not bool(jnp.isfinite(lin.cost)) or not bool(lin.finite):
        return LMResult(z, jnp.asarray(NONFINITE), jnp.asarray(0), lin.cost)
    status = CONVERGED if bool(_cosine(lin.gradient, lin.norms, jnp.sqrt(lin.cost)) <= _GTOL) \
        else -1
    d, lam, nu, steps = lin.norms, _LAM0, 2.0, 0
    while status < 0:
        step, predicted = _normal_step(lin.gram, lin.gradient, lam, _scales(lin.norms, d))
        z_new = z + step
        cost_new = cost(z_new)
        rho, ok = _gain(lin.cost, cost_new, predicted)
        steps += 1
        if bool(ok):
            new = linearise(z_new)
            done = _done(step, z_new, lin.cost, cost_new, predicted, new.gradient, new.norms,
                         jnp.sqrt(new.cost), rtol, atol)
            z, d, lam, nu = z_new, jnp.maximum(d, new.norms), _damped(lam, rho), 2.0
            lin = new
            status = CONVERGED if bool(done) else -1
        else:
            lam, nu = lam * nu, nu * 2.0
            if lam > _LAM_MAX:
                at_minimum = _cosine(lin.gradient, d, jnp.sqrt(lin.cost)) <= _STALL_GTOL
                status = CONVERGED if bool(at_minimum) else STALLED
        if status < 0 and steps >= max_steps:
            status = MAX_STEPS
    return LMResult(z, jnp.asarray(status), jnp.asarray(steps), lin.cost)
