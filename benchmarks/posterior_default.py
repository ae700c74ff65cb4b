"""`fitstiff posterior` with its defaults on four realistic logs (issue 13).

Writes four ``chamber+dahl`` logs of the paper's 32 mm rodless cylinder at 0, 2, 4 and 6 bar
(triangle cycles of 0.1-4 mm at 200 Hz, 3 200-12 800 samples each, about 35 000 in all; 0.2 N
force noise with lag-1 correlation 0.5, 1 um displacement and 2 mbar pressure noise), then runs
``fitstiff posterior LOGS --model chamber+dahl --out DIR`` with every sampler option at its
default in a fresh process and reports wall time, peak resident memory (``ru_maxrss`` of the
child), whether the chain converged by its own rule, its length and autocorrelation times.

The reference, in the same run: the previous defaults (``--moves stretch --sample-offsets``:
emcee's stretch move, force offsets sampled) for the same number of steps as the default run
needed, reporting their autocorrelation times and the time those defaults would need to
converge (``50 tau`` steps at their measured cost per step, rounded up to a check).

    python benchmarks/posterior_default.py --json benchmarks/results/posterior_default.json
    python benchmarks/posterior_default.py --scale 0.25       # 4x shorter logs (a rehearsal)
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RATE_HZ = 200.0
AMPLITUDES_MM = (0.1, 0.5, 1.0, 2.0, 4.0)
#: (supply bar, samples): 35 000 in all
LOGS = ((0.0, 3200), (2.0, 6400), (4.0, 12800), (6.0, 12600))
CHECK_EVERY = 500               # fitstiff posterior's default


def write_logs(folder: Path, *, scale: float = 1.0) -> list[Path]:
    from fitstiff.data import paper_rig
    from fitstiff.io.log import Rig
    from fitstiff.physics.programs import TriangleCycles
    from fitstiff.physics.simulate import Noise, simulate, write_log

    travel_mm = 4 * sum(AMPLITUDES_MM)                  # one cycle of every amplitude
    paths = []
    for bar, samples in LOGS:
        rate = travel_mm * RATE_HZ / (samples * scale)  # mm/s: one pass through the cycles
        rig = Rig.from_mapping(paper_rig(supply_bar=bar))
        sim = simulate("chamber+dahl", TriangleCycles(amplitudes_mm=AMPLITUDES_MM,
                                                      rate_mm_s=rate),
                       rig=rig, params={"sigma0": 40, "Fc": 18},
                       noise=Noise(force_N=0.2, displacement_um=1.0, pressure_mbar=2.0,
                                   ar1=0.5), seed=int(bar) + 1, rate_hz=RATE_HZ,
                       name=f"p{bar:g}bar")
        path = folder / f"p{bar:g}bar.csv"
        write_log(sim.log, path, truth=sim.truth)
        paths.append(path)
    return paths


def run_cli(args: list[str]) -> dict[str, object]:
    """``fitstiff ARGS`` in a fresh process: wall time, the child's own peak RSS (from
    ``wait4``: ``RUSAGE_CHILDREN`` holds the largest of every child the caller has waited
    for, e.g. a test process's earlier ones)."""
    start = time.perf_counter()
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen([sys.executable, "-m", "fitstiff", *args], stdout=out,
                                stderr=err, text=True)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        wall = time.perf_counter() - start
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read(), err.read()
    if proc.returncode != 0:
        raise SystemExit(f"fitstiff {' '.join(args)} failed ({proc.returncode}):\n"
                         f"{stderr[-3000:]}")
    return {"wall_s": wall, "peak_rss_mb": usage.ru_maxrss / 1024, "stdout": stdout}


def summary(out: Path) -> dict[str, object]:
    post = json.loads((out / "posterior.json").read_text())
    d = post["diagnostics"]
    tau = {k: v for k, v in d["autocorr_time"].items() if v is not None}
    worst = max(tau, key=tau.get)
    return {"converged": d["converged"], "reason": d["reason"], "steps": d["steps"],
            "moves": d.get("moves", "stretch"), "integrated": d.get("integrated", []),
            "tau_max": tau[worst], "tau_max_name": worst, "tau": tau,
            "acceptance": d["acceptance_fraction"],
            "slope_N_per_mm": post["derived"]["presliding_slope_N_per_mm"],
            "breakaway_N": post["derived"]["breakaway_N"]}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=1.0,
                        help="factor on the log lengths (default 1: 35 000 samples)")
    parser.add_argument("--no-reference", action="store_true",
                        help="skip the previous defaults' run")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        logs = [str(p) for p in write_logs(folder, scale=args.scale)]
        samples = sum(sum(1 for _ in open(p)) - 1 for p in logs)
        print(f"{len(logs)} logs, {samples} samples", flush=True)
        new = run_cli(["posterior", *logs, "--model", "chamber+dahl", "--out",
                       str(folder / "new")])
        result: dict[str, object] = {"samples": samples, "logs": len(logs),
                                     "default": {k: v for k, v in new.items() if k != "stdout"}
                                     | summary(folder / "new")}
        d = result["default"]
        print(f"default: {d['wall_s']:.0f} s, peak {d['peak_rss_mb']:.0f} MB, converged "
              f"{d['converged']} after {d['steps']} steps (tau {d['tau_max']:.1f})", flush=True)
        if not args.no_reference:
            steps = int(d["steps"])
            old = run_cli(["posterior", *logs, "--model", "chamber+dahl", "--moves", "stretch",
                           "--sample-offsets", "--steps", str(steps), "--out",
                           str(folder / "old")])
            o = {k: v for k, v in old.items() if k != "stdout"} | summary(folder / "old")
            need = math.ceil(50 * o["tau_max"] / CHECK_EVERY + 1) * CHECK_EVERY
            per_step = o["wall_s"] / steps
            o["projected_steps"] = need
            o["projected_wall_s"] = per_step * need
            result["previous_defaults"] = o
            result["speedup"] = o["projected_wall_s"] / d["wall_s"]
            print(f"previous defaults, {steps} steps: {o['wall_s']:.0f} s, tau "
                  f"{o['tau_max']:.1f} ({o['tau_max_name']}): would need ~{need} steps, "
                  f"~{o['projected_wall_s']:.0f} s; the default is {result['speedup']:.1f}x "
                  "faster to convergence", flush=True)
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
