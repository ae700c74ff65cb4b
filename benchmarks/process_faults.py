"""Process-level faults of the command line (issue 36), before -> after.

Runs every case of the issue on ``python -m fitstiff`` in a subprocess, once per source tree
given (``--tree NAME=PATH``, the tree's root on PYTHONPATH), and writes the exit code, the
number of stderr lines and the last line of each run, with what the run left in its output
directory, to ``benchmarks/results/process_faults.json`` and a markdown table on stdout.
Full-disk cases need a tmpfs (root, or a machine that lets this user mount one); they are
left out otherwise.

    python benchmarks/process_faults.py --tree before=/path/to/old/clone --tree after=.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
LOG = REPO / "data" / "synthetic" / "fig4" / "p6bar_x350mm.csv"
JSON_PATH = REPO / "benchmarks" / "results" / "process_faults.json"


def _copy(work: Path, name: str = "log", edit: Callable[[list[str]], list[str]] | None = None,
          sidecar: dict | None = None) -> Path:
    lines = LOG.read_text().splitlines()
    path = work / f"{name}.csv"
    path.write_text("\n".join(edit(lines) if edit else lines) + "\n")
    side = json.loads(LOG.with_suffix(".json").read_text()) | (sidecar or {})
    (work / f"{name}.json").write_text(json.dumps(side))
    return path


def _utf16(work: Path) -> list:
    path = work / "wide.csv"
    path.write_bytes(LOG.read_text().encode("utf-16-le"))
    return ["inspect", path]


def _spike(lines):
    cells = lines[815].split(",")
    cells[2] = "1e6"
    return lines[:815] + [",".join(cells)] + lines[816:]


@contextlib.contextmanager
def _disk(work: Path, size: str, leave_kib: int):
    mount = work / "disk"
    mount.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mount)],
                      capture_output=True).returncode != 0:
        yield None
        return
    try:
        free = shutil.disk_usage(mount).free // 1024
        with open(mount / "filler", "wb") as fh:
            fh.write(b"\0" * max(free - leave_kib, 0) * 1024)
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


@contextlib.contextmanager
def _terminal_sigint():
    """A shell's background job starts with SIGINT ignored, which fitstiff keeps ignored (as
    ``nohup`` asks); only an ignored disposition is inherited, so the parent handles SIGINT
    while it starts the child, which then has a terminal's."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _run(env, args, *, cwd, signal_after=None, close_stdout=False):
    with _terminal_sigint():
        proc = subprocess.Popen([sys.executable, "-m", "fitstiff", *map(str, args)], env=env,
                                cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True)
    if close_stdout:
        proc.stdout.close()
        err = proc.stderr.read()
        proc.wait(timeout=600)
        return proc.returncode, err
    if signal_after is not None:
        time.sleep(signal_after[1])
        proc.send_signal(signal_after[0])
    _, err = proc.communicate(timeout=600)
    return proc.returncode, err


