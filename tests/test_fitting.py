"""Least-squares identification: recovery, solver status, denoising, uncertainty, CLI."""

from __future__ import annotations

import dataclasses
import hashlib
import json

import numpy as np
import pytest
from conftest import REALDATA, REPO, run_benchmark

from fitstiff._testing.recovery import dataset
from fitstiff.cli import main
from fitstiff.data import paper_rig
from fitstiff.inference.comparison import compare
from fitstiff.inference.fitting import fit
from fitstiff.io.log import Rig
from fitstiff.physics.programs import TriangleCycles
from fitstiff.physics.simulate import Noise, simulate, write_log


@pytest.mark.parametrize("friction, seed", [("dahl", 101), ("lugre", 102), ("maxwell_slip:3", 103)])
def test_recovers_seal_and_chamber_from_four_logs(friction, seed):
    """Paper-like data (0.2 N, 1 um, 2 mbar noise; 0-6 bar): slope and breakaway within 2 %
    and 3 standard errors, n within 0.05, from the data-driven default start."""
    logs, derived, n_true = dataset(friction, seed)
    result = fit(logs, f"chamber+{friction}")
    assert result.converged
    assert abs(result.value("n") - n_true) <= 0.05
    for key in ("presliding_slope_N_per_mm", "breakaway_N"):
        value, stderr = result.derived[key]
        assert abs(value / derived[key] - 1) <= 0.02, (key, value, derived[key])
        assert abs(value - derived[key]) <= 3 * stderr, (key, value, stderr, derived[key])


def _single(noise_um: float, seed: int):
    rig = Rig.from_mapping(paper_rig())
    prog = TriangleCycles(rate_mm_s=1.0, amplitudes_mm=(0.1, 0.3, 0.6, 1.0))
    return simulate("dahl", prog, rig=rig, params={"sigma0": 40, "Fc": 18}, seed=seed,
                    noise=Noise(force_N=0.2, displacement_um=noise_um), rate_hz=1000).log


@pytest.mark.parametrize("noise_um", [1.0, 3.0])
def test_displacement_noise_biases_a_plain_fit_and_denoising_removes_it(noise_um):
    log = _single(noise_um, seed=7)
    plain = fit([log], "dahl", denoise=False)
    clean = fit([log], "dahl")   # default: denoise when the noise is measurable
    assert clean.per_log[0]["denoised_displacement"]
    assert clean.per_log[0]["displacement_noise_um"] == pytest.approx(noise_um, rel=0.15)
    bias_plain = plain.value("Fc") / 18 - 1
    bias_clean = clean.value("Fc") / 18 - 1
    assert bias_plain > 0.05            # chatter: several percent (1 um) to > 20 % (3 um)
    if noise_um >= 3:
        assert bias_plain > 0.20
    assert abs(bias_clean) < 0.01
    assert abs(clean.value("sigma0") / 40e3 - 1) < 0.01


def test_solver_status_is_never_dropped(tmp_path, capsys):
    log = _single(1.0, seed=3)
    result = fit([log], "dahl", max_steps=2)
    assert not result.converged
    assert "maximum number of steps" in result.message
    assert result.warnings[0].startswith("the solver did not converge")
    d = result.to_dict()
    assert d["converged"] is False and "maximum number of steps" in d["message"]
    assert "NOT CONVERGED" in result.table()


def test_a_spent_step_budget_with_a_flat_cost_is_converged_and_says_so():
    """Issue 17 item 3 (LuGre on the O-ring logs): the step budget can run out while the cost
    no longer changes on the scale of the standard errors. Started at the optimum with a
    one-step budget, the fit is converged and says why; two steps from the data-driven
    start, where the cost still falls, it is not."""
    from fitstiff.inference.fitting import fit_problem
    from fitstiff.inference.problem import Problem

    log = _single(1.0, seed=3)
    problem = Problem([log], "dahl")
    best = fit_problem(problem)
    assert best.converged
    again = fit_problem(problem, max_steps=1, initial=problem.unpack(best.theta))
    assert again.converged and again.message.startswith("converged (the cost is flat")
    assert any(w.startswith("the step budget ran out with the cost flat") for w in again.warnings)
    np.testing.assert_allclose(again.theta, best.theta, rtol=1e-4, atol=1e-6)
    early = fit_problem(problem, max_steps=2)
    assert not early.converged and "maximum number of steps" in early.message


