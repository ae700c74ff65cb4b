"""fitstiff report and fitstiff demo: self-contained pages, every figure twice, verified inputs,
the quick demo end to end, the page rendered in headless Chromium."""

from __future__ import annotations

import base64
import hashlib
import json
import re
import shutil
from pathlib import Path

import pytest
from conftest import REPO, check_renders_in_chromium, needs_chromium

from fitstiff.cli import main
from fitstiff.data import fig4_logs
from fitstiff.errors import InputError
from fitstiff.present.report import FIGURES, REPORT, REPORT_MANIFEST, write_report

IMG = re.compile(r"<img\b[^>]*\bsrc=\"([^\"]*)\"")


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> Path:
    """``fitstiff demo --quick``: OUT/fit, OUT/posterior with its report."""
    out = tmp_path_factory.mktemp("demo")
    assert main(["demo", "--quick", "--out", str(out)]) == 0
    return out




def check_page(report: Path, figures: set[str]) -> None:
    """One HTML file whose images are all embedded PNGs, with no script and no reference
    outside it; every figure in figures/ as PNG and SVG, the same ones as on the page."""
    page = report.read_text(encoding="utf-8")
    sources = IMG.findall(page)
    assert len(sources) == len(figures)
    for src in sources:
        prefix = "data:image/png;base64,"
        assert src.startswith(prefix)
        assert base64.b64decode(src[len(prefix):])[:8] == b"\x89PNG\r\n\x1a\n"
    assert not re.search(r"(src|href)\s*=\s*[\"']?\s*(https?:)?//", page, re.IGNORECASE)
    assert not re.search(r"<(script|link|iframe|object)\b|@import|url\(", page, re.IGNORECASE)
    written = sorted(p.name for p in (report.parent / FIGURES).iterdir())
    assert written == sorted(f"{name}.{ext}" for name in figures for ext in ("png", "svg"))
    for name in figures:
        assert (report.parent / FIGURES / f"{name}.svg").read_text().lstrip().startswith("<?xml")
        assert f'id="{name}"' in page


def loop_figures(kind: str) -> set[str]:
    return {f"{kind}_{p.stem}" for p in fig4_logs()}


def test_bundled_logs_are_the_generated_ones():
    bundled = sorted(p for p in fig4_logs()[0].parent.iterdir())
    assert [p.name for p in bundled] == [f"p{bar}bar_x350mm.{ext}" for bar in (0, 2, 4, 6)
                                         for ext in ("csv", "json", "truth.json")]
    for path in bundled:
        original = REPO / "data" / "synthetic" / "fig4" / path.name
        assert hashlib.sha256(path.read_bytes()).digest() == \
            hashlib.sha256(original.read_bytes()).digest(), path.name


def test_demo_ends_in_a_posterior_report(demo):
    report = demo / "posterior" / REPORT
    figures = (loop_figures("loop") | loop_figures("residuals")
               | {"chamber_vs_seal", "corner", "trace_n", "trace_sigma0", "trace_Fc",
                  "friction_vs_pressure"})
    check_page(report, figures)
    page = report.read_text(encoding="utf-8")
    assert "Posterior report: chamber+dahl" in page
    # issue 35: the numbers engineers quote open the page (median, 5-95 %)
    assert re.search(r'<p class="numbers">Pre-sliding slope 4\d\.\d+ N/mm \[[0-9.]+, [0-9.]+\], '
                     r'breakaway 1\d\.\d+ N \[[0-9.]+, [0-9.]+\] \(90 % intervals\)</p>', page)
    # a 120-step chain: the verdict says it did not converge, and why
    assert re.search(r"The chain did NOT converge: [^<]*--steps 120", page)
    assert re.search(r"Mean acceptance fraction 0\.\d\d", page)
    assert "Effective samples: fewest" in page
    # the truth of the synthetic logs is in the table (sigma0 = 40 N/mm)
    assert re.search(r"<td class=\"name\">sigma0</td>.*?<td class=\"num\">40</td></tr>", page)
    # ... next to the least-squares value the walkers started from
    assert re.search(r"<td class=\"name\">sigma0</td>(<td[^>]*>[^<]*</td>){4}"
                     r"<td class=\"num\">[0-9.]+ ± [0-9.]+</td>", page)
    manifest = json.loads((demo / "posterior" / REPORT_MANIFEST).read_text())
    assert manifest["options"]["kind"] == "posterior"
    assert "posterior.json" in json.loads((demo / "posterior" / "manifest.json").read_text())[
        "outputs"]                                  # the run's own manifest is untouched


