"""Posterior-calibration datasets (``benchmarks/calibration.py``, tests/test_posterior.py).

Each seed draws a truth over realistic ranges - pre-sliding slope 30-50 N/mm, breakaway
14-21 N, polytropic exponent 1.0-1.4, force noise 0.1-0.3 N with lag-1 correlation 0-0.9
(low-pass filtered force channels), 1 um displacement and 2 mbar pressure noise - and simulates
two ``chamber+dahl`` logs of the paper's cylinder (2 bar at 1 mm/s, 6 bar at 5 mm/s; triangle
cycles of 0.05, 0.2, 0.5 and 1 mm).
"""

from __future__ import annotations

import numpy as np

from fitstiff.io.log import Rig
from fitstiff.physics.programs import TriangleCycles
from fitstiff.physics.simulate import Noise, simulate

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
        rig = Rig.from_mapping({"bore_mm": 32, "stroke_mm": 700, "start_position_mm": 350,
                                "supply_bar": bar})
        sim = simulate("chamber+dahl", TriangleCycles(rate_mm_s=rate, amplitudes_mm=AMPLITUDES_MM),
                       rig=rig, params={k: truth[k] for k in ("sigma0", "Fc", "n")},
                       noise=noise, seed=seed * 10 + int(bar), name=f"p{bar:g}",
                       rate_hz=rate * 1e3 / UM_PER_SAMPLE)
        logs.append(sim.log)
    truth |= {k: float(sim.truth["derived"][k]) for k in QUANTITIES}
    return logs, truth
