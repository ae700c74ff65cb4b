"""Long logs fitted in windows (issue 36): ``fitstiff.inference.chunks``.

A chunked problem runs each log as consecutive windows with the scan state carried across
them; its fit must equal the whole-log fit, its predictions the whole log's, whatever the
window size. Small windows here (a few hundred samples) put many boundaries, and the log's
both ends, inside a short log."""

from __future__ import annotations

import numpy as np
import pytest

from fitstiff._jax import jax, jnp
from fitstiff.data import paper_rig
from fitstiff.errors import InputError
from fitstiff.inference import chunks, lm
from fitstiff.inference.fitting import fit_problem
from fitstiff.inference.fitting.start import initial_guess
from fitstiff.inference.problem import Problem
from fitstiff.io.log import Rig
from fitstiff.physics.params import Parameterization
from fitstiff.physics.programs import TriangleCycles
from fitstiff.physics.simulate import Noise, simulate
from fitstiff.segments import denoise


@pytest.fixture(scope="module")
def logs():
    rig = Rig.from_mapping(paper_rig())
    out = []
    for seed, cycles in ((1, 2), (2, 1)):
        sim = simulate("chamber+dahl", TriangleCycles(amplitudes_mm=(0.05, 0.2, 1.0),
                                                      cycles=cycles, rate_mm_s=1.0),
                       rig=rig, params={"sigma0": 40, "Fc": 18},
                       noise=Noise(force_N=0.2, displacement_um=1.0, pressure_mbar=2.0),
                       seed=seed, rate_hz=500.0, name=f"log{seed}")
        out.append(sim.log)
    return out


@pytest.fixture
def small_windows(monkeypatch):
    monkeypatch.setattr(chunks, "WINDOW", 377)      # not a divisor of any log's length


@pytest.mark.parametrize("spec", [
    "chamber+dahl",
    "chamber+lugre+asymmetry+dwell_stiction",
    "chamber+dahl+stribeck+heat_transfer+leakage+force_drift",
    "chamber+maxwell_slip:3+time_delay",
    "chamber+dahl+rig_compliance+inertia",
])
def test_windows_predict_what_the_whole_log_does(logs, small_windows, spec):
    """Predicted force, per-term forces and pressures of every log, window by window (the
    scan state carried, margins read around each window) equal the whole-log run's, for
    stateful modifiers, an input term that reads 0.1 s around each sample, a series
    compliance and the acceleration at the log's ends."""
    whole = Problem(logs, spec, chunked=False, denoise=False)
    chunked = Problem(logs, spec, chunked=True, denoise=False)
    assert chunked.chunked and not whole.chunked
    theta = whole.pack(*initial_guess(whole))
    for a, b in zip(whole.per_log(theta), chunked.per_log(theta)):
        for key in ("force", "contributions", "pressure_a", "pressure_b"):
            assert b[key].shape == a[key].shape
            np.testing.assert_allclose(b[key], a[key], rtol=1e-10, atol=1e-9 * np.max(
                np.abs(a[key])), err_msg=f"{spec}: {key}")


@pytest.mark.parametrize("delay_s", [
    3.3e-3,
    # a shift that reads ahead put later samples into the first window's margin before the
    # log, and its first step moved the state from there: 0.094 N apart from the first sample
    -3.3e-3])
def test_windows_predict_what_the_whole_log_does_with_a_time_delay(logs, small_windows, delay_s):
    """The test above runs the time delay at its start value, 0; here it shifts the drive
    by 1.65 samples either way."""
    from fitstiff.physics.params import Parameterization

    spec = "chamber+maxwell_slip:3+time_delay"
    whole = Problem(logs, spec, chunked=False, denoise=False)
    chunked = Problem(logs, spec, chunked=True, denoise=False)
    model, nuisances = initial_guess(whole)
    model = Parameterization(model).with_values(model, {"delay": delay_s})
    theta = whole.pack(model, nuisances)
    for a, b in zip(whole.per_log(theta), chunked.per_log(theta)):
        np.testing.assert_allclose(b["force"], a["force"], rtol=1e-10,
                                   atol=1e-9 * np.max(np.abs(a["force"])))


def test_windows_keep_a_measured_compliances_runs(logs, small_windows):
    """rig_compliance:measured keeps its piston to the monotone runs of the displacement it is
    given, found in the samples it is given: the windows predict what the whole log does up
    to the projection in the runs that cross a window's edge (many here: 377-sample windows
    on 1 mm/s triangles; a piston left free to reverse ratchets the friction state, 1.5 N RMS
    apart)."""
    spec = "chamber+dahl+rig_compliance:measured"
    whole = Problem(logs, spec, chunked=False)
    chunked = Problem(logs, spec, chunked=True)
    model, nuisances = initial_guess(whole)
    model = Parameterization(model).with_values(model, {"compliance": 1.5e-5})
    theta = whole.pack(model, nuisances)
    for a, b in zip(whole.per_log(theta), chunked.per_log(theta)):
        gap = b["force"] - a["force"]
        assert np.sqrt(np.mean(gap ** 2)) < 0.1 and np.max(np.abs(gap)) < 0.5


