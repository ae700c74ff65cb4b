"""Issue 36: faults a process meets, tested the way they happen, on ``python -m fitstiff`` in a
subprocess: a closed stdout, signals at any moment, a full disk, and arguments that used to
pass or end in a traceback. Every case: the documented exit code, one line on stderr, no
traceback, and no result without its manifest (nor a stale lock) left behind."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import REPO

LOG = REPO / "data" / "synthetic" / "fig4" / "p6bar_x350mm.csv"
ENV = dict(os.environ, PYTHONPATH=str(REPO), FITSTIFF_CACHE_DIR="",
           HDF5_USE_FILE_LOCKING="FALSE")


def fitstiff(*args, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fitstiff", *map(str, args)], env=ENV,
                          capture_output=True, text=True, timeout=300, **kw)


@contextlib.contextmanager
def terminal_sigint():
    """A child started in the block gets SIGINT as a terminal's foreground job has it: a
    shell's background job (and its children) start with SIGINT ignored, which fitstiff keeps
    ignored, as ``nohup`` asks. Only an ignored disposition is inherited, so the parent
    handles it for the moment of the start (no ``preexec_fn``: a fork of a process with JAX's
    threads that runs Python code may deadlock)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def one_line(proc) -> str:
    lines = proc.stderr.splitlines()
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    return lines[0]


def left_behind(directory: Path) -> list[str]:
    """What a failed run left in ``directory`` (nothing, or a directory that does not exist)."""
    return sorted(p.name for p in directory.iterdir()) if directory.exists() else []


def test_a_closed_stdout_ends_quietly():
    """``fitstiff inspect log.csv --json | head -1``: the reader has gone before the JSON is
    written; the command ends as usual, without a BrokenPipeError traceback."""
    proc = subprocess.Popen([sys.executable, "-m", "fitstiff", "inspect", str(LOG), "--json"],
                            env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()                         # the reader ends before anything is written
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 0, err
    assert err == ""


@pytest.mark.parametrize("signum, after_s", [
    (signal.SIGINT, 0.3),      # while Python imports the command (JAX's extensions included)
    (signal.SIGINT, 2.5),      # during the fit
    (signal.SIGTERM, 0.3),
    (signal.SIGTERM, 2.5)])
def test_a_signal_ends_a_command_with_one_line_and_the_shells_code(tmp_path, signum, after_s):
    """Ctrl-C and ``kill`` at any moment: exit 130 / 143, one line that says what was kept, no
    traceback, the output directory as it was (a SIGINT while JAX's extension modules load used
    to crash the interpreter; SIGTERM exited 130 or, outside posterior, left a stale lock)."""
    out = tmp_path / "out"
    with terminal_sigint():
        proc = subprocess.Popen([sys.executable, "-m", "fitstiff", "fit", str(LOG), "--out",
                                 str(out)], env=ENV, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True)
    time.sleep(after_s)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signum, err
    name = signal.Signals(signum).name
    assert err.splitlines() == [f"fitstiff fit: interrupted by {name}; its unfinished outputs "
                                "were discarded"]
    assert left_behind(out) == []


def test_an_ignored_sigint_stays_ignored(tmp_path):
    """A command started with SIGINT ignored (``nohup``, a shell's background job) keeps it
    so, as Python itself does: the fit runs to its end."""
    out = tmp_path / "out"
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        proc = subprocess.Popen([sys.executable, "-m", "fitstiff", "fit", str(LOG), "--out",
                                 str(out)], env=ENV, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True)
    finally:
        signal.signal(signal.SIGINT, previous)
    time.sleep(1.0)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    assert {"fit.json", "manifest.json"} <= set(left_behind(out))


def _sidecar_with_null(tmp_path):
    log = shutil.copy(LOG, tmp_path / "log.csv")
    sidecar = json.loads(LOG.with_suffix(".json").read_text())
    (tmp_path / "log.json").write_text(json.dumps(sidecar | {"bore_mm": None}))
    return [log]


def _copy_of_the_log(tmp_path):
    shutil.copy(LOG.with_suffix(".json"), tmp_path / "copy.json")
    return [LOG, shutil.copy(LOG, tmp_path / "copy.csv")]


def _utf16(tmp_path):
    path = tmp_path / "wide.csv"
    path.write_bytes(LOG.read_text().encode("utf-16-le"))        # no byte-order mark
    return [path]


def _loop(tmp_path):
    path = tmp_path / "loop.csv"
    path.symlink_to(path)
    return [path]


@pytest.mark.parametrize("command, files, args, expected", [
    ("fit", lambda t: [LOG], ["--out", ""], "argument --out: is empty"),
    ("inspect", lambda t: [LOG], ["--out", ""], "argument --out: is empty"),
    ("fit", lambda t: [LOG], ["--model", "", "--out", "{out}"], "argument --model: is empty"),
    ("inspect", lambda t: [LOG, LOG], [], "is the same file as"),
    ("inspect", _copy_of_the_log, [], "has the same content as"),
    ("inspect", _sidecar_with_null, [], "log.json: key 'bore_mm': is null"),
    ("inspect", _utf16, [], "is not UTF-8 (it looks like UTF-16 LE)"),
    ("fit", _loop, ["--out", "{out}"], "loop.csv: file: cannot be read (Too many levels"),
    ("fit", lambda t: [LOG], ["--fix", "sigma=40", "--out", "{out}"],
     "use one of: n, sigma0, Fc"),
], ids=["fit-out-empty", "inspect-out-empty", "model-empty", "same-file", "same-content",
        "sidecar-null", "utf16", "symlink-loop", "fix-names"])
def test_bad_arguments_are_refused_in_one_line(tmp_path, command, files, args, expected):
    out = tmp_path / "out"
    proc = fitstiff(command, *files(tmp_path), *[a.format(out=out) for a in args],
                    cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert expected in one_line(proc)
    assert left_behind(out) == [] and left_behind(tmp_path).count("manifest.json") == 0


def test_a_log_after_the_column_entries_is_named():
    """``--columns time=1:s force=2:N excel.csv`` took the file for a column entry and ended
    with "the following arguments are required: LOG"."""
    proc = fitstiff("inspect", "--columns", "time=1:s", "force=2:N", "excel.csv")
    assert proc.returncode == 2
    assert ("entry 'excel.csv' is not QUANTITY=COLUMN[:UNIT]; it looks like a LOG file: put "
            "the LOG files before --columns") in one_line(proc)


@contextlib.contextmanager
def small_disk(tmp_path, size: str):
    """A tmpfs of ``size`` (skips where this machine does not let the tests mount one)."""
    mount = tmp_path / "disk"
    mount.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mount)],
                          capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({done.stderr.decode().strip()})")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


