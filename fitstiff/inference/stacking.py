"""Logs of one structure stacked for one ``vmap``-ed scan: a
:class:`~fitstiff.inference.problem.Problem` runs its logs as a few stacks (chamber modes,
observed channels and time alike, lengths within :data:`PAD_RATIO` of the longest), each
padded to its longest log with zero weight, so the compile time does not grow with the number
of logs and padding wastes little work."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import equinox as eqx
import numpy as np

from fitstiff._jax import jax, jnp
from fitstiff.io.log import Log
from fitstiff.physics.drive import Drive
from fitstiff.physics.model import difference_acceleration, time_steps
from fitstiff.signal.monotone import pad_runs

__all__ = ["PAD_RATIO", "Group", "build_groups", "length_buckets", "pad", "pad_drive",
           "same_closed_forms", "same_structure", "ResidualSeries", "residual_series"]

#: a log shorter than this times the longest of its stack is run in a stack of its own
#: (``benchmarks/posterior_default.py``: four logs of 3 200-12 800 samples)
PAD_RATIO = 0.7


class Group(eqx.Module):
    """Logs with one static structure, padded and stacked for one vmap-ed scan (a pytree:
    :meth:`Problem.compiled` passes its arrays to compiled functions as arguments)."""

    index: tuple[int, ...] = eqx.field(static=True)   # positions of the logs in Problem.logs
    drive: Drive                 # stacked: leaves have a leading log axis
    force: jnp.ndarray           # (L, N) measured force
    weight: jnp.ndarray          # (L, N) 1/sigma_F * sample weight (0 on padding)
    pressure: tuple              # per chamber: (L, N) measured abs pressure or None
    pressure_weight: tuple       # per chamber: (L, N) 1/sigma_p (0 on padding) or None


def build_groups(drives: Sequence[Drive], logs: Sequence[Log],
                 sample_weights: Sequence[np.ndarray], force_noise: Sequence[float],
                 pressure_noise: Sequence[Mapping[str, float]], *,
                 host: bool = False) -> list[Group]:
    """Logs of one structure (chamber modes, observed channels, time) are stacked and run
    as one ``vmap``-ed scan, padded to the longest; logs much shorter than the longest
    start their own stack (:data:`PAD_RATIO`), so padding wastes little work. ``host``: the
    stacks are NumPy arrays, a log alone in its stack a view of its arrays (no copy)."""
    if host:
        def stack(xs):
            xs = [np.asarray(x) for x in xs]
            return xs[0][None] if len(xs) == 1 else np.stack(xs)
        array = np.asarray
    else:
        def stack(xs):
            return jnp.stack(xs)
        array = jnp.asarray
    keys: dict[tuple, list[int]] = {}
    for i, d in enumerate(drives):
        keys.setdefault((d.modes, d.observed, d.has_time), []).append(i)
    stacks = [bucket for index in keys.values()
              for bucket in length_buckets(index, [len(d) for d in drives])]
    groups = []
    for index in stacks:
        n_max = max(len(drives[i]) for i in index)
        padded = same_closed_forms([pad_drive(drives[i], n_max) for i in index])
        stacked = jax.tree.map(lambda *xs: stack(xs), *padded)
        force = stack([pad(logs[i].force, n_max) for i in index])
        weight = stack([pad(sample_weights[i], n_max, fill=0.0)
                        / force_noise[i] for i in index])
        pressures, pressure_weights = [], []
        for c, chamber in enumerate(("a", "b")):
            if not drives[index[0]].observed[c]:
                pressures.append(None)
                pressure_weights.append(None)
                continue
            attr = f"pressure_{chamber}"
            pressures.append(array(stack(
                [pad(getattr(logs[i], attr), n_max) for i in index])))
            pressure_weights.append(array(stack(
                [pad(sample_weights[i] > 0, n_max, fill=0.0).astype(float)
                 / pressure_noise[i][chamber] for i in index])))
        groups.append(Group(tuple(index), stacked, array(force), array(weight),
                            tuple(pressures), tuple(pressure_weights)))
    return groups


def length_buckets(index: Sequence[int], lengths: Sequence[int], *,
                   pad_ratio: float = PAD_RATIO) -> list[list[int]]:
    """``index`` cut into stacks of similar length: longest first, a log shorter than
    ``pad_ratio`` times its stack's longest starts the next stack (in log order within)."""
    order = sorted(index, key=lambda i: -lengths[i])
    stacks: list[list[int]] = []
    for i in order:
        if stacks and lengths[i] >= pad_ratio * lengths[stacks[-1][0]]:
            stacks[-1].append(i)
        else:
            stacks.append([i])
    return [sorted(stack) for stack in stacks]