def test_identifiability_warning_names_the_combination():
    log = _single(0.0, seed=4)
    result = fit([log], "dahl+rig_compliance")
    text = " ".join(result.warnings)
    assert "compliance" in text and "sigma0" in text


def test_fix_holds_a_parameter_and_reports_it():
    logs, _, _ = dataset("dahl", 5)
    result = fit(logs[2:], "chamber+dahl", fix={"n": 1.25})
    params = result.parameters()
    assert params["n"] == {"value": 1.25, "stderr": None, "unit": "-", "fixed": True}
    assert "n" not in result.names


def test_multistart_reports_agreement():
    log = _single(1.0, seed=5)
    result = fit([log], "dahl", starts=3, seed=1)
    assert result.starts["requested"] == 3
    assert 1 <= result.starts["agreed"] <= result.starts["converged"] <= 3


def test_compare_ranks_the_true_model_first():
    rig = Rig.from_mapping(paper_rig())
    logs = [simulate("dahl+viscous", TriangleCycles(rate_mm_s=r, amplitudes_mm=(0.5, 1.0)),
                     rig=rig, params={"c": 400.0}, seed=i, rate_hz=200 * r,
                     noise=Noise(force_N=0.1, displacement_um=0.0)).log
            for i, r in enumerate((1.0, 5.0, 20.0))]
    comparison, results = compare(logs, ["dahl", "dahl+viscous"])
    assert comparison.ranked_by == "heldout_rms_N"
    assert comparison.rows[0]["model"] == "dahl+viscous"
    assert results[0].model.spec == "dahl+viscous"


def test_cli_writes_fit_json_and_leaves_inputs_alone(tmp_path, capsys):
    logs, _, _ = dataset("dahl", 6)
    paths = []
    for log in logs[:2]:
        paths.append(write_log(log, tmp_path / f"{log.name}.csv")[0])
    before = {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in paths}
    out = tmp_path / "out"
    code = main(["fit", *map(str, paths), "--model", "chamber+dahl", "--fix", "n=1.3",
                 "--out", str(out)])
    assert code == 0
    printed = capsys.readouterr().out
    assert "sigma0" in printed and "N/mm" in printed
    data = json.loads((out / "fit.json").read_text())
    for key in ("model", "parameters", "derived", "rms_N", "converged", "files"):
        assert key in data
    for key in ("presliding_slope_N_per_mm", "breakaway_N", "presliding_range_mm",
                "chamber_stiffness_N_per_mm"):
        assert set(data["derived"][key]) == {"value", "stderr"}
    assert data["parameters"]["sigma0"]["unit"] == "N/mm"
    manifest = json.loads((out / "manifest.json").read_text())
    hashes = {i["path"]: i["sha256"] for i in manifest["inputs"]}
    assert [hashes[str(p)] for p in paths] == list(before.values())
    assert str(paths[0].with_suffix(".json")) in hashes          # sidecars are inputs too
    assert before == {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in paths}


@pytest.mark.parametrize("argv, fragment", [
    (["--fix", "nope=1"], "'nope' is not a parameter"),
    (["--fix", "n=abc"], "is not a number"),
    (["--range", "5"], "is not START:STOP"),
    (["--weight", "slidng=2"], "unknown region"),
    (["--model", "chamber+dhal"], "unknown term 'dhal'"),
])
def test_cli_bad_options_exit_2_with_one_line(tmp_path, capsys, argv, fragment):
    log = _single(1.0, seed=8)
    path = write_log(log, tmp_path / "a.csv")[0]
    code = main(["fit", str(path), "--out", str(tmp_path / "o"), *argv])
    err = capsys.readouterr().err
    assert code == 2
    assert fragment in err and len(err.strip().splitlines()) == 1


