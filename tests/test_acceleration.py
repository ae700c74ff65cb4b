"""Smoothed acceleration for the inertia term (fitstiff.denoise.smooth_acceleration)."""

import glob
from pathlib import Path

import numpy as np
import pytest

from fitstiff.denoise import _curvature_noise, _quadratic_curvature, smooth_acceleration

INERTIA = Path(__file__).resolve().parents[1] / "data" / "synthetic" / "effects" / "inertia"


def test_a_parabola_is_differentiated_exactly_even_with_uneven_times():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, size=400))
    x = 0.3 * t**2 - 0.01 * t + 1e-3
    np.testing.assert_allclose(smooth_acceleration(x, t, noise=1e-6), 0.6, rtol=1e-6)


def test_a_noisy_sine_keeps_its_amplitude_and_sheds_the_noise():
    rng = np.random.default_rng(1)
    t = np.arange(0, 1.0, 1e-3)
    w = 2 * np.pi * 5.0
    x = 0.3e-3 * np.sin(w * t) + 1e-6 * rng.normal(size=t.size)
    truth = -0.3e-3 * w**2 * np.sin(w * t)
    a = smooth_acceleration(x, t, noise=1e-6)
    inner = slice(50, -50)
    err = a[inner] - truth[inner]
    # the plain second difference carries a noise of 2.4 m/s^2 here, ~8x the signal
    assert np.sqrt(np.mean(err**2)) < 0.1 * np.sqrt(np.mean(truth[inner] ** 2))
    slope = np.polyfit(truth[inner], a[inner], 1)[0]
    assert 0.9 < slope < 1.05                  # neither diluted nor attenuated much


def test_the_noise_formula_matches_a_simulation():
    rng = np.random.default_rng(2)
    t = np.arange(0, 2.0, 1e-3)
    m, noise = 8, 1e-6
    a = _quadratic_curvature(noise * rng.normal(size=t.size), t, m)
    assert np.std(a[m:-m]) == pytest.approx(_curvature_noise(m, noise, 1e-3), rel=0.1)


def test_a_fit_with_inertia_recovers_the_mass_of_the_bundled_set():
    """Before: the difference of the smoothed velocity diluted the mass to 1.9 kg (truth 5)."""
    from fitstiff.fitting import fit
    from fitstiff.loading import load_logs

    logs = load_logs(sorted(glob.glob(str(INERTIA / "*.csv"))))
    result = fit(logs, "chamber+dahl+inertia")
    assert result.converged
    assert result.value("mass") == pytest.approx(5.0, rel=0.08)
    assert result.rms_N < 0.3                  # force noise 0.2 N
