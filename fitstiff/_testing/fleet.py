"""Synthetic fleets for the fleet's tests and benchmark (``benchmarks/fleet.py``), written
with the independent rig simulator (:mod:`fitstiff._testing.rig_sim`, no fitstiff physics).

:func:`make_fleet` lays a fleet out as ``fitstiff fleet`` reads it,
``ROOT/<cylinder>/[<run>/]log<k>.csv`` with sidecars, and writes ``ROOT.truth.json`` beside the
folder (outside it: the fleet folder holds cylinders only): per cylinder its pre-sliding
stiffness ``sigma0`` (N/mm) and Coulomb level ``Fc`` (N, the breakaway), whether it is a
planted outlier and of which kind, and its drift per run.

Population: ``sigma0`` and ``Fc`` log-normal about 40 N/mm and 18 N with the given spreads;
outliers ``Fc x 1.30`` ("breakaway") or ``sigma0 x 0.75`` ("slope"); a drifting cylinder's
``Fc`` changes by ``drift`` over its runs (linearly in the run index), and every cylinder
with runs scatters by ``run_scatter`` (log sd) from run to run.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from fitstiff._testing import rig_sim as rs

__all__ = ["make_fleet", "planted", "POSITIONS"]

#: each log's start position (m) and supply (Pa gauge): two operating points per cylinder
POSITIONS = ((0.25, 6e5), (0.45, 4e5))


def _program(samples: int, rate_hz: float) -> rs.Program:
    amplitudes = (0.2, 0.5, 1.0, 2.0)
    path = 4 * sum(amplitudes)                         # mm per pass of the triangles
    speed = path / max(samples / rate_hz - 0.1, 0.5)
    return rs.Program(tuple(rs.triangles(amplitudes, speed)), "growing triangles")


def _write_unit(job) -> None:
    from fitstiff.physics.simulate import write_log

    folder, sigma0, fc, seed, samples, rate_hz, noise_n = job
    rng = np.random.default_rng(seed)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    program = _program(samples, rate_hz)
    for k, (x0, supply) in enumerate(POSITIONS):
        log, _ = rs.simulate_log(program, base=rs.Base(sigma0=sigma0, Fc=fc, x0=x0,
                                                       supply=supply),
                                 noise=rs.SensorNoise(force_N=noise_n), rate_hz=rate_hz,
                                 substeps=3, rng=rng, name=f"log{k}")
        write_log(log, folder / f"log{k}.csv")


def make_fleet(root: str | os.PathLike, *, cylinders: int, seed: int = 0,
               slope_sd: float = 0.08, breakaway_sd: float = 0.06, outliers: float = 0.03,
               with_runs: int = 0, runs: int = 5, drifting: int = 0, drift: float = 0.10,
               run_scatter: float = 0.01, samples: int = 4000, rate_hz: float = 500.0,
               noise_N: float = 0.2, processes: int = 1) -> dict:
    """Write a fleet under ``root`` and return its truth (also in ``<root>.truth.json``).

    Args:
        cylinders: how many.
        slope_sd, breakaway_sd: the population's log spreads of sigma0 and Fc.
        outliers: the share of planted outliers (alternately breakaway +30 %, slope -25 %).
        with_runs: cylinders (the first ones) logged in ``runs`` runs; the others once.
        drifting: of those, how many drift; ``drift``: their Fc change over all runs.
        samples: samples per log (two logs per run).
        processes: simulate in this many processes.
    """
    root = Path(root)
    rng = np.random.default_rng(seed)
    n_out = int(round(outliers * cylinders))
    # outliers among the single-run cylinders (their runs would make them drift tests too)
    candidates = np.arange(with_runs, cylinders)
    planted = set(rng.choice(candidates, size=min(n_out, candidates.size), replace=False)
                  .tolist())
    drifting_set = set(range(min(drifting, with_runs)))
    truth, jobs = {}, []
    for c in range(cylinders):
        name = f"cyl{c:04d}"
        sigma0 = 40e3 * math.exp(slope_sd * rng.normal())
        fc = 18.0 * math.exp(breakaway_sd * rng.normal())
        kind = None
        if c in planted:
            kind = ("breakaway", "slope")[sorted(planted).index(c) % 2]
            if kind == "breakaway":
                fc *= 1.30
            else:
                sigma0 *= 0.75
        n_runs = runs if c < with_runs else 1
        per_run = (drift / max(n_runs - 1, 1)) if c in drifting_set else 0.0
        for r in range(n_runs):
            scatter = math.exp(run_scatter * rng.normal()) if n_runs > 1 else 1.0
            folder = root / name / (f"run{r + 1}" if n_runs > 1 else "")
            jobs.append((str(folder), sigma0 * scatter, fc * (1 + per_run * r) * scatter,
                         int(rng.integers(2**31)), samples, rate_hz, noise_N))
        truth[name] = {"sigma0_N_per_mm": sigma0 / 1e3, "Fc_N": fc, "outlier": kind,
                       "runs": n_runs, "drift_per_run": per_run}
    if processes > 1:
        with ProcessPoolExecutor(processes) as pool:
            list(pool.map(_write_unit, jobs, chunksize=8))
    else:
        for job in jobs:
            _write_unit(job)
    out = {"cylinders": truth, "settings": {
        "seed": seed, "slope_sd": slope_sd, "breakaway_sd": breakaway_sd,
        "outliers": outliers, "with_runs": with_runs, "runs": runs, "drifting": drifting,
        "drift": drift, "run_scatter": run_scatter, "samples": samples, "rate_hz": rate_hz}}
    root.with_name(root.name + ".truth.json").write_text(json.dumps(out, indent=1))
    return out


def planted(truth: dict, kind: str | None = None) -> Sequence[str]:
    """The planted outliers (of one ``kind``) of a truth from :func:`make_fleet`."""
    return sorted(c for c, t in truth["cylinders"].items()
                  if t["outlier"] and (kind is None or t["outlier"] == kind))
