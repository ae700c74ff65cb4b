"""What the diagnosis' noise floor should be: the force noise, and what the displacement's
noise makes of the force through the model, measured on the withheld-effect benchmark's
datasets (whose sensor noise is known: each is simulated again without it).

Per dataset (pooled over its logs, over the samples a fit counts):

- ``force_noise_N``: the force noise actually drawn (noisy minus clean force channel);
- ``floor_data_N``: :func:`~fitstiff.signal.noise.noise_floor` of the force channel alone
  (the diagnosis' floor);
- ``floor_residual_N``: the same with the baseline's full-data prediction as the
  ``reference`` (each lag's variance the smaller of the force's and of the residual's);
- ``true_rms_N``: the in-sample RMS of the true model (the baseline plus the withheld
  effects) fitted to the logs: a floor no model of the library goes below in-sample;
- ``displacement_part_N``: the same fit's RMS on the logs with the clean force channel and
  the noisy displacement: what the displacement's noise (and the encoder's quantum) leaves
  in the force residual, through the denoised drive and the fit's parameters.

A floor that held-out decisions can rely on is about ``sqrt(force_noise**2 +
displacement_part**2)`` (``achievable_N``), checked against ``true_rms_N``.

The displacement part from the logs alone (no truth), a candidate estimator
(``estimated_displacement_part_N``, :func:`estimate_displacement_part`): the baseline fitted
to the logs, its prediction as a noise-free force on its own denoised drive, the drive with
AR(1) noise of each log's estimated displacement noise as the measured displacement, and the
baseline fitted again: the RMS of that fit.

    python benchmarks/noise_floor.py                      # the ten datasets of DEFAULT_IDS
    python benchmarks/noise_floor.py --ids null/0 single/stribeck/2 --json F
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np

import fitstiff._testing.rig_sim as rs
from fitstiff._testing.withheld import make_dataset
from fitstiff.inference.fitting import fit
from fitstiff.inference.fitting.result import FitResult
from fitstiff.signal.noise import marginal_scale, pooled_noise_floor

RESULTS = Path(__file__).parent / "results" / "noise_floor.json"

DEFAULT_IDS = ("null/0", "null/1", "null/2", "null/3", "null/4", "single/stribeck/2",
               "single/asymmetry/0", "single/asymmetry/2", "single/leakage/0",
               "single/maxwell_slip/1")


def _pooled_rms(parts: list[np.ndarray]) -> float:
    sq = sum(float(p @ p) for p in parts)
    return math.sqrt(sq / max(sum(p.size for p in parts), 1))


@contextlib.contextmanager
def _silenced(*channels: str):
    """The datasets made inside have the noise of ``channels`` (``SensorNoise`` fields) at
    zero. The random draws stay the same (a zero amplitude still draws), so every other
    channel and every later log are those of the noisy dataset; ``make_dataset(clean=True)``
    draws nothing, and its later logs differ."""
    original = rs.SensorNoise

    def silenced(**kw):
        return dataclasses.replace(original(**kw), **{c: 0.0 for c in channels})

    rs.SensorNoise = silenced
    try:
        yield
    finally:
        rs.SensorNoise = original


def estimate_displacement_part(result: FitResult, *, seed: int = 0) -> float:
    """The force RMS that the displacement's noise leaves in a fit of ``result``'s model,
    from the logs alone (see the module docstring): one simulated replicate."""
    p = result.problem
    predicted = p.per_log(result.theta)
    rng = np.random.default_rng(seed)
    simulated = []
    for i, log in enumerate(p.logs):
        n = len(log)
        drive = np.asarray(p.drives[i].displacement)[:n]
        rho = p.displacement_rho[i]
        e = rs._ar1(rng, n, p.segmentations[i].noise * marginal_scale(rho), rho)
        channels = {"displacement": drive + e, "force": np.asarray(predicted[i]["force"])}
        if log.pressure_a is not None and log.pressure_b is not None:
            channels |= {"pressure_a": np.asarray(predicted[i]["pressure_a"]),
                         "pressure_b": np.asarray(predicted[i]["pressure_b"])}
        simulated.append(dataclasses.replace(log, **channels))
    return fit(simulated, model=result.model).rms_N


def measure(dataset_id: str, *, short: bool = False) -> dict[str, object]:
    """The figures of the module docstring for one dataset (``short``: the test suite's
    version of it, :func:`~fitstiff._testing.withheld.make_dataset`)."""
    start = time.perf_counter()
    logs, truth = make_dataset(dataset_id, short=short)
    with _silenced("force_N"):          # the same logs, the force channel without its noise
        quiet, _ = make_dataset(dataset_id, short=short)
    spec = "+".join([truth["baseline"], *truth["effects"]])
    base = fit(logs, model=truth["baseline"])
    masks = [w > 0 for w in base.problem.sample_weights]
    drawn = [np.asarray(a.force - b.force)[m] for a, b, m in zip(logs, quiet, masks)]
    _, data = pooled_noise_floor(base.problem.logs, masks)
    predicted = [np.asarray(p["force"]) for p in base.problem.per_log(base.theta)]
    _, residual = pooled_noise_floor(base.problem.logs, masks, references=predicted)
    true = fit(logs, model=spec)
    part = fit(quiet, model=spec)
    force_noise = _pooled_rms(drawn)
    return {"id": dataset_id, "model": spec, "force_noise_N": force_noise,
            "floor_data_N": data, "floor_residual_N": residual,
            "true_rms_N": true.rms_N, "displacement_part_N": part.rms_N,
            "achievable_N": math.hypot(force_noise, part.rms_N),
            "estimated_displacement_part_N": estimate_displacement_part(base),
            "converged": bool(base.converged and true.converged and part.converged),
            "wall_s": time.perf_counter() - start}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ids", nargs="+", default=list(DEFAULT_IDS), metavar="ID")
    parser.add_argument("--short", action="store_true",
                        help="the short datasets of the test suite (triangles and nested loops)")
    parser.add_argument("--json", type=Path, default=RESULTS,
                        help="resumable record (default benchmarks/results/noise_floor.json)")
    args = parser.parse_args(argv)
    rows = json.loads(args.json.read_text()) if args.json.exists() else []
    done = {r["id"] for r in rows}
    print(f"{'dataset':<24}{'force':>8}{'data':>8}{'resid':>8}{'true':>8}{'displ':>8}"
          f"{'achiev':>8}{'est.dis':>8}  (N)")
    for did in args.ids:
        if did not in done:
            rows.append(measure(did, short=args.short))
            args.json.write_text(json.dumps(rows, indent=1))
        r = next(x for x in rows if x["id"] == did)
        print(f"{did:<24}" + "".join(f"{r[k]:>8.4f}" for k in (
            "force_noise_N", "floor_data_N", "floor_residual_N", "true_rms_N",
            "displacement_part_N", "achievable_N", "estimated_displacement_part_N")))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
