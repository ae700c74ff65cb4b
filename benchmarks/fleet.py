"""Fleet benchmark (issue 34): throughput against loops of ``fitstiff.fit`` / ``fitstiff fit``
measured in the same run, worker scaling, memory per worker, and the population's flags
against the planted truth.

The fleet (:func:`fitstiff._testing.fleet.make_fleet`, the independent rig simulator):
``--cylinders`` cylinders x 2 logs x ``--samples`` samples; population spread slope sd 8 %,
breakaway sd 6 %; 3 % planted outliers (breakaway +30 % or slope -25 %, alternately); the
first ``--with-runs`` cylinders logged in 5 runs, ``--drifting`` of them with a 10 % change of
the friction level over their runs (2.5 % per run), every cylinder with runs scattering by
1 % from run to run. It is written once to ``--data`` (reused while its settings match).

Measured, in one run on this machine:

1. ``fitstiff fleet DATA --out ...`` as a subprocess, cold (empty compilation cache), default
   workers (one per core): wall time including the population model; the peak RSS of each
   worker process (polled every 0.2 s).
2. The same command on the first ``--subset`` cylinders with ``--workers 1`` and
   ``--workers 2`` (cold each): the scaling.
3. An in-process loop of ``load_logs`` + ``fitstiff.fit`` over ``--loop`` cylinders (one
   process, its compilation once): cylinders per second.
4. A loop of ``fitstiff fit`` processes over ``--processes`` cylinders (each with the
   compilation cache of the first), extrapolated to the fleet.
5. Flags against the truth: outlier recall (all, per kind) and false flags among the other
   cylinders, at ``q``; the recall at a 1 % false-flag rate (the predictive p-value's
   threshold set on the inliers' own p-values); drift found among the drifting cylinders and
   false drift flags among the other cylinders with runs.
6. Agreement of ``--check`` rows with a single ``fitstiff.fit`` of their logs.

    python benchmarks/fleet.py [--cylinders 1000] [--data /tmp/fitstiff-fleet]
        [--json benchmarks/results/fleet.json]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pandas as pd
import psutil

from fitstiff._testing.fleet import make_fleet


def _fleet(data: Path, args) -> dict:
    settings = {"seed": args.seed, "slope_sd": 0.08, "breakaway_sd": 0.06, "outliers": 0.03,
                "with_runs": args.with_runs, "runs": 5, "drifting": args.drifting,
                "drift": 0.10, "run_scatter": 0.01, "samples": args.samples, "rate_hz": 500.0}
    truth_file = data.with_name(data.name + ".truth.json")
    if truth_file.exists():
        truth = json.loads(truth_file.read_text())
        if truth["settings"] == settings and len(truth["cylinders"]) == args.cylinders:
            return truth
    shutil.rmtree(data, ignore_errors=True)
    t0 = time.perf_counter()
    truth = make_fleet(data, cylinders=args.cylinders, processes=os.cpu_count() or 1,
                       **{k: v for k, v in settings.items() if k != "seed"}, seed=args.seed)
    print(f"generated {args.cylinders} cylinders in {time.perf_counter() - t0:.0f} s",
          file=sys.stderr)
    return truth


class _PeakWorkers:
    """Peak RSS (MB) of each descendant process of ``pid`` that lives long enough to see."""

    def __init__(self, pid: int):
        self.pid, self.peak, self._stop = pid, {}, threading.Event()
        self._thread = threading.Thread(target=self._poll, daemon=True)
        self._thread.start()

    def _poll(self):
        try:
            root = psutil.Process(self.pid)
        except psutil.Error:
            return
        while not self._stop.is_set():
            try:
                procs = [root] + root.children(recursive=True)
            except psutil.Error:
                break
            for p in procs:
                try:
                    rss = p.memory_info().rss / 2**20
                except psutil.Error:
                    continue
                self.peak[p.pid] = max(self.peak.get(p.pid, 0.0), rss)
            time.sleep(0.2)

    def stop(self) -> dict:
        self._stop.set()
        self._thread.join()
        return self.peak


def _run_fleet(source: Path, out: Path, *, workers: int | None, cache: Path) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    shutil.rmtree(cache, ignore_errors=True)
    env = dict(os.environ, FITSTIFF_CACHE_DIR=str(cache))
    command = [sys.executable, "-m", "fitstiff", "fleet", str(source), "--out", str(out)]
    if workers:
        command += ["--workers", str(workers)]
    t0 = time.perf_counter()
    proc = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    watch = _PeakWorkers(proc.pid)
    stdout, stderr = proc.communicate()
    wall = time.perf_counter() - t0
    peak = watch.stop()
    if proc.returncode:
        raise SystemExit(f"fitstiff fleet failed ({proc.returncode}): {stderr[-2000:]}")
    units = len(pd.read_parquet(out / "fleet.parquet"))
    main_rss = peak.pop(proc.pid, math.nan)
    workers_rss = sorted(peak.values(), reverse=True)
    return {"wall_s": wall, "units": units, "units_per_s": units / wall,
            "main_peak_mb": main_rss, "worker_peak_mb": workers_rss[:max(workers or 0, 4)],
            "summary": stdout.strip().splitlines()[:8]}


def _subset(data: Path, names: list[str], where: Path) -> Path:
    shutil.rmtree(where, ignore_errors=True)
    where.mkdir(parents=True)
    for name in names:
        (where / name).symlink_to((data / name).resolve())
    return where


_LOOP = """
import json, sys, time
from pathlib import Path
from fitstiff import fit
from fitstiff.io.loading import load_logs
data, names = Path(sys.argv[1]), sys.argv[2:]
t0 = time.perf_counter()
first = None
for k, name in enumerate(names):
    fit(load_logs(sorted((data / name).rglob("*.csv"))[:2]), "chamber+dahl")
    first = first or time.perf_counter() - t0
