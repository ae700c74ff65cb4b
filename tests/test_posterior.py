"""Posterior: analytic moments, exact likelihoods, priors, recovery, calibration machinery,
kill-and-resume, the CLI contract."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import warnings

import numpy as np
import pytest
from conftest import REPO, polyline, run_benchmark

from fitstiff.cli import main
from fitstiff.data import paper_rig
from fitstiff.errors import InputError
from fitstiff.inference.likelihood import (AR1, Gaussian, Layout, LinearNuisances, StudentT,
                                           TurningPoints)
from fitstiff.inference.posterior import sample_posterior
from fitstiff.inference.posterior.chain import ChainBackend, ChainStore
from fitstiff.inference.priors import Priors
from fitstiff.inference.problem import Problem, ResidualSeries
from fitstiff.io.loading import load_log
from fitstiff.io.log import Log
from fitstiff.physics.simulate import write_log

FIG4 = REPO / "data" / "synthetic" / "fig4" / "p6bar_x350mm.csv"


# -- exact likelihoods ------------------------------------------------------------------------
def _layout(mask):
    n = len(mask)
    return Layout.from_series([ResidualSeries(0, "force", slice(0, n), np.asarray(mask))],
                              ["force[x]"])


def test_ar1_likelihood_is_the_exact_gaussian_one():
    """-(n/2) log Q with Q = r' C^-1 r, C the stationary AR(1) covariance (unit innovations),
    is the exact likelihood with the scale integrated out; padding is not data."""
    rng = np.random.default_rng(0)
    phi, n = 0.7, 60
    r = rng.standard_normal(n)
    cov = phi ** np.abs(np.subtract.outer(np.arange(n), np.arange(n))) / (1 - phi**2)
    q = r @ np.linalg.solve(cov, r)
    padded = np.concatenate([r, np.zeros(7)])
    layout = _layout(np.arange(n + 7) < n)
    ll = float(AR1(phi=(phi,)).log_likelihood(padded, layout))
    assert ll == pytest.approx(-0.5 * n * np.log(q), rel=1e-12)
    # the estimate of phi from the residuals: lag-1 regression over consecutive data
    e = np.zeros(20000)
    for k in range(1, e.size):
        e[k] = 0.6 * e[k - 1] + rng.standard_normal()
    assert AR1().prepared(e, _layout(np.ones(e.size, bool))).phi[0] == pytest.approx(0.6, abs=0.02)


def test_turning_point_errors_are_integrated_out_exactly():
    """With columns U of displacement errors at the turning points, the sum of squares is
    r' (C + U U' / s^2)^-1 r (Woodbury), s the noise scale at the optimum; a known sigma gives
    the Gaussian with covariance sigma^2 I + U U'."""
    rng = np.random.default_rng(2)
    n, phi = 50, 0.5
    layout = _layout(np.ones(n, bool))
    u = 0.3 * rng.standard_normal((n, 2))
    turning = TurningPoints(u, np.zeros(2, dtype=int))
    r_hat, r = rng.standard_normal(n), rng.standard_normal(n)
    model = AR1(phi=(phi,)).prepared(r_hat, layout, turning_points=turning)
    innovations = np.concatenate([[np.sqrt(1 - phi**2) * r_hat[0]], r_hat[1:] - phi * r_hat[:-1]])
    s2 = innovations @ innovations / n
    corr = phi ** np.abs(np.subtract.outer(np.arange(n), np.arange(n))) / (1 - phi**2)
    q = r @ np.linalg.solve(corr + u @ u.T / s2, r)
    assert float(model.log_likelihood(r, layout)) == pytest.approx(-0.5 * n * np.log(q), rel=1e-12)
    known = Gaussian(sigma=2.0).prepared(r_hat, layout, turning_points=turning)
    q = r @ np.linalg.solve(4.0 * np.eye(n) + u @ u.T, r)
    assert float(known.log_likelihood(r, layout)) == pytest.approx(-0.5 * q, rel=1e-12)


