"""``inspect_log`` and ``fitstiff inspect`` on a tiny canonical log written here."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fitstiff.cli import main
from fitstiff.io.loading import load_log
from fitstiff.segments.inspection import format_summary, inspect_log
from fitstiff.segments.segmentation import REGIONS

FS = 200.0
SIDECAR = {"bore_mm": 32, "rod_mm": 0, "stroke_mm": 100, "start_position_mm": 50,
           "supply_bar": 6}


def write_log(tmp_path, *, name="run1", with_time=True, sidecar=SIDECAR, seed=0):
    """Two triangle cycles of +-2 mm at 10 mm/s with a 1 s hold at +1 mm; force = 40 N/mm;
    ``seed`` of the displacement noise."""
    step = 10e-3 / FS * 1e3                                  # mm per sample
    knots_i, knots_x = [0], [0.0]
    for target in (2, -2, 1, 1, -2, 0):
        hold = target == knots_x[-1]
        knots_i.append(knots_i[-1] + (int(FS) if hold else round(abs(target - knots_x[-1]) / step)))
        knots_x.append(float(target))
    i = np.arange(knots_i[-1] + 1)
    x = np.interp(i, knots_i, knots_x) + np.random.default_rng(seed).normal(0, 0.003, i.size)
    columns = {"time_s": i / FS} if with_time else {}
    columns |= {"displacement_mm": x, "force_N": 40 * x}
    path = tmp_path / f"{name}.csv"
    rows = [",".join(columns)] + [",".join(f"{v:.6g}" for v in row)
                                  for row in zip(*columns.values())]
    path.write_text("\n".join(rows) + "\n")
    if sidecar is not None:
        (tmp_path / f"{name}.json").write_text(json.dumps(sidecar))
    return path


def test_inspect_log_summary(tmp_path):
    summary = inspect_log(load_log(write_log(tmp_path)))
    assert summary["file"] == "run1"
    assert summary["samples"] == 481
    assert summary["sampling"]["sample_rate_hz"] == pytest.approx(FS)
    assert summary["sampling"]["duration_s"] == pytest.approx(480 / FS)
    assert summary["sampling"]["gaps"]["count"] == 0
    d = summary["ranges"]["displacement_mm"]
    assert d["min"] == pytest.approx(-2, abs=0.02) and d["max"] == pytest.approx(2, abs=0.02)
    assert summary["ranges"]["force_N"]["span"] == pytest.approx(160, rel=0.01)
    assert summary["ranges"]["pressure_a_bar"] is None
    assert summary["pressure_level_bar"] == 6
    seg = summary["segmentation"]
    assert seg["reversals"] == 4 and seg["loops"] == 1
    assert seg["pauses"]["count"] == 1
    assert seg["pauses"]["longest_s"] == pytest.approx(1.0, abs=2 / FS)
    assert set(summary["regions"]) == {"presliding", "sliding", "dwell", "standstill",
                                       "stroke_end"}
    assert summary["regions"]["stroke_end"] == 0.0      # +-2 mm about mid-stroke
    assert sum(summary["regions"][r] for r in ("presliding", "sliding", "dwell",
                                               "standstill")) == pytest.approx(1)
    assert summary["rig"]["present"]["bore_mm"] == 32
    assert summary["rig"]["missing"] == ["dead_length_a_mm", "dead_length_b_mm", "load_kg"]
    text = format_summary(summary)
    for expected in ("reversals           4", "pauses              1", "missing metadata",
                     "dead_length_a_mm"):
        assert expected in text


def test_inspect_without_time_or_sidecar(tmp_path):
    summary = inspect_log(load_log(write_log(tmp_path, with_time=False, sidecar=None)))
    assert summary["sampling"]["has_time"] is False
    assert summary["segmentation"]["pauses"] is None
    assert summary["segmentation"]["reversal_times_s"] is None
    assert summary["segmentation"]["reversals"] == 4    # the hold creates no reversal
    assert set(summary["regions"]) == {"presliding", "sliding"}
    assert "bore_mm" in summary["rig"]["missing"]
    notes = " ".join(summary["notes"])
    assert "quasi-static" in notes and "stroke_end region skipped" in notes
    assert "time                none (quasi-static log)" in format_summary(summary)


def test_cli_json(tmp_path, capsys):
    paths = [str(write_log(tmp_path, name=n, seed=k)) for k, n in enumerate(("a", "b"))]
    assert main(["inspect", *paths, "--json"]) == 0
    document = json.loads(capsys.readouterr().out)
    assert [s["file"] for s in document["logs"]] == ["a", "b"]
    assert document["logs"][0]["segmentation"]["reversals"] == 4


def test_cli_text_and_out(tmp_path, capsys):
    path = write_log(tmp_path)
    out = tmp_path / "out"
    assert main(["inspect", str(path), "--out", str(out), "--threshold-mm", "0.05"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("run1 (") and "reversal threshold  0.05 mm" in text
    written = json.loads((out / "inspect.json").read_text())
    assert written["logs"][0]["segmentation"]["threshold_mm"] == pytest.approx(0.05)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["outputs"] == ["inspect.json"]
    assert {p["path"] for p in manifest["inputs"]} == {str(path), str(tmp_path / "run1.json")}


def test_cli_bad_input_is_one_line_exit_2(tmp_path, capsys):
    path = write_log(tmp_path)
    assert main(["inspect", str(path), "--threshold-mm", "-1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "segmentation option 'threshold': found -0.001; give a positive number" in err
    assert main(["inspect", str(tmp_path / "missing.csv")]) == 2


def test_inspect_imports_neither_jax_nor_matplotlib(tmp_path):
    """`fitstiff inspect` builds only its own parser: no JAX, matplotlib or samplers are
    imported (a cold `inspect` took 7 s when every subcommand's module was loaded), and a
    JAX command run afterwards in a fresh process still gets the persistent compilation
    cache through JAX's environment variables."""
    import subprocess
    import sys

    from conftest import REPO

    log = REPO / "data" / "synthetic" / "fig4" / "p6bar_x350mm.csv"
    code = ("import sys, os; from fitstiff.cli import console; "
            f"rc = console(['inspect', {str(log)!r}]); "
            "print(rc, sorted(m for m in ('jax', 'matplotlib', 'emcee', 'h5py') "
            "if m in sys.modules), os.environ.get('JAX_COMPILATION_CACHE_DIR'))")
    env = {k: v for k, v in __import__("os").environ.items() if not k.startswith("JAX_")}
    env["FITSTIFF_CACHE_DIR"] = str(tmp_path / "cache")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=env, cwd=tmp_path, check=True)
    assert done.stdout.strip().splitlines()[-1] == f"0 [] {tmp_path / 'cache'}"


