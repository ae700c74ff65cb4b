"""Calibration of the posterior: how often do the 90 % intervals cover the truth?

Each dataset (:func:`fitstiff._testing.calibration.dataset`) draws a truth over realistic
ranges - pre-sliding slope 30-50 N/mm, breakaway 14-21 N, polytropic exponent 1.0-1.4, force
noise 0.1-0.3 N with lag-1 correlation 0-0.9 (low-pass filtered force channels), 1 um
displacement and 2 mbar pressure noise - and simulates two logs of the paper's cylinder (2 bar
at 1 mm/s, 6 bar at 5 mm/s; triangle cycles of 0.05, 0.2, 0.5 and 1 mm). ``chamber+dahl`` is
fitted once, then sampled with each noise model; the score is the fraction of datasets whose
90 % interval (q05, q95) of the pre-sliding slope and of the breakaway force contains the true
value, with its binomial standard error. A calibrated posterior covers 90 %. For comparison
the least-squares interval ``value +- 1.645 stderr`` (Laplace covariance with AR(1) inflation
and turning-point errors) is scored too.

By default the posterior uses uniform priors over exactly the ranges the truths are drawn from
(``--priors draw``), so every dataset is drawn from the prior the sampler uses and a calibrated
posterior covers 90 % by construction; ``--priors default`` keeps fitstiff's default weak
priors (log-normal, a factor of 10 per standard deviation), which is what users get.

    python benchmarks/calibration.py --datasets 50 --json calibration.json
    python benchmarks/calibration.py --datasets 3 --steps 600 --noise-models ar1
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np

from fitstiff._testing.calibration import DRAW_PRIORS, QUANTITIES, dataset
from fitstiff.inference.fitting import fit
from fitstiff.inference.posterior import sample_posterior
from fitstiff.present.reopen import Z90


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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", type=int, default=50)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--noise-models", default="ar1,gaussian")
    parser.add_argument("--walkers", type=int, default=16)
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--tau-multiple", type=float, default=30.0)
    parser.add_argument("--priors", choices=("draw", "default"), default="draw",
                        help="uniform priors over the draw ranges (default) or fitstiff's defaults")
    parser.add_argument("--moves", default="de", help="emcee proposal (fitstiff's MOVES)")
    parser.add_argument("--sample-offsets", action="store_true",
                        help="sample the force offsets instead of integrating them out")
    parser.add_argument("--json", metavar="FILE")
    args = parser.parse_args()
    models = tuple(m for m in args.noise_models.split(",") if m)
    rows = []
    for seed in range(args.first_seed, args.first_seed + args.datasets):
        row = score(seed, noise_models=models, walkers=args.walkers, steps=args.steps,
                    tau_multiple=args.tau_multiple, priors=args.priors, moves=args.moves,
                    integrate_offsets=not args.sample_offsets)
        rows.append(row)
        parts = [f"seed {seed:3d} ar1 {row['truth']['ar1']:.2f} lag1 {row['residual_lag1']:+.2f}"]
        for m in models:
            e = row[m]
            marks = "".join("+" if e[k]["covered"] else "-" for k in QUANTITIES)
            parts.append(f"{m} {marks} {'conv' if e['converged'] else 'NOT '} "
                         f"tau {e['max_tau']:.0f} {e['seconds']:.0f}s")
        print("  ".join(parts), flush=True)
        if args.json:
            with open(args.json, "w") as fh:
                json.dump(rows, fh, indent=2)
    for m in (*models, "least_squares"):
        for key in QUANTITIES:
            p, se = coverage(rows, m, key)
            print(f"{m:13s} {key:28s} 90 % interval coverage {100 * p:5.1f} % "
                  f"+- {100 * se:.1f} ({len(rows)} datasets)")
    for m in models:
        for key in QUANTITIES:
            mid, top, ratio = agreement(rows, m, key)
            print(f"{m:13s} {key:28s} posterior median - least squares: median {mid:.2f}, "
                  f"largest {top:.2f} standard errors; interval width ratio {ratio:.2f}")
    for m in models:
        conv = np.mean([r[m]["converged"] for r in rows])
        print(f"{m:13s} converged in {100 * conv:.0f} % of the runs")


if __name__ == "__main__":
    main()
