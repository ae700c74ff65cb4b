"""Reversal-preserving denoising of the displacement channel.

A rate-independent hysteresis model driven by a noisy displacement *chatters*: every
noise-made micro-reversal restarts the pre-sliding curve, so the modelled force never climbs as
far as it should, and a fit compensates with a larger breakaway and a smaller slope. The true
motion between two genuine reversals is monotone, so the estimate used here is:

1. estimate the displacement noise from the data
   (:func:`fitstiff.signal.noise.estimate_noise`) and find the genuine reversals with the
   hysteresis rule of the segmentation (threshold a multiple of that noise);
2. estimate each turning point (its sample and its extreme displacement) by a **local fit**
   of the samples around it (:func:`turning_points`): the raw extreme sample overshoots the
   true apex by a good part of the noise (the largest of the samples within the noise of it),
   more so the higher the sample rate, and every branch after the reversal would start that
   far too early;
3. between consecutive turning points, replace the displacement by its **isotonic
   regression** (least-squares monotone fit, increasing or decreasing as the segment goes),
   bounded by the fitted extremes. Inside a segment this removes every micro-reversal and
   averages the noise over the flat stretches.

The result is the least-squares displacement that has exactly the reversals the segmentation
found: an errors-in-variables estimate of the input under the constraint that the piston did
not turn anywhere else.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from fitstiff.signal.noise import marginal_scale

__all__ = ["chatters", "curvature_noise", "denoise_displacement", "quadratic_curvature",
           "reversal_samples", "segment_velocity", "smooth_acceleration", "smooth_force",
           "turning_points", "value_noise"]

_SEARCH = 3   # samples either side of a reversal index searched for the raw extremum


def chatters(x: np.ndarray, reversals: np.ndarray) -> bool:
    """Whether the displacement ``x`` turns where the segmentation finds no reversal: more
    than twice as many changes of direction (between its non-zero steps) as genuine
    ``reversals``, and at least 5 more.

    The displacement-noise estimate (MAD of second differences) is zero on a quantised
    encoder that stands still most of the time, yet a one-count toggle during a pause
    restarts a rate-independent pre-sliding curve each time: over a 20 s pause at 500 Hz the
    ratchet moved a Dahl force from 19 to 15 N (1.4 N RMS fit error on a log whose noise was
    0.2 N, 0.20 N once denoised). A few extra turns at rounded corners stay below the bar."""
    steps = np.diff(np.asarray(x, dtype=float))
    steps = steps[steps != 0]
    turns = int(np.count_nonzero(np.diff(np.sign(steps)))) if steps.size > 1 else 0
    genuine = len(reversals)
    return turns > 2 * genuine and turns >= genuine + 5


def reversal_samples(x: np.ndarray, reversals: np.ndarray) -> np.ndarray:
    """The turning samples of ``x`` (the raw extrema near the segmentation's reversals)."""
    return _extrema(np.asarray(x, dtype=float), np.asarray(reversals, dtype=int))


def _extrema(x: np.ndarray, reversals: np.ndarray) -> np.ndarray:
    """Each reversal moved to the raw extremum within ``_SEARCH`` samples.

    The segmentation places reversals on a median-filtered signal, whose peaks are flattened
    by a sample; cutting there would make the isotonic fit average the true peak with its
    neighbour and shave the turning point.
    """
    out = []
    for r in reversals:
        lo, hi = max(r - _SEARCH, 0), min(r + _SEARCH + 1, x.shape[0])
        window = x[lo:hi]
        after = x[min(hi + _SEARCH, x.shape[0] - 1)]
        is_max = after < x[r]
        out.append(lo + int(np.argmax(window) if is_max else np.argmin(window)))
    return np.asarray(out, dtype=int)


def denoise_displacement(displacement: np.ndarray, reversals: np.ndarray, *,
                         noise: float | None = None, still: np.ndarray | None = None
                         ) -> np.ndarray:
    """Monotone least-squares fit of ``displacement`` between the ``reversals`` (indices),
    with each turning point at its local-fit estimate (:func:`turning_points`).

    The segments share their end samples (a reversal belongs to both sides); a shared sample
    takes the value of the segment that starts there. That can only move a reversal by one
    sample, never add one: the result has exactly ``len(reversals)`` turning points. Each
    turning sample takes the fitted extremum, and no sample of the two segments beside it goes
    past that (isotonic regression with a bound is the clipped unbounded one). ``noise``
    (displacement noise, m) sizes the local fits; ``None`` estimates it from the data.

    ``still`` (per sample, non-zero inside a pause: the segmentation's
    :attr:`~fitstiff.segments.segmentation.Segmentation.still`) holds each pause at one level:
    a pause is one block of the monotone fit, and a pause that holds a turning point stands at
    the turn's level, its samples' mean. Left to the monotone fit alone, a pause's noise
    became a staircase in the direction of the segment it lies in: after a reversal each of
    its sub-um steps moved a Dahl force at twice the pre-sliding stiffness (0.15 N over a
    0.4 s hold on the withheld benchmark's ``null/12``), which a friction level rising at low
    speed (Stribeck) then explained.
    """
    from scipy.optimize import isotonic_regression  # slow to import; only fits need it

    x = np.asarray(displacement, dtype=float)
    n = x.shape[0]
    index, value, _ = turning_points(x, np.asarray(reversals, dtype=int), noise=noise,
                                     still=still)
    spans = _still_spans(still, n)
    cuts = np.concatenate([[0], index, [n - 1]])
    out = x.copy()
    for start, stop in zip(cuts[:-1], cuts[1:]):
        if stop <= start:
            continue
        segment = x[start:stop + 1]
        increasing = bool(segment[-1] >= segment[0])
        block = _blocks(spans, start, stop + 1)
        weights = np.bincount(block).astype(float)
        means = np.bincount(block, weights=segment) / weights
        out[start:stop + 1] = isotonic_regression(means, weights=weights,
                                                  increasing=increasing).x[block]
    for k, (r, v) in enumerate(zip(index, value)):
        lo = cuts[k]
        hi = cuts[k + 2]
        # a peak lies above its two neighbours' middle (not above each: a turn in a hold has
        # a neighbour at its own level, noise either side of it)
        is_max = v >= 0.5 * (x[lo] + x[hi])
        out[lo:hi + 1] = np.minimum(out[lo:hi + 1], v) if is_max else np.maximum(
            out[lo:hi + 1], v)
        out[r] = v
    for start, stop in spans:               # a pause at a turn stands at the turn's level
        turns = index[(index >= start) & (index < stop)]
        if turns.size:
            out[start:stop] = out[turns[0]]
    return out


def _still_spans(still: np.ndarray | None, n: int) -> np.ndarray:
    """Half-open ``[start, stop)`` spans of the non-zero entries of ``still`` (none if
    ``None``)."""
    if still is None:
        return np.empty((0, 2), dtype=int)
    flag = np.asarray(still) > 0
    if flag.shape != (n,):
        raise ValueError(f"still has {flag.size} entries for a displacement of {n} samples")
    edges = np.diff(flag.astype(np.int8), prepend=0, append=0)
    return np.column_stack([np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)])


