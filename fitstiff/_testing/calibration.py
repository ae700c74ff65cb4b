"""Posterior-calibration datasets and their scoring (``benchmarks/calibration.py`` runs them at
full size, tests/test_posterior.py a small version).

Each seed draws a truth over realistic ranges - pre-sliding slope 30-50 N/mm, breakaway
14-21 N, polytropic exponent 1.0-1.4, force noise 0.1-0.3 N with lag-1 correlation 0-0.9
(low-pass filtered force channels), 1 um displacement and 2 mbar pressure noise - and simulates
two ``chamber+dahl`` logs of the paper's cylinder (2 bar at 1 mm/s, 6 bar at 5 mm/s; triangle
cycles of 0.05, 0.2, 0.5 and 1 mm).
"""

from __future__ import annotations

import math
import time

import numpy as np

from fitstiff.data import paper_rig
from fitstiff.inference.fitting import fit
from fitstiff.inference.posterior import sample_posterior
from fitstiff.io.log import Rig
from fitstiff.physics.programs import TriangleCycles
from fitstiff.physics.simulate import Noise, simulate
from fitstiff.present.reopen import Z90

LOGS = ((2.0, 1.0), (6.0, 5.0))          # (supply bar, rate mm/s)
AMPLITUDES_MM = (0.05, 0.2, 0.5, 1.0)
UM_PER_SAMPLE = 5.0
#: the derived quantities whose true values a dataset's truth holds
QUANTITIES = ("presliding_slope_N_per_mm", "breakaway_N")

#: the ranges the truths are drawn from, as fitstiff prior overrides (display units)
DRAW_PRIORS = {"sigma0": {"dist": "uniform", "lower": 30.0, "upper": 50.0, "unit": "N/mm"},
               "Fc": {"dist": "uniform", "lower": 14.0, "upper": 21.0, "unit": "N"},
               "n": {"dist": "uniform", "lower": 1.0, "upper": 1.4}}


def draw_truth(rng: np.random.Generator) -> dict[str, float]:
    """Seal, chamber and sensor values of one dataset (see the module docstring)."""
    draw = {k: float(rng.uniform(v["lower"], v["upper"])) for k, v in DRAW_PRIORS.items()}
    return {**draw, "force_N": float(rng.uniform(0.1, 0.3)),
            "ar1": float(rng.uniform(0.0, 0.9))}


def dataset(seed: int):
    """Two logs and the truth (drawn values plus the true derived quantities)."""
    rng = np.random.default_rng(seed)
    truth = draw_truth(rng)
    noise = Noise(force_N=truth["force_N"], displacement_um=1.0, pressure_mbar=2.0,
                  ar1=truth["ar1"])
    logs = []
    for bar, rate in LOGS:
        rig = Rig.from_mapping(paper_rig(supply_bar=bar))
        sim = simulate("chamber+dahl", TriangleCycles(rate_mm_s=rate, amplitudes_mm=AMPLITUDES_MM),
                       rig=rig, params={k: truth[k] for k in ("sigma0", "Fc", "n")},
                       noise=noise, seed=seed * 10 + int(bar), name=f"p{bar:g}",
                       rate_hz=rate * 1e3 / UM_PER_SAMPLE)
        logs.append(sim.log)
    truth |= {k: float(sim.truth["derived"][k]) for k in QUANTITIES}
    return logs, truth


def score(seed: int, *, noise_models=("ar1", "gaussian"), walkers: int = 16, steps: int = 3000,
          tau_multiple: float = 30.0, priors: str = "draw", moves: str = "de",
          integrate_offsets: bool = True) -> dict[str, object]:
    """One dataset: fit, sample with each noise model, check the 90 % intervals."""
    logs, truth = dataset(seed)
    t0 = time.perf_counter()
    result = fit(logs, "chamber+dahl")
    row: dict[str, object] = {"seed": seed, "truth": truth, "fit_converged": result.converged,
                              "fit_seconds": time.perf_counter() - t0,
                              "residual_lag1": result.residual_autocorrelation}
    row["least_squares"] = {}
    for key in QUANTITIES:
        value, err = result.derived[key]
        row["least_squares"][key] = _entry(value - Z90 * err, value, value + Z90 * err,
                                           truth[key])
    for name in noise_models:
        t0 = time.perf_counter()
        post = sample_posterior(result, noise_model=name, walkers=walkers, steps=steps,
                                tau_multiple=tau_multiple, seed=seed, progress=False, draws=1,
                                priors=DRAW_PRIORS if priors == "draw" else None,
                                moves=moves, integrate_offsets=integrate_offsets)
        entry: dict[str, object] = {"converged": post.diagnostics.converged,
                                    "reason": post.diagnostics.reason,
                                    "steps": post.diagnostics.steps,
                                    "max_tau": max(post.diagnostics.autocorr_time.values()),
                                    "seconds": time.perf_counter() - t0}
        for key in QUANTITIES:
            s = post.summary(key)
            entry[key] = _entry(s["q05"], s["q50"], s["q95"], truth[key])
        row[name] = entry
    return row


def _entry(q05: float, q50: float, q95: float, truth: float) -> dict[str, object]:
    return {"q05": q05, "q50": q50, "q95": q95, "covered": bool(q05 <= truth <= q95)}


def coverage(rows, noise_model: str, key: str) -> tuple[float, float]:
    """Fraction of rows whose interval covers the truth, and its binomial standard error."""
    hits = [r[noise_model][key]["covered"] for r in rows]
    p = float(np.mean(hits))
    return p, math.sqrt(max(p * (1 - p), 1e-12) / len(hits))


def agreement(rows, noise_model: str, key: str) -> tuple[float, float, float]:
    """Posterior against least squares where the model is right (issue 17 item 1): the median
    and largest ``|posterior median - least squares| / least-squares standard error``, and the
    median ratio of the 90 % interval widths (posterior / least squares)."""
    shift, width = [], []
    for r in rows:
        ls, post = r["least_squares"][key], r[noise_model][key]
        se = (ls["q95"] - ls["q05"]) / (2 * Z90)
        shift.append(abs(post["q50"] - ls["q50"]) / se)
        width.append((post["q95"] - post["q05"]) / (ls["q95"] - ls["q05"]))
    return float(np.median(shift)), float(np.max(shift)), float(np.median(width))
