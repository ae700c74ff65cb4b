"""The log of the speed benchmarks (``benchmarks/fit_speed.py``, ``benchmarks/posterior_speed.py``)
and their NumPy references, which the tests also trust: :func:`reference_residuals` (what a
user would write: a per-sample loop, exact Dahl step, exact polytropic chamber) and
:func:`reference_log_posterior` (fitstiff's log-posterior of that model, written out)."""

from __future__ import annotations

import math

import numpy as np

from fitstiff.data import paper_rig
from fitstiff.inference.problem import Problem
from fitstiff.io.log import Log, Rig
from fitstiff.physics.programs import TriangleCycles
from fitstiff.physics.simulate import Noise, simulate

RIG = Rig.from_mapping(paper_rig())


def make_log() -> Log:
    """One 4 000-sample ``chamber+dahl`` log (paper cylinder, 6 bar, 1.1 kHz, sigma0 40 N/mm,
    Fc 18 N, n 1.3; 0.2 N, 1 um, 2 mbar noise)."""
    program = TriangleCycles(rate_mm_s=2.0, amplitudes_mm=(0.05, 0.1, 0.2, 0.5, 1.0),
                             cycles=1)
    sim = simulate("chamber+dahl", program, rig=RIG, params={"sigma0": 40, "Fc": 18, "n": 1.3},
                   noise=Noise(force_N=0.2, displacement_um=1.0, pressure_mbar=2.0),
                   seed=1, name="bench", rate_hz=1100.0)   # 4 070 samples
    return sim.log.slice(0, 4000)


def reference_residuals(p, x, force, p_a, p_b, rig, sigma_f, sigma_p):
    """NumPy per-sample loop: exact Dahl + exact polytropic chamber (what a user writes)."""
    n, sigma0, fc, offset, state0 = p
    area = rig.area_a
    l_a0 = rig.start_position
    l_b0 = rig.stroke - rig.start_position
    p0 = rig.supply_pressure + rig.ambient_pressure
    amb = rig.ambient_pressure
    out_f = np.empty_like(x)
    out_pa = np.empty_like(x)
    out_pb = np.empty_like(x)
    f = state0 * fc
    prev = x[0]
    for k in range(x.shape[0]):
        dx = x[k] - prev
        prev = x[k]
        d = math.copysign(1.0, dx) if dx != 0 else 0.0
        f = d * fc + (f - d * fc) * math.exp(-sigma0 * abs(dx) / fc)
        u = x[k] - x[0]                # the chambers close at the first sample
        pa = p0 * (l_a0 / (l_a0 + u)) ** n
        pb = p0 * (l_b0 / (l_b0 - u)) ** n
        out_f[k] = f + area * (pb - amb) - area * (pa - amb) + offset
        out_pa[k] = pa
        out_pb[k] = pb
    return np.concatenate([(out_f - force) / sigma_f, (out_pa - p_a) / sigma_p,
                           (out_pb - p_b) / sigma_p])


def reference_log_posterior(theta: np.ndarray, problem: Problem, noise) -> float:
    """NumPy log-posterior of ``theta = [logit n, log sigma0, log Fc, offset, atanh s0]``:
    AR(1) errors per channel (``noise.phi``) with the scale integrated out, the turning-point
    displacement errors integrated out with the Woodbury terms ``noise.marginal`` prepared at
    the least-squares optimum (constants of the run, as in fitstiff), log-normal priors on
    sigma0 and Fc, the transforms' log-Jacobians."""
    n_par = problem.model.term("chamber").params()[0]
    lo, hi = n_par.lower, n_par.upper
    y_n, y_s, y_f, offset, y_0 = theta
    n = lo + (hi - lo) / (1 + math.exp(-y_n))
    sigma0, fc, state0 = math.exp(y_s), math.exp(y_f), math.tanh(y_0)
    log = problem.logs[0]
    x = np.asarray(problem.drives[0].displacement)
    r = reference_residuals((n, sigma0, fc, offset, state0), x, log.force, log.pressure_a,
                            log.pressure_b, log.rig, problem.force_noise[0], 1.0)
    k = x.size
    scale = problem.pressure_noise[0]
    series = (r[:k], r[k:2 * k] / scale["a"], r[2 * k:] / scale["b"])
    whitened = [np.concatenate([[math.sqrt(1 - p**2) * e[0]], e[1:] - p * e[:-1]])
                for e, p in zip(series, noise.phi)]
    squares = [float(w @ w) for w in whitened]
    if noise.marginal is not None:                        # e'e - v' M v per force series
        m = noise.marginal
        v = np.asarray(m.project(np.concatenate(whitened)))
        for column_series, term in zip(m.series, v * (m.inverse @ v)):
            squares[column_series] -= term
    lp = -0.5 * k * sum(math.log(q) for q in squares)
    for value, median in ((sigma0 / 1e3, 40.0), (fc, 18.0)):             # log-normal priors
        lp += -math.log(value) - 0.5 * (math.log(value / median) / math.log(10.0)) ** 2
    u = (n - lo) / (hi - lo)
    lp += math.log((hi - lo) * u * (1 - u)) + y_s + y_f + math.log(1 - state0**2)
    return lp
