"""What does the model's input cost a diagnosis on data with nothing missing?

A null dataset of the withheld-effect benchmark (`benchmarks/withheld.py`) holds no effect
the baseline lacks, yet its held-out RMS sits above the noise floor and some candidate's
score screen is significant on most of them. This script separates the part the
displacement channel makes: each dataset is simulated again with the same draws but the
displacement exact (its noise and encoder quantum set to 0; the force and its noise are
the same samples), and the baseline is fitted and every candidate screened three ways:

- ``denoised``: the logged displacement, denoised as every fit does by default;
- ``raw``: the logged displacement as it is (``denoise=False``);
- ``exact``: the exact displacement (no denoising needed).

Per dataset and way: the baseline's RMS (N), the pooled noise floor, and every candidate's
screen log p (the screen's level is log(0.05 / candidates), about -5.6).

    python benchmarks/drive_gap.py [--ids null/12 null/5 ...] [--json F]

About 15-25 s a dataset and way on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

DEFAULT_IDS = ("null/12", "null/5", "null/95", "null/1")
WAYS = ("denoised", "raw", "exact")


def dataset(dataset_id: str, way: str):
    """The logs and truth of ``dataset_id``, with the displacement exact for ``way ==
    "exact"`` (the simulator's draws are the same: its noise scaled by 0)."""
    import fitstiff._testing.rig_sim as rs
    import fitstiff._testing.withheld as wh

    if way != "exact":
        return wh.make_dataset(dataset_id)
    noisy = rs.SensorNoise

    class ExactDisplacement(noisy):
        def __init__(self, **kw):
            super().__init__(**dict(kw, displacement_um=0.0, quantum_um=0.0))

    rs.SensorNoise = ExactDisplacement
    try:
        return wh.make_dataset(dataset_id)
    finally:
        rs.SensorNoise = noisy


def screened(dataset_id: str, way: str) -> dict[str, object]:
    """The baseline's fit and every candidate's screen on one way of one dataset."""
    from fitstiff.diagnosis.diagnose import _setting, baseline_fit
    from fitstiff.diagnosis.screen import screen
    from fitstiff.diagnosis.select import MIN_GAIN
    from fitstiff.diagnosis.supermodel import SuperProblem, candidate_names
    from fitstiff.inference.selection import Selection

    start = time.perf_counter()
    logs, truth = dataset(dataset_id, way)
    names, _ = candidate_names(truth["baseline"], "all", logs=logs)
    sp = SuperProblem(logs, truth["baseline"], names,
                      selection=Selection.given(None, {"denoise": way == "denoised"}))
    fit = baseline_fit(sp)
    st = _setting(sp, names, fit, alpha=0.05, min_shrink=0.3)
    scores, _ = screen(sp, fit.theta, fit.hold, active=list(sp.baseline_terms),
                       candidates=names, noise=st.noise, weights=st.weights, alpha=0.05,
                       min_gain=MIN_GAIN)
    x = np.asarray(sp.physical(fit.theta, fit.hold, sp.model_mask(sp.baseline_terms)))
    squares, count = 0.0, 0
    for log, force, w in zip(sp.problem.logs, sp.forces(x, fit.theta),
                             sp.problem.sample_weights):
        keep = np.asarray(w) > 0
        squares += float(np.sum((np.asarray(force)[keep] - log.force[keep]) ** 2))
        count += int(keep.sum())
    return {"noise_N": st.noise_pooled, "baseline_rms_N": (squares / count) ** 0.5,
            "converged": bool(fit.converged),
            "log_p": {s.effect: float(s.log_p) for s in scores}, "samples": count,
            "wall_s": time.perf_counter() - start}


def main(argv=None) -> None:
    import jax

    jax.config.update("jax_enable_x64", True)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ids", nargs="+", default=list(DEFAULT_IDS))
    parser.add_argument("--ways", nargs="+", default=list(WAYS), choices=WAYS)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    out: dict[str, dict[str, object]] = {}
    for dataset_id in args.ids:
        for way in args.ways:
            row = screened(dataset_id, way)
            out[f"{dataset_id} {way}"] = row
            top = sorted(row["log_p"].items(), key=lambda kv: kv[1])[:3]
            print(f"{dataset_id:10s} {way:9s} noise {row['noise_N']:.4f} N  baseline RMS "
                  f"{row['baseline_rms_N']:.4f} N  strongest "
                  + ", ".join(f"{e} {lp:.1f}" for e, lp in top), flush=True)
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
