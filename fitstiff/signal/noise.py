"""The noise of a channel, estimated from its high-frequency part (not from a model's misfit).

Used for the force channel's noise floor in the diagnosis and for the correlation of the
displacement noise behind the turning points' errors (:class:`~fitstiff.inference.problem.Problem`).

A model that misses an effect leaves a residual larger than the sensor noise; to say how much
larger, the noise must be known independently of any model. Differences of the raw channel
remove the smooth signal: second differences of a force that changes smoothly between samples
are almost pure noise (a reversal kink or a breakaway touches a handful of samples, which a
median-based scale ignores). For AR(1) noise of marginal standard deviation ``s`` and lag-1
correlation ``rho``, the lag-``k`` second difference ``f[t+k] - 2 f[t] + f[t-k]`` has variance

    D_k = 2 s**2 (1 - rho**k) (3 - rho**k),

and fitting ``D_1 .. D_4`` (robust, MAD-based, Gaussian-equivalent variances) gives ``s`` and
``rho``. White noise has ``rho = 0`` and ``D_k = 6 s**2``. A smooth but fast signal (a 10 Hz
sine at 1 kHz) leaves its curvature in the wider differences, ``f'' (k dt)**2``, which grows as
``k**4`` while the noise's ``D_k`` saturates; the fit carries a term ``c k**4`` (``c >= 0``)
for it, so that the curvature is not read as correlated noise (the bundled time_delay set:
0.674 N without that term, truth 0.2 N). Checked on white and AR(1) noise
(``tests/test_diagnosis.py``): within 10 % for ``rho`` up to 0.5 on a few thousand samples.
A fitted model's prediction (``reference``) lets the estimate set aside what a fast log's
signal leaves in the wider differences (:func:`noise_floor`). Noise correlated over many
samples (``rho`` near 1) looks like signal to any such estimator: beyond about 0.7 the
estimate degrades, ``rho`` is capped at 0.95 and the estimate says so.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

__all__ = ["NoiseFloor", "RHO_GRID", "ar1_shape", "estimate_noise", "marginal_scale",
           "noise_floor", "pooled_noise_floor", "robust_var"]

_MAD = 1.4826
_METHOD = "second differences at lags 1-4 (robust), AR(1) plus a k^4 curvature term"
_RHO_MIN, _RHO_MAX = -0.9, 0.95


@dataclasses.dataclass(frozen=True)
class NoiseFloor:
    """Noise of one channel: marginal standard deviation ``sigma`` (channel unit) and lag-1
    correlation ``rho``; ``method`` names the estimator, ``capped`` whether ``rho`` hit its
    cap (the estimate is then a lower bound of the noise)."""

    sigma: float
    rho: float
    method: str = _METHOD
    capped: bool = False

    def effective_samples(self, n: int) -> float:
        """Effective number of independent samples in a mean over ``n`` consecutive ones."""
        return n * (1.0 - self.rho) / (1.0 + self.rho) if n > 0 else 0.0

    def to_dict(self) -> dict[str, object]:
        return {"sigma_N": self.sigma, "rho": self.rho, "method": self.method,
                "capped": self.capped}


def marginal_scale(rho: float) -> float:
    """Marginal standard deviation of AR(1) noise with lag-1 correlation ``rho`` per unit of
    the white-noise level read from its lag-1 second differences (``sqrt(D_1 / 6)``, e.g.
    :func:`estimate_noise`): ``sqrt(6 / (2 (1 - rho)(3 - rho)))``;
    1 for white noise, 2.2 at ``rho = 0.73``."""
    return math.sqrt(3.0 / ((1.0 - rho) * (3.0 - rho)))


def robust_var(d: np.ndarray) -> float:
    """Gaussian-equivalent variance of ``d`` from its median absolute deviation,
    ``(1.4826 MAD)**2`` (0 for no values): the ``D_k`` that :func:`noise_floor` fits."""
    if d.size == 0:
        return 0.0
    deviation = d - np.median(d)
    np.abs(deviation, out=deviation)          # in place: a long log's channel is one copy
    return float((_MAD * np.median(deviation, overwrite_input=True)) ** 2)


def ar1_shape(rho: float, k: np.ndarray) -> np.ndarray:
    """``D_k / s**2`` for AR(1) noise: ``2 (1 - rho**k)(3 - rho**k)``, the variance of its
    lag-``k`` second differences per unit marginal variance (see the module docstring)."""
    r = rho ** k
    return 2.0 * (1.0 - r) * (3.0 - r)


_LAGS = np.arange(1, 5)
#: the lag-1 correlations :func:`noise_floor` tries (the first of equal costs wins)
RHO_GRID = np.linspace(_RHO_MIN, _RHO_MAX, 371)
#: ``D_k / s**2`` of AR(1) noise (:func:`ar1_shape`) at every grid point (rows) and lag (columns)
_SHAPES = ar1_shape(RHO_GRID[:, None], _LAGS[None, :])


def noise_floor(values: np.ndarray, *, mask: np.ndarray | None = None,
                reference: np.ndarray | None = None) -> NoiseFloor:
    """Estimate the noise of ``values`` (one channel, equally spaced samples).

    The robust variances ``D_k`` of the lag-``k`` second differences, ``k = 1..4``, are fitted
    by ``s**2 * 2 (1 - rho**k)(3 - rho**k) + c k**4`` in relative error (a grid over ``rho``;
    ``s**2, c >= 0`` by least squares for each). ``mask``: samples to use (a difference counts
    when its three samples are all in the mask); all by default.

    ``reference``: a prediction of the channel (a fitted model's, same length). Each ``D_k`` is
    then the smaller of the channel's and of its residual's (``values - reference``): where the
    signal turns faster than the lags span (the pre-sliding curve after a reversal of a fast
    log), its differences are not noise, and a median-based scale is not robust to a tenth of
    the samples so raised (on the withheld benchmark's 20 mm/s logs the channel alone read the
    force noise 10-15 % high, rho 0.52 for 0.35). A model removes that curvature; it cannot
    lower a difference's noise, and the smaller variance guards against a model worse than
    none. A model's slow misfit (the effect it misses) cancels in the differences.
    """
    f = np.asarray(values, dtype=np.float64)
    if f.size < 2 * _LAGS[-1] + 8:
        return NoiseFloor(0.0, 0.0)
    keep = None if mask is None else np.asarray(mask, dtype=bool)
    d = _lag_variances(f, keep)
    if reference is not None:
        g = np.asarray(reference, dtype=np.float64)
        if g.shape != f.shape:
            raise ValueError(f"noise_floor: reference of shape {g.shape} for values of "
                             f"shape {f.shape}")
        residual = f - g
        if np.all(np.isfinite(residual)):
            d = np.minimum(d, _lag_variances(residual, keep))
    if not np.all(d > 0):
        return NoiseFloor(0.0, 0.0)
    curvature = (_LAGS.astype(float) ** 4) / d          # relative to each D_k
    s2, c = _nonnegative_pairs(_SHAPES / d, curvature)
    fitted = s2[:, None] * (_SHAPES / d) + c[:, None] * curvature
    cost = np.where(s2 > 0, np.sum((fitted - 1.0) ** 2, axis=1), np.inf)
    if not np.isfinite(cost).any():
        return NoiseFloor(0.0, 0.0)
    best = int(np.argmin(cost))          # the first of equal costs, as a scan of the grid
    rho, s2 = float(RHO_GRID[best]), float(s2[best])
    method = _METHOD + (" of the channel or of a fitted model's residual, the smaller per lag"
                        if reference is not None else "")
    return NoiseFloor(math.sqrt(s2), rho, method=method, capped=rho >= _RHO_MAX - 1e-9)


def _lag_variances(f: np.ndarray, keep: np.ndarray | None) -> np.ndarray:
    """The robust variances ``D_k`` of ``f``'s lag-``k`` second differences, ``k`` in
    ``_LAGS`` (only differences whose three samples are all in ``keep``, when given)."""
    d = np.empty(_LAGS.size)
    for j, k in enumerate(_LAGS):
        second = f[2 * k:] - 2.0 * f[k:-k]
        second += f[:-2 * k]
        if keep is not None:          # (without a mask, no copy of a long log)
            second = second[keep[2 * k:] & keep[k:-k] & keep[:-2 * k]]
        d[j] = robust_var(second)
    return d


def _nonnegative_pairs(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of ``a`` (grid points x lags): least squares ``x a + y b = 1`` with
    ``x, y >= 0`` (two unknowns: the unconstrained solution by the normal equations, else the
    corner ``y = 0``), for the whole grid at once (a scan of the grid took 45 ms per channel
    in 371 small ``lstsq`` calls, and :func:`~fitstiff.signal.spikes.find_spikes` runs it on every
    channel of every log loaded)."""
    aa, ab, bb = np.sum(a * a, axis=1), a @ b, float(b @ b)
    a1, b1 = np.sum(a, axis=1), float(np.sum(b))
    det = aa * bb - ab * ab
    with np.errstate(divide="ignore", invalid="ignore"):
        x = (a1 * bb - ab * b1) / det
        y = (aa * b1 - ab * a1) / det
    inside = (det > 0) & (x >= 0) & (y >= 0)
    corner = np.maximum(a1 / aa, 0.0)
    return np.where(inside, x, corner), np.where(inside, y, 0.0)


def pooled_noise_floor(logs, masks, *, references=None) -> tuple[list[NoiseFloor], float]:
    """Each log's force noise floor over its counted samples (``masks``), and the floor
    pooled over the logs by their counted samples: ``sqrt(sum n_k sigma_k^2 / sum n_k)`` (N).
    ``references``: per log, a fitted model's predicted force (:func:`noise_floor`)."""
    refs = [None] * len(logs) if references is None else list(references)
    floors = [noise_floor(log.force, mask=m, reference=g)
              for log, m, g in zip(logs, masks, refs)]
    counts = np.array([np.count_nonzero(m) for m in masks], dtype=float)
    sig2 = np.array([f.sigma**2 for f in floors])
    return floors, math.sqrt(float(np.sum(counts * sig2) / counts.sum()))


def estimate_noise(displacement: np.ndarray) -> float:
    """Gaussian-equivalent standard deviation of the white noise on a sampled channel
    (``displacement``, or any other), from its lag-1 second differences: the quick level
    that :func:`noise_floor` refines with the correlation of the noise.

    ``1.4826 * MAD(diff(x, 2)) / sqrt(6)``: robust to spikes and to the motion itself (a ramp
    has zero second difference, a turning point affects a handful of samples).
    """
    x = np.asarray(displacement, dtype=np.float64)
    if x.size < 3:
        return 0.0
    d2 = np.diff(x, 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / math.sqrt(6.0))
