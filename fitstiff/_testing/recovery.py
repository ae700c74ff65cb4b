"""Parameter-recovery datasets (``benchmarks/recovery.py``, tests/test_fitting.py).

For each seed: a true seal (slope 30-50 N/mm, breakaway 14-21 N) and n (1.0-1.4), and 4 logs
of the paper's cylinder at 0, 2, 4, 6 bar gauge, driven at 0.2, 1, 5 and 20 mm/s (so rate
effects such as LuGre's Stribeck curve are identifiable; 5 um per sample) with realistic noise
(0.2 N force, 1 um displacement, 2 mbar pressure).
"""

from __future__ import annotations

import numpy as np

from fitstiff.data import paper_rig
from fitstiff.io.log import Rig
from fitstiff.physics.programs import TriangleCycles
from fitstiff.physics.simulate import Noise, simulate

AMPLITUDES_MM = (0.05, 0.1, 0.2, 0.5, 1.0)
LOGS = ((0.0, 0.2), (2.0, 1.0), (4.0, 5.0), (6.0, 20.0))   # (supply bar, rate mm/s)
UM_PER_SAMPLE = 5.0


def truth_for(friction: str, rng: np.random.Generator) -> dict[str, float]:
    slope, breakaway = rng.uniform(30, 50), rng.uniform(14, 21)
    values = {"n": float(rng.uniform(1.0, 1.4))}
    if friction == "dahl":
        values |= {"sigma0": slope, "Fc": breakaway}
    elif friction == "lugre":
        values |= {"sigma0": slope, "Fs": breakaway, "Fc": 0.8 * breakaway,
                   "sigma1": 100.0, "vs": 2.0}
    elif friction.startswith("maxwell_slip"):
        n = int(friction.split(":")[1])
        k = slope / n
        shape = np.arange(1, n + 1, dtype=float)
        delta = shape * breakaway / (k * shape.sum())
        values |= {f"k_{i + 1}": k for i in range(n)}
        values |= {f"delta_{i + 1}": float(d) for i, d in enumerate(delta)}
    return values


def dataset(friction: str, seed: int):
    """Four logs (one per supply pressure and speed) of ``chamber+<friction>``, their true
    derived values and n."""
    rng = np.random.default_rng(seed)
    truth = truth_for(friction, rng)
    logs = []
    for bar, rate in LOGS:
        rig = Rig.from_mapping(paper_rig(supply_bar=bar))
        program = TriangleCycles(rate_mm_s=rate, amplitudes_mm=AMPLITUDES_MM)
        sim = simulate(f"chamber+{friction}", program, rig=rig, params=truth,
                       noise=Noise(force_N=0.2, displacement_um=1.0, pressure_mbar=2.0),
                       seed=seed * 10 + int(bar), name=f"p{bar:g}",
                       rate_hz=rate * 1e3 / UM_PER_SAMPLE)
        logs.append(sim.log)
    return logs, sim.truth["derived"], truth["n"]