def test_fit_report(tmp_path):
    """The report of a one-log fit with a sample range and a fitted closing pressure (a per-log
    nuisance): both change the fitted curves, and the report reproduces fit.json's per-log RMS
    (or refuses) only if it rebuilds them."""
    log = fig4_logs()[-1]
    assert main(["fit", str(log), "--free", "closing_pressure", "--range", "100:700",
                 "--out", str(tmp_path)]) == 0
    report = write_report(tmp_path)
    check_page(report, {f"loop_{log.stem}", f"residuals_{log.stem}", "chamber_vs_seal"})
    page = report.read_text(encoding="utf-8")
    assert "Fit report: chamber+dahl" in page
    assert "The fit converged (lm, " in page
    # issue 35: the numbers engineers quote open the page, each interval estimate ± 1.645
    # se; a quantity the data leave without an error says so (here the breakaway: 600 samples)
    data = json.loads((tmp_path / "fit.json").read_text())["derived"]
    quote = re.search(r'<p class="numbers">Pre-sliding slope ([0-9.]+) N/mm \[([0-9.]+), '
                      r'([0-9.]+)\], breakaway ([0-9.]+) N (\(not determined\)|\[[^]]*\])', page)
    slope, breakaway = data["presliding_slope_N_per_mm"], data["breakaway_N"]
    value, low, high = map(float, quote.groups()[:3])
    assert value == pytest.approx(slope["value"], rel=1e-3)
    assert high - low == pytest.approx(2 * 1.645 * slope["stderr"], rel=0.05)
    assert float(quote.group(4)) == pytest.approx(breakaway["value"], rel=1e-3)
    assert (quote.group(5) == "(not determined)") == (breakaway["stderr"] is None)
    # issue 17 item 5: the samples outside --range are drawn as not fitted, the RMS is theirs
    assert "Light grey: samples outside the fitted range (not fitted)." in page
    assert "over the 600 fitted samples" in page
    # one pressure: the friction table without the plot
    assert "Friction against pressure" in page and "friction_vs_pressure" not in page
    assert re.search(r"<td class=\"name\">Fc</td><td class=\"num\">18\.\d*</td>", page)
    # issue 35: Dahl's sigma0 and Fc are its pre-sliding slope and breakaway: the derived
    # rows say so instead of reading as second estimates
    assert '<td class="name">presliding_slope (= sigma0)</td>' in page
    assert '<td class="name">breakaway (= Fc)</td>' in page
    assert '<td class="name">presliding_range</td>' in page
    assert json.loads((tmp_path / REPORT_MANIFEST).read_text())["options"]["kind"] == "fit"


@pytest.fixture
def moved_fit(demo, tmp_path) -> tuple[Path, Path]:
    """A copy of the demo's fit directory whose inputs are copies of the bundled logs."""
    logs = tmp_path / "logs"
    shutil.copytree(fig4_logs()[0].parent, logs)
    run = tmp_path / "fit"
    shutil.copytree(demo / "fit", run, ignore=shutil.ignore_patterns(FIGURES, "report*"))
    for name in ("manifest.json", "fit.json"):
        text = (run / name).read_text().replace(str(fig4_logs()[0].parent), str(logs))
        (run / name).write_text(text)
    return run, logs / "p2bar_x350mm.csv"


