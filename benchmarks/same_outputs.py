"""Do two trees of fitstiff write the same outputs? The check behind a "no behaviour change"
refactor (issue 35): a fixed set of runs - simulate, inspect, fit (synthetic and the real
O-ring log), posterior, diagnose, report of each, stiffness - is run with each tree's code
(``PYTHONPATH=TREE python -m fitstiff ...``, the persistent compilation cache off) and every
file written is compared.

Compared as written, less what names the tree or the clock: the tree's and the output
directory's paths,
``*_utc`` stamps and wall times in JSON (``timing_s``, ``seconds``, ...), a report's "made"
time, the hashes in the manifests (each file is compared itself), matplotlib's random ids in SVG files, and the
creation attributes of ``posterior.nc`` (its groups are compared as data).

    python benchmarks/same_outputs.py --before /path/to/old/clone --after .
    python benchmarks/same_outputs.py --before OLD --after . --json result.json

Exit status 0 when every file is the same, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

FIG4 = "data/synthetic/fig4"
#: (name, arguments); ``{out}`` is the run's output folder, relative paths are the tree's
RUNS = (
    ("sim", ["simulate", "--model", "chamber+dahl", "--set", "sigma0=40", "--set", "Fc=18",
             "--seed", "3", "--program", "nested", "--out", "{out}/sim"]),
    ("inspect", ["inspect", f"{FIG4}/p6bar_x350mm.csv", "--out", "{out}/inspect"]),
    ("fit", ["fit", f"{FIG4}/p0bar_x350mm.csv", f"{FIG4}/p2bar_x350mm.csv",
             f"{FIG4}/p4bar_x350mm.csv", f"{FIG4}/p6bar_x350mm.csv", "--out", "{out}/fit"]),
    ("fit_real", ["fit", "data/real/oring/O-ring_3bar.csv", "--format", "zillen_oring",
                  "--out", "{out}/fit_real"]),
    ("post", ["posterior", f"{FIG4}/p6bar_x350mm.csv", "--walkers", "24", "--steps", "300",
              "--out", "{out}/post"]),
    ("diag", ["diagnose", "data/synthetic/effects/viscous/triangle_1mm_s.csv",
              "data/synthetic/effects/viscous/triangle_20mm_s.csv",
              "data/synthetic/effects/viscous/triangle_5mm_s.csv",
              "--candidates", "viscous,stribeck,asymmetry", "--out", "{out}/diag"]),
    ("report_fit", ["report", "{out}/fit"]),
    ("report_post", ["report", "{out}/post"]),
    ("report_diag", ["report", "{out}/diag"]),
    ("stiffness", ["stiffness", "--bore-mm", "32", "--stroke-mm", "700", "--position-mm", "350",
                   "--supply-bar", "6", "--json"]),
)
_CLOCK_KEYS = re.compile(r".*_utc|elapsed_s|wall_s|seconds|timing_s|duration_s|compile_s|sha256")
_TIME = re.compile(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(\.\d+)?(\+00:00|Z)?")
_SVG_IDS = re.compile(r"\b([pm]|image)[0-9a-f]{10}\b")
_HASH = re.compile(r"[0-9a-f]{64}")


def run_all(tree: Path, out: Path) -> None:
    """Every run of :data:`RUNS` with ``tree``'s code, stdout kept as ``<name>.stdout``."""
    env = {**os.environ, "PYTHONPATH": str(tree), "FITSTIFF_CACHE_DIR": ""}
    out.mkdir(parents=True, exist_ok=True)
    for name, args in RUNS:
        argv = [a.replace("{out}", str(out)) for a in args]
        done = subprocess.run([sys.executable, "-m", "fitstiff", *argv], cwd=tree, env=env,
                              capture_output=True, text=True)
        if done.returncode:
            raise SystemExit(f"{tree}: fitstiff {' '.join(argv)} exited {done.returncode}:\n"
                             f"{done.stderr[-2000:]}")
        (out / f"{name}.stdout").write_text(done.stdout)


def _strip(value, *, manifest: bool):
    if isinstance(value, dict):
        if manifest and value and all(isinstance(v, str) and _HASH.fullmatch(v)
                                      for v in value.values()):
            return sorted(value)        # file -> hash: the files are compared themselves
        return {k: _strip(v, manifest=manifest) for k, v in value.items()
                if not _CLOCK_KEYS.fullmatch(k)}
    if isinstance(value, list):
        return [_strip(v, manifest=manifest) for v in value]
    return value


def normalised(path: Path, root: Path, tree: Path):
    """What of ``path`` (written under ``root`` by ``tree``'s code) must be the same in both
    trees."""
    raw = path.read_bytes()
    try:
        text = raw.decode()
    except UnicodeDecodeError:
        return raw
    text = text.replace(str(root), "<OUT>").replace(str(tree), "<TREE>")
    if path.suffix == ".svg":
        return _SVG_IDS.sub(r"\1<ID>", text)
    if path.suffix == ".html":
        return _TIME.sub("<TIME>", text)
    if path.suffix == ".json":
        try:
            return json.dumps(_strip(json.loads(text), manifest=path.name.endswith(
                "manifest.json")), sort_keys=True)
        except ValueError:
            return text
    return text


def _same_netcdf(a: Path, b: Path) -> bool:
    import xarray as xr

    for group in ("posterior", "sample_stats", "log_likelihood", "posterior_predictive",
                  "observed_data", "constant_data"):
        try:
            x, y = xr.open_dataset(a, group=group), xr.open_dataset(b, group=group)
        except OSError:
            continue
        if not x.drop_attrs().identical(y.drop_attrs()):
            return False
    return True


def compare(a: Path, b: Path, *, trees: tuple[Path, Path]) -> dict[str, list[str]]:
    """``same``, ``different``, ``only_before``, ``only_after``: relative paths (``a`` written
    by ``trees[0]``, ``b`` by ``trees[1]``)."""
    fa = {p.relative_to(a) for p in a.rglob("*") if p.is_file()}
    fb = {p.relative_to(b) for p in b.rglob("*") if p.is_file()}
    out = {"same": [], "different": [], "only_before": sorted(map(str, fa - fb)),
           "only_after": sorted(map(str, fb - fa))}
    for rel in sorted(fa & fb):
        if rel.suffix == ".nc":
            same = _same_netcdf(a / rel, b / rel)
        else:
            same = (normalised(a / rel, a, trees[0])
                    == normalised(b / rel, b, trees[1]))
        out["same" if same else "different"].append(str(rel))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", type=Path, required=True, help="tree of the old code")
    parser.add_argument("--after", type=Path, required=True, help="tree of the new code")
    parser.add_argument("--json", type=Path, help="write the comparison here")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        for label, tree in (("before", args.before), ("after", args.after)):
            print(f"running {label} ({tree.resolve()}) ...", flush=True)
            run_all(tree.resolve(), Path(tmp) / label)
        result = compare(Path(tmp) / "before", Path(tmp) / "after",
                         trees=(args.before.resolve(), args.after.resolve()))
    print(f"{len(result['same'])} files the same, {len(result['different'])} different, "
          f"{len(result['only_before'])} only before, {len(result['only_after'])} only after")
    for key in ("different", "only_before", "only_after"):
        for rel in result[key]:
            print(f"  {key}: {rel}")
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    return 0 if not (result["different"] or result["only_before"] or result["only_after"]) else 1


if __name__ == "__main__":
    raise SystemExit(main())