def test_offsets_are_integrated_out_exactly_under_flat_priors():
    """A column g with a flat prior (a force offset) next to turning-point columns U: the
    marginal over the offset and the scale is -((n - 1)/2) log Q, Q = r'S^-1 r -
    (g'S^-1 r)^2 / (g'S^-1 g) with S = C + U U'/s^2 (the generalised least-squares residual);
    Student-t noise refuses (no closed form)."""
    rng = np.random.default_rng(3)
    n, phi = 40, 0.6
    layout = _layout(np.ones(n, bool))
    u = 0.3 * rng.standard_normal((n, 2))
    g = np.ones((n, 1)) * 0.5                        # d r / d offset (the force weight)
    turning = TurningPoints(u, np.zeros(2, dtype=int))
    linear = LinearNuisances(g, np.zeros(1, dtype=int), np.array([7]))
    r_hat, r = rng.standard_normal(n), rng.standard_normal(n) + 3.0
    model = AR1(phi=(phi,)).prepared(r_hat, layout, turning_points=turning, linear=linear)
    innovations = np.concatenate([[np.sqrt(1 - phi**2) * r_hat[0]], r_hat[1:] - phi * r_hat[:-1]])
    s2 = innovations @ innovations / n
    corr = phi ** np.abs(np.subtract.outer(np.arange(n), np.arange(n))) / (1 - phi**2)
    inv = np.linalg.inv(corr + u @ u.T / s2)
    q = r @ inv @ r - (g[:, 0] @ inv @ r) ** 2 / (g[:, 0] @ inv @ g[:, 0])
    assert float(model.log_likelihood(r, layout)) == pytest.approx(-0.5 * (n - 1) * np.log(q),
                                                                   rel=1e-12)
    assert model.dof(layout).tolist() == [n - 1]
    # the same value with the statistics the conditional draws need
    ll, statistics = model.solved_likelihood(r, layout)
    assert float(ll) == pytest.approx(-0.5 * (n - 1) * np.log(q), rel=1e-12)
    assert float(statistics[1]) == pytest.approx(q, rel=1e-12)
    # the conditional draw with zero deviates (and chi2 = q, so s = 1) is the GLS offset
    # correction; unit deviates give the columns of the Cholesky root of its covariance
    # 1 / (g'S^-1 g)
    best = -(g[:, 0] @ inv @ r) / (g[:, 0] @ inv @ g[:, 0])
    rows = np.repeat(np.asarray(statistics)[None], 4, axis=0)
    deviates = np.vstack([np.zeros(3), np.eye(3)])
    draws = model.linear_draws(rows, deviates, np.full((4, 1), q))[:, 0]
    assert draws[0] == pytest.approx(best, rel=1e-9)
    assert np.sum((draws[1:] - best) ** 2) == pytest.approx(1 / (g[:, 0] @ inv @ g[:, 0]),
                                                            rel=1e-9)
    with pytest.raises(ValueError, match="cannot integrate"):
        StudentT(nu=4).prepared(r_hat, layout, linear=linear)


def test_student_t_scale_is_estimated_robustly():
    rng = np.random.default_rng(1)
    r = 2.5 * rng.standard_t(4, size=20000)
    r[:200] = 1e3                                      # gross outliers
    scale = StudentT(nu=4).prepared(r, _layout(np.ones(r.size, bool))).scale[0]
    assert scale == pytest.approx(2.5, rel=0.05)


# -- the analytic posterior -------------------------------------------------------------------
def _linear_log(force=None):
    t, x = polyline([0, 2e-3, -1e-3, 1.5e-3, -2e-3, 0.0], rate=2e-3, fs=100.0)
    return Log("lin", displacement=x, force=np.zeros_like(x) if force is None else force,
               time=t)