def test_a_stroke_shorter_than_the_presliding_range_is_named(capsys):
    """Issue 17 item 4: legs of 0.2 mm against the 0.5 mm default presliding range leave no
    sample that can be sliding; inspect says so and suggests a range from the data. A log
    whose longest legs reach the range (minor loops inside) gets no such note."""
    from conftest import polyline

    from fitstiff.io.log import Log
    from fitstiff.segments.segmentation import segment

    t, x = polyline([0.0, 0.2e-3, 0.0, 0.2e-3, 0.0], rate=0.1e-3, fs=1000.0)
    short = Log("short", displacement=x, force=np.zeros_like(x), time=t)
    given = segment(short, presliding_range=0.5e-3)
    notes = [n for n in given.notes if "presliding range" in n]
    assert len(notes) == 1 and "no sample can be sliding" in notes[0]
    assert "--presliding-range-mm (e.g. 0.067)" in notes[0]
    assert not (given.region == 1).any()                 # no sliding sample
    # the default follows the data: a third of the median leg, said in a note
    derived = segment(short)
    assert derived.presliding_range == pytest.approx(0.2e-3 / 3, rel=0.02)
    notes = [n for n in derived.notes if "presliding range" in n]
    assert len(notes) == 1 and "a third of the median travel, 0.067 mm" in notes[0]
    shares = {r: float(np.mean(derived.region == k)) for k, r in enumerate(REGIONS)}
    assert shares["sliding"] > 0.5 and shares["presliding"] > 0.2
    assert "presliding range" in format_summary(inspect_log(short))
    t, x = polyline([0.0, 1e-3, 0.8e-3, 1e-3, 0.0], rate=1e-3, fs=1000.0)
    long = Log("long", displacement=x, force=np.zeros_like(x), time=t)
    assert not [n for n in segment(long).notes if "presliding range" in n]