def fill(disk: Path, leave_kib: int) -> None:
    """Fill ``disk`` up to ``leave_kib`` KiB of free room."""
    free = shutil.disk_usage(disk).free // 1024
    with open(disk / "filler", "wb") as fh:
        fh.write(b"\0" * max(free - leave_kib, 0) * 1024)


@pytest.mark.parametrize("leave_kib", [0, 16])
@pytest.mark.parametrize("command", ["inspect", "fit"])
def test_a_full_disk_leaves_no_result_without_its_manifest(tmp_path, command, leave_kib):
    """A disk full before or while the outputs are written: exit 2 and one line; the run
    leaves nothing (a result file used to stay without its manifest, and with no room at all
    a stale lock and a traceback from the lock's pid write)."""
    with small_disk(tmp_path, "2m") as disk:
        fill(disk, leave_kib)
        out = disk / "out"
        proc = fitstiff(command, LOG, "--out", out)
        if proc.returncode == 0:            # it fitted: then the result is whole
            assert {"manifest.json"} <= set(left_behind(out))
            return
        assert proc.returncode == 2, proc.stderr
        assert "No space left on device" in one_line(proc)
        assert left_behind(out) == []


@pytest.mark.slow
def test_a_chain_survives_a_full_disk_and_resumes(tmp_path):
    """A posterior on a disk that fills: it stops before a write the disk cannot take (HDF5
    used to segfault and leave a chain that --resume could not read), says where the chain is
    kept, and --resume finishes it once there is room."""
    args = ["posterior", LOG, "--model", "chamber+dahl", "--walkers", "16", "--steps", "3000",
            "--check-every", "500", "--draws", "5"]
    with small_disk(tmp_path, "2m") as disk:
        fill(disk, 400)
        out = disk / "post"
        proc = fitstiff(*args, "--out", out)
        assert proc.returncode == 2, proc.stderr
        line = one_line(proc)
        assert "No space left on device for the next" in line and "--resume" in line
        assert left_behind(out) == [".chain.h5.partial.h5"]
        (disk / "filler").unlink()
        resumed = fitstiff(*args, "--out", out, "--resume")
        assert resumed.returncode == 0, resumed.stderr
        assert {"chain.h5", "posterior.json", "manifest.json"} <= set(left_behind(out))


def test_a_report_does_not_block_the_next_step_of_the_run_it_shows(tmp_path):
    """``fitstiff report out/fit`` then the README's next ``fitstiff fit ... --out out/fit``:
    refused before ("is an input of the run recorded in out/fit/report.manifest.json"). A
    log that a run in the directory read stays protected."""
    from fitstiff.cli import main

    out = tmp_path / "fit"
    for args in (["fit", LOG, "--out", out], ["report", out], ["fit", LOG, "--out", out],
                 ["report", out]):
        assert main(list(map(str, args))) == 0          # in-process: the rule, not the process
    log = tmp_path / "log.csv"                           # a log in DIR that a fit read
    shutil.copy(LOG, log)
    shutil.copy(LOG.with_suffix(".json"), tmp_path / "log.json")
    assert main(["fit", str(log), "--out", str(tmp_path)]) == 0
    assert main(["report", str(tmp_path)]) == 0
    assert main(["simulate", "--program", "ramp", "--name", "log", "--out", str(tmp_path)]) == 2