print(json.dumps({"cylinders": len(names), "wall_s": time.perf_counter() - t0,
                  "first_s": first}))
"""


def _loop_fit(data: Path, names: list[str], *, tree: Path | None = None) -> dict:
    """An in-process loop of ``load_logs`` + ``fitstiff.fit`` over ``names``, in a fresh
    process (of the fitstiff at ``tree``: an earlier version, for the before figure)."""
    env = dict(os.environ)
    if tree is not None:
        env["PYTHONPATH"] = str(tree)
    out = subprocess.run([sys.executable, "-c", _LOOP, str(data), *names], env=env,
                         check=True, capture_output=True, text=True)
    result = json.loads(out.stdout.strip().splitlines()[-1])
    result["units_per_s"] = result["cylinders"] / result["wall_s"]
    if tree is not None:
        result["tree"] = str(tree)
    return result


def _loop_cli(data: Path, names: list[str], tmp: Path) -> dict:
    cache = tmp / "cli-cache"
    env = dict(os.environ, FITSTIFF_CACHE_DIR=str(cache))
    times = []
    for name in names:
        files = [str(f) for f in sorted((data / name).rglob("*.csv"))[:2]]
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "fitstiff", "fit", *files, "--out",
                        str(tmp / "cli" / name)], check=True, env=env,
                       stdout=subprocess.DEVNULL)
        times.append(time.perf_counter() - t0)
    return {"cylinders": len(names), "seconds": times, "units_per_s": len(names) / sum(times)}


def _flags(table: pd.DataFrame, truth: dict, q: float) -> dict:
    from scipy import stats

    cylinders = truth["cylinders"]
    per = table.groupby("cylinder").first()
    planted = {c for c, t in cylinders.items() if t["outlier"]}
    flagged = set(per.index[per["outlier"].astype(bool)])
    inliers = set(cylinders) - planted
    out = {"q": q, "planted": len(planted), "flagged": len(flagged),
           "recall": len(flagged & planted) / max(len(planted), 1),
           "false_flags": len(flagged & inliers), "false_flag_rate": len(flagged & inliers)
           / max(len(inliers), 1)}
    for kind in ("breakaway", "slope"):
        group = {c for c in planted if cylinders[c]["outlier"] == kind}
        out[f"recall_{kind}"] = len(flagged & group) / max(len(group), 1)
    # the recall at a 1 % false-flag rate: each cylinder's smallest predictive p over the
    # quantities, from the population's estimates; the threshold from the inliers' own p
    pop = table.attrs.get("population") or {}
    quantities = pop.get("quantities", {})
    p_min = pd.Series(1.0, index=per.index)
    for name, est in quantities.items():
        tau = est["spread_sd_log"] or 0.0
        y = np.log(per[name].where(per[name] > 0))
        s = per[f"{name}_stderr"] / per[name]
        z = (y - math.log(est["mean"])) / np.sqrt(tau**2 + s**2)
        p = pd.Series(2 * stats.norm.sf(np.abs(z.to_numpy(float))), index=per.index)
        p_min = np.minimum(p_min, p.fillna(1.0))
    threshold = float(np.quantile(p_min[sorted(inliers)], 0.01))
    out["recall_at_1pct_false_flags"] = float(np.mean(p_min[sorted(planted)] <= threshold))
    for kind in ("breakaway", "slope"):
        group = sorted(c for c in planted if cylinders[c]["outlier"] == kind)
        out[f"recall_at_1pct_false_flags_{kind}"] = float(np.mean(p_min[group] <= threshold))
    drifting = {c for c, t in cylinders.items() if t["drift_per_run"]}
    steady = {c for c, t in cylinders.items() if t["runs"] > 1} - drifting
    drift_flagged = set(per.index[per["drift"].astype(bool)])
    out["drift"] = {"drifting": len(drifting), "found": len(drift_flagged & drifting),
                    "recall": len(drift_flagged & drifting) / max(len(drifting), 1),
                    "false_flags": len(drift_flagged & steady),
                    "false_flag_rate": len(drift_flagged & steady) / max(len(steady), 1),
                    "per_run_found": {c: float(per.loc[c, "drift_per_run"])
                                      for c in sorted(drift_flagged)}}
    return out


def _agreement(data: Path, table: pd.DataFrame, names: list[str]) -> dict:
    from fitstiff import fit
    from fitstiff.io.loading import load_logs

    worst = 0.0
    columns = ["presliding_slope_N_per_mm", "breakaway_N", "presliding_range_mm",
               "chamber_stiffness_N_per_mm"]
    for name in names:
        row = table[table["cylinder"] == name].iloc[0]
        result = fit(load_logs(row["files"].split(";")), "chamber+dahl").to_dict()
        for c in columns:
            ref = result["derived"][c]["value"]
            worst = max(worst, abs(row[c] - ref) / abs(ref))
    return {"cylinders": len(names), "largest_relative_difference": worst}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cylinders", type=int, default=1000)
    parser.add_argument("--samples", type=int, default=4000)
    parser.add_argument("--with-runs", type=int, default=100)
    parser.add_argument("--drifting", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--subset", type=int, default=200,
                        help="cylinders of the 1-against-2-worker comparison")
    parser.add_argument("--loop", type=int, default=60, help="cylinders of the fit loop")
    parser.add_argument("--processes", type=int, default=20,
                        help="cylinders of the fitstiff fit process loop")
    parser.add_argument("--before", type=Path, metavar="TREE",
                        help="also time the fit loop with the fitstiff of this source tree "
                             "(an earlier version: the before figure)")
    parser.add_argument("--before-cylinders", type=int, default=5)
    parser.add_argument("--check", type=int, default=10,
                        help="rows checked against a single fit")
    parser.add_argument("--q", type=float, default=0.01)
    parser.add_argument("--data", type=Path, default=Path(tempfile.gettempdir())
                        / "fitstiff-fleet")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    truth = _fleet(args.data, args)
    names = sorted(truth["cylinders"])
    single = [n for n in names if truth["cylinders"][n]["runs"] == 1]
    with tempfile.TemporaryDirectory(prefix="fitstiff-fleet-bench-") as tmp:
        tmp = Path(tmp)
        report: dict = {"settings": truth["settings"], "cylinders": len(names),
                        "cores": len(os.sched_getaffinity(0))}
        report["fleet"] = whole = _run_fleet(args.data, tmp / "out", workers=None,
                                             cache=tmp / "cache")
        print(f"whole fleet: {whole['units']} units in {whole['wall_s']:.1f} s", file=sys.stderr)
        table = pd.read_parquet(tmp / "out" / "fleet.parquet")
        table.attrs["population"] = json.loads((tmp / "out" / "population.json").read_text())
        report["flags"] = _flags(table, truth, args.q)
        report["population"] = table.attrs["population"]["quantities"]
        subset = _subset(args.data, names[:args.subset], tmp / "subset")
        report["scaling"] = {w: _run_fleet(subset, tmp / f"out{w}", workers=w,
                                           cache=tmp / f"cache{w}") for w in (1, 2)}
        report["loop_fit"] = _loop_fit(args.data, single[:args.loop])
        if args.before:
            report["loop_fit_before"] = _loop_fit(args.data, single[:args.before_cylinders],
                                                  tree=args.before)
        report["loop_cli"] = _loop_cli(args.data, single[:args.processes], tmp)
        report["agreement"] = _agreement(args.data, table, single[:args.check])
    fleet_rate = whole["units_per_s"]
    report["ratios"] = {
        "against_fit_loop": fleet_rate / report["loop_fit"]["units_per_s"],
        "against_cli_loop": fleet_rate / report["loop_cli"]["units_per_s"],
        **({"against_fit_loop_before": fleet_rate / report["loop_fit_before"]["units_per_s"]}
           if "loop_fit_before" in report else {}),
        "two_workers_against_one": (report["scaling"][2]["units_per_s"]
                                    / report["scaling"][1]["units_per_s"])}
    report["targets"] = {
        "whole_fleet_s<=120": whole["wall_s"] <= 120,
        "against_fit_loop>=5": report["ratios"]["against_fit_loop"] >= 5,
        "against_cli_loop>=50": report["ratios"]["against_cli_loop"] >= 50,
        "two_workers>=1.6": report["ratios"]["two_workers_against_one"] >= 1.6,
        "worker_peak<=1GB": max(whole["worker_peak_mb"] or [math.inf]) <= 1024,
        "outlier_recall>=0.95": report["flags"]["recall"] >= 0.95,
        "outlier_false_flags<=1%": report["flags"]["false_flag_rate"] <= 0.01,
        "drift_recall>=0.9": report["flags"]["drift"]["recall"] >= 0.9,
        "drift_false_flags<=2%": report["flags"]["drift"]["false_flag_rate"] <= 0.02,
        "agreement<=1e-6": report["agreement"]["largest_relative_difference"] <= 1e-6}
    text = json.dumps(report, indent=1, default=float)
    print(text)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