def pad(a, n: int, *, fill: float | None = None) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.shape[0] == n:
        return a
    value = a[-1] if fill is None else fill
    return np.concatenate([a, np.full(n - a.shape[0], value)])


def pad_drive(drive: Drive, n: int) -> Drive:
    """Extend a drive to ``n`` samples by holding the last state (time keeps ticking)."""
    m = len(drive)
    if m == n:
        return dataclasses.replace(drive, name="") if drive.name else drive
    dt = float(drive.time[-1] - drive.time[-2]) if m > 1 else 1.0
    time = np.concatenate([np.asarray(drive.time),
                           float(drive.time[-1]) + dt * np.arange(1, n - m + 1)])
    return dataclasses.replace(
        drive, name="", time=jnp.asarray(time),
        displacement=jnp.asarray(pad(drive.displacement, n)),
        pressure_a=jnp.asarray(pad(drive.pressure_a, n)),
        pressure_b=jnp.asarray(pad(drive.pressure_b, n)),
        still=jnp.asarray(pad(drive.still, n)),
        velocity=None if drive.velocity is None else jnp.asarray(pad(drive.velocity, n,
                                                                       fill=0.0)),
        acceleration=(None if drive.acceleration is None
                      else jnp.asarray(pad(drive.acceleration, n, fill=0.0))),
        measured_force=(None if drive.measured_force is None
                        else jnp.asarray(pad(drive.measured_force, n))),
        runs=(None if drive.runs is None
              else pad_runs(drive.runs, n, int(drive.runs.before.shape[0]))),
        log_volume_ratios=(None if drive.log_volume_ratios is None
                           else tuple(jnp.asarray(pad(r, n)) for r in drive.log_volume_ratios)))


def same_closed_forms(drives: list[Drive]) -> list[Drive]:
    """Drives of one stack (one length) with one structure for the closed forms (a stack is
    one ``vmap``-ed evaluation): runs of one count, or none when one of them has none; the
    widest chamber span, or none (nor log volume ratios) when one of them has none."""
    spans = [d.log_volume_span for d in drives]
    span = None if None in spans else max(spans)
    count = (None if any(d.runs is None for d in drives)
             else max(int(d.runs.before.shape[0]) for d in drives))
    return [dataclasses.replace(d, runs=None if count is None else pad_runs(d.runs, len(d), count),
                                log_volume_span=span,
                                log_volume_ratios=None if span is None else d.log_volume_ratios)
            for d in drives]


def same_structure(drives: list[Drive]) -> list[Drive]:
    """Drives that all carry a velocity (and acceleration) when one does.

    ``denoise="auto"`` denoises only the logs whose displacement is noisy, and logs of one
    length are stacked into a batch; a log left as measured gets the difference quotients
    the model would take itself (the same values), so the batch has one structure.
    """
    out = list(drives)
    for field in ("velocity", "acceleration"):
        if not any(getattr(d, field) is not None for d in out):
            continue
        for k, d in enumerate(out):
            if getattr(d, field) is not None:
                continue
            dt, dt_mid = time_steps(d.time)
            x = d.displacement
            v = d.velocity if d.velocity is not None else jnp.diff(x, prepend=x[0]) / dt
            value = v if field == "velocity" else difference_acceleration(v, dt_mid)
            out[k] = dataclasses.replace(d, **{field: jnp.asarray(value)})
    return out


class ResidualSeries(NamedTuple):
    """Where one log's channel lies in the residual vector of
    :meth:`~fitstiff.inference.problem.Problem.residuals` (see :func:`residual_series`)."""

    log: int          # index into Problem.logs
    channel: str      # "force", "pressure_a" or "pressure_b"
    span: slice       # its entries of the residual vector (padded length, in time order)
    mask: np.ndarray  # (len,) bool: samples with weight > 0 (the others are exactly 0)


def residual_series(groups: Sequence[Group], channels: Sequence[str]) -> list[ResidualSeries]:
    """The layout of the residual vector of stacked ``groups``: one entry per log and observed
    channel (``"force"``, ``"pressure_a"``, ``"pressure_b"``; only those in ``channels``), in
    the order of the vector. Each covers its log's padded length in time order; samples
    outside ``mask`` (padding, zero weight) have residual exactly 0."""
    out, start = [], 0
    for g in groups:
        n = g.force.shape[1]
        channels_here = [("force", g.weight)] + [
            (f"pressure_{c}", w) for c, w in zip("ab", g.pressure_weight) if w is not None]
        for channel, weight in channels_here:
            if channel not in channels:
                continue
            positive = np.asarray(weight) > 0          # one transfer, not one per row
            for row, i in enumerate(g.index):
                out.append(ResidualSeries(i, channel, slice(start, start + n),
                                          positive[row]))
                start += n
    return out