@pytest.mark.parametrize("integrate", [True, False], ids=["offset-integrated", "offset-sampled"])
def test_linear_model_posterior_matches_the_analytic_one(integrate):
    """force = c v + drift t + offset + white noise; flat priors on (c, drift, offset) and the
    Gaussian noise scale integrated out (Jeffreys): the posterior is a multivariate t with
    n - 3 degrees of freedom about the OLS estimate, scale s^2 (X'X)^-1. c goes through the
    log transform: its mean is off by ~0.2 sd unless the log-Jacobian is right."""
    template = Problem([_linear_log()], "viscous+force_drift", denoise=False)

    def design(c, drift):
        model = template.par.with_values(template.model, {"c": c, "drift": drift})
        return template.per_log(template.pack(model))[0]["force"]

    v_col = design(1.0, 0.0)
    x_mat = np.column_stack([v_col, design(1.0, 1.0) - v_col, np.ones_like(v_col)])
    rng = np.random.default_rng(5)
    truth = np.array([25.0, 0.02, 0.3])
    y = x_mat @ truth + 0.2 * rng.standard_normal(v_col.size)
    beta, rss, *_ = np.linalg.lstsq(x_mat, y, rcond=None)
    nu = y.size - 3
    cov = nu / (nu - 2) * rss[0] / nu * np.linalg.inv(x_mat.T @ x_mat)
    sd = np.sqrt(np.diag(cov))
    assert 3.5 < beta[0] / sd[0] < 8     # c > 0 barely truncates; a missing Jacobian: -0.25 sd

    post = sample_posterior([_linear_log(y)], "viscous+force_drift",
                            fit_options={"denoise": False}, noise_model=Gaussian(),
                            priors={"c": {"dist": "flat"}}, walkers=32, steps=3000,
                            check_every=1000, seed=2, progress=False, draws=10,
                            integrate_offsets=integrate)
    samples = post.samples.reshape(-1, 3)
    assert post.names == ("c", "drift", "offset[lin]")
    assert post.diagnostics.integrated == (("offset[lin]",) if integrate else ())
    np.testing.assert_array_less(np.abs(samples.mean(0) - beta), 0.05 * sd)
    np.testing.assert_allclose(samples.std(0), sd, rtol=0.05)
    corr = np.corrcoef(samples.T)[0, 1]
    assert corr == pytest.approx(cov[0, 1] / (sd[0] * sd[1]), abs=0.05)


# -- priors -------------------------------------------------------------------------------------
def test_default_priors_and_overrides(tmp_path):
    problem = Problem([_linear_log()], "viscous+force_drift", denoise=False)
    priors = Priors(problem)
    assert priors.to_dict()["c"] == {"dist": "log_normal", "median": 50.0,
                                     "sd_log": pytest.approx(np.log(10)), "unit": "N s/m"}
    assert priors.to_dict()["drift"]["dist"] == "flat"
    assert priors.to_dict()["offset[lin]"]["dist"] == "flat"
    normal = Priors(problem, {"c": {"dist": "normal", "mean": 40, "sd": 10, "unit": "N s/m"}})
    x = np.array([60.0, 0.0, 0.0])
    assert float(normal.log_density(x)) == pytest.approx(-0.5 * 2.0**2)
    bounded = Priors(problem, {"offset": {"dist": "uniform", "lower": -1, "upper": 1}})
    assert float(bounded.log_density(np.array([60.0, 0.0, 2.0]))) == -np.inf


@pytest.mark.parametrize("content, fragment", [
    ({"sigma9": {"dist": "flat"}}, "prior 'sigma9': names no sampled parameter; use one of: c,"),
    ({"c": {"dist": "normal", "mean": 40, "sd": 10, "unit": "N/mm"}},
     "unit 'N/mm' differs from the parameter's display unit 'N s/m'; write the values in N s/m"),
    ({"c": {"dist": "gamma"}}, "unknown dist 'gamma'; use one of: flat, uniform"),
    ({"c": {"dist": "normal", "mean": 40}}, "missing sd; 'normal' takes mean, sd"),
    ({"c": {"dist": "uniform", "lower": 5, "upper": 1}}, "needs lower < upper"),
])
def test_bad_priors_name_the_file_and_fix(tmp_path, content, fragment):
    path = tmp_path / "priors.json"
    path.write_text(json.dumps(content))
    problem = Problem([_linear_log()], "viscous+force_drift", denoise=False)
    with pytest.raises(ValueError) as info:
        Priors(problem, path)
    assert str(info.value).startswith(str(path))
    assert fragment in str(info.value)