def test_changed_or_missing_input_is_one_line_exit_2(moved_fit, capsys):
    run, log = moved_fit
    lines = log.read_text().splitlines(keepends=True)
    log.write_text("".join(lines[:-1]))                          # one row fewer
    assert main(["report", str(run)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith(f"fitstiff report: error: {log}: input of the run in "
                          f"{run / 'manifest.json'}: has changed since the run (sha256 ")
    assert err.rstrip().endswith("restore the original file or run again on the new one")
    log.unlink()
    assert main(["report", str(run)]) == 2
    assert capsys.readouterr().err == (f"fitstiff report: error: {log}: input of the run in "
                                       f"{run / 'manifest.json'}: is missing; restore the file "
                                       "or run again\n")
    assert not (run / REPORT).exists()


def test_logs_read_in_a_way_the_manifest_does_not_record_are_named(moved_fit):
    """A manifest from before runs recorded their reading options, of headerless files: the
    report says so instead of the loader's advice to pass --no-header."""
    run, log = moved_fit
    log.write_text("".join(log.read_text().splitlines(keepends=True)[1:]))    # no header
    manifest = json.loads((run / "manifest.json").read_text())
    manifest["options"].pop("reading")
    for entry in manifest["inputs"]:
        if entry["path"] == str(log):
            entry["sha256"] = hashlib.sha256(log.read_bytes()).hexdigest()
    (run / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(InputError, match=(
            re.escape(f"{run / 'manifest.json'}: re-reading the run's logs: failed ({log}: line "
                      "1: looks like data, not a header") + r".*\): the manifest does not record "
            r"how they were read \(--format, --columns, --no-header, --delimiter, rig "
            r"overrides\), so they were read as canonical CSV files; report runs on canonical")):
        write_report(run)


def test_a_fit_the_logs_do_not_reproduce_is_refused(moved_fit):
    run, _ = moved_fit
    fit = json.loads((run / "fit.json").read_text())
    fit["parameters"]["Fc"]["value"] *= 1.05
    (run / "fit.json").write_text(json.dumps(fit))
    with pytest.raises(InputError, match=r"fit\.json: log p0bar_x350mm: the fitted model gives "
                                         r"an RMS residual of .* N on the re-read log, fit\.json "
                                         r"says 0\.20\d* N; the log was read"):
        write_report(run)


@pytest.mark.parametrize("setup, message", [
    (lambda d: None, "holds none of posterior.json, fit.json"),
    (lambda d: (d / "fit.json").write_text("{}"), "manifest.json: file: is missing; the run did "
                                                  "not finish"),
])
def test_not_a_run_directory(tmp_path, setup, message):
    setup(tmp_path)
    with pytest.raises(InputError, match=re.escape(message)):
        write_report(tmp_path)


@needs_chromium
def test_posterior_report_renders_in_chromium(demo, tmp_path):
    """The page as a browser shows it (:func:`conftest.check_renders_in_chromium`)."""
    check_renders_in_chromium(demo / "posterior" / REPORT, tmp_path)


def test_log_table_shows_the_regulated_pressure_a_log_carries():
    """Issue 17 item 5: a log without supply_bar but with a logged chamber pressure (a
    regulated chamber) shows that pressure (mean, bar gauge), not n/a."""
    import numpy as np

    from fitstiff.io.log import Log, Rig
    from fitstiff.present.report.text import pressure_cell

    x = np.linspace(0.0, 1e-3, 50)
    regulated = Log("r", displacement=x, force=np.zeros(50), time=np.arange(50) * 0.01,
                    pressure_a=np.full(50, 101325.0 + 3.0e5), rig=Rig())
    assert pressure_cell(regulated, None) == "regulated A 3"
    assert pressure_cell(regulated, 6e5) == "6"
    bare = Log("b", displacement=x, force=np.zeros(50), time=np.arange(50) * 0.01)
    assert pressure_cell(bare, None) == "n/a"


def test_friction_against_pressure_and_the_seal_alone(demo):
    """Issue 17 items 5-6: the demo's logs (0-6 bar, one seal friction level of 18 N) show a
    sliding friction per log, measured and modelled, that agree; the loop figure shows the
    seal force alone (force minus chamber and offset) beside the whole loop."""
    page = (demo / "posterior" / REPORT).read_text(encoding="utf-8")
    section = page[page.index("Friction against pressure"):]
    rows = re.findall(r"<tr><td class=\"name\">(p\dbar_x350mm)</td>"
                      r"<td class=\"num\">([-0-9.]+)</td><td class=\"num\">([-0-9.]+)</td>"
                      r"<td class=\"num\">([-0-9.]+)</td>", section)
    assert [r[0] for r in rows] == [p.stem for p in fig4_logs()]
    for _, bar, measured, model in rows:
        assert 5.0 < float(measured) < 18.5        # below Fc: the short legs do not saturate
        assert float(model) == pytest.approx(float(measured), rel=0.05)
    assert [float(r[1]) for r in rows] == pytest.approx([0, 2, 4, 6], abs=0.05)
    assert "Middle: the seal&#x27;s force as measured" in page
