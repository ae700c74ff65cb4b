"""Where the model misses: held-out residuals by region, log, pressure, direction and speed.

Cells are the segmentation's tags (:meth:`~fitstiff.segments.segmentation.Segmentation.to_frame`):
motion region (presliding, sliding, dwell, standstill) x log x pressure level x direction x
speed band, plus a ``stroke_end`` cell per log and direction. Each cell gets its bias, RMS,
share of the squared error and two z-scores against the log's noise floor (``sigma``, AR(1)
``rho`` from :func:`~fitstiff.signal.noise.noise_floor`), with effective sample sizes for
correlated noise:

    z_bias = bias / (sigma / sqrt(n (1 - rho) / (1 + rho)))
    z_rms  = (rms**2 / sigma**2 - 1) / sqrt(2 (1 + rho**2) / ((1 - rho**2) n))

A cell is **above the noise floor** when ``z_rms > 3`` and its RMS exceeds the noise by more
than 10 %.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd

from fitstiff.segments.segmentation import Segmentation
from fitstiff.signal.noise import NoiseFloor

__all__ = ["region_table", "region_summary", "above_floor", "pooled_excess", "Z_ABOVE",
           "EXCESS_ABOVE"]

Z_ABOVE = 3.0
EXCESS_ABOVE = 1.1
_MIN_SAMPLES = 10
_KEYS = ["file", "region", "pressure_bar", "direction", "speed_band"]


def region_table(residuals: Sequence[np.ndarray], segmentations: Sequence[Segmentation],
                 noise: Sequence[NoiseFloor], masks: Sequence[np.ndarray]) -> pd.DataFrame:
    """One row per cell with at least 10 samples (see the module docstring).

    ``residuals``: per log, held-out model - measured force (N); ``masks``: per log, the
    samples that count (weight > 0).
    """
    frames = []
    for res, seg, nf, mask in zip(residuals, segmentations, noise, masks):
        frame = seg.to_frame()
        frame["residual"] = res
        frame["sigma"] = nf.sigma
        frame["rho"] = nf.rho
        frame = frame[np.asarray(mask, bool)]
        frames.append(frame)
    data = pd.concat(frames, ignore_index=True)
    data["region"] = data["region"].astype(str)
    data["speed_band"] = data["speed_band"].astype(str)
    data["file"] = data["file"].astype(str)
    ends = data[data["stroke_end"].fillna(False).astype(bool)].copy()
    ends["region"] = "stroke_end"
    ends["speed_band"] = "all"
    total = float(np.sum(data["residual"] ** 2))
    rows = []
    for source in (data, ends):
        for key, cell in source.groupby(_KEYS, dropna=False, observed=True):
            n = len(cell)
            if n < _MIN_SAMPLES:
                continue
            r = cell["residual"].to_numpy()
            sigma = float(cell["sigma"].iloc[0])
            rho = float(cell["rho"].iloc[0])
            rms = math.sqrt(float(r @ r) / n)
            bias = float(r.mean())
            rows.append({**dict(zip(_KEYS, key)), "samples": n, "bias_N": bias, "rms_N": rms,
                         "share": float(r @ r) / total if total > 0 else 0.0,
                         "z_bias": _z_bias(bias, sigma, rho, n),
                         "z_rms": _z_rms(rms, sigma, rho, n),
                         "noise_N": sigma,
                         "excess_N": math.sqrt(max(rms**2 - sigma**2, 0.0))})
    table = pd.DataFrame(rows)
    if not table.empty:
        table["direction"] = table["direction"].map({1: "toward_B", -1: "toward_A",
                                                     0: "still"})
        table["pressure_bar"] = table["pressure_bar"].astype(float)
    return table


def _z_bias(bias: float, sigma: float, rho: float, n: int) -> float:
    n_eff = n * (1 - rho) / (1 + rho)
    return bias / (sigma / math.sqrt(n_eff)) if sigma > 0 and n_eff > 0 else math.inf


def _z_rms(rms: float, sigma: float, rho: float, n: int) -> float:
    if sigma <= 0:
        return math.inf
    n_eff = n * (1 - rho**2) / (1 + rho**2)
    return (rms**2 / sigma**2 - 1.0) / math.sqrt(2.0 / n_eff)


def above_floor(table: pd.DataFrame) -> pd.DataFrame:
    """The cells whose residual stays above the noise floor, the largest share of the squared
    error first (a large excess over a handful of samples ranks below a broad one)."""
    if table.empty:
        return table
    keep = (table["z_rms"] > Z_ABOVE) & (table["rms_N"] > EXCESS_ABOVE * table["noise_N"])
    return table[keep].sort_values("share", ascending=False)


def pooled_excess(cells: pd.DataFrame) -> pd.Series:
    """Per region: the RMS excess over the noise (N) pooled over the given cells (by samples);
    stroke_end cells overlap the motion regions and are pooled on their own."""
    if cells.empty:
        return pd.Series(dtype=float)
    out = {}
    for region, group in cells.groupby("region"):
        n = group["samples"].to_numpy(float)
        ms = float(np.sum(n * group["rms_N"].to_numpy() ** 2) / n.sum())
        noise = float(np.sum(n * group["noise_N"].to_numpy() ** 2) / n.sum())
        out[region] = math.sqrt(max(ms - noise, 0.0))
    return pd.Series(out).sort_values(ascending=False)


def region_summary(residuals: Sequence[np.ndarray], segmentations: Sequence[Segmentation],
                   noise: Sequence[NoiseFloor], masks: Sequence[np.ndarray], *,
                   value: str = "z_rms") -> pd.DataFrame:
    """Region (rows: presliding, sliding, dwell, standstill, stroke_end) x log (columns) of
    ``value`` (``z_rms``, ``rms_N`` or ``excess_N``) over each log's samples of the region;
    NaN where a log has fewer than 10 samples of it (or cannot have it)."""
    regions = ("presliding", "sliding", "dwell", "standstill", "stroke_end")
    table = {}
    for res, seg, nf, mask in zip(residuals, segmentations, noise, masks):
        column = {}
        for region in regions:
            if region not in seg.available_regions:
                column[region] = np.nan
                continue
            r = np.asarray(res)[seg.mask(region) & np.asarray(mask, bool)]
            if r.size < _MIN_SAMPLES:
                column[region] = np.nan
                continue
            rms = math.sqrt(float(r @ r) / r.size)
            column[region] = {"z_rms": _z_rms(rms, nf.sigma, nf.rho, r.size), "rms_N": rms,
                              "excess_N": math.sqrt(max(rms**2 - nf.sigma**2, 0.0))}[value]
        table[seg.name] = column
    return pd.DataFrame(table).reindex(list(regions))