def test_chunked_fit_equals_the_whole_log_fit(logs, small_windows):
    """Two logs with their pressures: the estimates to 1e-8 relative, the standard errors
    (covariance, AR(1) factor, the turning points' errors by the backward sweep) and the
    derived quantities to 1e-6, the same steps, cost and warnings."""
    a = fit_problem(Problem(logs, "chamber+dahl", chunked=False, denoise=False),
                    solver="lm-normal")
    b = fit_problem(Problem(logs, "chamber+dahl", chunked=True, denoise=False))
    assert a.converged and b.converged and a.steps == b.steps
    assert b.solver == "lm-normal"
    np.testing.assert_allclose(b.values, a.values, rtol=1e-8)
    np.testing.assert_allclose(b.stderr, a.stderr, rtol=1e-6)
    for name, (value, stderr) in a.derived.items():
        assert b.derived[name][0] == pytest.approx(value, rel=1e-8)
        assert b.derived[name][1] == pytest.approx(stderr, rel=1e-6)
    assert b.cost == pytest.approx(a.cost, rel=1e-10)
    assert b.residual_autocorrelation == pytest.approx(a.residual_autocorrelation, rel=1e-8)
    assert b.warnings == a.warnings
    assert [p["rms_N"] for p in b.to_dict()["per_log"]] == pytest.approx(
        [p["rms_N"] for p in a.to_dict()["per_log"]], rel=1e-8)


def test_chunked_fit_of_denoised_logs(logs, small_windows):
    """Denoised logs: the same estimates; the standard errors within 1e-3. The stepped law's
    derivative at a sample with no motion (a denoised turning point's flat neighbour) is
    zero where the whole log's closed form over the monotone runs moves the branch after it:
    the turning points' errors differ by that (exactly equal without flats, above)."""
    a = fit_problem(Problem(logs[:1], "chamber+dahl", chunked=False), solver="lm-normal")
    b = fit_problem(Problem(logs[:1], "chamber+dahl", chunked=True))
    np.testing.assert_allclose(b.values, a.values, rtol=1e-8)
    np.testing.assert_allclose(b.stderr, a.stderr, rtol=1e-3)


def test_chunked_problem_keeps_the_logs_arrays(logs):
    """No copies of a log's channels: the drive's time and pressures and the stacked force are
    views of the log's arrays, NumPy arrays on the host."""
    problem = Problem(logs[:1], "chamber+dahl", chunked=True, denoise=False)
    log, drive, group = logs[0], problem.drives[0], problem.groups[0]
    for a, b in ((drive.time, log.time), (drive.pressure_a, log.pressure_a),
                 (drive.displacement, log.displacement), (group.force, log.force),
                 (group.drive.time, log.time)):
        assert isinstance(a, np.ndarray) and np.shares_memory(a, b)


def test_chunked_problem_refuses_other_solvers(logs):
    with pytest.raises(InputError, match="fitted in windows"):
        fit_problem(Problem(logs[:1], "chamber+dahl", chunked=True), solver="dogleg")


def test_reduced_lm_takes_the_steps_of_the_normal_form():
    """levenberg_marquardt_reduced over reductions = levenberg_marquardt(normal=True) on the
    residual vector: the same steps, status and solution (a Rosenbrock-like problem)."""
    def fn(z):
        return jnp.stack([10 * (z[1] - z[0] ** 2), 1 - z[0], 0.3 * z[2] * z[0] - 0.1])

    def linearise(z):
        jt = lm.jacobian_rows(fn, z)
        r = fn(z)
        return lm.Linearisation(r @ r, jt @ jt.T, jt @ r, jnp.sqrt(jnp.sum(jt**2, axis=1)),
                                jnp.all(jnp.isfinite(jt)))

    z0 = jnp.asarray([-1.2, 1.0, 0.5])
    a = jax.jit(lambda z: lm.levenberg_marquardt(fn, z, normal=True))(z0)
    b = lm.levenberg_marquardt_reduced(linearise, lambda z: fn(z) @ fn(z), z0)
    assert int(a.status) == int(b.status) == lm.CONVERGED
    assert int(a.steps) == int(b.steps)
    np.testing.assert_allclose(np.asarray(b.value), np.asarray(a.value), rtol=1e-10)


def test_segment_velocity_in_blocks_is_the_same(monkeypatch):
    """segment_velocity, a block at a time: bitwise the same slopes as in one block."""
    rng = np.random.default_rng(0)
    n = 5000
    t = np.cumsum(rng.uniform(0.5, 1.5, n)) * 1e-3
    shape = np.sign(np.sin(np.arange(n) / 300))
    x = np.cumsum(shape * 1e-6) + rng.normal(0, 1e-7, n)
    reversals = np.flatnonzero(np.diff(shape)) + 1
    one = denoise.segment_velocity(x, t, reversals, noise=1e-7)
    monkeypatch.setattr(denoise, "_BLOCK", 333)
    np.testing.assert_array_equal(denoise.segment_velocity(x, t, reversals, noise=1e-7), one)


def test_a_posterior_takes_a_chunked_fit(logs):
    """Commands other than the fit take a chunked problem as it is (they evaluate its logs
    whole, the arrays passed from the host): a short posterior from a chunked fit runs and
    its samples sit at the fit's estimates."""
    from fitstiff.inference.posterior.sampler import sample_posterior

    fit = fit_problem(Problem(logs[:1], "chamber+dahl", chunked=True, denoise=False))
    post = sample_posterior(fit, walkers=16, steps=300, check_every=100, progress=False,
                            draws=50)
    assert np.all(np.isfinite(post.samples)) and np.all(np.isfinite(post.log_prob))
    median = np.median(post.samples.reshape(-1, post.samples.shape[-1]), axis=0)
    np.testing.assert_allclose(median[:3], fit.values[:3], rtol=0.02)