def cases():
    """(name, function(work, env) -> (exit code, stderr, out dir)) for every case."""
    def plain(args_of, **kw):
        def go(work, env):
            args = args_of(work)
            code, err = _run(env, args, cwd=work, **kw)
            return code, err, work / "out"
        return go

    def disk(command, leave_kib, extra=()):
        def go(work, env):
            with _disk(work, "2m", leave_kib) as mount:
                if mount is None:
                    return None
                code, err = _run(env, [command, LOG, *extra, "--out", mount / "out"],
                                 cwd=work)
                left = sorted(p.name for p in (mount / "out").iterdir()) \
                    if (mount / "out").exists() else []
                return code, err, left
        return go

    def report_then_fit(work, env):
        out = work / "out"
        for args in (["fit", LOG, "--out", out], ["report", out]):
            _run(env, args, cwd=work)
        code, err = _run(env, ["fit", LOG, "--out", out], cwd=work)
        return code, err, None

    def loop(work):
        (work / "loop.csv").symlink_to(work / "loop.csv")
        return ["fit", work / "loop.csv", "--out", work / "out"]

    posterior = ["--model", "chamber+dahl", "--walkers", "16", "--steps", "3000",
                 "--check-every", "500", "--draws", "5"]
    return [
        ("fit, disk full (0 KB free)", disk("fit", 0)),
        ("fit, disk full (16 KB free)", disk("fit", 16)),
        ("inspect, disk full (0 KB free)", disk("inspect", 0)),
        ("posterior, disk full (64 KB free)", disk("posterior", 64, posterior)),
        ("posterior, disk fills while sampling (400 KB free)", disk("posterior", 400,
                                                                   posterior)),
        ("fit, input a symlink loop, with --out", plain(loop)),
        ("inspect --json, stdout closed", plain(lambda w: ["inspect", LOG, "--json"],
                                                close_stdout=True)),
        ("fit, SIGINT after 0.8 s", plain(lambda w: ["fit", LOG, "--out", w / "out"],
                                          signal_after=(signal.SIGINT, 0.8))),
        ("fit, SIGINT after 3 s", plain(lambda w: ["fit", LOG, "--out", w / "out"],
                                        signal_after=(signal.SIGINT, 3.0))),
        ("fit, SIGTERM after 3 s", plain(lambda w: ["fit", LOG, "--out", w / "out"],
                                         signal_after=(signal.SIGTERM, 3.0))),
        ("fit --out ''", plain(lambda w: ["fit", LOG, "--out", ""])),
        ("inspect --out ''", plain(lambda w: ["inspect", LOG, "--out", ""])),
        ("fit --model ''", plain(lambda w: ["fit", LOG, "--model", "", "--out", w / "out"])),
        ("fit log.csv log.csv", plain(lambda w: ["fit", LOG, LOG, "--out", w / "out"])),
        ("inspect, sidecar bore_mm null", plain(lambda w: ["inspect", _copy(
            w, sidecar={"bore_mm": None})])),
        ("inspect, UTF-16 LE without BOM", plain(_utf16)),
        ("fit, one 1e6 N force sample", plain(lambda w: [
            "fit", _copy(w, edit=_spike), "--out", w / "out"])),
        ("fit, force_N relabelled force_kN", plain(lambda w: [
            "fit", _copy(w, edit=lambda ls: [ls[0].replace("force_N", "force_kN"), *ls[1:]]),
            "--out", w / "out"])),
        ("report DIR, then fit --out DIR", report_then_fit),
        ("inspect --columns ... excel.csv", plain(lambda w: [
            "inspect", "--columns", "time=1:s", "force=2:N", "excel.csv"])),
        ("fit --fix sigma=40", plain(lambda w: ["fit", LOG, "--fix", "sigma=40", "--out",
                                                w / "out"])),
    ]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tree", action="append", required=True, metavar="NAME=PATH")
    parser.add_argument("--json", type=Path, default=JSON_PATH)
    parser.add_argument("--only", metavar="TEXT",
                        help="run only the cases whose name holds TEXT; the others are kept "
                             "from the JSON")
    args = parser.parse_args(argv)
    trees = dict(t.split("=", 1) for t in args.tree)
    results: dict[str, dict[str, object]] = {}
    if args.only and args.json.exists():
        results = json.loads(args.json.read_text())["cases"]
    for name, go in cases():
        if args.only and args.only not in name:
            continue
        results[name] = {}
        for tree, path in trees.items():
            env = dict(os.environ, PYTHONPATH=str(Path(path).resolve()), FITSTIFF_CACHE_DIR="",
                       HDF5_USE_FILE_LOCKING="FALSE")
            with tempfile.TemporaryDirectory() as tmp:
                got = go(Path(tmp), env)
                if got is None:
                    results[name][tree] = None
                    continue
                code, err, out = got
                left = (out if isinstance(out, list) else
                        sorted(p.name for p in out.iterdir()) if out and out.exists() else [])
            lines = err.strip().splitlines()
            results[name][tree] = {"exit": code, "stderr_lines": len(lines),
                                   "last_line": lines[-1] if lines else "", "left": left}
        print(name, json.dumps(results[name])[:300], flush=True)
    args.json.write_text(json.dumps({"trees": trees, "cases": results}, indent=2) + "\n")
    print("\n| case | " + " | ".join(trees) + " |\n|---|" + "---|" * len(trees))
    order = [name for name, _ in cases()]
    for name, per_tree in sorted(results.items(), key=lambda kv: order.index(kv[0])):
        cells = []
        for tree in trees:
            r = per_tree[tree]
            cells.append("n/a (no tmpfs)" if r is None else
                         f"exit {r['exit']}, {r['stderr_lines']} line(s): "
                         f"`{r['last_line'][:90]}`"
                         + (f"; left {', '.join(r['left'])}" if r["left"] else ""))
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
