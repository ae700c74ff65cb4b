"""Outputs never destroy data: --out is claimed before any work, locked, written all or
nothing, and never overwrites an input, a log's sidecar or a file fitstiff did not write
(issue 16). Every input stays byte-identical (SHA-256) with its mode."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

import fitstiff.cli.demo
import fitstiff.cli.fit
import fitstiff.cli.inspect
import fitstiff.cli.posterior
import fitstiff.cli.simulate
from fitstiff.cli import main
from fitstiff.data import fig4_logs
from fitstiff.errors import InputError
from fitstiff.io.output import LOCK_NAME, STAGING_PREFIX, OutputDir

FIG4 = fig4_logs()[-1]          # p6bar_x350mm.csv, 1 481 samples, with sidecar


def snapshot(directory: Path) -> dict[str, tuple[str, int]]:
    """Every file below ``directory``: SHA-256 and permission bits."""
    return {str(p.relative_to(directory)): (hashlib.sha256(p.read_bytes()).hexdigest(),
                                            stat.S_IMODE(p.stat().st_mode))
            for p in sorted(directory.rglob("*")) if p.is_file()}


def log_pair(directory: Path, stem: str, source: Path = FIG4) -> Path:
    """A copy of a bundled log and its sidecar as ``directory/<stem>.csv|json`` (mode 0644)."""
    directory.mkdir(parents=True, exist_ok=True)
    csv = directory / f"{stem}.csv"
    shutil.copyfile(source, csv)
    shutil.copyfile(source.with_suffix(".json"), directory / f"{stem}.json")
    for p in (csv, csv.with_suffix(".json")):
        p.chmod(0o644)
    return csv


def boom(*args, **kwargs):
    raise AssertionError("the command started working before it checked --out")


@pytest.fixture
def no_work(monkeypatch):
    """Make any loading / fitting / sampling / simulating fail the test."""
    for module in (fitstiff.cli.fit, fitstiff.cli.posterior, fitstiff.cli.inspect):
        monkeypatch.setattr(module, "logs_from_args", boom)
    monkeypatch.setattr(fitstiff.cli.simulate, "simulate", boom)


def one_error_line(capsys, command: str) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"fitstiff {command}: error: "), err
    return err.strip()


# -- reproducer: another log's sidecar --------------------------------------------------------
def test_fit_never_overwrites_another_logs_sidecar(tmp_path, capsys, no_work, monkeypatch):
    """d/fit.csv + d/fit.json and d/a.csv + d/a.json: ``fit d/a.csv --out d`` used to replace
    d/fit.json (fit.csv's sidecar) with the fit result and make it 0600."""
    d = tmp_path / "d"
    log_pair(d, "fit")
    a = log_pair(d, "a")
    before = snapshot(d)
    monkeypatch.chdir(tmp_path)
    assert main(["fit", "d/a.csv", "--out", "d"]) == 2
    assert one_error_line(capsys, "fit") == (
        "fitstiff fit: error: d/fit.json: --out d: is the sidecar of the log d/fit.csv; give "
        "another --out directory (a new or empty one)")
    assert snapshot(d) == before                      # bytes and modes, nothing added
    # without the other log's sidecar the name is still a sidecar-to-be: refused as well
    (d / "fit.json").unlink()
    assert main(["fit", str(a), "--out", str(d)]) == 2
    assert "is the sidecar of the log" in one_error_line(capsys, "fit")
    assert not (d / "fit.json").exists()


@pytest.mark.parametrize("command, stem", [("fit", "fit"), ("posterior", "posterior"),
                                           ("inspect", "inspect")])
def test_own_sidecar_is_refused_before_any_work(tmp_path, capsys, no_work, monkeypatch,
                                                command, stem):
    """The run's own sidecar (``<command>.json`` of its log ``<command>.csv``) is refused up
    front: no fit, no chain, and no chain.h5 / posterior.nc / predictive.npz left behind."""
    log = log_pair(tmp_path, stem)
    before = snapshot(tmp_path)
    assert main([command, str(log), "--out", str(tmp_path)]) == 2
    message = one_error_line(capsys, command)
    assert f"{tmp_path / (stem + '.json')}: --out {tmp_path}: is an input of this run" in message
    assert snapshot(tmp_path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"{stem}.csv", f"{stem}.json"]


def test_files_fitstiff_did_not_write_are_refused(tmp_path, capsys, no_work):
    out = tmp_path / "out"
    out.mkdir()
    (out / "fit.json").write_text("my notes\n")
    assert main(["fit", str(FIG4), "--out", str(out)]) == 2
    assert "fit.json: --out" in (line := one_error_line(capsys, "fit"))
    assert "exists and was not written by fitstiff (no manifest in" in line
    (out / "fit.json").unlink()
    (out / "manifest.json").write_text("{}\n")           # not a fitstiff manifest
    assert main(["fit", str(FIG4), "--out", str(out)]) == 2
    assert "manifest.json: --out" in (line := one_error_line(capsys, "fit"))
    assert "exists and is not a fitstiff manifest" in line
    (out / "manifest.json").unlink()
    (out / "figures").mkdir()
    (out / "figures" / "mine.png").write_bytes(b"png")
    with pytest.raises(InputError, match="figures/mine.png: --out .*: exists and was not "
                                         "written by fitstiff"):
        OutputDir(out, planned=["figures/"]).claim()
    assert not (out / LOCK_NAME).exists()                # a refused claim releases the lock


def test_rerun_replaces_own_outputs_keeps_modes_and_refuses_edited_ones(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["fit", str(FIG4), "--out", str(out)]) == 0
    fit_json = out / "fit.json"
    assert stat.S_IMODE(fit_json.stat().st_mode) == 0o666 & ~_umask()   # not 0600
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["output_sha256"] == {
        "fit.json": hashlib.sha256(fit_json.read_bytes()).hexdigest()}
    fit_json.chmod(0o640)
    assert main(["fit", str(FIG4), "--out", str(out), "--fix", "n=1.4"]) == 0
    assert stat.S_IMODE(fit_json.stat().st_mode) == 0o640          # mode kept on replace
    assert json.loads(fit_json.read_text())["parameters"]["n"]["fixed"]
    capsys.readouterr()
    fit_json.write_text(fit_json.read_text().replace('"converged"', '"converged" ', 1))
    assert main(["fit", str(FIG4), "--out", str(out)]) == 2
    assert "fit.json: --out" in (line := one_error_line(capsys, "fit"))
    assert "has changed since fitstiff wrote it (sha256" in line


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_runs_sharing_a_directory_keep_each_others_record(tmp_path, capsys):
    """Two simulated logs into one directory: the second manifest keeps the first run's
    record (outputs still there), so re-simulating the first is recognised as fitstiff's."""
    args = ["simulate", "--program", "ramp", "--distance-mm", "0.5", "--out", str(tmp_path)]
    assert main([*args, "--name", "a"]) == 0
    assert main([*args, "--name", "b", "--seed", "2"]) == 0
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["outputs"] == ["b.csv", "b.json", "b.truth.json"]
    [earlier] = manifest["earlier_runs"]
    assert earlier["outputs"] == ["a.csv", "a.json", "a.truth.json"] and earlier["seed"] == 0
    assert main([*args, "--name", "a", "--seed", "3"]) == 0
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert [r["outputs"][0] for r in manifest["earlier_runs"]] == ["b.csv"]
    # a log that a run recorded here used is not re-simulated over
    assert main(["fit", str(tmp_path / "b.csv"), "--model", "dahl", "--out", str(tmp_path)]) == 0
    capsys.readouterr()
    assert main([*args, "--name", "b"]) == 2
    assert one_error_line(capsys, "simulate").endswith(
        f"b.csv: --out {tmp_path}: is an input of the run recorded in "
        f"{tmp_path / 'manifest.json'}; give another --out directory (a new or empty one)")


# -- reproducer: unwritable --out --------------------------------------------------------------
@pytest.mark.parametrize("argv", [
    ["fit", str(FIG4)], ["inspect", str(FIG4)], ["posterior", str(FIG4)],
    ["simulate"], ["stiffness", "--bore-mm", "32", "--stroke-mm", "700"],
])
def test_out_below_a_regular_file_is_exit_2_before_work(tmp_path, capsys, no_work, argv):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main([*argv, "--out", str(blocker / "out")]) == 2
    assert one_error_line(capsys, argv[0]).endswith(
        f"{blocker / 'out'}: --out: cannot be created: {blocker} is a file, not a directory; "
        "give a path below a directory")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_report_out_below_a_regular_file(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    run = tmp_path / "run"
    run.mkdir()
    assert main(["report", str(run), "--out", str(blocker / "r")]) == 2
    assert "cannot be created: " in one_error_line(capsys, "report")


@pytest.fixture
def read_only_dir(tmp_path):
    """A directory this process cannot write to: mode 0555, and for root (who ignores modes)
    the immutable attribute; skipped where neither works."""
    path = tmp_path / "ro"
    path.mkdir()
    path.chmod(0o555)
    immutable = False
    if os.access(path, os.W_OK) and _can_write(path):
        immutable = subprocess.run(["chattr", "+i", str(path)], capture_output=True).returncode \
            == 0 if shutil.which("chattr") else False
        if not immutable or _can_write(path):
            path.chmod(0o755)
            pytest.skip("cannot make a directory read-only for this user (root without chattr)")
    yield path
    if immutable:
        subprocess.run(["chattr", "-i", str(path)], check=True)
    path.chmod(0o755)


def _can_write(path: Path) -> bool:
    try:
        (path / ".probe").write_text("x")
    except OSError:
        return False
    (path / ".probe").unlink()
    return True


@pytest.mark.parametrize("argv", [["fit", str(FIG4)], ["inspect", str(FIG4)],
                                  ["posterior", str(FIG4)]])
def test_read_only_out_is_exit_2_before_work(read_only_dir, capsys, no_work, argv):
    assert main([*argv, "--out", str(read_only_dir)]) == 2
    line = one_error_line(capsys, argv[0])
    assert line.startswith(f"fitstiff {argv[0]}: error: {read_only_dir}: --out: is not "
                           "writable (") and line.endswith("give a directory you can write to")
    assert main([*argv, "--out", str(read_only_dir / "new")]) == 2
    assert f"--out: cannot be created in {read_only_dir} (" in one_error_line(capsys, argv[0])


# -- failed runs leave nothing ------------------------------------------------------------------
def test_a_failed_run_leaves_the_directory_as_it_was(tmp_path, capsys, monkeypatch):
    out = tmp_path / "out"
    assert main(["fit", str(FIG4), "--out", str(out)]) == 0
    before = snapshot(out)

    from fitstiff.inference.fitting import FitResult

    to_dict, calls = FitResult.to_dict, []

    def fails_after_compare(self):
        # compare.json takes the first summary; writing the winner's fit.json then fails
        calls.append(1)
        if len(calls) > 1:
            raise RuntimeError("solver exploded")
        return to_dict(self)

    monkeypatch.setattr(FitResult, "to_dict", fails_after_compare)
    with pytest.raises(RuntimeError):
        main(["fit", str(FIG4), "--compare", "dahl", "--out", str(out)])
    assert len(calls) == 2
    assert snapshot(out) == before                  # compare.json was staged, not written
    assert not [p for p in out.iterdir() if p.name.startswith(".")]
    # a directory the failed run created is removed again
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,force_N\n0,1\n")
    assert main(["fit", str(bad), "--out", str(tmp_path / "new" / "deep")]) == 2
    assert not (tmp_path / "new").exists()


def test_staging_of_a_killed_run_is_marked_and_swept(tmp_path):
    stale = tmp_path / f"{STAGING_PREFIX}99999-0"
    stale.mkdir()
    (stale / "fit.json").write_text("half")
    with OutputDir(tmp_path, planned=["fit.json"]) as out:
        assert not stale.exists()
        out.write_json("fit.json", {"a": 1})
        out.finish()
    assert json.loads((tmp_path / "fit.json").read_text()) == {"a": 1}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fit.json", "manifest.json"]


# -- the lock ---------------------------------------------------------------------------------
HOLDER = """
import sys
from fitstiff.io.output import OutputDir
out = OutputDir(sys.argv[1], planned=["fit.json"]).claim()
print("claimed", flush=True)
sys.stdin.read()
"""


def test_second_run_is_refused_and_a_dead_runs_lock_does_not_block(tmp_path, capsys, no_work):
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(tmp_path)],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "claimed"
        assert main(["fit", str(FIG4), "--out", str(tmp_path)]) == 2
        assert one_error_line(capsys, "fit") == (
            f"fitstiff fit: error: --out {tmp_path} is in use by pid {holder.pid}: (another "
            "fitstiff run writes there); wait for it to finish, or give another --out "
            "directory")
    finally:
        holder.kill()                       # SIGKILL: no cleanup, the lock file stays
        holder.wait()
    assert (tmp_path / LOCK_NAME).read_text().strip() == str(holder.pid)
    with OutputDir(tmp_path, planned=["fit.json"]) as out:     # the kernel dropped the lock
        assert (tmp_path / LOCK_NAME).read_text().strip() == str(os.getpid())
        out.write_json("fit.json", {})
        out.finish()
    assert not (tmp_path / LOCK_NAME).exists()


def test_concurrent_posteriors_second_is_refused_first_completes(tmp_path, capsys):
    """Reproducer: two posteriors on one --out. The first used to crash with a broadcast error
    after the second deleted and recreated the shared partial chain."""
    out = tmp_path / "post"
    first = subprocess.Popen(
        [sys.executable, "-m", "fitstiff", "posterior", str(FIG4), "--walkers", "12",
         "--steps", "200", "--check-every", "100", "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 300
        while not (out / LOCK_NAME).exists():
            assert first.poll() is None and time.monotonic() < deadline, first.communicate()
            time.sleep(0.05)
        assert main(["posterior", str(FIG4), "--walkers", "12", "--steps", "200",
                     "--out", str(out)]) == 2
        assert f"--out {out} is in use by pid {first.pid}" in one_error_line(capsys,
                                                                             "posterior")
        stdout, stderr = first.communicate(timeout=600)
    finally:
        if first.poll() is None:
            first.send_signal(signal.SIGKILL)
    assert first.returncode == 0, stderr
    from fitstiff.inference.posterior.chain import ChainBackend

    assert ChainBackend(out / "chain.h5", read_only=True).iteration == 200
    assert not (out / LOCK_NAME).exists()


def test_demo_checks_every_directory_before_the_first_step(tmp_path, capsys, monkeypatch):
    (tmp_path / "posterior").mkdir()
    (tmp_path / "posterior" / "report.html").write_text("<p>my page</p>")
    monkeypatch.setattr(fitstiff.cli.demo, "_subcommand", boom)
    assert main(["demo", "--quick", "--out", str(tmp_path)]) == 2
    assert "report.html: --out" in one_error_line(capsys, "demo")
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["posterior", "report.html"]