def test_real_oring_files_fit_jointly(tmp_path, capsys):
    files = sorted(str(p) for p in REALDATA.glob("O-ring_*bar.csv"))
    code = main(["fit", *files, "--format", "zillen_oring", "--model", "chamber+dahl",
                 "--out", str(tmp_path)])
    assert code == 0
    data = json.loads((tmp_path / "fit.json").read_text())
    assert data["converged"]
    assert 2 < data["derived"]["breakaway_N"]["value"] < 20
    assert len(data["files"]) == 4


def test_closing_pressure_can_be_a_per_log_nuisance():
    """Logs whose supply pressure nobody wrote down: --free closing_pressure recovers it from
    the logged chamber pressures (and the force), per log."""
    logs = []
    for bar in (2.0, 5.0):
        rig = Rig.from_mapping(paper_rig(start_position_mm=100, supply_bar=bar))
        sim = simulate("chamber+dahl", TriangleCycles(rate_mm_s=1.0, amplitudes_mm=(0.2, 1.0)),
                       rig=rig, seed=int(bar), name=f"p{bar:g}", rate_hz=200)
        unknown = Rig.from_mapping(paper_rig(start_position_mm=100, supply_bar=None))
        logs.append(sim.log.replace(rig=unknown))
    result = fit(logs, "chamber+dahl", free=["closing_pressure"])
    assert result.converged
    assert [log["closing_pressure_bar"] for log in result.per_log] == [
        pytest.approx(2.0, abs=0.01), pytest.approx(5.0, abs=0.01)]
    assert result.value("n") == pytest.approx(1.3, abs=0.02)


def test_logs_denoised_and_left_as_measured_fit_together():
    """denoise='auto' denoises only noisy displacements; a batch of one noisy and one exact log
    crashed stacking drives with and without a velocity (found by benchmarks/withheld.py)."""
    from fitstiff.inference.problem import Problem
    from fitstiff.physics.programs import TriangleCycles
    from fitstiff.physics.simulate import Noise, simulate

    rig = Rig(bore=0.032, rod=0.0, stroke=0.7, start_position=0.35, supply_pressure=5e5)
    program = TriangleCycles(amplitudes_mm=(0.2, 1.0), rate_mm_s=5.0)
    logs = [simulate("chamber+dahl", program, rig=rig, seed=k, name=f"l{k}",
                     noise=Noise(displacement_um=du)).log for k, du in enumerate((1.0, 0.0))]
    problem = Problem(logs, "chamber+dahl")
    assert problem.denoised == [True, False]
    exact = problem.drives[1]
    x, t = np.asarray(exact.displacement), np.asarray(exact.time)
    np.testing.assert_allclose(np.asarray(exact.velocity)[1:], np.diff(x) / np.diff(t))
    result = fit(logs, "chamber+dahl")
    assert result.converged
    assert result.value("sigma0") == pytest.approx(40e3, rel=0.05)


def test_logs_of_very_different_length_run_in_their_own_stacks():
    """Logs are stacked (one vmap-ed scan) and padded to the longest of their stack; a log
    shorter than PAD_RATIO x the longest gets its own stack. The residuals per log are the same
    whatever the stacking: in a stack of two, alone, or alone in a problem of its own."""
    from fitstiff.inference.problem import Problem
    from fitstiff.inference.stacking import length_buckets

    rig = Rig(bore=0.032, rod=0.0, stroke=0.7, start_position=0.35, supply_pressure=5e5)
    logs = [simulate("chamber+dahl", TriangleCycles(amplitudes_mm=(0.2, 1.0), rate_mm_s=rate),
                     rig=rig, seed=k, name=f"l{k}", rate_hz=200).log
            for k, rate in enumerate((4.0, 1.0, 1.1))]
    lengths = [len(log) for log in logs]
    assert lengths[0] < 0.5 * lengths[1] and lengths[2] > 0.7 * lengths[1]
    assert length_buckets([0, 1, 2], lengths) == [[1, 2], [0]]
    assert length_buckets([0, 1, 2], lengths, pad_ratio=0.0) == [[0, 1, 2]]
    split = Problem(logs, "chamber+dahl")
    assert [g.index for g in split.groups] == [(1, 2), (0,)]
    theta = split.pack(split.model, {"offset": [0.1, 0.2, 0.3]})
    per_log = split.per_log(theta)
    for i, log in enumerate(logs):
        alone = Problem([log], "chamber+dahl")
        own = alone.per_log(alone.pack(split.model, {"offset": [0.1 * (i + 1)]}))[0]
        np.testing.assert_allclose(per_log[i]["force"], own["force"], rtol=1e-12, atol=1e-12)