def _blocks(spans: np.ndarray, start: int, stop: int) -> np.ndarray:
    """Block number of each sample of ``[start, stop)`` for the monotone fit: a pause's
    samples share one block, every other sample has its own; numbered in order."""
    new = np.ones(stop - start, dtype=bool)        # the sample starts a new block
    for a, b in spans:
        a, b = max(a, start), min(b, stop)
        if b - a > 1:
            new[a + 1 - start:b - start] = False
    return np.cumsum(new) - 1


_TP_SPAN = 15.0     # a turning-point window reaches this many noise levels from the apex
_TP_MIN = 10        # samples either side, at least
_TP_MAX = 400       # and at most
_TP_GRID = 4        # kink positions per sample
_TP_FIT = 3.0       # a turn model whose residual RMS exceeds this many noise levels misfits
#: roundings (samples) of the turn model's kink (:func:`_turn_profile`)
_TP_ROUNDING = (0.0, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0)
#: a turn next to a pause stands in it if the samples between lie within this many marginal
#: noise levels of the pause's mean (:func:`_paused_turns`)
_TP_PAUSE_BAND = 5.0
#: residual sum of squares (in noise variances) a rounding must save over the sharp kink
_TP_ROUNDING_PENALTY = 4.0


def turning_points(x: np.ndarray, reversals: np.ndarray, *, noise: float | None = None,
                   rho: float = 0.0, still: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each reversal's extremum from a local least-squares fit: ``(sample index, value,
    standard error)`` per reversal.

    The raw extreme sample of a noisy turn overshoots: it is the largest of the several
    samples that lie within the noise of the apex (measured: 0.48 um at 1 kHz, 0.93 um at
    10 kHz for 1 um of noise at 1 mm/s), and the isotonic fit keeps it, so every branch
    after a reversal started that far too early - a bias in the slope and breakaway that
    grows with the sample rate. Here the samples within about ``_TP_SPAN`` noise levels of
    the apex (by the mean speed of the two legs) are fitted by
    ``a + b u + c u^2 + d sqrt(u^2 + r^2)``, ``u = i - i0``, a kink ``d`` rounded over ``r``
    samples (a triangle's turn, sharp or as the actuator rounds it) on a smooth curve (a
    sine's round turn), with ``i0`` on a quarter-sample grid (:func:`_turn_profile`); the
    estimate is the fitted curve's extremum and the sample nearest to it. The rounding ``r``
    is one per log (:func:`_shared_rounding`): the actuator rounds its corners over a time of
    its own, the same at every turn. A window the curve does not describe (residual RMS
    above ``_TP_FIT`` marginal noise levels: flat, ramp and flat around a turn placed in a
    hold after a stroke) is halved until it does. Reversals too close to each other or to
    the ends for a window keep the raw extreme sample and the noise as error.

    ``noise`` is the white-equivalent level (:func:`~fitstiff.signal.noise.estimate_noise`)
    and ``rho`` the lag-1 correlation of the noise: the errors are the fit's under AR(1)
    noise (the sandwich ``h^T R h`` with ``R_ij = rho^|i-j|``) of marginal level
    ``noise * marginal_scale(rho)``. On the calibration datasets' AR(1) displacement noise
    (1 um, 240 turning points) the errors read as white noise were half the actual ones (z sd
    3.0); with ``rho`` the z sd is 1.03.

    ``still`` (per sample, non-zero inside a pause; see :func:`denoise_displacement`): a
    reversal in a pause (or next to one: :func:`_paused_turns`) stands at the pause's mean,
    with the error of a mean of that many AR(1) samples, at its extreme sample (or the
    pause's sample nearest to it). Its window still votes on the log's
    corner rounding: the actuator rounds its corner into the pause as into any turn (left
    out, the withheld benchmark's 200 Hz log read its rounded corners as sharp in two of five
    noise draws, the other turns' apexes +1.5 um beyond instead of +0.1).
    """
    x = np.asarray(x, dtype=float)
    reversals = np.asarray(reversals, dtype=int)
    n = x.shape[0]
    raw = _extrema(x, reversals)
    if noise is None:
        from fitstiff.signal.noise import estimate_noise
        noise = estimate_noise(x)
    index, value = raw.copy(), x[raw].copy()
    error = np.full(raw.shape, float(noise) * marginal_scale(rho))
    if noise <= 0:
        return index, value, error
    level = float(noise) * marginal_scale(rho)
    bounds = np.concatenate([[0], raw, [n - 1]])
    spans = _still_spans(still, n)
    windows: list[tuple[int, slice, dict]] = []      # (turn k, its window, its profile)
    paused = _paused_turns(x, raw, spans, _TP_PAUSE_BAND * level)
    for k, r in enumerate(raw):
        prev, nxt = bounds[k], bounds[k + 2]
        steps = [abs(x[r] - x[prev]) / max(r - prev, 1), abs(x[nxt] - x[r]) / max(nxt - r, 1)]
        step = max(min(steps), 1e-300)
        w = int(np.clip(np.ceil(_TP_SPAN * noise / step), _TP_MIN, _TP_MAX))
        w = min(w, (r - prev) // 2, (nxt - r) // 2)
        # a window the turn model does not describe is halved until it does (a fast stroke
        # into a hold, seen from a reversal placed in the hold: flat, ramp, flat; its fitted
        # "extremum" lay 11 um beyond every sample of a 1 um-noise log, and a Dahl force
        # jumped 1.2 N at the turn)
        while w >= _TP_MIN:
            profile = _turn_profile(x[r - w:r + w + 1])
            if profile and min(p.sse for p in profile.values()) <= (
                    _TP_FIT**2 * (2 * w + 1) * level**2):
                windows.append((k, slice(r - w, r + w + 1), profile))
                break
            w //= 2
    rounding = _shared_rounding([p for _, _, p in windows], level)
    for k, (start, stop) in paused.items():
        index[k] = min(max(raw[k], start), stop - 1)
        value[k] = float(np.mean(x[start:stop]))
        error[k] = level * math.sqrt(_ar1_mean_variance(stop - start, rho))
    for k, window, profile in windows:
        if k in paused:
            continue
        fitted = _turn_estimate(x[window], profile[max(r for r in profile if r <= rounding)],
                                rho, level)
        if fitted is None:
            continue
        offset, value[k], error[k] = fitted
        index[k] = window.start + int(round(offset))
    return index, value, error


def _paused_turns(x: np.ndarray, raw: np.ndarray, spans: np.ndarray, band: float
                  ) -> dict[int, tuple[int, int]]:
    """Turn ``k``: the pause ``(start, stop)`` it stands in, for the turns whose extreme
    sample ``raw[k]`` lies in a pause, or next to one with every sample between within
    ``band`` of the pause's mean (the segmentation starts a pause once the displacement has
    settled in its band: the apex of a stroke into a pause is often a sample or two
    before)."""
    out: dict[int, tuple[int, int]] = {}
    for k, r in enumerate(raw):
        for start, stop in spans:
            if start <= r < stop:
                out[k] = (int(start), int(stop))
                break
            gap = x[r:start] if r < start else x[stop:r + 1]
            if gap.size <= stop - start and np.all(
                    np.abs(gap - np.mean(x[start:stop])) <= band):
                out[k] = (int(start), int(stop))
                break
    return out


def _ar1_mean_variance(m: int, rho: float) -> float:
    """Variance of the mean of ``m`` consecutive AR(1) samples of unit marginal variance and
    lag-1 correlation ``rho``: ``sum_ij rho^|i-j| / m**2``."""
    if rho == 0.0:
        return 1.0 / m
    total = m * (1.0 + rho) / (1.0 - rho) - 2.0 * rho * (1.0 - rho**m) / (1.0 - rho) ** 2
    return total / m**2


class _TurnFit(NamedTuple):
    """The turn model fitted to one window for one rounding ``r``: the best kink position
    ``kink`` (samples from the window's start), the coefficients, the Gram matrix and design
    at that kink, and the residual sum of squares."""

    r: float
    kink: float
    coef: np.ndarray
    gram: np.ndarray
    design: np.ndarray
    sse: float


def _basis(u: np.ndarray, r: float, scale: float) -> np.ndarray:
    return np.stack([np.ones_like(u), u / scale, (u / scale) ** 2,
                     np.sqrt(u**2 + r**2) / scale], -1)


def _turn_profile(y: np.ndarray) -> dict[float, _TurnFit]:
    """The turn model ``a + b u + c u^2 + d sqrt(u^2 + r^2)``, ``u = i - i0`` (a kink at
    ``i0`` rounded over ``r`` samples on a smooth curve) fitted to ``y`` (one window around a
    turn, the apex near its middle) for each rounding ``r`` of :data:`_TP_ROUNDING` the
    window can hold: linear in ``a, b, c, d`` for each ``(i0, r)``, ``i0`` every quarter
    sample, the best ``i0`` kept per ``r``. Empty if the sharp kink is ill-posed.

    ``r = 0`` is the sharp kink of a triangle's turn; an actuator rounds that kink over a few
    milliseconds, and a sharp kink fitted to a rounded turn puts the apex where the legs
    meet, beyond the turn (measured with ``benchmarks/turning_points.py``: +3.3 um at 5 mm/s
    and 500 Hz, corners rounded over 6 ms, 0.73 um of noise); a sine's round turn seen over a
    window of +-1 rad is neither a parabola nor a kink (+3.1 um at 10 Hz and 500 Hz)."""
    m = y.shape[0]
    i = np.arange(m, dtype=float)
    centre = (m - 1) / 2
    y0 = y - y[int(centre)]
    kinks = centre + np.arange(-_TP_GRID * (m // 4), _TP_GRID * (m // 4) + 1) / _TP_GRID
    u = i[None, :] - kinks[:, None]                          # (K, m)
    scale = max(centre, 1.0)
    out: dict[float, _TurnFit] = {}
    for r in (r for r in _TP_ROUNDING if r <= centre):
        if r > 0:
            # a rounded kink sits near the sharp one: searched within two samples of it
            # (the whole grid for every rounding made a 10 kHz log's turns 5x slower)
            near = np.abs(kinks - out[0.0].kink) <= 2.0
            kinks, u = kinks[near], u[near]
        design = _basis(u, r, scale)
        gram = np.einsum("kmi,kmj->kij", design, design)
        rhs = np.einsum("kmi,m->ki", design, y0)
        try:
            coef = np.linalg.solve(gram, rhs[..., None])[..., 0]
        except np.linalg.LinAlgError:
            if r == 0:
                return {}
            continue                    # a wide rounding on a short window: the parabola
        sse = np.sum((np.einsum("kmi,ki->km", design, coef) - y0) ** 2, axis=1)
        k = int(np.argmin(sse))
        out[r] = _TurnFit(r, float(kinks[k]), coef[k], gram[k], design[k], float(sse[k]))
    return out


def _shared_rounding(profiles: Sequence[dict[float, _TurnFit]], level: float) -> float:
    """The kink rounding (samples) of a log's turns: the ``r`` of :data:`_TP_ROUNDING` that
    minimises the residual sum of squares summed over the turns (a window too short for
    ``r`` counts with the widest rounding it holds), kept only where it saves
    :data:`_TP_ROUNDING_PENALTY` noise variances over the sharp kink.

    The actuator rounds its corners over a time of its own, so one rounding serves every
    turn of the log. Chosen turn by turn, noise decided it: a rounded turn read as sharp
    puts its apex several um beyond the true one (+4.4 to +5.6 um on four of the 5.4 mm/s
    turns of the withheld benchmark's null/12, a 500 Hz log with corners rounded over
    6 ms), and a sharp turn read as rounded pulls its apex inward."""
    if not profiles:
        return 0.0
    total = {r: 0.0 for r in _TP_ROUNDING}
    for profile in profiles:
        for r in total:
            usable = [q for q in profile if q <= r]
            total[r] += profile[max(usable)].sse
    return min(total, key=lambda r: total[r] + (r > 0) * _TP_ROUNDING_PENALTY * level**2)


def _turn_estimate(y: np.ndarray, fit: _TurnFit, rho: float, level: float):
    """``(position, extremum, standard error)`` of a fitted turn model (:func:`_turn_profile`)
    on its window ``y``: the fitted curve's extremum in the direction of the turn, and its
    error under AR(1) noise of lag-1 correlation ``rho`` and marginal ``level``; ``None`` if
    ill-posed."""
    m = y.shape[0]
    i = np.arange(m, dtype=float)
    centre = (m - 1) / 2
    y0 = y - y[int(centre)]
    scale = max(centre, 1.0)
    grid = np.linspace(0.0, m - 1.0, _TP_GRID * (m - 1) + 1)
    curve = _basis(grid - fit.kink, fit.r, scale) @ fit.coef
    is_max = y0[0] + y0[-1] < 2 * np.mean(y0)                # ends below the middle: a peak
    j = int(np.argmax(curve) if is_max else np.argmin(curve))
    row = _basis(np.asarray(grid[j] - fit.kink), fit.r, scale)
    try:
        h = np.linalg.solve(fit.gram, row)                # (X^T X)^-1 row
    except np.linalg.LinAlgError:
        return None
    # with AR(1) noise the sandwich row (X^T X)^-1 X^T R X (X^T X)^-1 row, R_ij = rho^|i-j|
    xh = fit.design @ h
    lags = np.abs(i[:, None] - i[None, :])
    var = float(xh @ (rho ** lags) @ xh) * level**2
    return grid[j], float(curve[j] + y[int(centre)]), float(np.sqrt(max(var, 0.0)))


def segment_velocity(displacement: np.ndarray, time: np.ndarray, reversals: np.ndarray, *,
                     noise: float) -> np.ndarray:
    """Velocity by a local linear fit that never straddles a reversal.

    Rate-dependent terms (LuGre's ``g(v)``, Stribeck, viscous) see the velocity; the plain
    difference quotient of a noisy displacement is so noisy that their nonlinearity biases a
    fit. Each sample's velocity is the least-squares slope over up to ``m`` samples either
    side *within its own monotone segment*, with ``m`` chosen so the noise on the velocity is
    about 3 % of the typical speed: ``m = (40 noise / step)^(2/3)``, 2 ... 50.
    """
    x = np.asarray(displacement, dtype=float)
    t = np.asarray(time, dtype=float)
    n = x.shape[0]
    steps = np.abs(np.diff(x))
    step = float(np.median(steps[steps > 0])) if np.any(steps > 0) else 1.0
    m = int(np.clip(np.ceil((40.0 * noise / step) ** (2 / 3)), 2, 50)) if noise > 0 else 1
    cuts = np.unique(np.concatenate([[0], _extrema(x, np.asarray(reversals, dtype=int)),
                                     [n - 1]]))
    v = np.empty(n)
    for start in range(0, n, _BLOCK):           # a block at a time: memory bounded in n
        idx = np.arange(start, min(start + _BLOCK, n))
        v[idx] = _local_slopes(x, t, idx, cuts, m)
    return v


#: samples per block of :func:`segment_velocity` (its working set is about 20 arrays of this)
_BLOCK = 2**18


def _local_slopes(x: np.ndarray, t: np.ndarray, idx: np.ndarray, cuts: np.ndarray,
                  m: int) -> np.ndarray:
    """:func:`segment_velocity` at the samples ``idx``: the slope of ``x`` against ``t`` over up
    to ``m`` samples either side within the segment between ``cuts``."""
    n = x.shape[0]
    seg = np.searchsorted(cuts, idx, side="right") - 1   # reversal -> next segment
    seg = np.minimum(seg, len(cuts) - 2)
    # a reversal sample belongs to the segment it ends
    at_cut = np.isin(idx, cuts[1:-1])
    seg[at_cut] -= 1
    lo = np.maximum(idx - m, cuts[seg])
    hi = np.minimum(idx + m, cuts[seg + 1])
    # window sums with time and displacement taken relative to the window's own sample, so
    # that neither a long log nor a long pause in it (t - t[0] of 1e9 s and more) costs
    # precision or overflows, as running sums over the whole log would
    size = idx.shape[0]
    cnt = np.zeros(size)
    sd = np.zeros(size)
    sy = np.zeros(size)
    sdd = np.zeros(size)
    sdy = np.zeros(size)
    t_here, x_here = t[idx], x[idx]
    for j in range(-m, m + 1):
        k = np.clip(idx + j, 0, n - 1)
        inside = (idx + j >= lo) & (idx + j <= hi)
        d = np.where(inside, t[k] - t_here, 0.0)
        y = np.where(inside, x[k] - x_here, 0.0)
        cnt += inside
        sd += d
        sy += y
        sdd += d * d
        sdy += d * y
    var = sdd - sd * sd / cnt
    cov = sdy - sd * sy / cnt
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(var > 0, cov / var, 0.0)


_ACCEL_NOISE = 0.05
_ACCEL_PILOT = 25    # half-width of the pilot fit that measures that typical size
#: narrower half-widths the window rule of :func:`smooth_acceleration` may fall back to
_ACCEL_WIDTHS = (1, 2, 3, 4, 5, 6, 8, 10, 12, 16, 20, 25, 32, 40)
#: half-width of the confidence intervals the rule intersects, in standard deviations
_ACCEL_GAMMA = 5.0


def smooth_acceleration(displacement: np.ndarray, time: np.ndarray, *,
                        noise: float) -> np.ndarray:
    """Acceleration (m/s^2) by local quadratic fits, the window narrowed where ``a`` jumps.

    The inertia term needs ``a``; the difference of a smoothed velocity carries so much noise
    (it grows as ``noise / dt^2``) that the noise in the regressor dilutes a fitted mass
    (measured: 1.9 kg for 5 kg on 0.3 mm sines at 5-15 Hz, 1 um noise, 1 kHz). Here ``a`` is
    twice the quadratic coefficient of a least-squares parabola through ``2 m + 1`` samples
    (in their own times).

    **The widest window** ``M`` is the smallest half-width whose noise on ``a`` is at most
    5 % of the typical acceleration, measured by a wide pilot fit (``m = 25``); 2 ... 50.
    That share trades the noise against the attenuation of a wide window; on the bundled
    inertia set (``chamber+dahl+inertia``, truth 5 kg, force noise 0.2 N, sines) one window
    of that size per log fits 4.77 kg at 20 % (RMS 0.50 N), 5.07 kg at 10 % (0.28 N), 5.20 kg
    at 5 % (0.24 N), 5.38 kg at 2 % (0.26 N).

    **Per sample the window narrows** where a wide one would smear an impulse, by the
    intersection of confidence intervals (Katkovnik's ICI rule for local polynomial
    derivatives): the estimates for ``m = 1, 2, 3, ...`` up to ``M`` each give the interval
    ``a_m +- 5 s_m`` (``s_m`` the noise of ``a_m`` for white displacement noise ``noise``),
    and the widest ``m`` whose interval still meets all the narrower ones' is kept. On a
    smooth signal every interval holds the truth and ``M`` is kept; at a rounded triangle
    corner, an acceleration impulse a few samples long, the wide windows disagree with the
    narrow ones at once and ``m`` stays at 1-3. With one window per log, the reversal
    impulses of the triangle programs of ``benchmarks/withheld.py`` (corners rounded over
    6 ms, 200-600 Hz) were smeared over up to 101 samples: on its five withheld-inertia
    datasets (0.5-6.4 kg) ``chamber+dahl+inertia`` fitted 1.29-1.49 x the mass at an RMS of
    1.9-20 x the force noise, with this rule 1.06-1.17 x at 1.2-9.7 x (the rest is the
    corners' shape below the sample spacing), and the bundled set 5.18 kg at 0.26 N. With
    intervals of +- 2 s_m the datasets gave 0.95-1.05 x, but noise stopped the rule early on
    the bundled sines (1.19 kg); +- 4 s_m: 5.15 kg at 0.30 N; +- 6 s_m: 5.20 kg at 0.24 N and
    1.08-1.20 x at 1.2-10 x.
    """
    x = np.asarray(displacement, dtype=float)
    t = np.asarray(time, dtype=float)
    n = x.shape[0]
    if n < 5:
        return np.zeros(n)
    dt = float(np.median(np.diff(t)))
    pilot = quadratic_curvature(x, t, min(_ACCEL_PILOT, (n - 1) // 2))
    typical = float(np.sqrt(np.mean(pilot**2)))
    widest = 2
    while (widest < min(50, (n - 1) // 2)
           and curvature_noise(widest, noise, dt) > _ACCEL_NOISE * typical):
        widest += 1
    widths = [m for m in _ACCEL_WIDTHS if m < widest] + [widest]
    return _intersect(zip(_quadratic_curvatures(x, t, widths),
                          (_ACCEL_GAMMA * curvature_noise(m, noise, dt) for m in widths)),
                      np.zeros(n))


def _intersect(estimates, out: np.ndarray) -> np.ndarray:
    """The ICI rule: over ``(estimate, half-width)`` pairs of growing windows, per sample the
    last estimate whose interval ``estimate +- half-width`` still meets every earlier one's
    (``out`` where none does)."""
    lower, upper = np.full(out.shape, -np.inf), np.full(out.shape, np.inf)
    consistent = np.ones(out.shape, dtype=bool)
    for value, half in estimates:
        lower = np.maximum(lower, value - half)
        upper = np.minimum(upper, value + half)
        consistent &= lower <= upper
        out = np.where(consistent, value, out)
    return out


def curvature_noise(m: int, noise: float, dt: float) -> float:
    """Standard deviation of ``2 c2`` from a parabola through ``2 m + 1`` evenly spaced
    samples (spacing ``dt``) with white noise ``noise``: the noise of
    :func:`quadratic_curvature` of half-width ``m``, which sets the confidence intervals of
    :func:`smooth_acceleration`'s window rule."""
    k = np.arange(-m, m + 1, dtype=float)
    s0, s2, s4 = k.size, np.sum(k**2), np.sum(k**4)
    return 2.0 * noise * float(np.sqrt(s0 / (s0 * s4 - s2**2))) / dt**2


def quadratic_curvature(x: np.ndarray, t: np.ndarray, m: int) -> np.ndarray:
    """``2 c2`` of the least-squares parabola through samples ``i - m ... i + m`` (clipped at
    the ends), in each window's own times relative to sample ``i``: the acceleration from one
    fixed window (:func:`smooth_acceleration` chooses the window per sample)."""
    return next(_quadratic_curvatures(x, t, (m,)))


def _quadratic_curvatures(x: np.ndarray, t: np.ndarray, widths):
    """:func:`quadratic_curvature` for each of the increasing half-widths ``widths`` in
    turn."""
    scale = float(np.median(np.diff(t))) or 1.0
    for coef in _local_quadratics(x, t, widths):
        yield 2.0 * coef[:, 2] / scale**2


def _local_quadratics(x: np.ndarray, t: np.ndarray, widths):
    """Coefficients ``(c0, c1, c2)`` per sample of the least-squares parabola through samples
    ``i - m ... i + m`` (clipped at the ends), in ``x - x_i`` against ``(t - t_i) / dt`` (``dt``
    the median spacing), for each of the increasing half-widths ``widths`` in turn (0 where
    the window cannot hold a parabola). The windows are nested, so the sums of one width grow
    into the next's by its two new offsets: every offset is visited once, not once per
    width."""
    n = x.shape[0]
    idx = np.arange(n)
    sums = np.zeros((n, 5))          # sum of d^0 ... d^4
    rhs = np.zeros((n, 3))           # sum of y, d y, d^2 y
    scale = float(np.median(np.diff(t))) or 1.0

    def add(j):
        k = idx + j
        inside = (k >= 0) & (k < n)
        kc = np.clip(k, 0, n - 1)
        d = np.where(inside, (t[kc] - t) / scale, 0.0)
        y = np.where(inside, x[kc] - x, 0.0)
        w = inside.astype(float)
        for p in range(5):
            sums[:, p] += w * d**p
        for p in range(3):
            rhs[:, p] += w * d**p * y

    reached = -1
    for m in widths:
        for j in range(reached + 1, m + 1):
            add(j)
            if j:
                add(-j)
        reached = m
        a = np.stack([sums[:, 0:3], sums[:, 1:4], sums[:, 2:5]], axis=1)
        ok = np.abs(np.linalg.det(a)) > 1e-12 * np.maximum(sums[:, 4] * sums[:, 0], 1e-300)
        a[~ok] = np.eye(3)
        coef = np.linalg.solve(a, rhs[..., None])[..., 0]
        yield np.where(ok[:, None], coef, 0.0)


#: half-widths the window rule of :func:`smooth_force` chooses from
_VALUE_WIDTHS = (1, 2, 3, 4, 5, 6, 8, 10, 12, 16, 20, 25)
#: half-width of the confidence intervals its rule intersects, in standard deviations
_VALUE_GAMMA = 2.0


def smooth_force(force: np.ndarray, time: np.ndarray | None, *, noise: float) -> np.ndarray:
    """The force with its noise (standard deviation ``noise``) smoothed out by local
    quadratic fits whose window narrows where the force turns fast (the ICI rule of
    :func:`smooth_acceleration` on the fitted value: the widest window whose interval
    ``value +- 2 s_m`` meets every narrower one's, up to 51 samples).

    The series compliance of ``rig_compliance:measured`` moves the piston by ``C F`` with the
    logged force ``F``: its noise, times ``C`` and the pre-sliding stiffness, came back as
    force error, and the refit kept ``C`` far below the truth to avoid it. On the withheld
    dataset ``single/rig_compliance/1`` (truth 9.5e-3 mm/N, seal 55.6 N/mm, force noise
    0.11 N AR(1) 0.47, 200-600 Hz) the fit on all the data found 1.0e-3 mm/N (sigma0 35 N/mm)
    with the raw force, 4.9e-3 with a fixed 9-sample Savitzky-Golay filter, 7.8e-3 (49 N/mm)
    with 21 samples, 4.8e-3 with 51 (the reversals smeared).
    """
    y = np.asarray(force, dtype=float)
    n = y.shape[0]
    if n < 5 or not noise > 0:
        return y.copy()
    t = np.arange(n, dtype=float) if time is None else np.asarray(time, dtype=float)
    widths = [m for m in _VALUE_WIDTHS if m <= (n - 1) // 2]
    return _intersect(((y + coef[:, 0], _VALUE_GAMMA * value_noise(m, noise))
                       for m, coef in zip(widths, _local_quadratics(y, t, widths))), y.copy())


def value_noise(m: int, noise: float) -> float:
    """Standard deviation of ``c0`` from a parabola through ``2 m + 1`` evenly spaced samples
    with white noise ``noise``: the noise of the fitted value of half-width ``m``, which sets
    the confidence intervals of :func:`smooth_force`'s window rule."""
    k = np.arange(-m, m + 1, dtype=float)
    s0, s2, s4 = k.size, np.sum(k**2), np.sum(k**4)
    return noise * float(np.sqrt(s4 / (s0 * s4 - s2**2)))
