"""Peak memory of a 1 M-sample fit (issue 16: at most 1 GB resident).

Writes one ``chamber+dahl`` log of the paper's cylinder at 10 kHz for 100 s (1 000 001
samples; triangle cycles 0.05-1 mm at 1 mm/s, 0.2 N / 1 um / 2 mbar noise) as a CSV with its
sidecar, then runs ``load_logs`` + ``fit`` + ``fit.json`` in a fresh subprocess and reports
its peak resident set size (the kernel's ``VmHWM``), with the peak of
each stage (loading, building the problem, the solve, the covariance summary; the kernel's
peak counter is reset between stages through ``/proc/self/clear_refs``).

    python benchmarks/fit_memory.py --json benchmarks/results/fit_memory.json
    python benchmarks/fit_memory.py --seconds 10          # a 100 000-sample rehearsal

Issue 36 (logs of any length in bounded memory): ``--samples N`` writes a log of about ``N``
samples instead (10 kHz, whole cycles of the program: 74 000 samples each), also measures ``fitstiff inspect`` on it, and fits a ``--reference``-sample
log (1 M) in the same run for the wall-time ratio. A child past ``--timeout`` seconds is
stopped; its peak resident set is polled every 0.2 s, so a stopped run still reports it.

    python benchmarks/fit_memory.py --samples 10000000 --json benchmarks/results/fit_memory_10m.json
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RATE_HZ = 10000.0


def write_log(folder: Path, seconds: float) -> Path:
    from fitstiff.data import paper_rig
    from fitstiff.io.log import Rig
    from fitstiff.physics.programs import TriangleCycles
    from fitstiff.physics.simulate import Noise, simulate, write_log as write

    amplitudes = (0.05, 0.1, 0.2, 0.5, 1.0)
    cycles = max(1, int(round(seconds / (4 * sum(amplitudes)))))
    rig = Rig.from_mapping(paper_rig())
    program = TriangleCycles(amplitudes_mm=amplitudes, cycles=cycles, rate_mm_s=1.0)
    sim = simulate("chamber+dahl", program, rig=rig, params={"sigma0": 40, "Fc": 18},
                   noise=Noise(force_N=0.2, displacement_um=1.0, pressure_mbar=2.0), seed=1,
                   rate_hz=RATE_HZ, name="long")
    path = folder / "long.csv"
    write(sim.log, path, truth=sim.truth)
    return path


_CHILD = r"""
import json, sys, time
from fitstiff.malloc import limit_arenas
limit_arenas()          # as the command line does, before JAX starts its threads

def peak_mb():
    # the largest stage peak and the rest of the run: not getrusage's ru_maxrss, which keeps
    # the forking parent's resident set from before the exec (the parent that simulated a
    # 10 M-sample log is larger than this child)
    return max([hwm_mb(), *stages.values()])

def hwm_mb():
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024

def reset():
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False

stages = {}
t0 = time.perf_counter()
import fitstiff.inference.fitting as fitting
from fitstiff.io.loading import load_logs
from fitstiff.inference.problem import Problem
stages["import"] = hwm_mb(); reset()
logs = load_logs([sys.argv[1]])
stages["load"] = hwm_mb(); reset()
problem = Problem(logs, "chamber+dahl")
stages["problem"] = hwm_mb(); reset()
result = fitting.fit_problem(problem)
stages["solve_and_summary"] = hwm_mb()
doc = result.to_dict()
print(json.dumps({"peak_rss_mb": peak_mb(), "stage_peaks_mb": stages,
                  "samples": len(logs[0]), "converged": result.converged,
                  "steps": result.steps, "seconds": time.perf_counter() - t0,
                  "sigma0_N_per_mm": doc["parameters"]["sigma0"],
                  "Fc_N": doc["parameters"]["Fc"]}))
"""


def measure(csv: Path) -> dict:
    out = subprocess.run([sys.executable, "-c", _CHILD, str(csv)], capture_output=True,
                         text=True, check=False)
    if out.returncode:
        raise SystemExit(f"the fit failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def watched(command: list[str], *, timeout: float) -> dict:
    """Run ``command``; its wall time, exit status, last output line and peak resident set
    (polled every 0.2 s with psutil: a run stopped at ``timeout`` still has one)."""
    import psutil

    t0 = time.perf_counter()
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    watch = psutil.Process(proc.pid)
    peak, stopped = 0.0, False
    while proc.poll() is None:
        try:
            peak = max(peak, watch.memory_info().rss / 2**20)
        except psutil.Error:
            break
        if time.perf_counter() - t0 > timeout:
            proc.kill()
            stopped = True
            break
        time.sleep(0.2)
    output = proc.communicate()[0]
    lines = output.strip().splitlines()
    return {"wall_s": time.perf_counter() - t0, "returncode": proc.returncode,
            "stopped_at_timeout": stopped, "peak_rss_mb": peak,
            "last_line": lines[-1] if lines else ""}


def _fit_run(csv: Path, timeout: float) -> dict:
    run = watched([sys.executable, "-c", _CHILD, str(csv)], timeout=timeout)
    if run["returncode"] == 0:
        polled = run["peak_rss_mb"]
        run.update(json.loads(run.pop("last_line")))
        run["polled_peak_rss_mb"] = polled      # the resident set seen from outside
    return run


def long_log(args) -> dict:
    """``inspect`` and ``fit`` of an ``--samples`` log, and the fit of a ``--reference`` one."""
    result: dict = {"samples_requested": args.samples, "reference_samples": args.reference}
    with tempfile.TemporaryDirectory() as tmp:
        for key, samples in (("reference", args.reference), ("long", args.samples)):
            folder = Path(tmp) / key
            folder.mkdir()
            start = time.perf_counter()
            csv = write_log(folder, samples / RATE_HZ)
            result[f"{key}_csv_mb"] = csv.stat().st_size / 1e6
            print(f"wrote {csv.stat().st_size / 1e6:.0f} MB CSV in "
                  f"{time.perf_counter() - start:.0f} s", flush=True)
            if key == "long":
                result["inspect"] = watched([sys.executable, "-m", "fitstiff", "inspect",
                                             str(csv), "--json"], timeout=args.timeout)
                print(json.dumps(result["inspect"])[:300], flush=True)
            result[f"{key}_fit"] = _fit_run(csv, args.timeout)
            print(json.dumps(result[f"{key}_fit"])[:300], flush=True)
    ref, long = result["reference_fit"], result["long_fit"]
    if ref.get("returncode") == 0 and long.get("returncode") == 0:
        result["fit_wall_ratio"] = long["wall_s"] / ref["wall_s"]
    result["targets"] = {"inspect_peak_mb_at_most": 1024, "fit_peak_mb_at_most": 2048,
                         "fit_wall_ratio_at_most": 12.0, "reference_fit_peak_mb_at_most": 1024}
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=100.0)
    parser.add_argument("--samples", type=int,
                        help="a long log of this many samples: inspect and fit it, and fit a "
                             "--reference one for the wall-time ratio")
    parser.add_argument("--reference", type=int, default=1_000_000)
    parser.add_argument("--timeout", type=float, default=1800.0,
                        help="seconds a child may run (--samples)")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    if args.samples:
        result = long_log(args)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            start = time.perf_counter()
            csv = write_log(Path(tmp), args.seconds)
            print(f"wrote {csv.stat().st_size / 1e6:.0f} MB CSV in "
                  f"{time.perf_counter() - start:.0f} s", flush=True)
            result = measure(csv)
    result["command"] = "python benchmarks/fit_memory.py " + " ".join(argv or sys.argv[1:])
    print(json.dumps(result, indent=1))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