# -- recovery and the CLI contract ---------------------------------------------------------------
def test_cli_posterior_contains_truth_and_writes_every_file(tmp_path, capsys):
    """Synthetic chamber+dahl log (fig4, 6 bar): the 90 % intervals of slope and breakaway
    contain the truth; posterior.json follows DESIGN §5; InferenceData and draws are readable."""
    import arviz as az

    out = tmp_path / "post"
    before = FIG4.read_bytes()
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)     # e.g. ArviZ's "more chains than draws"
        code = main(["posterior", str(FIG4), "--model", "chamber+dahl", "--walkers", "12",
                     "--steps", "1500", "--tau-multiple", "20", "--seed", "4", "--out", str(out)])
    assert code == 0
    assert FIG4.read_bytes() == before
    truth = json.loads(FIG4.with_suffix("").with_suffix(".truth.json").read_text())["derived"]
    post = json.loads((out / "posterior.json").read_text())
    assert post["model"] == "chamber+dahl"
    for key in ("presliding_slope_N_per_mm", "breakaway_N"):
        s = post["derived"][key]
        assert set(s) == {"q05", "q50", "q95", "mean", "std", "unit"}
        assert s["q05"] <= truth[key] <= s["q95"], (key, s, truth[key])
    assert post["parameters"]["sigma0"]["unit"] == "N/mm"
    fit = post["fit"]                     # the least-squares start, in fit.json's units
    assert set(fit) == {"converged", "rms_N", "parameters", "derived"}
    assert fit["parameters"]["sigma0"]["unit"] == "N/mm"
    assert fit["parameters"]["sigma0"]["value"] == pytest.approx(
        post["parameters"]["sigma0"]["q50"], rel=0.05)
    diag = post["diagnostics"]
    assert {"acceptance_fraction", "autocorr_time", "effective_samples", "converged", "reason",
            "steps", "walkers", "noise_model"} <= set(diag)
    assert diag["noise_model"] == "ar1" and diag["walkers"] == 12
    # the force offset is integrated out analytically: no chain, no autocorrelation time
    assert set(diag["autocorr_time"]) == {"n", "sigma0", "Fc", "friction_state0[p6bar_x350mm]"}
    assert diag["integrated"] == ["offset[p6bar_x350mm]"] and diag["moves"] == "de"
    assert post["nuisances"]["offset[p6bar_x350mm]"]["std"] > 0
    assert isinstance(diag["converged"], bool) and diag["reason"]
    assert post["files"] == [str(FIG4)]
    idata = az.from_netcdf(out / "posterior.nc")
    assert idata.posterior["sigma0"].shape[0] == 12
    assert idata.posterior["sigma0"].attrs["unit"] == "N/mm"
    assert float(idata.posterior["breakaway_N"].median()) == pytest.approx(
        post["derived"]["breakaway_N"]["q50"], rel=1e-3)
    draws = np.load(out / "predictive.npz")
    curves = draws["log0_model_force_draws_N"]
    assert curves.shape == (200, draws["log0_force_N"].size)
    rms = np.sqrt(np.mean((np.median(curves, 0) - draws["log0_force_N"]) ** 2))
    assert rms == pytest.approx(float(draws["log0_noise_sd_N"]), rel=0.2)
    # every sample: the median and spread of the draws (the report's curve and band)
    median, spread = draws["log0_model_force_median_N"], draws["log0_model_force_spread_N"]
    assert median.shape == spread.shape == (len(load_log(FIG4)),)
    thinned = median[::-(-len(median) // 2000)]           # the draws' thinning: ceil(n / 2000)
    assert thinned.shape == (curves.shape[1],)
    np.testing.assert_allclose(thinned, np.median(curves.astype(float), 0), atol=1e-3)
    assert np.all(spread >= 0) and 0 < np.median(spread) < float(draws["log0_noise_sd_N"])
    manifest = json.loads((out / "manifest.json").read_text())
    assert set(manifest["outputs"]) == {"chain.h5", "posterior.nc", "predictive.npz",
                                        "posterior.json"}
    assert not list(out.glob(".*partial*"))
    assert ChainBackend(out / "chain.h5", read_only=True).get_chain().shape == (
        diag["steps"], 12, 4)


def test_posterior_json_reads_back_to_the_same_content():
    """Issue 14: Posterior.from_dict, beside to_dict, reads posterior.json back as a typed
    record (summaries, diagnostics, noise model; the samples stay in chain.h5) that writes the
    same content again; with and without the least-squares start (a resumed run has none), and
    a file from before integrated offsets (no ``integrated``, ``moves``)."""
    import dataclasses

    from fitstiff.inference.posterior import Posterior

    rng = np.random.default_rng(1)
    log = _linear_log()
    force = 15.0 * np.gradient(log.displacement, log.time) + 0.2 * rng.standard_normal(len(log))
    post = sample_posterior([Log("lin", log.displacement, force, log.time)],
                            "viscous+force_drift", fix={"drift": 0.0},
                            fit_options={"denoise": False}, noise_model=Gaussian(), walkers=8,
                            steps=200, check_every=100, seed=1, progress=False, draws=5)
    data = json.loads(json.dumps(post.to_dict()))        # through JSON, as on disk
    record = Posterior.from_dict(data)
    assert record.to_dict() == data
    assert record.names == post.names == ("c", "offset[lin]")
    assert record.free_parameters == ("c",) and record.parameters["drift"]["fixed"]
    assert record.diagnostics.integrated == ("offset[lin]",) == post.diagnostics.integrated
    assert record.diagnostics.steps == 200 and record.diagnostics.walkers == 8
    assert isinstance(record.noise, Gaussian) and record.fit["converged"] in (True, False)
    sd, unit = record.noise_scale["force[lin]"]
    assert unit == "N" and sd == pytest.approx(post.noise_scale["force[lin]"][0], rel=1e-12)
    resumed = dataclasses.replace(record, fit=None, identifiable=None,
                                  identifiable_reason=None, identifiability=None)
    assert "fit" not in resumed.to_dict() and "identifiable" not in resumed.to_dict()
    assert Posterior.from_dict(resumed.to_dict()).to_dict() == resumed.to_dict()
    for key in ("integrated", "moves"):
        del data["diagnostics"][key]
    older = Posterior.from_dict(data).diagnostics
    assert older.integrated == () and older.moves == "stretch"


@pytest.mark.parametrize("argv, fragment", [
    (["--walkers", "4"], "--walkers 4: fewer than twice the 4 sampled coordinates"),
    (["--walkers", "8", "--sample-offsets"],
     "--walkers 8: fewer than twice the 5 sampled coordinates"),
    (["--resume"], "holds no chain.h5 to continue; run without --resume first"),
    (["--priors", "missing.json"], "missing.json: --priors: cannot be read"),
    (["--steps", "0"], "--steps 0: must be at least 1"),
])
def test_cli_bad_options_exit_2_with_one_line(tmp_path, capsys, argv, fragment):
    code = main(["posterior", str(FIG4), "--out", str(tmp_path / "o")] + argv)
    err = capsys.readouterr().err
    assert code == 2
    assert fragment in err and err.count("\n") == 1


# -- kill and resume -------------------------------------------------------------------------
def _chain(path):
    stored = ChainStore(path, read_only=True).read()
    return stored.chain, stored.log_prob


def test_killed_run_resumes_to_the_uninterrupted_chain(tmp_path):
    """SIGTERM mid-run keeps the chain; --resume continues it from the stored random state,
    ending with exactly the chain of an uninterrupted run."""
    rng = np.random.default_rng(3)
    log = _linear_log()
    force = 15.0 * np.gradient(log.displacement, log.time) + 0.2 * rng.standard_normal(len(log))
    csv = write_log(Log("lin", log.displacement, force, log.time), tmp_path / "lin.csv")[0]
    # long enough that the run is still sampling when the kill arrives (at 4 000 steps a
    # fast run on a busy machine sometimes finished first)
    argv = ["posterior", str(csv), "--model", "viscous", "--denoise", "off", "--walkers", "8",
            "--steps", "12000", "--tau-multiple", "1000", "--check-every", "1000",
            "--noise-model", "gaussian", "--seed", "9", "--draws", "5"]
    killed = tmp_path / "killed"
    env = dict(os.environ, FITSTIFF_CACHE_DIR="", HDF5_USE_FILE_LOCKING="FALSE",
               PYTHONPATH=str(REPO))
    proc = subprocess.Popen([sys.executable, "-m", "fitstiff"] + argv + ["--out", str(killed)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    partial = killed / ".chain.h5.partial.h5"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            if ChainBackend(partial, read_only=True).iteration > 0:
                break
        except (OSError, KeyError):
            pass
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err.decode()           # the shell's code of SIGTERM
    assert err.decode().splitlines() == [
        f"fitstiff posterior: interrupted by SIGTERM; the chain so far is kept in {partial}; "
        "continue it with --resume"]                        # one line, no traceback
    stopped_at = len(_chain(partial)[0])
    assert 0 < stopped_at < 12000

    assert main(argv + ["--out", str(killed), "--resume"]) == 0
    straight = tmp_path / "straight"
    assert main(argv + ["--out", str(straight)]) == 0
    resumed_chain, resumed_lp = _chain(killed / "chain.h5")
    chain, lp = _chain(straight / "chain.h5")
    assert resumed_chain.shape == chain.shape and chain.shape[0] > stopped_at
    np.testing.assert_array_equal(resumed_chain, chain)
    np.testing.assert_array_equal(resumed_lp, lp)
    a = json.loads((killed / "posterior.json").read_text())
    b = json.loads((straight / "posterior.json").read_text())
    assert a["parameters"] == b["parameters"]
    # a chain sampled under other options is not continued, and is left in place
    code = main(argv + ["--model", "viscous+force_drift", "--out", str(killed), "--resume"])
    assert code == 2
    np.testing.assert_array_equal(_chain(killed / "chain.h5")[0], chain)


def test_an_interrupt_dropped_by_python_still_stops_the_run(tmp_path):
    """A signal's KeyboardInterrupt raised inside a garbage-collection callback (JAX has one)
    is dropped by Python: the command line's handler records it and the sampler asks after
    every step, so the run stops there with the chain kept (a kill was once ignored so)."""
    import gc

    from fitstiff.interrupts import Signals, pending

    with Signals():
        handler = signal.getsignal(signal.SIGTERM)

        def collecting(phase, info):
            if phase == "start":
                handler(signal.SIGTERM, None)            # the handler, as the signal runs it

        gc.callbacks.append(collecting)
        try:
            gc.collect()                             # the exception is lost, and not reported
        finally:
            gc.callbacks.remove(collecting)
        assert pending() == signal.SIGTERM
    assert pending() is None
    assert signal.getsignal(signal.SIGTERM) is not handler         # handlers restored

    rng = np.random.default_rng(1)
    log = _linear_log()
    force = 15.0 * np.gradient(log.displacement, log.time) + 0.2 * rng.standard_normal(len(log))
    asked = []
    chain = tmp_path / "chain.h5"
    with pytest.raises(KeyboardInterrupt):
        sample_posterior([Log("lin", log.displacement, force, log.time)], "viscous",
                         fit_options={"denoise": False}, noise_model=Gaussian(), walkers=8,
                         steps=200, check_every=100, seed=1, progress=False, backend=chain,
                         interrupted=lambda: asked.append(1) or len(asked) >= 7)
    stored = ChainStore(chain, read_only=True).read()
    assert stored.chain.shape == (7, 8, 1)                 # the seventh step, then stopped
    assert ChainBackend(chain, read_only=True).get_blobs().shape[:2] == (7, 8)


def test_chain_file_is_an_emcee_backend_and_older_files_still_read(tmp_path):
    """Issue 14: the chain is stored through emcee's backend interface (ChainBackend), in
    fitstiff's own layout, whatever the batching: a sampler writing through it gives emcee's
    in-memory chain, accepted counts and random state. A file of an older fitstiff (emcee's
    HDFBackend layout) is still read, and not continued."""
    import emcee

    def sampler(backend=None):
        out = emcee.EnsembleSampler(8, 2, lambda x: -0.5 * np.sum(x**2, axis=-1),
                                    vectorize=True, backend=backend)
        out.random_state = np.random.RandomState(1).get_state()
        return out

    start = np.random.default_rng(0).standard_normal((8, 2))
    memory = sampler()
    memory.run_mcmc(start, 60, progress=False)
    backend = ChainBackend(tmp_path / "chain.h5")
    backend.flush_seconds = 0.0                     # a batch every step
    backend.reset(8, 2)
    sampler(backend).run_mcmc(start, 60, progress=False)
    reread = ChainBackend(tmp_path / "chain.h5", read_only=True)
    assert reread.iteration == 60 and reread.shape == (8, 2)
    np.testing.assert_array_equal(reread.get_chain(), memory.get_chain())
    np.testing.assert_array_equal(reread.get_log_prob(thin=3), memory.get_log_prob(thin=3))
    np.testing.assert_array_equal(reread.accepted, memory.backend.accepted)
    assert all(np.array_equal(a, b) for a, b in zip(reread.random_state,
                                                    memory.random_state))
    with pytest.raises(RuntimeError, match="read-only"):
        reread.reset(8, 2)

    # blobs (the statistics of the integrated offsets) round-trip with the chain
    def with_blobs(x):
        return np.column_stack([-0.5 * np.sum(x**2, axis=-1), x**2, np.sum(x, axis=-1)])

    def blob_sampler(backend=None):
        out = emcee.EnsembleSampler(8, 2, with_blobs, vectorize=True, backend=backend)
        out.random_state = np.random.RandomState(1).get_state()
        return out

    memory = blob_sampler()
    memory.run_mcmc(start, 40, progress=False)
    blobbed = ChainBackend(tmp_path / "blobs.h5")
    blobbed.flush_seconds = 0.0
    blobbed.reset(8, 2)
    blob_sampler(blobbed).run_mcmc(start, 25, progress=False)
    again = ChainBackend(tmp_path / "blobs.h5")                 # a resumed run
    blob_sampler(again).run_mcmc(None, 15, progress=False)
    again.flush()
    reread = ChainBackend(tmp_path / "blobs.h5", read_only=True)
    assert reread.has_blobs() and reread.get_blobs().shape == (40, 8, 3)
    np.testing.assert_array_equal(reread.get_chain(), memory.get_chain())
    np.testing.assert_array_equal(reread.get_blobs(thin=4, discard=3),
                                  memory.get_blobs(thin=4, discard=3))
    with pytest.raises(ValueError, match="have no blobs"):       # steps without, then with
        ChainBackend(tmp_path / "chain.h5").grow(2, np.zeros((8, 3)))
    with pytest.raises(ValueError, match="the new steps none"):
        ChainBackend(tmp_path / "blobs.h5").grow(2, None)
    # a chain with integrated offsets but no blobs (an older fitstiff) is not continued
    store = ChainStore(tmp_path / "chain.h5")
    store.write_settings({"integrated": ["offset[a]"]}, settings=Gaussian(),
                         theta_start=np.zeros(2))
    with pytest.raises(InputError, match="without the statistics"):
        store.resume({"integrated": ["offset[a]"]})

    older = tmp_path / "older.h5"
    emcee_file = emcee.backends.HDFBackend(str(older))
    emcee_file.reset(8, 2)
    sampler(emcee_file).run_mcmc(start, 20, progress=False)
    ChainStore(older).write_settings({"model": "x"}, settings=Gaussian(),
                                     theta_start=np.zeros(2))
    read = ChainStore(older, read_only=True).read()
    np.testing.assert_array_equal(read.chain, memory.get_chain()[:20])
    assert read.kept is None and read.theta_start.shape == (2,)
    with pytest.raises(InputError, match="written by an older fitstiff"):
        ChainStore(older).resume({"model": "x"})


# -- calibration machinery --------------------------------------------------------------------
def test_calibration_benchmark_runs_small():
    """The calibration machinery on three datasets (the coverage itself needs >= 50: see
    benchmarks/calibration.py)."""
    from fitstiff._testing import calibration

    rows = [calibration.score(seed, noise_models=("ar1",), walkers=16, steps=100,
                              tau_multiple=50) for seed in range(3)]
    for row in rows:
        entry = row["ar1"]
        assert not entry["converged"] and entry["steps"] == 100
        for key in calibration.QUANTITIES:
            q = entry[key]
            assert q["q05"] < q["q50"] < q["q95"]
            assert abs(q["q50"] / row["truth"][key] - 1) < 0.02
    p, se = calibration.coverage(rows, "ar1", "breakaway_N")
    assert 0 <= p <= 1 and se >= 0


def test_default_posterior_benchmark_runs_small(tmp_path):
    """benchmarks/posterior_default.py on logs 20 x shorter, without the reference: the CLI
    with default sampler options converges and the summary has what the README quotes."""
    out = tmp_path / "pd.json"
    run_benchmark("posterior_default.py", "--scale", "0.05", "--no-reference", "--json", out)
    result = json.loads(out.read_text())
    d = result["default"]
    assert result["logs"] == 4 and 1500 < result["samples"] < 2000
    assert d["converged"] and d["moves"] == "de" and len(d["integrated"]) == 4
    assert d["tau_max"] > 0 and d["wall_s"] > 0 and d["peak_rss_mb"] > 0


# -- the speed benchmark's reference ----------------------------------------------------------
def test_speed_benchmark_reference_is_the_same_log_posterior():
    """benchmarks/posterior_speed.py compares against a NumPy log-posterior; it must be the
    same function (up to one constant), or the speed-up means nothing."""
    from fitstiff._testing.speed import make_log, reference_log_posterior
    from fitstiff.inference.fitting import fit_problem
    from fitstiff.inference.posterior import log_posterior

    problem = Problem([make_log()], "chamber+dahl")
    fit = fit_problem(problem)
    lp = log_posterior(fit, batch=4)
    assert lp.noise.marginal is not None          # turning points are part of both
    coords = fit.theta + 0.05 * np.random.default_rng(1).standard_normal((4, problem.size))
    jax_values = np.asarray(lp(coords))
    assert np.ptp(jax_values) > 1.0               # the points are far enough apart to tell
    ref = np.array([reference_log_posterior(c, problem, lp.noise) for c in coords])
    assert np.ptp(ref - jax_values) < 1e-3


def test_posterior_that_contradicts_least_squares_says_the_model_is_wrong():
    """Issue 17 item 1: a converged posterior whose median sits far from the least-squares
    value (the real O-ring logs with chamber+dahl: breakaway 4.51 N against 6.17 +- 0.11 N)
    says that the model does not describe the logs and points to fitstiff diagnose; on data
    the model describes (a Dahl log fitted with dahl), nothing is said."""
    import types

    from fitstiff.inference.fitting import fit
    from fitstiff.inference.posterior.sampler import disagreements
    from fitstiff.io.log import Rig
    from fitstiff.physics.programs import TriangleCycles
    from fitstiff.physics.simulate import Noise, simulate

    rng = np.random.default_rng(0)
    derived = {"presliding_slope_N_per_mm": 13.8 + 0.27 * rng.standard_normal((50, 8)),
               "breakaway_N": 4.51 + 0.04 * rng.standard_normal((50, 8))}
    misfit = types.SimpleNamespace(derived={"presliding_slope_N_per_mm": (32.8, 6.5),
                                            "breakaway_N": (6.17, 0.11)})
    said = disagreements(misfit, derived, "ar1")
    assert len(said) == 1 and "breakaway_N" in said[0] and "fitstiff diagnose" in said[0]
    agree = types.SimpleNamespace(derived={"presliding_slope_N_per_mm": (13.9, 0.3),
                                           "breakaway_N": (4.52, 0.05)})
    assert disagreements(agree, derived, "ar1") == []

    rig = Rig.from_mapping(paper_rig())
    log = simulate("dahl", TriangleCycles(rate_mm_s=2.0, amplitudes_mm=(0.2, 0.5, 1.0)),
                   rig=rig, params={"sigma0": 40, "Fc": 18}, seed=2, rate_hz=200,
                   noise=Noise(force_N=0.05, ar1=0.3)).log
    post = sample_posterior(fit([log], "dahl"), walkers=16, steps=4000, tau_multiple=20,
                            check_every=250, seed=1, progress=False, draws=5)
    assert post.diagnostics.converged, post.diagnostics.reason
    assert not [w for w in post.warnings if "disagree" in w]