def _friction_only_logs(tmp_path, n=2):
    """Friction-only logs (no rig geometry in the sidecar): chamber terms cannot be built."""
    paths = []
    for i, rate in enumerate((1.0, 3.0)[:n]):
        log = simulate("dahl", TriangleCycles(rate_mm_s=rate, amplitudes_mm=(0.2, 0.6)),
                       rig=Rig(), params={"sigma0": 40, "Fc": 18}, seed=i, rate_hz=200,
                       noise=Noise(force_N=0.1, displacement_um=0.0), name=f"f{i}").log
        paths.append(write_log(log, tmp_path / f"f{i}.csv")[0])
    return [str(p) for p in paths]


def test_cli_compare_writes_the_winner_and_every_models_estimates(tmp_path, capsys):
    """Issue 17: --compare on friction-only data fits only the compared models (not the
    default --model, which needs bore_mm), writes the winner's fit.json, keeps spec
    arguments (maxwell_slip:3) and every model's parameters and derived values."""
    paths = _friction_only_logs(tmp_path)
    out = tmp_path / "o"
    code = main(["fit", *paths, "--compare", "dahl,maxwell_slip:3", "--out", str(out)])
    printed = capsys.readouterr().out
    assert code == 0, printed
    assert "maxwell_slip:3 " in printed and "fit.json holds the winner" in printed
    data = json.loads((out / "compare.json").read_text())
    assert [r["spec"] for r in data["models"]][0] == "dahl"            # the truth wins
    for row in data["models"]:
        assert row["parameters"] and "breakaway_N" in row["derived"]
    assert {r["spec"] for r in data["models"]} == {"dahl", "maxwell_slip:3"}
    assert json.loads((out / "fit.json").read_text())["model"] == "dahl"
    manifest = json.loads((out / "manifest.json").read_text())
    assert set(manifest["outputs"]) >= {"fit.json", "compare.json"}


