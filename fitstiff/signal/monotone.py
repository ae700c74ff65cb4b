"""Monotone runs of a displacement: the stretches over which friction states have a closed form.

Between two reversals the displacement moves one way (steps of one sign, or none). Over such a
run a friction element that only depends on the travel has an exact closed form from the
run's start (Dahl: ``F = s Fc + (F0 - s Fc) exp(-sigma0 |x - x0| / Fc)``), so only the values
at the run starts need stepping, one per run instead of one per sample. The problems drive
the model with a displacement denoised to be monotone between reversals, so a log has a few
dozen runs for thousands of samples; XLA's CPU loop costs about 0.1 us per iteration whatever
it computes, most of a stepped Dahl term's cost under ``vmap`` over a posterior's walkers.

The runs of a drive's displacement are found once, in NumPy (:func:`find_runs`), and kept
in the drive (:attr:`fitstiff.physics.drive.Drive.runs`); the terms check that the displacement they
are given still moves one way within each run (:meth:`Runs.holds`) and return NaN, not a
wrong value, where it does not.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from fitstiff._jax import jax, jnp

__all__ = ["Runs", "count_runs", "directions", "find_runs", "monotone_in_runs", "pad_runs"]

#: the closed form pays when a log has at most this fraction of its samples as runs (it adds
#: a gather and a vectorised exp per sample; one loop iteration per run remains)
_MAX_RUN_FRACTION = 0.25


class Runs(NamedTuple):
    """The monotone runs of a displacement of ``n`` samples (a pytree of arrays).

    Attributes:
        index: ``(n,)`` int, the run of every sample; run 0 also holds the samples before the
            first step.
        before: ``(R,)`` int, the sample just before each run's first step (-1 for run 0;
            ``n - 1`` for padding runs, which no sample belongs to).
        sign: ``(R,)`` the direction of each run (+1, -1; 0 for a padding run or a
            displacement that never moves).
    """

    index: Any
    before: Any
    sign: Any

    def start(self, x):
        """``x`` (``(n,)``) at the start of each run (``x[0]`` for run 0) -> ``(R,)``."""
        return x[jnp.maximum(self.before, 0)]

    def holds(self, dx):
        """Whether the steps ``dx`` (``(n,)``) go nowhere against their run's direction."""
        return jnp.all(self.sign[self.index] * dx >= 0.0)


def directions(x):
    """The monotone runs of ``x`` (``(n,)``, traced; no derivative flows through them) as
    per-sample arrays: the direction of each sample's run (+1, -1; 0 where ``x`` never moves)
    and the run's number. The runs of :func:`find_runs`, found inside a traced function: a
    run starts at a moving sample whose direction differs from the previous moving one, and
    the samples before the first step belong to the first run."""
    x = jax.lax.stop_gradient(x)
    n = x.shape[0]
    step = jnp.sign(jnp.diff(x, prepend=x[:1]))
    i = jnp.arange(n)
    last = jax.lax.cummax(jnp.where(step != 0, i, -1))      # the last moving sample so far
    sign = jnp.where(last >= 0, step[jnp.maximum(last, 0)], step[jnp.argmax(step != 0)])
    before = jnp.concatenate([sign[:1], sign[:-1]])
    return sign, jnp.cumsum((step != 0) & (step != before))


def monotone_in_runs(y, sign, index):
    """``y`` (``(n,)``, traced) made to move one way within each run (``sign``, ``index``
    per sample, :func:`directions`): the mean of its upper envelope from the run's start
    (running maximum along the run's direction) and its lower envelope from the run's end
    (running minimum from the end). Where ``y`` already moves one way within a run it is
    returned as it is; samples of sign 0 keep their values.

    For a signal that must keep the runs of the displacement but carries noise of its own
    (the piston position ``x - C F`` of ``rig_compliance:measured``, with the logged force's
    noise): a stepped friction law reads every step against the run's direction as a
    reversal, and noise-made reversals ratchet its state. The two envelopes lead and lag by
    about the same amount, so their mean keeps the level of ``y``.
    """
    s = sign.astype(y.dtype)
    w = s * y
    # runs stacked into one increasing sequence (each run starts above every value of the
    # runs before it, so the running extremes restart at every run); the sample each
    # envelope takes its value from is found without derivatives (those of the running
    # extremes compile to a large scan: 3 s for a forward-mode Jacobian of 5 000 samples),
    # then gathered from the run's own samples
    z = jax.lax.stop_gradient(w + 2.0 * (jnp.max(jnp.abs(w)) + 1.0) * index.astype(y.dtype))
    i = jnp.arange(z.shape[0])
    up = jax.lax.cummax(jnp.where(z >= jax.lax.cummax(z), i, 0))
    down = jax.lax.cummin(jnp.where(z <= jax.lax.cummin(z, reverse=True), i,
                                    z.shape[0] - 1), reverse=True)
    return jnp.where(s != 0, s * 0.5 * (w[up] + w[down]), y)


def count_runs(x) -> int:
    """Number of monotone runs of the displacement ``x`` (1 + its changes of direction; a
    step of 0 continues the run it is in)."""
    s = np.sign(np.diff(np.asarray(x, dtype=float)))
    s = s[s != 0]
    return 1 + int(np.count_nonzero(s[1:] != s[:-1]))


def find_runs(x) -> Runs | None:
    """The :class:`Runs` of the displacement ``x``, or ``None`` when they are
    more than a quarter of its samples (the closed form would not pay; the terms step every
    sample)."""
    x = np.asarray(x, dtype=float)
    n = x.shape[0]
    step = np.sign(np.diff(x, prepend=x[:1]))
    moving = np.flatnonzero(step)
    # a run starts at a moving sample whose direction differs from the previous moving one
    first = moving[1:][step[moving[1:]] != step[moving[:-1]]]
    if 1 + first.size > max(1, _MAX_RUN_FRACTION * n):
        return None
    index = np.zeros(n, dtype=int)
    index[first] = 1
    index = np.cumsum(index)
    before = np.concatenate([[-1], first - 1])
    sign = np.concatenate([step[moving[:1]] if moving.size else [0.0], step[first]])
    return _jax(index, before, sign)


def pad_runs(runs: Runs, n: int, count: int) -> Runs:
    """``runs`` of a displacement extended to ``n`` samples by holding its last value (the
    padding belongs to the last run), with ``count`` runs (the added ones are empty)."""
    index, before, sign = (np.asarray(a) for a in runs)
    index = np.concatenate([index, np.full(n - index.size, index[-1])])
    extra = count - before.size
    return _jax(index, np.concatenate([before, np.full(extra, n - 1)]),
                np.concatenate([sign, np.zeros(extra)]))


def _jax(index, before, sign) -> Runs:
    return Runs(jnp.asarray(index, dtype=jnp.int32), jnp.asarray(before, dtype=jnp.int32),
                jnp.asarray(sign, dtype=float))
