"""A long log's least squares in windows: memory bounded in the log's length.

A :class:`~fitstiff.inference.problem.Problem` built with ``chunked=True`` (by default when its
residual vector would exceed :data:`~fitstiff.inference.problem.CHUNKED_ROWS` entries) keeps
its per-sample arrays as NumPy arrays on the host, views of the logs' where they can be. Its fit
never evaluates a whole log at once: :class:`Windows` runs each log as consecutive windows of
:data:`WINDOW` samples, the model's scan state carried from one window to the next
(:meth:`~fitstiff.physics.model.Model.run_window`), and reduces each window before the next
one starts:

- the normal equations ``J^T J``, ``J^T r``, the column norms and the cost, built one window's
  Jacobian at a time by forward mode, the tangent of the carried state carried with it
  (:meth:`Windows.linearise`, for :func:`~fitstiff.inference.lm.levenberg_marquardt_reduced`);
- the covariance summary: ``R`` of ``J = QR`` by a QR of each window's Jacobian stacked under
  the ``R`` so far (the tall-skinny QR), the friction states' columns, the largest entry, the
  predicted force (:meth:`Windows.summary`);
- the turning points' errors (``C^T C``, ``C = S B^T J``), whose ``B^T`` is a reverse-mode
  product: the windows are swept backwards, each window's Jacobian formed again from its
  stored start state and tangent, with the adjoint of the carried state carried back
  (:meth:`Windows.errors_in_variables_gram`).

Each window reads a margin of samples on either side
(:meth:`~fitstiff.physics.model.Model.reach`: the previous sample's displacement and time, the
next one's velocity, an input term's reach); before the log's first sample the margin holds
the first values (time runs back at the first step), after its last the displacement takes
one more step of its last increment and then holds (time runs on at the last step), so the
differences at the log's ends are those of the whole log. Samples past the end weigh 0.

What is held: the logs and the problem's per-sample arrays, a window's working set (a few
times ``WINDOW`` samples by the parameters), and per window its start state and tangent. The
results equal the whole-log path's up to rounding (``tests/test_chunks.py``).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import numpy as np

from fitstiff._jax import jax, jnp
from fitstiff.inference import lm
from fitstiff.inference.problem import with_nuisances
from fitstiff.physics.drive import Drive

__all__ = ["WINDOW", "Windows", "WindowSummary"]

#: samples per window: a window's Jacobian of a 10-parameter model with two logged pressures
#: is 16 MB
WINDOW = 2**16


class _Window(NamedTuple):
    """One window's inputs: the drive with its margins, the measurements and weights of its
    samples (margins excluded), and the turning points' errors over the drive's samples."""

    drive: Drive
    force: np.ndarray
    weight: np.ndarray
    pressure: tuple
    pressure_weight: tuple
    reversal_noise: np.ndarray
    #: how the drive's displacement is made of the log's samples in the window (``x[k] =
    #: tie_a[k] x[tie_i[k]] + tie_b[k] x[tie_j[k]]``, positions in the window): itself, the
    #: first sample before the log, the last step continued after it. The reverse pass moves
    #: a log's sample and what is made of it together, as on the whole log
    tie_i: np.ndarray
    tie_j: np.ndarray
    tie_a: np.ndarray
    tie_b: np.ndarray


class _LogData(NamedTuple):
    """One log's per-sample arrays (the problem's, views where they can be)."""

    index: int
    n: int
    drive: Drive
    force: np.ndarray
    weight: np.ndarray
    pressure: tuple
    pressure_weight: tuple


class WindowSummary(NamedTuple):
    """The covariance summary's reductions over all windows (:meth:`Windows.summary`)."""

    cost: float
    largest: float
    r_factor: np.ndarray
    state_cross: np.ndarray
    state_norm2: np.ndarray
    force: list            # per log, the predicted force (unpadded)
    starts: list           # per log, per window: the state and its tangents at its start