def test_cli_compare_checks_every_model_before_any_fit(tmp_path, capsys, monkeypatch):
    """A compared model the logs cannot carry (a chamber without bore_mm) stops the run
    before the first fit, naming that model; nothing is written."""
    import fitstiff.inference.comparison as comparison

    paths = _friction_only_logs(tmp_path)
    calls = []
    monkeypatch.setattr(comparison, "fit", lambda *a, **k: calls.append(a) or 1 / 0)
    out = tmp_path / "o"
    code = main(["fit", *paths, "--compare", "dahl,chamber+dahl", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and not calls
    assert "--compare model 'chamber+dahl'" in err and err.count("\n") == 1
    assert not (out / "compare.json").exists() and not (out / "fit.json").exists()
    code = main(["fit", *paths, "--compare", "dahl", "--fix", "Fc=18", "--out", str(out)])
    assert code == 2 and "--fix with --compare" in capsys.readouterr().err


def test_capped_residual_autocorrelation_is_called_a_misfit_not_a_factor():
    """Issue 17 item 7: a fit that misses a smooth force (here the chamber) has residuals
    whose lag-1 correlation reaches the cap; the warning says the standard errors are a lower
    bound of a misfit, not an AR(1) factor to trust."""
    rig = Rig.from_mapping(paper_rig(start_position_mm=100))
    log = simulate("chamber+dahl", TriangleCycles(rate_mm_s=1.0, amplitudes_mm=(0.5, 2.0)),
                   rig=rig, seed=3, rate_hz=500, noise=Noise(force_N=0.01,
                                                             displacement_um=0.0)).log
    result = fit([log], "dahl")
    assert result.residual_autocorrelation == pytest.approx(0.99)
    text = " ".join(result.warnings)
    assert "slow systematic misfit" in text and "lower bound" in text
    assert "strongly autocorrelated" not in text


def test_fit_json_says_what_pressure_friction_is_relative_to():
    """Issue 17 item 6: beta (1/bar) is relative to p_ref, the mean seal pressure of the logs
    (0.1 bar grid); fit.json records it under settings."""
    logs = []
    for bar in (2.0, 6.0):
        rig = Rig.from_mapping(paper_rig(supply_bar=bar))
        logs.append(simulate("chamber+dahl", TriangleCycles(rate_mm_s=2.0,
                                                            amplitudes_mm=(0.2, 1.0)),
                             rig=rig, seed=int(bar), rate_hz=200, name=f"p{bar:g}").log)
    data = fit(logs, "chamber+dahl+pressure_friction").to_dict()
    assert data["settings"]["pressure_friction"]["p_ref"] == pytest.approx(4e5)
    assert data["parameters"]["beta"]["unit"] == "1/bar"
    assert data["parameters"]["beta"]["value"] == pytest.approx(0.0, abs=0.01)


def test_values_at_a_bound_or_beyond_the_data_are_flagged():
    """Issue 17 item 3: a converged fit whose parameter sits at a bound of its range (here
    the polytropic exponent at 1.0, where the data were made) says so; a breakaway force far
    above every measured force is called an extrapolation. An effect at its null (c = 0) is
    an absent effect, not a warning."""
    from fitstiff.inference.fitting.summary import implausible

    rig = Rig.from_mapping(paper_rig(start_position_mm=100))
    log = simulate("chamber+dahl", TriangleCycles(rate_mm_s=2.0, amplitudes_mm=(0.5, 2.0)),
                   rig=rig, params={"n": 1.0}, seed=3, rate_hz=200,
                   noise=Noise(force_N=0.05)).log
    result = fit([log], "chamber+dahl+viscous")
    text = " ".join(result.warnings)
    assert "n sits at its lower bound (1 -)" in text
    assert "c sits at" not in text
    values = np.asarray([result.value(n) for n in result.problem.par.names])
    largest = float(np.max(np.abs(log.force)))
    said = implausible(result.problem, values, {"breakaway_N": (20 * largest, 1.0)})
    assert any("model's extrapolation" in w for w in said)
    assert not any("extrapolation" in w for w in
                   implausible(result.problem, values, {"breakaway_N": (18.0, 0.1)}))
    # LuGre's static friction below its sliding friction (the real O-ring fit: 0.47 < 6.19 N)
    from fitstiff.inference.problem import Problem

    lugre = Problem([log], "chamber+lugre")
    for fs, flagged in ((9.0, True), (18.0, False)):
        values = np.asarray([{"Fs": fs, "Fc": 18.0}.get(n, 1.0) for n in lugre.par.names])
        said = implausible(lugre, values, {"breakaway_N": (fs, 0.1)})
        assert any("below the sliding friction" in w for w in said) == flagged


def test_fit_json_reads_back_to_the_fitted_theta():
    """Issue 14: the inverse of FitResult.to_dict lives beside it; fit.json's parameters and
    per-log nuisances (a fitted closing pressure included) give the fitted theta back."""
    import json

    from fitstiff.inference.fitting import FitResult

    logs, _, _ = dataset("dahl", 5)
    result = fit(logs[2:], "chamber+dahl", free=["closing_pressure"])
    data = json.loads(json.dumps(result.to_dict()))          # through JSON, as on disk
    theta = FitResult.theta_from_dict(result.problem, data)
    np.testing.assert_allclose(np.asarray(result.problem.physical(theta)),
                               np.asarray(result.problem.physical(result.theta)), rtol=1e-9)
    assert data["per_log"][0]["closing_pressure_bar"] != logs[2].rig.supply_pressure / 1e5


def test_the_memory_lean_path_gives_the_fit_of_the_default_one():
    """A Jacobian beyond LEAN_JACOBIAN_MB switches to the normal-equations solve and the
    column-at-a-time summary (benchmarks/fit_memory.py: 1 M samples in 923 MB); asked for
    on a small joint fit (``solver="lm-normal"``, which takes both lean paths), it lands on
    the same optimum with the same standard errors."""
    logs, _, _ = dataset("dahl", 5)
    default = fit(logs[:2], "chamber+dahl")
    lean = fit(logs[:2], "chamber+dahl", solver="lm-normal")
    assert default.solver == "lm" and lean.solver == "lm-normal"
    assert default.converged and lean.converged
    for name, p in default.parameters().items():
        q = lean.parameters()[name]
        np.testing.assert_allclose(q["value"], p["value"], rtol=1e-5, atol=1e-9, err_msg=name)
        if p["stderr"] is not None:
            np.testing.assert_allclose(q["stderr"], p["stderr"], rtol=1e-3, err_msg=name)
    np.testing.assert_allclose(lean.rms_N, default.rms_N, rtol=1e-7)


def test_the_summary_shares_its_jacobian_with_the_turning_point_columns():
    """The default summary builds C^T = J^T B S from its own J and takes the predicted force
    from the residuals' forward pass; both equal what the lean path computes apart
    (eiv_gram, one JVP and VJP per parameter) and what per_log predicts. Calibration dataset
    0 has AR(1) displacement noise: its turning points' errors are not zero."""
    from fitstiff._testing.calibration import dataset as calibration_dataset
    from fitstiff.inference import fitting
    from fitstiff.inference.fitting import summary as fitting_summary
    from fitstiff.inference.problem import Problem

    logs, _ = calibration_dataset(0)
    problem = Problem(logs[:2], "chamber+dahl")
    theta = problem.pack(*fitting.initial_guess(problem))
    spans = tuple(tuple((s.span.start, s.span.stop) for s in problem.residual_series()
                        if s.log == i) for i in range(problem.n_logs))
    evaluate = fitting_summary.summary_evaluate
    shared = problem.compiled(evaluate, spans=spans, sequential=False)(theta)
    apart = problem.compiled(evaluate, spans=spans, sequential=True)(theta)
    assert apart.eiv_gram is None
    gram = np.asarray(problem.compiled(fitting_summary.errors_in_variables_gram)(theta))
    assert np.abs(gram).max() > 0
    np.testing.assert_allclose(np.asarray(shared.eiv_gram), gram, rtol=1e-10,
                               atol=1e-12 * np.abs(gram).max())
    per_log = problem.per_log(theta)
    for summary in (shared, apart):
        np.testing.assert_allclose(float(summary.cost), float(apart.cost), rtol=1e-12)
        for force, pred in zip(problem.unpad(summary.force), per_log):
            np.testing.assert_array_equal(force, pred["force"])


def test_fit_json_reports_the_marginal_displacement_noise_of_correlated_noise():
    """Calibration dataset 0: 1 um of AR(1) displacement noise with lag-1 correlation 0.73.
    Read as white noise its level looks like 0.46 um; fit.json reports the marginal level and
    the correlation (the turning points' errors use both)."""
    from fitstiff._testing.calibration import dataset as calibration_dataset

    logs, truth = calibration_dataset(0)
    result = fit(logs, "chamber+dahl")
    for entry in result.to_dict()["per_log"]:
        assert entry["displacement_noise_um"] == pytest.approx(1.0, rel=0.25)
        assert entry["displacement_noise_rho"] == pytest.approx(truth["ar1"], abs=0.15)


def test_fit_speed_benchmark_runs_small(tmp_path):
    """benchmarks/fit_speed.py once each (a warm fit, a reference fit, a cold and a second
    CLI fit): both fits find the same seal, and its targets are the ratios it states."""
    out = tmp_path / "fs.json"
    run_benchmark("fit_speed.py", "--repeats", "1", "--cold-runs", "1", "--json", out)
    r = json.loads(out.read_text())
    assert r["fitstiff_converged"] and len(r["cold_cli_runs_s"]) == 1
    assert r["sigma0_fitstiff_N_per_mm"] == pytest.approx(r["sigma0_reference_N_per_mm"],
                                                          rel=1e-5)
    assert r["Fc_fitstiff_N"] == pytest.approx(r["Fc_reference_N"], rel=1e-5)
    # the stored run that docs/benchmarks.md quotes (sigma0 = 39.977 N/mm, Fc = 18.0084 N)
    # found what this code finds
    stored = json.loads((REPO / "benchmarks" / "results" / "fit_speed.json").read_text())
    for key in ("sigma0_fitstiff_N_per_mm", "Fc_fitstiff_N", "sigma0_reference_N_per_mm",
                "Fc_reference_N"):
        assert r[key] == pytest.approx(stored[key], rel=1e-6), key
    t = r["targets"]
    assert r["cold_cli_in_reference_fits"] == pytest.approx(r["cold_cli_s"]
                                                            / r["reference_fit_s"])
    assert t["cold_met"] == (r["cold_cli_in_reference_fits"]
                             <= t["cold_in_reference_fits_at_most"])
    assert t["warm_met"] == (r["speedup_warm_vs_reference"] >= t["warm_speedup_at_least"])
    assert t["cold_in_reference_fits_at_most"] == pytest.approx(6.0 / 0.140)


def test_held_out_near_ties_go_to_the_identifiable_model_then_bic():
    """Issue 31: on the demo's logs LuGre led Dahl held out by 0.0004 N (noise 0.2 N) with
    `identifiable: NO`; a near-tie (within 1 % of the noise) goes to the identifiable model,
    then to BIC; a clear held-out lead wins whatever else."""
    from fitstiff.inference.comparison import rank_held_out

    held, bic = [0.2008, 0.2004, 0.2300], [422.2, 426.9, 400.0]
    assert rank_held_out(held, bic, [True, False, True], tie=0.002) == [0, 1, 2]
    assert rank_held_out(held, bic, [True, True, True], tie=0.002) == [0, 1, 2]
    assert rank_held_out(held, [430.0, 426.9, 400.0], [True, True, True], tie=0.002) == [1, 0, 2]
    # a clear lead of an unidentifiable model stands
    assert rank_held_out([0.25, 0.20], [1.0, 2.0], [True, False], tie=0.002) == [1, 0]


def test_the_table_states_the_reference_pressure_of_pressure_friction():
    """Issue 31: Fc with pressure_friction is the level at p_ref, printed nowhere before."""
    rig = Rig.from_mapping(paper_rig(supply_bar=4))
    logs = [simulate("dahl", TriangleCycles(rate_mm_s=5.0, amplitudes_mm=(0.5, 1.0)),
                     rig=dataclasses.replace(rig, supply_pressure=bar * 1e5), seed=i,
                     rate_hz=500, noise=Noise(force_N=0.1, displacement_um=0.0)).log
            for i, bar in enumerate((2.0, 6.0))]
    result = fit(logs, "dahl+pressure_friction")
    assert "p_ref = 4 bar gauge" in result.table()
    assert result.to_dict()["settings"]["pressure_friction"]["p_ref"] == pytest.approx(4e5)


@pytest.mark.slow
def test_fit_memory_benchmark_runs_small(tmp_path):
    """benchmarks/fit_memory.py --samples (issue 36's long-log run), small: inspect and both
    fits finish, their peaks are measured, the wall ratio is the long fit's over the
    reference's, and both fits find the simulated seal."""
    out = tmp_path / "fm.json"
    run_benchmark("fit_memory.py", "--samples", "150000", "--reference", "74000",
                  "--timeout", "600", "--json", out)
    r = json.loads(out.read_text())
    assert r["inspect"]["returncode"] == 0 and r["inspect"]["peak_rss_mb"] > 0
    for key in ("reference_fit", "long_fit"):
        fit = r[key]
        assert fit["returncode"] == 0 and fit["converged"], key
        assert fit["peak_rss_mb"] >= fit["stage_peaks_mb"]["import"] > 0
        assert fit["sigma0_N_per_mm"]["value"] == pytest.approx(40, rel=0.01)
        assert fit["Fc_N"]["value"] == pytest.approx(18, rel=0.01)
    assert r["long_fit"]["samples"] == 2 * r["reference_fit"]["samples"] - 1   # 2 cycles, 1
    assert r["fit_wall_ratio"] == pytest.approx(r["long_fit"]["wall_s"]
                                                / r["reference_fit"]["wall_s"])
