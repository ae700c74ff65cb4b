"""Reversal-preserving denoising of the displacement channel.

A rate-independent hysteresis model driven by a noisy displacement *chatters*: every
noise-made micro-reversal restarts the pre-sliding curve, so the modelled force never climbs as
far as it should, and a fit compensates with a larger breakaway and a smaller slope. The true
motion between two genuine reversals is monotone, so the estimate used here is:

1. estimate the displacement noise from the data (:func:`fitstiff.segmentation.estimate_noise`)
   and find the genuine reversals with the hysteresis rule of the segmentation (threshold a
   multiple of that noise);
2. between consecutive reversals, replace the displacement by its **isotonic regression**
   (least-squares monotone fit, increasing or decreasing as the segment goes). Inside a
   segment this removes every micro-reversal and averages the noise over the flat stretches;
   the reversal points themselves stay where the data put them.

The result is the least-squares displacement that has exactly the reversals the segmentation
found: an errors-in-variables estimate of the input under the constraint that the piston did
not turn anywhere else.
"""

from __future__ import annotations

import numpy as np

__all__ = ["denoise_displacement", "reversal_samples", "segment_velocity"]

_SEARCH = 3   # samples either side of a reversal index searched for the raw extremum


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


def denoise_displacement(displacement: np.ndarray, reversals: np.ndarray) -> np.ndarray:
    """Monotone least-squares fit of ``displacement`` between the ``reversals`` (indices).

    The segments share their end samples (a reversal belongs to both sides); a shared sample
    takes the value of the segment that starts there. That can only move a reversal by one
    sample, never add one: the result has exactly ``len(reversals)`` turning points.
    """
    from scipy.optimize import isotonic_regression  # slow to import; only fits need it

    x = np.asarray(displacement, dtype=float)
    n = x.shape[0]
    cuts = np.unique(np.concatenate([[0], _extrema(x, np.asarray(reversals, dtype=int)),
                                     [n - 1]]))
    out = x.copy()
    for start, stop in zip(cuts[:-1], cuts[1:]):
        segment = x[start:stop + 1]
        increasing = segment[-1] >= segment[0]
        out[start:stop + 1] = isotonic_regression(segment, increasing=bool(increasing)).x
    return out


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
    seg = np.searchsorted(cuts, np.arange(n), side="right") - 1   # reversal -> next segment
    seg = np.minimum(seg, len(cuts) - 2)
    # a reversal sample belongs to the segment it ends
    at_cut = np.isin(np.arange(n), cuts[1:-1])
    seg[at_cut] -= 1
    idx = np.arange(n)
    lo = np.maximum(idx - m, cuts[seg])
    hi = np.minimum(idx + m, cuts[seg + 1])
    # window sums with time and displacement taken relative to the window's own sample, so
    # that neither a long log nor a long pause in it (t - t[0] of 1e9 s and more) costs
    # precision or overflows, as running sums over the whole log would
    cnt = np.zeros(n)
    sd = np.zeros(n)
    sy = np.zeros(n)
    sdd = np.zeros(n)
    sdy = np.zeros(n)
    for j in range(-m, m + 1):
        k = np.clip(idx + j, 0, n - 1)
        inside = (idx + j >= lo) & (idx + j <= hi)
        d = np.where(inside, t[k] - t, 0.0)
        y = np.where(inside, x[k] - x, 0.0)
        cnt += inside
        sd += d
        sy += y
        sdd += d * d
        sdy += d * y
    var = sdd - sd * sd / cnt
    cov = sdy - sd * sy / cnt
    with np.errstate(invalid="ignore", divide="ignore"):
        v = np.where(var > 0, cov / var, 0.0)
    return v
