"""Calibration of the least-squares standard errors against the sample rate (issue 16).

For each sample rate and seed: simulate one ``chamber+dahl`` log of the paper's cylinder
(6 bar, mid-stroke, sigma0 = 40 N/mm, Fc = 18 N, n = 1.3) driven by triangle cycles of
0.2 and 1 mm at 1 mm/s (4.8 s), with realistic white noise (0.2 N force, 1 um
displacement, 2 mbar pressure; the seed draws the noise), fit ``chamber+dahl`` from the
default start and record the z-scores ``(estimate - truth) / stderr`` of the pre-sliding
slope and the breakaway force. Per rate: mean and sd of the z-scores and how many of the
90 % intervals (estimate +- 1.645 stderr) hold the truth. Calibrated errors give mean 0,
sd 1 and 18 of 20.

    python benchmarks/rate_calibration.py --seeds 20 --label after
    python benchmarks/rate_calibration.py --seeds 4 --rates 1000 --label dev --json /tmp/rc.json

Resumable: every fit is appended to the JSON file (``--json``, default
``benchmarks/results/rate_calibration.json``) under ``--label`` as soon as it ends, and a rerun
skips the (rate, seed) pairs already there. The file keeps the runs of every label (the
"before" run of the old turning-point treatment stays beside the "after" one).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from fitstiff.data import paper_rig
from fitstiff.inference.fitting import fit
from fitstiff.io.log import Rig
from fitstiff.physics.programs import TriangleCycles
from fitstiff.physics.simulate import Noise, simulate

RESULTS = Path(__file__).parent / "results" / "rate_calibration.json"
RATES_HZ = (200.0, 1000.0, 10000.0)
AMPLITUDES_MM = (0.2, 1.0)
RATE_MM_S = 1.0
TRUTH = {"sigma0": 40.0, "Fc": 18.0, "n": 1.3}
NOISE = Noise(force_N=0.2, displacement_um=1.0, pressure_mbar=2.0)
QUANTITIES = ("presliding_slope_N_per_mm", "breakaway_N")
Z90 = 1.6448536269514722


def one_fit(rate_hz: float, seed: int) -> dict[str, object]:
    """Simulate and fit one log; the z-scores of the slope and the breakaway."""
    rig = Rig.from_mapping(paper_rig())
    program = TriangleCycles(amplitudes_mm=AMPLITUDES_MM, rate_mm_s=RATE_MM_S)
    sim = simulate("chamber+dahl", program, rig=rig, params=TRUTH, noise=NOISE, seed=seed,
                   rate_hz=rate_hz, name=f"r{int(rate_hz)}_s{seed}")
    start = time.perf_counter()
    result = fit([sim.log], "chamber+dahl")
    seconds = time.perf_counter() - start
    entry: dict[str, object] = {"seed": seed, "samples": len(sim.log),
                                "converged": result.converged, "fit_s": round(seconds, 2)}
    for name in QUANTITIES:
        value, stderr = result.derived[name]
        truth = float(sim.truth["derived"][name])
        entry[name] = {"value": value, "stderr": stderr, "truth": truth,
                       "z": (value - truth) / stderr if stderr > 0 else None}
    return entry


def summarise(entries: list[dict[str, object]]) -> dict[str, object]:
    out: dict[str, object] = {"seeds": len(entries),
                              "converged": sum(bool(e["converged"]) for e in entries)}
    for name in QUANTITIES:
        z = np.array([e[name]["z"] for e in entries if e[name]["z"] is not None], float)
        out[name] = {"z_mean": float(np.mean(z)) if z.size else None,
                     "z_sd": float(np.std(z, ddof=1)) if z.size > 1 else None,
                     "inside_90": int(np.sum(np.abs(z) <= Z90)),
                     "median_stderr": float(np.median([e[name]["stderr"] for e in entries]))}
    return out


def _write(path: Path, data: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        json.dump(data, f, indent=1)
        f.write("\n")
    os.replace(tmp, path)


def table(run: dict[str, object]) -> str:
    lines = [f"{'rate':>8} {'n':>3} | {'slope z mean':>12} {'sd':>5} {'in 90%':>7} | "
             f"{'breakaway z mean':>16} {'sd':>5} {'in 90%':>7}"]
    for rate, block in run["rates"].items():
        s = block["summary"]
        a, b = s[QUANTITIES[0]], s[QUANTITIES[1]]
        lines.append(f"{rate:>8} {s['seeds']:>3} | {a['z_mean']:>+12.2f} {a['z_sd']:>5.2f} "
                     f"{a['inside_90']:>4}/{s['seeds']:<2} | {b['z_mean']:>+16.2f} "
                     f"{b['z_sd']:>5.2f} {b['inside_90']:>4}/{s['seeds']:<2}")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--rates", type=float, nargs="+", default=list(RATES_HZ))
    parser.add_argument("--label", default="after",
                        help="name of this run in the JSON file (e.g. before, after)")
    parser.add_argument("--json", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    data = json.loads(args.json.read_text()) if args.json.exists() else {}
    run = data.setdefault(args.label, {"setup": {
        "model": "chamber+dahl", "truth": TRUTH, "amplitudes_mm": AMPLITUDES_MM,
        "rate_mm_s": RATE_MM_S, "noise": {"force_N": NOISE.force_N,
                                          "displacement_um": NOISE.displacement_um,
                                          "pressure_mbar": NOISE.pressure_mbar},
        "command": "python benchmarks/rate_calibration.py --seeds N --label " + args.label},
        "rates": {}})
    for rate in args.rates:
        key = f"{rate:g}"
        block = run["rates"].setdefault(key, {"fits": []})
        done = {e["seed"] for e in block["fits"]}
        for seed in range(args.seeds):
            if seed in done:
                continue
            entry = one_fit(rate, seed)
            block["fits"].append(entry)
            block["fits"].sort(key=lambda e: e["seed"])
            block["summary"] = summarise(block["fits"])
            _write(args.json, data)
            z = [entry[q]["z"] for q in QUANTITIES]
            print(f"{key} Hz seed {seed}: z slope {_f(z[0])}, breakaway {_f(z[1])} "
                  f"({entry['samples']} samples, {entry['fit_s']} s)", flush=True)
        block["summary"] = summarise(block["fits"])
        _write(args.json, data)
    print(table(run))
    return 0


def _f(z):
    return "n/a" if z is None or not math.isfinite(z) else f"{z:+.2f}"


if __name__ == "__main__":
    raise SystemExit(main())
