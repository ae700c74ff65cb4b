"""The fleet's batched fits on the CPU and on a GPU, measured in one run (issue 34).

Where JAX sees a GPU, a fleet's units of one structure are solved ``--lanes`` at a time as one
``vmap``-ed call (:func:`fitstiff.inference.fitting.fit_problems`). This measures, in one
process and then end to end, how many cylinders per second each backend fits:

1. A fleet of ``--cylinders`` cylinders x 2 logs x ``--samples`` samples is written by the
   independent rig simulator (:func:`fitstiff._testing.fleet.make_fleet`; population spread,
   3 % planted outliers, no runs).
2. Each unit is read and its problem built on the CPU (the host's share of a fleet: seconds
   per unit).
3. Per backend (``cpu``, and ``gpu`` where JAX sees one), in this process:
   - one unit at a time (:func:`~fitstiff.inference.fitting.fit_problem`, the fleet's CPU
     path): the first call (compilation) and warm cylinders per second;
   - for each of ``--lanes`` (GPU; ``--cpu-lanes`` on the CPU): the batched solve alone
     (the first chunk with its compilation, then every chunk warm) and the whole of
     :func:`fit_problems` (solve, flat-cost check, covariance summary; warm), in cylinders
     per second. On the GPU the units are repeated ``--tile`` times (batches of thousands
     from a fleet that is quick to simulate and build).
   The estimates of the last batched run are compared with the CPU's one-at-a-time fits
   (largest relative difference of the slope and the breakaway).
4. ``--end-to-end``: ``fitstiff fleet`` as a subprocess over the whole fleet, cold, once on
   the CPU (``JAX_PLATFORMS=cpu``, one worker per core, the default) and once per GPU layout
   of ``--gpu-layouts`` (``WORKERSxLANES``), wall time and cylinders per second.

Results go to ``--json`` as each step finishes (a run cut short keeps what it measured).

    python benchmarks/fleet_gpu.py [--cylinders 256] [--lanes 256 1024] [--cpu-lanes 16]
        [--tile 4] [--single 16] [--end-to-end] [--gpu-layouts 1x256 4x64]
        [--json benchmarks/results/fleet_gpu.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _save(path: Path | None, result: dict) -> None:
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(result, indent=2, default=str) + "\n")
    print(json.dumps(result, default=str)[-600:], file=sys.stderr, flush=True)


def _estimates(results) -> np.ndarray:
    keys = ("presliding_slope_N_per_mm", "breakaway_N")
    return np.array([[r.to_dict()["derived"][k]["value"] for k in keys] for r in results],
                    dtype=float)


def _backend(name: str, problems, *, lanes_list, single: int, step=lambda out: None) -> dict:
    import jax

    from fitstiff.inference.compiling import compiled_batch
    from fitstiff.inference.fitting import fit_problem, fit_problems
    from fitstiff.inference.fitting.solve import _solve
    from fitstiff.inference.fitting.start import initial_guess

    device = jax.devices(name)[0]
    out: dict = {"device": str(device), "device_kind": getattr(device, "device_kind", ""),
                 "units": len(problems)}
    with jax.default_device(device):
        t0 = time.perf_counter()
        first = fit_problem(problems[0])
        out["single_first_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        one_at_a_time = [first] + [fit_problem(p) for p in problems[1:single]]
        warm = time.perf_counter() - t0
        out["single_warm_units_per_s"] = (single - 1) / warm if single > 1 else None
        out["single_units"] = single
        out["lanes"] = {}
        step(out)
        batched = []
        for lanes in lanes_list:
            lanes = min(lanes, len(problems))
            groups: dict = {}          # problems of one structure share a compiled batch
            for p in problems:
                groups.setdefault(p.structure_key(), []).append(p)
            chunks = [g[i:i + lanes] for g in groups.values() for i in range(0, len(g), lanes)]
            starts = [jax.numpy.stack([p.pack(*initial_guess(p)) for p in c]) for c in chunks]
            entry: dict = {"chunks": len(chunks), "structures": len(groups)}
            for attempt in ("cold", "warm"):
                t0 = time.perf_counter()
                for k, (chunk, theta0) in enumerate(zip(chunks, starts)):
                    solve = compiled_batch(chunk, _solve, lanes=lanes, solver="lm",
                                           rtol=1e-5, atol=1e-5, max_steps=400)
                    jax.block_until_ready(solve(theta0))
                    if attempt == "cold" and k == 0:
                        entry["solve_first_chunk_s"] = time.perf_counter() - t0
                        break
                if attempt == "warm":
                    entry["solve_warm_units_per_s"] = len(problems) / (time.perf_counter() - t0)
            t0 = time.perf_counter()
            fit_problems(chunks[0], lanes=lanes)          # the summary's compilation
            entry["summary_first_chunk_s"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            batched = fit_problems(problems, lanes=lanes)
            entry["fit_problems_s"] = time.perf_counter() - t0
            entry["fit_problems_units_per_s"] = len(problems) / entry["fit_problems_s"]
            entry["converged"] = sum(bool(r.converged) for r in batched)
            out["lanes"][str(lanes)] = entry
            step(out)
        out["_batched"] = batched
        out["_single"] = one_at_a_time
    return out


def _end_to_end(data: Path, tmp: Path, *, env: dict, flags: list[str]) -> dict:
    out_dir = tmp / ("e2e-" + "-".join(flags).replace("--", ""))
    shutil.rmtree(out_dir, ignore_errors=True)
    command = [sys.executable, "-m", "fitstiff", "fleet", str(data), "--out", str(out_dir),
               *flags]
    t0 = time.perf_counter()
    proc = subprocess.run(command, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    result = {"flags": flags, "wall_s": wall, "rc": proc.returncode}
    if proc.returncode:
        result["stderr"] = proc.stderr[-1500:]
        return result
    import pandas as pd

    table = pd.read_parquet(out_dir / "fleet.parquet")
    result.update(units=len(table), units_per_s=len(table) / wall,
                  converged=int(table["converged"].sum()),
                  breakaway=table["breakaway_N"].to_numpy(float).tolist())
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cylinders", type=int, default=256)
    parser.add_argument("--samples", type=int, default=4000)
    parser.add_argument("--lanes", type=int, nargs="+", default=[256, 1024],
                        help="units per batched call on the GPU")
    parser.add_argument("--cpu-lanes", type=int, nargs="*", default=[16],
                        help="units per batched call on the CPU (over the fleet's units)")
    parser.add_argument("--tile", type=int, default=4,
                        help="the GPU's batched fits run over the units repeated this often")
    parser.add_argument("--single", type=int, default=16,
                        help="units fitted one at a time per backend")
    parser.add_argument("--end-to-end", action="store_true")
    parser.add_argument("--gpu-layouts", nargs="+", default=["1x256", "4x64"],
                        help="WORKERSxLANES of the end-to-end GPU runs")
    parser.add_argument("--data", type=Path, default=Path(tempfile.gettempdir())
                        / "fitstiff-fleet-gpu")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)

    import jax

    jax.config.update("jax_enable_x64", True)
    from fitstiff._testing.fleet import make_fleet
    from fitstiff.fleet import discover
    from fitstiff.inference.problem import Problem
    from fitstiff.io.loading import load_logs

    backends = ["cpu"] + (["gpu"] if any(d.platform == "gpu" for d in jax.devices()) else [])
    result: dict = {"argv": sys.argv[1:], "python": platform.python_version(),
                    "jax": jax.__version__, "cpu_count": os.cpu_count(),
                    "backends": backends, "devices": [str(d) for d in jax.devices()],
                    "default_backend": jax.default_backend(),
                    "jax_platforms": os.environ.get("JAX_PLATFORMS")}
    t0 = time.perf_counter()
    shutil.rmtree(args.data, ignore_errors=True)
    make_fleet(args.data, cylinders=args.cylinders, samples=args.samples, with_runs=0,
               drifting=0, outliers=0.03, processes=os.cpu_count() or 1, seed=0)
    result["generate_s"] = time.perf_counter() - t0
    units = discover(args.data)
    t0 = time.perf_counter()
    with jax.default_device(jax.devices("cpu")[0]):
        problems = [Problem(load_logs(u.files), "chamber+dahl") for u in units]
    result["build_s_per_unit"] = (time.perf_counter() - t0) / len(units)
    result["units"] = len(units)
    _save(args.json, result)

    reference = None
    for name in backends:
        gpu = name != "cpu"
        measured = _backend(name, problems * (args.tile if gpu else 1),
                            lanes_list=args.lanes if gpu else args.cpu_lanes,
                            single=min(args.single, len(problems)),
                            step=lambda out, name=name: _save(args.json, dict(
                                result, **{name: {k: v for k, v in out.items()
                                                  if not k.startswith("_")}})))
        single, batched = measured.pop("_single"), measured.pop("_batched")
        if reference is None:
            reference = _estimates(single)
        if batched:
            measured["batched_vs_cpu_single_max_rel"] = float(np.max(np.abs(
                _estimates(batched[:len(reference)]) / reference - 1)))
        measured["single_vs_cpu_single_max_rel"] = float(np.max(np.abs(
            _estimates(single) / reference - 1)))
        result[name] = measured
        _save(args.json, result)

    if args.end_to_end:
        runs = result["end_to_end"] = {}
        # the commands' output folders go with the run (only the figures are kept)
        with tempfile.TemporaryDirectory(prefix="fleet-gpu-e2e-") as tmp:
            tmp = Path(tmp)
            base = dict(os.environ, XLA_PYTHON_CLIENT_PREALLOCATE="false")
            runs["cpu"] = _end_to_end(args.data, tmp, env=dict(base, JAX_PLATFORMS="cpu"),
                                      flags=[])
            _save(args.json, result)
            if "gpu" in backends:
                for layout in args.gpu_layouts:
                    workers, lanes = (int(x) for x in layout.split("x"))
                    runs[f"gpu {layout}"] = _end_to_end(
                        args.data, tmp, env=base, flags=["--workers", str(workers), "--lanes",
                                                         str(lanes), "--chunk", str(lanes)])
                    _save(args.json, result)
        cpu = np.array(runs["cpu"].get("breakaway", []))
        for key, run in runs.items():
            if "breakaway" in run and cpu.size:
                run["breakaway_max_rel_vs_cpu"] = float(np.max(np.abs(
                    np.array(run.pop("breakaway")) / cpu - 1)))
            run.pop("breakaway", None)
        _save(args.json, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
