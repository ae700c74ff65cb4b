"""The fleet page of ``fitstiff report DIR`` (issue 34): the population, outliers, drift and
every cylinder-run of a ``fitstiff fleet`` directory on one self-contained page; a cylinder's
own report made on demand (``--cylinder NAME [--run RUN]``) and then linked; one-line errors."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest
from matplotlib.figure import Figure

from conftest import check_renders_in_chromium, needs_chromium
from fitstiff._testing.fleet import make_fleet
from fitstiff.cli import main
from fitstiff.present.fleet_page import plot_distribution, plot_drift, plot_loops


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    """5 cylinders of 2 short logs each: cyl0000 logged in 3 runs and drifting (+30 % Fc over
    them), one planted outlier (cyl0003, its force x 1.8: five cylinders tell a +30 % one
    from the population's spread only by chance), and a cylinder whose log cannot be read."""
    root = tmp_path_factory.mktemp("fleet_page")
    source = root / "fleet"
    truth = make_fleet(source, cylinders=5, seed=3, with_runs=1, runs=3, drifting=1,
                       drift=0.3, outliers=0.0, samples=800)
    for log in sorted((source / "cyl0003").glob("*.csv")):
        frame = pd.read_csv(log)
        frame["force_N"] *= 1.8
        frame.to_csv(log, index=False)
    truth["cylinders"]["cyl0003"]["outlier"] = "force x 1.8"
    bad = source / "zz_bad"
    bad.mkdir()
    (bad / "log0.csv").write_text("time_s,displacement_mm,force_N\n0,0,abc\n0.1,0.1,zz\n")
    out = root / "out"
    assert main(["fleet", str(source), "--out", str(out), "--workers", "1", "--q", "0.05"]) == 0
    return out, truth


@pytest.fixture(scope="module")
def page(fleet_dir):
    out, _ = fleet_dir
    assert main(["report", str(out)]) == 0
    return out / "report.html"


def test_the_page_names_every_cylinder_and_the_population(fleet_dir, page):
    out, truth = fleet_dir
    text = page.read_text(encoding="utf-8")
    table = pd.read_parquet(out / "fleet.parquet")
    population = json.loads((out / "population.json").read_text())
    assert len(table) == 8 and set(table["cylinder"]) == {*truth["cylinders"], "zz_bad"}
    for name in set(table["cylinder"]):
        assert f">{name}<" in text
    assert "8 cylinder-runs of 6 cylinders: 1 with an error, 0 not converged" in text
    for name, est in population["quantities"].items():
        lo, hi = est["mean_interval_95"]
        assert f"population mean {est['mean']:.4g}" in text and f"[{lo:.4g}, {hi:.4g}]" in text
        assert f"spread {100 * est['spread_sd_log']:.1f} %" in text
    # the planted outlier and the drifting cylinder are flagged, and drawn
    planted = [c for c, t in truth["cylinders"].items() if t["outlier"]]
    assert planted and {o["cylinder"] for o in population["outliers"]} >= set(planted)
    assert [d["cylinder"] for d in population["drift"]] == ["cyl0000"]
    for o in population["outliers"]:
        assert f"outlier {o['cylinder']}:" in text
    assert "drifting cyl0000: breakaway +" in text
    figures = ("fleet_distributions", "fleet_outliers", "fleet_drift")
    for name in figures:
        assert f'id="{name}"' in text
        assert (out / "figures" / f"{name}.png").is_file()
        assert (out / "figures" / f"{name}.svg").is_file()
    # self-contained: every image embedded, nothing fetched
    assert text.count('src="data:image/png;base64,') == len(figures)
    assert "http://" not in text and "https://" not in text and "<script" not in text
    # the exact command for a cylinder's report, and no link before it is made
    assert f"fitstiff report {out} --cylinder NAME [--run RUN]" in text
    assert f'title="fitstiff report {out} --cylinder cyl0000 --run run2"' in text
    assert 'href="cylinders/' not in text
    manifest = json.loads((out / "report.manifest.json").read_text())
    assert manifest["options"]["kind"] == "fleet"
    assert "report.html" in manifest["outputs"]


@needs_chromium
def test_the_page_renders_in_chromium(page, tmp_path):
    check_renders_in_chromium(page, tmp_path)


def test_a_cylinder_report_is_made_on_demand_and_linked(fleet_dir, page, capsys):
    out, _ = fleet_dir
    assert main(["report", str(out), "--cylinder", "cyl0000", "--run", "run2"]) == 0
    sub = out / "cylinders" / "cyl0000" / "run2"
    assert (sub / "report.html").is_file() and (sub / "manifest.json").is_file()
    fit = json.loads((sub / "fit.json").read_text())
    row = pd.read_parquet(out / "fleet.parquet").set_index(["cylinder", "run"]).loc[
        ("cyl0000", "run2")]
    assert fit["derived"]["breakaway_N"]["value"] == pytest.approx(row["breakaway_N"],
                                                                    rel=1e-9)
    assert "run fitstiff report" in capsys.readouterr().out
    assert main(["report", str(out)]) == 0
    text = page.read_text(encoding="utf-8")
    assert 'href="cylinders/cyl0000/run2/report.html"' in text
    assert text.count('href="cylinders/') == 1


@pytest.mark.parametrize("args, message", [
    (["--cylinder", "nope"], "--cylinder nope: is not in the fleet"),
    (["--cylinder", "cyl0000"], "has 3 runs; name one with --run"),
    (["--cylinder", "cyl0000", "--run", "run9"], "--run run9: is not a run of cyl0000"),
    (["--cylinder", "cyl0001", "--run", "1"], "leave --run out"),
    (["--cylinder", "zz_bad"], "failed in the fleet"),
    (["--run", "run1"], "--run: needs --cylinder"),
])
def test_bad_cylinder_requests_exit_2_with_one_line(fleet_dir, capsys, args, message):
    out, _ = fleet_dir
    capsys.readouterr()
    assert main(["report", str(out), *args]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_a_fleet_directory_without_its_population_exits_2(fleet_dir, tmp_path, capsys):
    out, _ = fleet_dir
    broken = tmp_path / "broken"
    broken.mkdir()
    for name in ("fleet.parquet", "manifest.json"):
        shutil.copy(out / name, broken / name)
    assert main(["report", str(broken)]) == 2
    err = capsys.readouterr().err
    assert "has no population.json" in err and err.count("\n") == 1
    assert not (broken / "report.html").exists()


def test_the_plots_take_an_axes_and_survive_degenerate_input():
    fig = Figure()
    axes = fig.subplots(2, 2).ravel()
    plot_distribution(axes[0], np.array([]), mean=None, spread=None, interval=None,
                      outliers=np.array([]), label="breakaway", unit="N")
    plot_distribution(axes[1], np.array([4.27, 4.271, 4.272, np.nan]), mean=4.271,
                      spread=1e-10, interval=[4.270, 4.272], outliers=np.array([4.272]),
                      label="chamber stiffness", unit="N/mm")
    assert any(line.get_label().startswith("population mean") for line in axes[1].lines)
    plot_loops(axes[2], None, None, title="nothing", missing="cyl9: log not read")
    plot_drift(axes[3], {"a": (np.arange(3.0), np.array([1.0, 1.1, 1.2])),
                         "b": (np.arange(2.0), np.array([np.nan, 2.0]))},
               drifting=["a"], label="breakaway")
    assert [line.get_label() for line in axes[3].lines][:1] == ["a"]
    fig.canvas.draw()