class Windows:
    """The windows of a chunked problem's logs and the reductions over them.

    Args:
        problem: a problem built with ``chunked=True``.
        window: samples per window (default :data:`WINDOW`, read when the windows are made).
    """

    def __init__(self, problem, *, window: int | None = None):
        self.problem = problem
        self.window = int(WINDOW if window is None else window)
        steps = []
        self.logs: list[_LogData] = []
        for g in problem.groups:
            for row, i in enumerate(g.index):
                n = len(problem.logs[i])
                drive = jax.tree.map(lambda a, n=n, row=row: np.asarray(a)[row, :n]
                                     if np.ndim(a) == 2 else np.asarray(a)[row], g.drive)
                pressures = tuple(None if p is None else np.asarray(p)[row, :n]
                                  for p in g.pressure)
                weights = tuple(None if w is None else np.asarray(w)[row, :n]
                                for w in g.pressure_weight)
                self.logs.append(_LogData(i, n, drive, np.asarray(g.force)[row, :n],
                                          np.asarray(g.weight)[row, :n], pressures, weights))
                t = np.asarray(drive.time)
                if n > 1:
                    steps.append(float(np.min(np.diff(t))) if drive.has_time else 1.0)
        self.logs.sort(key=lambda d: d.index)
        dt = min([s for s in steps if s > 0] or [1.0])
        self.margin = problem.model.reach(dt)
        self.has_state = "friction_state0" in problem.nuisance_names
        self.size = problem.size
        # the tangent directions: theta's entries, then (with initial friction states) the
        # state of the window's log in physical units (its column of the summary)
        e = np.eye(self.size + self.has_state)
        self._theta_basis = jnp.asarray(e[:, :self.size])
        self._state_basis = jnp.asarray(e[:, self.size:].sum(axis=1))
        self._compiled = {}

    # -- windows ----------------------------------------------------------------------------
    def count(self, log: _LogData) -> int:
        return max(1, math.ceil(log.n / self.window))

    def _window(self, log: _LogData, k: int, *, reversal_noise: bool = False) -> _Window:
        """The ``k``-th window of ``log`` (NumPy arrays)."""
        n, c, h = log.n, self.window, self.margin
        start = k * c
        idx = np.arange(start - h, start + c + h)
        held = np.clip(idx, 0, n - 1)
        before, after = idx < 0, idx > n - 1
        d = log.drive
        t = np.asarray(d.time)
        first = t[1] - t[0] if n > 1 else 1.0
        last = t[-1] - t[-2] if n > 1 else 1.0
        time = t[held] + np.where(before, idx * first, np.where(after, (idx - n + 1) * last, 0.0))
        x = np.asarray(d.displacement)
        # the tie: positions in the window of the samples each one is made of
        i = np.where(before, h - min(start, h), np.arange(idx.size))
        i = np.where(after, n - 1 - (start - h), i)
        j = np.where(after, max(n - 2, 0) - (start - h), i)
        tie_a = np.where(after, 2.0, 1.0) if n > 1 else np.ones(idx.size)
        tie_b = np.where(after, -1.0, 0.0) if n > 1 else np.zeros(idx.size)
        displacement = (tie_a * x[np.clip(idx[i], 0, n - 1)]
                        + tie_b * x[np.clip(idx[j], 0, n - 1)])

        def take(a):
            return None if a is None else np.asarray(a)[held]

        drive = dataclasses.replace(
            d, time=time, displacement=displacement, pressure_a=take(d.pressure_a),
            pressure_b=take(d.pressure_b), still=take(d.still), velocity=take(d.velocity),
            acceleration=take(d.acceleration), measured_force=take(d.measured_force),
            runs=None, log_volume_span=None, log_volume_ratios=None, name="")
        inner = np.arange(start, start + c)
        inside = inner < n
        inner = np.minimum(inner, n - 1)

        def measured(a):
            return None if a is None else a[inner]

        def weight(a):
            return None if a is None else np.where(inside, a[inner], 0.0)

        noise = np.zeros(0)
        if reversal_noise:
            row = self._reversal_noise(log)
            noise = np.where(before | after, 0.0, row[held])
        return _Window(drive, measured(log.force), weight(log.weight),
                       tuple(measured(p) for p in log.pressure),
                       tuple(weight(w) for w in log.pressure_weight), noise, i, j, tie_a,
                       tie_b)

    def _reversal_noise(self, log: _LogData) -> np.ndarray:
        for g, noise in zip(self.problem.groups, self.problem.reversal_noise()):
            if log.index in g.index:
                return np.asarray(noise)[g.index.index(log.index), :log.n]
        raise AssertionError("every log is in a group")

    # -- one window ---------------------------------------------------------------------------
    def _prediction(self, theta, dz, carry, win: _Window, log, first: bool):
        """The window's prediction and the state after it (``dz`` added to the log's initial
        friction state: the direction of its summary column)."""
        model, nuisances = self.problem.unpack(theta)
        if "friction_state0" in nuisances:
            nuisances = {**nuisances, "friction_state0": nuisances["friction_state0"] + dz}
        drive = with_nuisances(win.drive, nuisances, log)
        tie = (win.tie_i, win.tie_j, win.tie_a, win.tie_b)
        return model.run_window(drive, None if first else carry, start=self.margin,
                                length=self.window, tie=tie)

    def _residuals(self, theta, dz, carry, win: _Window, log, first: bool):
        """The window's whitened residuals, its predicted force and the state after it."""
        pred, carry = self._prediction(theta, dz, carry, win, log, first)
        parts = [(pred.force - win.force) * win.weight]
        for c, (measured, weight) in enumerate(zip(win.pressure, win.pressure_weight)):
            if measured is not None:
                modelled = pred.pressure_a if c == 0 else pred.pressure_b
                parts.append((modelled - measured) * weight)
        return jnp.concatenate(parts), pred.force, carry

    def _columns(self, theta, carry, carry_tangent, win, log, first):
        """The window's residuals ``r``, its Jacobian's rows ``J^T`` (one per tangent
        direction), its predicted force, and the state after it with its tangents."""
        def f(th, dz, cr):
            r, force, cr = self._residuals(th, dz, cr, win, log, first)
            return (r, cr), force

        def column(t, z, c):
            return jax.jvp(f, (theta, jnp.zeros(()), carry), (t, z, c), has_aux=True)

        (r, carry_out), (jt, tan_out), force = jax.vmap(column)(
            self._theta_basis, self._state_basis, carry_tangent)
        r, carry_out, force = jax.tree.map(lambda a: a[0], (r, carry_out, force))
        return r, jt, force, carry_out, tan_out

    def _linearise_window(self, theta, carry, carry_tangent, win, log, *, first):
        r, jt, _, carry_out, tan_out = self._columns(theta, carry, carry_tangent, win, log,
                                                     first)
        jt = jt[:self.size]
        return ((r @ r, lm.wide_dot(jt, jt), jt @ r, jnp.sum(jt**2, axis=1),
                 jnp.all(jnp.isfinite(r)) & jnp.all(jnp.isfinite(jt))), carry_out, tan_out)

    def _predict_window(self, theta, carry, win, log, *, first):
        return self._prediction(theta, 0.0, carry, win, log, first)

    def _cost_window(self, theta, carry, win, log, *, first):
        r, _, carry = self._residuals(theta, 0.0, carry, win, log, first)
        return r @ r, carry

    def _summary_window(self, theta, carry, carry_tangent, r_factor, win, log, *, first):
        r, jt, force, carry_out, tan_out = self._columns(theta, carry, carry_tangent, win,
                                                         log, first)
        u = jt[self.size] if self.has_state else jnp.zeros_like(r)
        jt = jt[:self.size]

        def largest(a):
            return jnp.where(jnp.any(jnp.isnan(a)), jnp.inf, jnp.max(jnp.abs(a)))

        stacked = jnp.concatenate([r_factor, jt.T])
        return ((r @ r, jnp.maximum(largest(r), largest(jt)),
                 jnp.linalg.qr(stacked, mode="r"), jt @ u, u @ u, force), carry_out, tan_out)

    def _eiv_window(self, theta, carry, carry_tangent, adjoint, win, log, *, first):
        """The window's rows of ``C^T`` (``S B^T J``; over the drive's samples, margins
        included) and the adjoint of the state before it."""
        _, jt, _, _, _ = self._columns(theta, carry, carry_tangent, win, log, first)
        jt = jt[:self.size]

        def g(x, cr):
            x = win.tie_a * x[win.tie_i] + win.tie_b * x[win.tie_j]
            moved = win._replace(drive=dataclasses.replace(win.drive, displacement=x))
            r, _, cr = self._residuals(theta, 0.0, cr, moved, log, first)
            return r, cr

        if first:
            _, vjp = jax.vjp(lambda x: g(x, None), win.drive.displacement)
            xbar = jax.vmap(lambda j, a: vjp((j, a))[0])(jt, adjoint)
            adjoint_in = adjoint
        else:
            _, vjp = jax.vjp(g, win.drive.displacement, carry)
            xbar, adjoint_in = jax.vmap(lambda j, a: vjp((j, a)))(jt, adjoint)
        return xbar * win.reversal_noise, adjoint_in

    def _fn(self, name: str, first: bool):
        key = (name, first)
        if key not in self._compiled:
            method = getattr(self, name)
            self._compiled[key] = jax.jit(functools.partial(method, first=first))
        return self._compiled[key]

    # -- sweeps -------------------------------------------------------------------------------
    def _sweep(self, name: str, theta, *, tangents: bool = True):
        """Run ``name`` over every window of every log in order, carrying the state (and its
        tangents); yields ``(log, k, outputs, carry_in, tangent_in)`` per window."""
        for log in self.logs:
            carry = tangent = None
            for k in range(self.count(log)):
                win = self._window(log, k)
                fn = self._fn(name, k == 0)
                if tangents:
                    out, carry_out, tangent_out = fn(theta, carry, tangent, win, log.index)
                else:
                    out, carry_out = fn(theta, carry, win, log.index)
                    tangent_out = None
                yield log, k, out, carry, tangent
                carry, tangent = carry_out, tangent_out

    def cost(self, theta) -> jax.Array:
        """``|r(theta)|^2`` over every window."""
        total = 0.0
        for _, _, value, _, _ in self._sweep("_cost_window", theta, tangents=False):
            total = total + value
        return jnp.asarray(total)

    def predict(self, theta) -> list[dict[str, np.ndarray]]:
        """Per log (in order): predicted force, per-term forces and pressures at ``theta``
        (:meth:`~fitstiff.inference.problem.Problem.per_log`)."""
        out = []
        for log in self.logs:
            parts = []
            carry = None
            for k in range(self.count(log)):
                pred, carry = self._fn("_predict_window", k == 0)(theta, carry,
                                                                  self._window(log, k),
                                                                  log.index)
                parts.append(jax.tree.map(np.asarray, pred))
            out.append({"force": np.concatenate([p.force for p in parts])[:log.n],
                        "contributions": np.concatenate([p.contributions
                                                         for p in parts])[:log.n],
                        "pressure_a": np.concatenate([p.pressure_a for p in parts])[:log.n],
                        "pressure_b": np.concatenate([p.pressure_b for p in parts])[:log.n]})
        return out

    def linearise(self, theta) -> lm.Linearisation:
        """The normal equations at ``theta``, accumulated over every window."""
        size = self.size
        cost, gram, grad, norms2 = 0.0, jnp.zeros((size, size)), jnp.zeros(size), jnp.zeros(size)
        finite = True
        for _, _, (c, gm, g, n2, ok), _, _ in self._sweep("_linearise_window", theta):
            cost, gram, grad, norms2 = cost + c, gram + gm, grad + g, norms2 + n2
            finite = finite & ok
        return lm.Linearisation(jnp.asarray(cost), gram, grad, jnp.sqrt(norms2),
                                jnp.asarray(finite))

    def summary(self, theta) -> WindowSummary:
        """The covariance summary's reductions at ``theta``."""
        problem = self.problem
        r_factor = jnp.zeros((0, self.size))
        cost, largest = 0.0, 0.0
        cross = np.zeros((problem.n_logs, self.size))
        norm2 = np.zeros(problem.n_logs)
        force = [np.empty(log.n) for log in self.logs]
        starts = [[] for _ in self.logs]
        for log, k, out, carry, tangent in self._sweep_summary(theta):
            starts[self.logs.index(log)].append((carry, tangent))
            c, big, r_factor, cr, n2, f = out
            cost += float(c)
            largest = max(largest, float(big))
            cross[log.index] += np.asarray(cr)
            norm2[log.index] += float(n2)
            stop = min((k + 1) * self.window, log.n)
            force[self.logs.index(log)][k * self.window:stop] = np.asarray(f)[:stop
                                                                              - k * self.window]
        if not self.has_state:
            cross, norm2 = np.zeros((0, self.size)), np.zeros(0)
        return WindowSummary(cost, largest, np.asarray(r_factor), cross, norm2, force, starts)

    def _sweep_summary(self, theta):
        """The summary's sweep: each window's QR stacked under the ``R`` so far."""
        r_factor = jnp.zeros((0, self.size))
        for log in self.logs:
            carry = tangent = None
            for k in range(self.count(log)):
                win = self._window(log, k)
                fn = self._fn("_summary_window", k == 0)
                out, carry_out, tangent_out = fn(theta, carry, tangent, r_factor, win,
                                                 log.index)
                r_factor = out[2]
                yield log, k, out, carry, tangent
                carry, tangent = carry_out, tangent_out

    def errors_in_variables_gram(self, theta, starts: list | None = None) -> np.ndarray:
        """``C^T C`` of the turning points' errors at ``theta`` (the whole-log
        :func:`~fitstiff.inference.fitting.summary.errors_in_variables_gram`); ``starts``:
        each window's start state and tangents (:attr:`WindowSummary.starts`), else found by a
        forward sweep."""
        size = self.size
        gram = np.zeros((size, size))
        for at, log in enumerate(self.logs):
            noise = self._reversal_noise(log)
            points = np.flatnonzero(noise)
            if not points.size:
                continue
            if starts is None:
                log_starts = []
                carry = tangent = None
                for k in range(self.count(log)):     # forward: each window's start state
                    log_starts.append((carry, tangent))
                    if k + 1 < self.count(log):
                        fn = self._fn("_linearise_window", k == 0)
                        _, carry, tangent = fn(theta, carry, tangent, self._window(log, k),
                                               log.index)
            else:
                log_starts = starts[at]
            ct = np.zeros((size, points.size))      # C^T at the turning points
            adjoint = None
            for k in reversed(range(self.count(log))):
                carry, tangent = log_starts[k]
                if adjoint is None:                   # after the last window: nothing
                    shape = self._carry_shapes(theta, log)
                    adjoint = jax.tree.map(lambda s: jnp.zeros((size,) + s.shape, s.dtype),
                                           shape)
                fn = self._fn("_eiv_window", k == 0)
                xbar, adjoint = fn(theta, carry, tangent, adjoint,
                                   self._window(log, k, reversal_noise=True), log.index)
                first = k * self.window - self.margin
                local = points - first
                inside = (local >= 0) & (local < xbar.shape[1])
                ct[:, inside] += np.asarray(xbar)[:, local[inside]]
            gram += ct @ ct.T
        return gram

    def _carry_shapes(self, theta, log: _LogData):
        """The shapes of the state carried between ``log``'s windows."""
        win = self._window(log, 0)
        return jax.eval_shape(lambda th: self._residuals(th, 0.0, None, win, log.index,
                                                         True)[2], theta)
