"""Physics terms: closed forms, limits, memory, dissipation, gradients, vmap, each effect."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import polyline, triangle
from scipy.integrate import solve_ivp

from fitstiff.data import paper_rig
from fitstiff.errors import InputError
from fitstiff.physics import gas_spring
from fitstiff.physics.drive import make_drive
from fitstiff.physics.model import build_model, parse_spec
from fitstiff.physics.params import Parameterization
from fitstiff.physics.terms import EFFECTS, ROLES, TERMS, Chamber, FrictionBase, Modifier


def run(spec, t, x, *, values=None, rig=None, **drive_kw):
    needs = "chamber" in spec or "pressure_friction" in spec
    drive = make_drive(displacement=x, time=t, rig=rig, needs_chamber=needs, **drive_kw)
    model = build_model(spec, drives=[drive])
    if values:
        model = Parameterization(model).with_values(model, values)
    return model, drive, model.run(drive)


# -- Dahl ------------------------------------------------------------------------------------
def dahl_closed_form(x, sigma0, fc):
    """Exact Dahl (alpha = 1) along the monotone segments of a polyline, from F = 0 at x[0]."""
    F = np.zeros_like(x)
    f_rev, x_rev, direction = 0.0, x[0], 0.0
    for i in range(1, len(x)):
        d = np.sign(x[i] - x[i - 1])
        if d != 0 and d != direction:         # reversal at the previous sample
            f_rev, x_rev, direction = F[i - 1], x[i - 1], d
        F[i] = direction * fc + (f_rev - direction * fc) * np.exp(
            -sigma0 * abs(x[i] - x_rev) / fc) if direction else F[i - 1]
    return F


def test_dahl_matches_closed_form_loop():
    t, x = triangle([0.1e-3, 0.3e-3, 1e-3])
    _, _, pred = run("dahl", t, x, values={"sigma0": 40e3, "Fc": 18.0})
    exact = dahl_closed_form(x, 40e3, 18.0)
    scale = np.max(np.abs(exact))
    np.testing.assert_allclose(np.asarray(pred.force), exact, rtol=0, atol=1e-9 * scale)


@pytest.mark.parametrize("alpha", [0.5, 1.0, 2.0])
def test_dahl_general_alpha_matches_ode(alpha):
    t, x = polyline([0.0, 0.8e-3, -0.5e-3])
    _, _, pred = run("dahl:alpha", t, x, values={"sigma0": 40e3, "Fc": 18.0, "alpha": alpha})

    def rhs(xx, f, s):
        y = 1 - f * s / 18.0
        return 40e3 * np.abs(y) ** alpha * np.sign(y)

    f = 0.0
    ref = [0.0]
    i_turn = int(np.argmax(x))
    for seg, s in ((slice(0, i_turn + 1), 1.0), (slice(i_turn, len(x)), -1.0)):
        xs = x[seg]
        sol = solve_ivp(rhs, (xs[0], xs[-1]), [f], t_eval=xs, args=(s,), rtol=1e-11,
                        atol=1e-12, method="LSODA")
        ref += list(sol.y[0][1:])
        f = sol.y[0][-1]
    np.testing.assert_allclose(np.asarray(pred.force), np.array(ref), atol=1e-5 * 18)


# -- LuGre -----------------------------------------------------------------------------------
def test_lugre_at_low_speed_approaches_dahl_with_fc_equal_g():
    t, x = triangle([0.2e-3, 0.6e-3], rate=1e-6, fs=1.0)   # 1 um/s, far below vs
    lugre = {"sigma0": 40e3, "sigma1": 200.0, "Fc": 15.0, "Fs": 18.0, "vs": 2e-3}
    _, _, pl = run("lugre", t, x, values=lugre)
    _, _, pd = run("dahl", t, x, values={"sigma0": 40e3, "Fc": 18.0})
    g = 15.0 + 3.0 * np.exp(-((1e-6 / 2e-3) ** 2))
    np.testing.assert_allclose(np.asarray(pl.force), np.asarray(pd.force), atol=1e-3 * g)


@pytest.mark.parametrize("fs", [100.0, 10_000.0])
def test_lugre_stiff_is_stable_and_accurate(fs):
    """sigma0 = 1e6 N/m at 100 Hz and 10 kHz: no blow-up, and equal to a stiff ODE solver."""
    pars = {"sigma0": 1e6, "sigma1": 1e3, "Fc": 15.0, "Fs": 18.0, "vs": 2e-3}
    t, x = polyline([0.0, 0.05e-3, -0.05e-3, 0.2e-3], rate=2e-3, fs=fs)
    _, _, pred = run("lugre", t, x, values=pars)
    f = np.asarray(pred.force)
    assert np.all(np.isfinite(f))
    def g(v):
        return 15.0 + 3.0 * np.exp(-((v / 2e-3) ** 2))

    def bristle(tt, z, v):
        return v - 1e6 * abs(v) * z / g(v)

    # piecewise constant velocity: integrate each sample interval with a stiff solver
    z, zs = 0.0, [0.0]
    for i in range(1, len(t)):
        v = (x[i] - x[i - 1]) / (t[i] - t[i - 1])
        sol = solve_ivp(bristle, (t[i - 1], t[i]), [z], args=(v,), method="Radau",
                        rtol=1e-10, atol=1e-14)
        z = sol.y[0][-1]
        zs.append(z)
    zs = np.array(zs)
    v = np.concatenate([[0.0], np.diff(x) / np.diff(t)])
    ref = 1e6 * zs + 1e3 * (v - 1e6 * np.abs(v) * zs / g(v))
    np.testing.assert_allclose(f, ref, atol=1e-6 * 18)
    assert np.max(np.abs(f - 1e3 * v)) <= 18.0 * (1 + 1e-9)


# -- Maxwell-slip: return-point memory ---------------------------------------------------------
def _minor_loop_gap(spec, values):
    """Force difference at the same point before and after a nested minor loop."""
    pts = [0.0, 1e-3, -1e-3, 0.5e-3, 0.1e-3, 0.5e-3, -1e-3]
    t, x = polyline(pts)
    _, _, pred = run(spec, t, x, values=values)
    f = np.asarray(pred.force)
    # x = 0.5 mm: passed on 0 -> 1 and 1 -> -1, then the reversal point of the minor loop,
    # then the end of the minor loop (back at the reversal point)
    hits = np.flatnonzero(np.isclose(x, 0.5e-3, atol=1e-12))
    assert len(hits) == 4
    return abs(f[hits[3]] - f[hits[2]]), f


def test_a_seal_says_what_in_its_values_is_not_seal_physics():
    """Issue 35: the physics question 'is the breakaway below the sliding friction?' is the
    term's, not the fit's (LuGre: Fs below 0.9 Fc); a Dahl seal has no such rule."""
    lugre = build_model("lugre").term("lugre")
    low = dataclasses.replace(lugre, Fs=9.0, Fc=18.0)
    assert len(low.implausible()) == 1 and "Fs 9 N" in low.implausible()[0]
    assert dataclasses.replace(lugre, Fs=18.0, Fc=18.0).implausible() == []
    assert build_model("dahl").term("dahl").implausible() == []


def test_maxwell_slip_minor_loops_close_dahl_minor_loops_do_not():
    gap_ms, _ = _minor_loop_gap("maxwell_slip:4", None)
    gap_dahl, _ = _minor_loop_gap("dahl", {"sigma0": 40e3, "Fc": 18.0})
    assert gap_ms < 1e-9
    assert gap_dahl > 0.1


@pytest.mark.parametrize("spec", ["dahl", "dahl:alpha", "lugre", "maxwell_slip:4", "coulomb"])
def test_friction_dissipates_over_a_closed_loop(spec):
    t, x = triangle([0.5e-3])
    _, _, pred = run(spec, t, x)
    f = np.asarray(pred.force)
    work = np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(x))  # work done on the seal
    assert work > 0.1 * 0.5e-3   # well above zero: at least 0.1 N over the loop


# -- chamber ---------------------------------------------------------------------------------
def test_chamber_stepwise_equals_exact_law(paper_rig):
    t, x = triangle([1e-3, 5e-3])
    model, drive, pred = run("chamber", t, x, rig=paper_rig, values={"n": 1.35})
    exact = gas_spring.chamber_force(
        x, p_a0=float(drive.p_a0), p_b0=float(drive.p_b0), l_a0=0.35, l_b0=0.35,
        area_a=paper_rig.area_a, area_b=paper_rig.area_b, n=1.35,
        p_amb=paper_rig.ambient_pressure)
    np.testing.assert_allclose(np.asarray(pred.force), exact, rtol=1e-10, atol=1e-10)
    p_a = float(drive.p_a0) * (0.35 / (0.35 + x)) ** 1.35
    np.testing.assert_allclose(np.asarray(pred.pressure_a), p_a, rtol=1e-12)


def test_chamber_measured_and_vented_modes(paper_rig):
    from fitstiff.io.log import Rig

    rig = Rig.from_mapping({"bore_mm": 25})
    t, x = triangle([1e-3])
    p_a = 101325.0 + 3e5 + 1e3 * np.sin(t)
    _, _, pred = run("chamber", t, x, rig=rig, pressure_a=p_a, vented=("b",))
    np.testing.assert_allclose(np.asarray(pred.force), -rig.area_a * (p_a - 101325.0))


@pytest.mark.parametrize("spec, rig, drive_kw", [
    ("chamber", paper_rig(), {}),
    ("chamber", {"bore_mm": 40, "rod_mm": 16, "stroke_mm": 200, "start_position_mm": 30,
                 "supply_bar": 4, "dead_length_a_mm": 12.0}, {}),
    ("chamber", {"bore_mm": 25, "stroke_mm": 100, "start_position_mm": 50, "supply_bar": 3},
     {"pressure_a": "measured"}),
    ("chamber", {"bore_mm": 25, "stroke_mm": 100, "start_position_mm": 50, "supply_bar": 2},
     {"vented": ("b",)}),
    ("viscous", None, {}), ("inertia", None, {}), ("force_drift", None, {})])
def test_terms_evaluated_outside_the_scan_equal_stepping(spec, rig, drive_kw):
    """The contract of Term.run_all: the same states and forces as stepping from init."""
    from fitstiff.io.log import Rig
    from fitstiff.physics.terms import Modulation

    t, x = triangle([1e-3, 5e-3])
    x = x + 0.2e-3                        # the chambers close at x[0], not at 0
    if "pressure_a" in drive_kw:
        drive_kw = {**drive_kw, "pressure_a": 101325.0 + 3e5 + 1e3 * np.sin(t)}
    drive = make_drive(displacement=x, time=t, needs_chamber=rig is not None,
                       rig=None if rig is None else Rig.from_mapping(rig), **drive_kw)
    model = build_model(spec, drives=[drive])
    term = model.terms[0]
    values = {"chamber": {"n": 1.3}, "viscous": {"c": 80.0}, "inertia": {"mass": 2.5},
              "force_drift": {"drift": 0.3}}[spec]
    term = Parameterization(model).with_values(model, values).terms[0]
    steps = model.steps(drive)
    states, forces = term.run_all(steps, drive)

    def body(state, s):
        state, force = term.step(state, s, drive, Modulation())
        return state, (state, force)

    _, (stepped_states, stepped) = jax.lax.scan(body, term.init(drive), steps)
    scale = float(np.max(np.abs(np.asarray(stepped)))) or 1.0
    np.testing.assert_allclose(np.asarray(forces), np.asarray(stepped), rtol=0,
                               atol=1e-11 * scale)
    for got, want in zip(jax.tree_util.tree_leaves(states),
                         jax.tree_util.tree_leaves(stepped_states)):
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-12)


@pytest.mark.parametrize("spec", ["dahl:alpha", "lugre", "maxwell_slip:3", "coulomb"])
def test_terms_with_a_memory_are_stepped(spec):
    t, x = triangle([1e-3])
    model, drive, _ = run(spec, t, x)
    assert model.terms[0].run_all(model.steps(drive), drive) is None



# -- the chamber's powers as a series ----------------------------------------------------------
@pytest.mark.parametrize("span", [2.0**-30, 2.0**-12, 2.0**-8, 2.0**-5])
def test_polytropic_series_equals_exp_with_its_derivatives(span):
    from fitstiff.physics.terms.chamber import SERIES_EXPONENT_LIMIT, polytropic_ratio, series_terms

    assert series_terms(span) is not None
    logs = jnp.asarray(np.random.default_rng(3).uniform(-span, span, 2000))
    for n in (1.0, 1.4, 1.67, -SERIES_EXPONENT_LIMIT, SERIES_EXPONENT_LIMIT):
        got = np.asarray(polytropic_ratio(logs, n, span=span))
        want = np.exp(n * np.asarray(logs))
        np.testing.assert_allclose(got, want, rtol=4 * 2.0**-52, atol=0)
        by_n = jax.grad(lambda m: polytropic_ratio(logs, m, span=span).sum())(n)
        np.testing.assert_allclose(by_n, np.sum(np.asarray(logs) * want), rtol=1e-13,
                                   atol=1e-13 * np.sum(np.abs(np.asarray(logs) * want)))
        by_log = jax.jacfwd(lambda v: polytropic_ratio(v, n, span=span))(logs)
        np.testing.assert_allclose(np.diag(np.asarray(by_log)), n * want, rtol=1e-14, atol=0)


def test_polytropic_series_is_nan_outside_its_bounds_and_exp_beyond_its_terms():
    from fitstiff.physics.terms.chamber import SERIES_EXPONENT_LIMIT, polytropic_ratio, series_terms

    span = 2.0**-8
    logs = jnp.linspace(-span, span, 101)
    assert np.all(np.isnan(np.asarray(polytropic_ratio(logs, SERIES_EXPONENT_LIMIT + 0.5,
                                                       span=span))))
    wide = logs.at[7].set(2.5 * span)          # a log ratio past the span it was promised
    assert np.all(np.isnan(np.asarray(polytropic_ratio(wide, 1.4, span=span))))
    assert series_terms(None) is None and series_terms(0.25) is None
    np.testing.assert_array_equal(np.asarray(polytropic_ratio(logs * 64, 1.4, span=0.25)),
                                  np.asarray(jnp.exp(1.4 * logs * 64)))
    terms = [series_terms(2.0**-k) for k in (30, 12, 8, 5)]
    assert terms == sorted(terms) and terms[0] < terms[-1]


def test_log_volume_span_of_a_hand_made_drive():
    import math

    from fitstiff.physics.drive import log_volume_span

    x = np.array([0.0, -1e-3, 4e-3, 2e-3])          # from the first sample
    true = max(math.log(0.104 / 0.1), math.log(0.2 / 0.196))
    span = log_volume_span(x, 0.1, 0.2, ("closed", "closed"))
    assert span == 2.0 ** round(math.log2(span)) and true <= span < 2 * true
    only_b = log_volume_span(x, 0.1, 0.2, ("vented", "closed"))
    assert math.log(0.2 / 0.196) <= only_b < 2 * math.log(0.2 / 0.196)
    assert log_volume_span(x, 0.1, 0.2, ("measured", "vented")) is None
    assert log_volume_span(x, float("nan"), 0.2, ("closed", "closed")) is None
    assert log_volume_span(x, 5e-4, 0.2, ("closed", "closed")) is None   # length <= 0


def test_stacked_drives_share_the_widest_span():
    from fitstiff.inference.stacking import same_closed_forms

    t, x = triangle([1e-3])
    drive = make_drive(displacement=x, time=t)
    spans = [d.log_volume_span for d in same_closed_forms(
        [dataclasses.replace(drive, log_volume_span=2.0**-8),
         dataclasses.replace(drive, log_volume_span=2.0**-6)])]
    assert spans == [2.0**-6, 2.0**-6]
    spans = [d.log_volume_span for d in same_closed_forms(
        [dataclasses.replace(drive, log_volume_span=2.0**-8), drive])]
    assert drive.log_volume_span is None and spans == [None, None]


def test_drive_log_volume_ratios_follow_its_displacement(paper_rig):
    """A drive's cached log volume ratios are the chamber's logs of its displacement, padded
    with it; a moved drive drops them and the chamber follows the new displacement."""
    from fitstiff.inference.stacking import pad_drive
    from fitstiff.physics.terms.chamber import Chamber

    t, x = triangle([1e-3, 2e-3])
    drive = make_drive(displacement=x, time=t, rig=paper_rig, needs_chamber=True)
    assert drive.log_volume_ratios is not None
    fresh = Chamber.log_ratios(drive, jnp.asarray(x) + 0.0)       # not the drive's array
    for cached, computed in zip(drive.log_volume_ratios, fresh):
        np.testing.assert_allclose(np.asarray(cached), np.asarray(computed), rtol=1e-14,
                                   atol=1e-18)
        assert float(jnp.max(jnp.abs(cached))) <= drive.log_volume_span
    padded = pad_drive(drive, len(drive) + 50)
    for cached, computed in zip(padded.log_volume_ratios,
                                Chamber.log_ratios(padded, padded.displacement + 0.0)):
        np.testing.assert_allclose(np.asarray(cached), np.asarray(computed), rtol=1e-14,
                                   atol=1e-18)
    model = build_model("chamber", drives=[drive])
    bumped = np.asarray(x) * 1.001                  # the same runs, a different displacement
    moved = drive.moved(jnp.asarray(bumped))
    assert moved.log_volume_ratios is None
    np.testing.assert_allclose(np.asarray(model.run(moved).pressure_a),
                               np.asarray(model.run(drive.with_displacement(bumped)).pressure_a),
                               rtol=1e-14)
    assert not np.allclose(np.asarray(model.run(moved).pressure_a),
                           np.asarray(model.run(drive).pressure_a), rtol=1e-9)


def test_turning_point_columns_see_the_chamber_through_the_moved_drive():
    """The turning points' columns (a Jacobian in the displacement) are the same with the
    drive's cached ratios as without them: the cache never stands for a moved displacement."""
    from fitstiff._testing.speed import make_log
    from fitstiff.inference.likelihood import Layout, TurningPoints
    from fitstiff.inference.problem import Problem

    problem = Problem([make_log().slice(0, 1500)], "chamber+dahl")
    theta = jnp.asarray(problem.pack(problem.model))
    layout = Layout.from_problem(problem)
    cached = TurningPoints.at(problem, theta, layout).columns
    object.__setattr__(problem, "_groups", [
        dataclasses.replace(g, drive=dataclasses.replace(g.drive, log_volume_ratios=None))
        for g in problem.groups])
    object.__setattr__(problem, "_compiled", {})
    computed = TurningPoints.at(problem, theta, layout).columns
    assert cached.shape == computed.shape and cached.shape[1] > 0
    np.testing.assert_allclose(cached, computed, rtol=1e-12, atol=1e-12 * np.abs(computed).max())


def test_the_benchmark_log_takes_the_series():
    """The chamber of a pre-sliding log's problem (denoised drive) evaluates its powers as a
    series (``benchmarks/posterior_speed.py``)."""
    from fitstiff._testing.speed import make_log
    from fitstiff.inference.problem import Problem
    from fitstiff.physics.terms.chamber import series_terms

    problem = Problem([make_log()], "chamber+dahl")
    span = problem.groups[0].drive.log_volume_span
    assert span is not None and series_terms(span) is not None

# -- Dahl over monotone runs -------------------------------------------------------------------
def stepped_dahl(term, drive, steps):
    from fitstiff.physics.terms import Modulation

    def body(state, s):
        return term.step(state, s, drive, Modulation())

    return np.asarray(jax.lax.scan(body, term.init(drive), steps)[1])


def plateaued_triangle():
    """A triangle program with dwells (steps of exactly 0) at and between reversals, and a
    noisy copy of it that turns back on itself 241 times (at the dwells)."""
    t, x = triangle([0.1e-3, 0.4e-3, 1e-3])
    x = np.repeat(x, np.where(np.arange(x.size) % 97 == 0, 6, 1))
    t = np.arange(x.size) * 1e-3
    noisy = x + 0.05e-6 * np.random.default_rng(3).standard_normal(x.size)
    return t, x, noisy


@pytest.mark.parametrize("noisy", [False, True])
@pytest.mark.parametrize("state0", [0.0, -0.7])
def test_dahl_over_monotone_runs_equals_stepping(noisy, state0):
    from fitstiff.signal.monotone import count_runs

    t, x, x_noisy = plateaued_triangle()
    x = x_noisy if noisy else x
    drive = make_drive(displacement=x, time=t, friction_state0=state0)
    assert drive.runs.before.shape[0] == count_runs(x)
    assert 7 <= count_runs(x) <= x.size // 4
    model = build_model("dahl", drives=[drive])
    term = Parameterization(model).with_values(model, {"sigma0": 60e3, "Fc": 15.0}).terms[0]
    steps = model.steps(drive)
    states, forces = term.run_all(steps, drive)
    stepped = stepped_dahl(term, drive, steps)
    np.testing.assert_allclose(np.asarray(forces), stepped, rtol=0, atol=1e-11 * 15.0)
    np.testing.assert_allclose(np.asarray(states), stepped, rtol=0, atol=1e-11 * 15.0)


def test_dahl_over_runs_differentiates_like_stepping():
    """Gradients in the parameters agree everywhere; in the displacement wherever the
    displacement moves on both sides of the sample (at a step of exactly 0 the stepped form's
    derivative decays toward 0 and the run's continues its direction: both are one-sided
    derivatives at a kink)."""
    t, x, _ = plateaued_triangle()
    drive = make_drive(displacement=x, time=t, friction_state0=0.3)
    model = build_model("dahl", drives=[drive])
    par = Parameterization(model)
    y0 = par.to_unconstrained(par.with_values(model, {"sigma0": 60e3, "Fc": 15.0}))

    def forces(y, x, stepped):
        d = dataclasses.replace(drive, runs=None) if stepped else drive
        return par.to_model(y, model).predict(eqx.tree_at(lambda d: d.displacement, d, x))

    moving = np.diff(x, prepend=np.nan) != 0
    # the displacement's columns where it moves on both sides, every 7th of them with the
    # reversals and the dwells' edges among them (the full n x n Jacobian of the stepped scan
    # took a test worker from 1.9 to 3.8 GB)
    cols = np.flatnonzero(moving & np.roll(moving, -1))[::7]
    x = jnp.asarray(x)

    def jacobian(stepped, wrt):
        if wrt == 0:
            return jax.jacfwd(forces)(y0, x, stepped)
        basis = jnp.zeros((cols.size, x.size)).at[np.arange(cols.size), cols].set(1.0)
        return jax.vmap(lambda e: jax.jvp(lambda u: forces(y0, u, stepped), (x,), (e,))[1],
                        out_axes=1)(basis)

    for wrt in (0, 1):
        by_runs = np.asarray(jacobian(False, wrt))
        by_steps = np.asarray(jacobian(True, wrt))
        scale = np.max(np.abs(by_steps))
        np.testing.assert_allclose(by_runs, by_steps, rtol=0, atol=1e-9 * scale)


def test_dahl_on_a_displacement_against_its_runs_is_nan_not_wrong():
    t, x, _ = plateaued_triangle()
    drive = make_drive(displacement=x, time=t)
    model = build_model("dahl", drives=[drive])
    assert np.all(np.isfinite(np.asarray(model.predict(drive))))
    moved = eqx.tree_at(lambda d: d.displacement, drive, jnp.asarray(x[::-1].copy()))
    assert np.all(np.isnan(np.asarray(model.predict(moved))))


def test_dahl_is_stepped_where_runs_do_not_pay():
    t = np.arange(2000) * 1e-3
    x = 1e-6 * np.random.default_rng(0).standard_normal(t.size)   # turns back every ~2 samples
    drive = make_drive(displacement=x, time=t)
    model = build_model("dahl", drives=[drive])
    assert drive.runs is None
    assert model.terms[0].run_all(model.steps(drive), drive) is None


def test_runs_of_a_hand_made_displacement():
    from fitstiff.signal.monotone import count_runs, find_runs, pad_runs

    x = np.repeat([0.0, 0.0, 1.0, 2.0, 2.0, 1.0, 1.0, 0.0, 0.5, 0.5], 2)
    assert count_runs(x) == 3
    runs = find_runs(x)
    np.testing.assert_array_equal(np.asarray(runs.index), [0] * 10 + [1] * 6 + [2] * 4)
    np.testing.assert_array_equal(np.asarray(runs.before), [-1, 9, 15])
    np.testing.assert_array_equal(np.asarray(runs.sign), [1, -1, 1])
    np.testing.assert_array_equal(np.asarray(runs.start(jnp.asarray(x))), [0.0, 2.0, 0.0])
    steps = jnp.diff(jnp.asarray(x), prepend=0.0)
    assert bool(runs.holds(steps)) and not bool(runs.holds(-steps))
    padded = pad_runs(runs, 23, 5)
    np.testing.assert_array_equal(np.asarray(padded.index)[-4:], [2, 2, 2, 2])
    np.testing.assert_array_equal(np.asarray(padded.before), [-1, 9, 15, 22, 22])
    np.testing.assert_array_equal(np.asarray(padded.sign), [1, -1, 1, 0, 0])
    assert find_runs(x[::2]) is None            # 3 runs in 10 samples: stepping pays
    assert count_runs(np.zeros(5)) == 1
    np.testing.assert_array_equal(np.asarray(find_runs(np.zeros(5)).sign), [0.0])



def test_a_signal_made_monotone_within_the_runs():
    """directions finds find_runs' runs inside a traced function; monotone_in_runs makes
    every run move its own way, keeps a run that already does, keeps the signal's level, leaves
    a displacement that never moves as it is, and differentiates as the gathered samples (the
    same as the envelopes' own derivative)."""
    from fitstiff.signal.monotone import directions, find_runs, monotone_in_runs

    rng = np.random.default_rng(3)
    x = np.concatenate([np.zeros(7), np.linspace(0, 1e-3, 400), np.full(9, 1e-3),
                        np.linspace(1e-3, -5e-4, 600), np.linspace(-5e-4, 2e-4, 300)])
    runs = find_runs(x)
    sign, index = (np.asarray(a) for a in jax.jit(directions)(jnp.asarray(x)))
    np.testing.assert_array_equal(index, np.asarray(runs.index))
    np.testing.assert_array_equal(sign, np.asarray(runs.sign)[np.asarray(runs.index)])
    noise = 3e-6 * rng.standard_normal(x.size)
    y = jnp.asarray(x + noise)
    out = np.asarray(monotone_in_runs(y, jnp.asarray(sign), jnp.asarray(index)))
    within = index[1:] == index[:-1]            # a run's first step leaves the last one's end
    assert np.all((np.diff(out) * sign[1:])[within] >= 0)
    assert np.count_nonzero(np.diff(np.asarray(y)) * sign[1:] < 0) > 300  # the raw one reverses
    assert abs(np.mean(out - x)) < 1e-6 and np.sqrt(np.mean((out - x) ** 2)) < 4e-6
    np.testing.assert_array_equal(np.asarray(monotone_in_runs(jnp.asarray(x), *directions(x))), x)
    still = jnp.zeros(5)
    np.testing.assert_array_equal(np.asarray(monotone_in_runs(still + noise[:5],
                                                              *directions(still))), noise[:5])
    grad = jax.grad(lambda c: jnp.sum(monotone_in_runs(y * c, sign, index) ** 2))(1.0)
    lift = 10.0 * index

    def envelopes(c):
        z = sign * y * c + lift
        return jnp.sum((sign * (0.5 * (jax.lax.cummax(z) + jax.lax.cummin(z, reverse=True))
                                - lift)) ** 2)

    assert np.isfinite(float(grad))
    assert float(grad) == pytest.approx(float(jax.grad(envelopes)(1.0)), rel=1e-9)


def test_measured_force_compliance_keeps_the_pistons_runs():
    """rig_compliance:measured on an independent rig simulation with pauses and holds, its
    force noise AR(1): the piston position ``x - C F`` made of the logged force reverses at
    every noise wiggle where the sensor stands still, and a stepped friction law would
    ratchet on each reversal. Kept to the sensor's runs, the model at the true parameters
    fits to the noise and the fit finds the compliance (withheld set rig_compliance/1:
    truth 9.54e-3 mm/N; without the runs 3.2 N RMS at the truth with the raw force)."""
    import fitstiff
    from fitstiff._testing import rig_sim as rs
    from fitstiff._testing.withheld import log_program

    base = rs.Base(sigma0=55e3, Fc=15.0, n=1.2, x0=0.3, supply=4.5e5, dead_a=0.02,
                   dead_b=0.03, chamber=True)
    noise = rs.SensorNoise(force_N=0.12, ar1=0.45, displacement_um=0.8, quantum_um=0.5,
                           pressure_mbar=3.0)
    log, truth = rs.simulate_log(log_program(0, 1.5, sweeps=False), base=base,
                                 effects={"rig_compliance": {"compliance": 9.5e-6}},
                                 noise=noise, rate_hz=200.0, substeps=5,
                                 rng=np.random.default_rng(7), name="compliant", p_ref=4.5e5)
    fixed = {"n": 1.2, "sigma0": 55e3, "Fc": 15.0, "compliance": 9.5e-6}
    at_truth = fitstiff.fit([log], model="chamber+dahl+rig_compliance:measured", fix=fixed)
    assert at_truth.rms_N < 1.6 * noise.force_N
    fitted = fitstiff.fit([log], model="chamber+dahl+rig_compliance:measured")
    assert fitted.converged
    assert fitted.parameters()["compliance"]["value"] == pytest.approx(9.5e-3, rel=0.15)


# -- gradients and vmap ----------------------------------------------------------------------
GRADIENT_SPECS = ["chamber+dahl", "chamber+dahl:alpha", "chamber+lugre+viscous",
                  "chamber+maxwell_slip:3", "coulomb+viscous"] + [
    f"chamber+dahl+{e}" for e in EFFECTS if e != "maxwell_slip"] + ["chamber+dahl+maxwell_slip:2"]


@pytest.mark.parametrize("spec", GRADIENT_SPECS)
def test_gradients_finite_and_match_finite_differences(spec, paper_rig):
    t = np.linspace(0, 2.0, 400)
    x = 0.6e-3 * np.sin(2 * np.pi * t / 1.3) + 0.2e-3 * np.sin(2 * np.pi * t / 0.37 + 0.3)
    still = (np.abs(np.gradient(x, t)) < 2e-4).astype(float)
    drive = make_drive(displacement=x, time=t, rig=paper_rig, needs_chamber=True, still=still)
    model = build_model(spec, drives=[drive])
    par = Parameterization(model)
    y0 = par.to_unconstrained(model)
    # evaluate at non-null effect values so every parameter matters
    y0 = y0 + 0.1

    @jax.jit
    def f(y):
        return par.to_model(y, model).predict(drive)

    jac = np.asarray(jax.jacfwd(f)(y0))
    assert np.all(np.isfinite(jac)), spec
    h = 1e-6
    for j, name in enumerate(par.names):
        e = np.zeros(par.size)
        e[j] = h
        fd = (np.asarray(f(y0 + e)) - np.asarray(f(y0 - e))) / (2 * h)
        scale = max(np.max(np.abs(fd)), 1e-6)
        assert np.max(np.abs(jac[:, j] - fd)) <= 2e-4 * scale + 1e-7, (spec, name)


def test_vmap_over_64_parameter_sets_equals_loop(paper_rig):
    t, x = triangle([0.2e-3, 0.8e-3])
    drive = make_drive(displacement=x, time=t, rig=paper_rig, needs_chamber=True)
    model = build_model("chamber+lugre+viscous", drives=[drive])
    par = Parameterization(model)
    ys = par.to_unconstrained(model) + 0.2 * np.random.default_rng(1).normal(size=(64, par.size))

    @jax.jit
    def f(y):
        return par.to_model(y, model).predict(drive)

    batched = np.asarray(jax.vmap(f)(jnp.asarray(ys)))
    looped = np.stack([np.asarray(f(y)) for y in ys])
    np.testing.assert_allclose(batched, looped, rtol=1e-12, atol=1e-12)


# -- every effect does what DESIGN §3 says -----------------------------------------------------
def plateau(f, mask):
    return float(np.median(f[mask]))


def test_viscous_adds_c_times_v():
    t, x = triangle([0.5e-3], rate=5e-3)
    _, _, base = run("dahl", t, x)
    _, drive, with_c = run("dahl+viscous", t, x, values={"c": 300.0})
    v = np.concatenate([[0.0], np.diff(x) / np.diff(t)])
    np.testing.assert_allclose(np.asarray(with_c.force - base.force), 300.0 * v, atol=1e-9)


def test_stribeck_friction_falls_with_speed():
    values = {"stribeck_ratio": 1.5, "stribeck_vs": 1e-3}
    plateaus = []
    for rate in (1e-5, 2e-2):
        t, x = polyline([0.0, 10e-3], rate=rate, fs=2000 * rate / 1e-3)
        _, _, pred = run("dahl+stribeck", t, x, values=values)
        plateaus.append(float(pred.force[-1]))
    assert plateaus[0] == pytest.approx(1.5 * 18.0, rel=1e-3)   # Fs at rest
    assert plateaus[1] == pytest.approx(18.0, rel=1e-3)         # Fc when sliding fast


def test_asymmetry_gives_direction_dependent_level():
    t, x = polyline([0.0, 10e-3, -10e-3], fs=200)
    _, _, pred = run("dahl+asymmetry", t, x, values={"level_asym": 0.2})
    f = np.asarray(pred.force)
    assert f.max() == pytest.approx(18.0 * 1.2, rel=1e-4)
    assert f.min() == pytest.approx(-18.0 * 0.8, rel=1e-4)


def test_pressure_friction_rises_with_pressure():
    from fitstiff.data import paper_rig
    from fitstiff.io.log import Rig

    t, x = polyline([0.0, 10e-3], fs=200)
    levels = {}
    for bar in (2.0, 6.0):
        rig = Rig.from_mapping(paper_rig(supply_bar=bar))
        drive = make_drive(displacement=x, time=t, rig=rig, needs_chamber=True)
        model = build_model("dahl+pressure_friction")
        model = Parameterization(model).with_values(model, {"beta": 0.05e-5})
        levels[bar] = float(model.predict(drive)[-1])
    assert levels[6.0] / levels[2.0] == pytest.approx(np.exp(0.05 * 4.0), rel=1e-4)


def _paused(first, second, pause):
    """A leg ``first`` (m, two points), a standstill of ``pause`` s, a leg ``second``; the
    standstill flag and the index where the second leg starts."""
    t1, x1 = polyline(first)
    t2, x2 = polyline(second)
    n_pause = int(pause * 1000)
    tp = t1[-1] + np.arange(1, n_pause + 1) * 1e-3
    t = np.concatenate([t1, tp, (tp[-1:] if n_pause else t1[-1]) + t2[1:] + 1e-3 * bool(n_pause)])
    x = np.concatenate([x1, np.full(n_pause, first[1]), x2[1:]])
    still = np.concatenate([np.zeros_like(x1), np.ones(n_pause), np.zeros(len(x2) - 1)])
    return t, x, still, len(x1) + n_pause


_JUNCTION = {"dwell_gain": 2.0, "dwell_tau": 1.0, "dwell_decay": 0.1e-3}


def test_dwell_stiction_peak_grows_with_log_of_the_standstill():
    # motion continues after the pause: the Dahl branch plus a junction peak of
    # gain ln(1 + t / tau) at dwell_decay of travel, released after a few decay lengths
    values = {"sigma0": 40e3, "Fc": 18.0}
    for pause in (0.0, 0.5, 5.0):
        t, x, still, k = _paused([0.0, 2e-3], [2e-3, 4e-3], pause)
        plain = np.asarray(run("dahl", t, x, still=still, values=values)[2].force)
        aged = np.asarray(run("dahl+dwell_stiction", t, x, still=still,
                              values=values | _JUNCTION)[2].force)
        extra = aged - plain
        assert np.array_equal(aged[:k], plain[:k])
        assert float(np.max(extra)) == pytest.approx(2.0 * np.log1p(pause / 1.0), rel=1e-3)
        peak = int(np.argmax(extra))
        assert x[peak] - 2e-3 == pytest.approx(0.1e-3, abs=2e-6) if pause else True
        assert abs(extra[-1]) < 1e-3 * max(extra.max(), 1.0)


def test_dwell_stiction_makes_the_reversal_after_a_pause_stiffer_and_higher():
    # motion reverses after the pause: the junction adds to the Dahl branch from +Fc to -Fc
    t, x, still, k = _paused([0.0, 2e-3], [2e-3, 0.0], 5.0)
    values = {"sigma0": 40e3, "Fc": 18.0}
    plain = np.asarray(run("dahl", t, x, still=still, values=values)[2].force)
    aged = np.asarray(run("dahl+dwell_stiction", t, x, still=still,
                          values=values | _JUNCTION)[2].force)
    assert np.array_equal(plain[:k], aged[:k])
    travel = 2e-3 - x[k:]
    near = (travel > 0) & (travel < 0.05e-3)
    slope_plain = np.polyfit(travel[near], plain[k:][near], 1)[0]
    slope_aged = np.polyfit(travel[near], aged[k:][near], 1)[0]
    assert slope_aged < slope_plain < 0           # force falls faster: a stiffer branch
    # the junction's full strength against the new direction at dwell_decay of travel
    extra = aged - plain
    assert float(extra.min()) == pytest.approx(-2.0 * np.log1p(5.0), rel=1e-3)
    assert travel[int(np.argmin(extra[k:]))] == pytest.approx(0.1e-3, abs=2e-6)


def test_heat_transfer_makes_stiffness_rate_dependent(paper_rig):
    def stiffness(rate, heat_rate):
        t, x = polyline([0.0, 1e-3], rate=rate, fs=1000 * rate / 1e-3)
        _, _, pred = run("chamber+heat_transfer", t, x, rig=paper_rig,
                         values={"n": 1.4, "heat_rate": heat_rate})
        return float(pred.force[-1]) / 1e-3

    k_iso = gas_spring.linear_stiffness(p_a0=701325.0, p_b0=701325.0, l_a0=0.35, l_b0=0.35,
                                        area_a=paper_rig.area_a, area_b=paper_rig.area_b, n=1.0)
    assert stiffness(1e2, 1.0) == pytest.approx(1.4 * k_iso, rel=2e-2)     # fast: adiabatic
    assert stiffness(1e-5, 1.0) == pytest.approx(k_iso, rel=2e-2)          # slow: isothermal


def test_leakage_relaxes_the_pressure_difference(paper_rig):
    t, x = polyline([0.0, 1e-3], rate=1e-2)
    t = np.concatenate([t, t[-1] + np.arange(1, 20001) * 1e-3])
    x = np.concatenate([x, np.full(20000, 1e-3)])
    _, _, pred = run("chamber+leakage", t, x, rig=paper_rig, values={"leak_rate": 0.5})
    f = np.asarray(pred.force)
    held = f[-20000:]
    # exponential decay of the chamber force toward ~0 with rate 0.5/s
    assert held[-1] < 1e-3 * held[0]
    k = np.searchsorted(t, t[-20000] + 2.0)
    assert f[k] / held[0] == pytest.approx(np.exp(-1.0), rel=2e-2)


def test_inertia_adds_mass_times_acceleration():
    t = np.linspace(0, 1, 2001)
    x = 1e-3 * np.sin(2 * np.pi * 5 * t)
    _, _, base = run("dahl", t, x)
    _, _, inert = run("dahl+inertia", t, x, values={"mass": 2.0})
    a = -(2 * np.pi * 5) ** 2 * x
    diff = np.asarray(inert.force - base.force)
    np.testing.assert_allclose(diff[5:-5], 2.0 * a[5:-5], atol=0.01 * 2.0 * np.abs(a).max())


def test_force_drift_adds_a_ramp():
    t, x = triangle([0.5e-3])
    _, _, base = run("dahl", t, x)
    _, _, drift = run("dahl+force_drift", t, x, values={"drift": 0.3})
    np.testing.assert_allclose(np.asarray(drift.force - base.force), 0.3 * (t - t[0]), atol=1e-9)


def test_time_delay_shifts_the_force():
    t, x = triangle([0.5e-3])
    _, _, base = run("dahl", t, x)
    _, _, late = run("dahl+time_delay", t, x, values={"delay": 0.05})
    lag = 50  # samples at 1 kHz
    np.testing.assert_allclose(np.asarray(late.force)[lag:], np.asarray(base.force)[:-lag],
                               atol=1e-9)


def test_rig_compliance_softens_the_presliding_slope():
    t, x = polyline([0.0, 1e-3, 0.9e-3], fs=20000)
    c = 1 / 100e3  # a 100 N/mm rig
    _, _, pred = run("dahl+rig_compliance", t, x, values={"compliance": c})
    f = np.asarray(pred.force)
    i = int(np.argmax(x))
    slope = (f[i + 5] - f[i]) / (x[i + 5] - x[i])
    sigma_rev = 40e3 * (1 + f[i] / 18.0)          # Dahl slope right after the reversal
    assert slope == pytest.approx(1 / (1 / sigma_rev + c), rel=2e-2)


# -- spec parsing ----------------------------------------------------------------------------
@pytest.mark.parametrize("spec, fragment", [
    ("chamber+dhal", "unknown term 'dhal'"),
    ("dahl+dahl", "appears twice"),
    ("chamber+stribeck", "modifies a friction base"),
    ("dahl+heat_transfer", "modifies the chamber term"),
    ("lugre+stribeck", "already contains the Stribeck curve"),
    ("maxwell_slip:0", "whole number from 1 to 32"),
    ("", "give terms joined by"),
])
def test_bad_specs_are_named(spec, fragment):
    with pytest.raises(InputError, match=fragment):
        build_model(spec)


def test_every_canonical_name_is_a_term():
    assert set(EFFECTS) <= set(TERMS)
    assert [n for n, _ in parse_spec("chamber+maxwell_slip:4+viscous")] == [
        "chamber", "maxwell_slip", "viscous"]


@pytest.mark.parametrize("token", [*TERMS, "rig_compliance:measured", "chamber:gated"])
def test_every_term_has_exactly_one_role(token):
    """Each term is an instance of one role base, and a modifier's target role must be in the
    model: without it the model is refused with the message that names the role."""
    name, _, arg = token.partition(":")
    term = TERMS[name].from_spec(arg or None)
    assert len([r for r in ROLES if isinstance(term, r)]) == 1
    if isinstance(term, Modifier):
        assert term.targets in ROLES
        host = next(c for c in TERMS.values() if issubclass(c, term.targets)).name
        assert isinstance(build_model(f"{host}+{token}").term(host), term.targets)
        wanted = {FrictionBase: "a friction base (dahl, lugre, maxwell_slip or coulomb)",
                  Chamber: "the chamber term"}[term.targets]
        other = "viscous" if term.targets is Chamber else "chamber"
        with pytest.raises(InputError) as info:
            build_model(f"{other}+{token}")
        assert str(info.value) == (f"model spec '{other}+{name}': '{name}' modifies {wanted} "
                                   f"but the model has none; add {wanted}")


def test_an_ordered_vector_is_checked_once_all_its_elements_are_set():
    """Setting slip displacements element by element passes through unordered vectors: the
    held-out fits of ``--compare`` set a Maxwell-slip fit's [1.4, 39, 52, 77] um into a model
    holding [180, 360, 540, 720] um one name at a time and failed on the way (issue 17, the
    O-ring logs). Only the final vector must be increasing."""
    from fitstiff.physics.params import Parameterization

    model = build_model("maxwell_slip:4")
    par = Parameterization(model)
    fitted = {"delta_1": 0.0014e-3, "delta_4": 0.077e-3, "delta_2": 0.039e-3,
              "delta_3": 0.052e-3}
    done = par.with_values(model, fitted)
    np.testing.assert_allclose(np.asarray(done.term("maxwell_slip").delta),
                               [0.0014e-3, 0.039e-3, 0.052e-3, 0.077e-3])
    with pytest.raises(InputError, match="delta_2: parameter 'delta'.*give an increasing"):
        par.with_values(model, {"delta_2": 10.0e-3})


@pytest.mark.parametrize("spec", ["chamber+dahl", "chamber:gated+dahl:alpha+maxwell_slip:3",
                                  "chamber+dahl+rig_compliance:measured",
                                  "dahl+maxwell_slip:6+dwell_stiction"])
def test_a_models_spec_builds_the_same_structure_again(spec):
    model = build_model(spec)
    assert model.spec == spec
    again = build_model(model.spec)
    assert [p.name for p in Parameterization(again).entries] == \
        [p.name for p in Parameterization(model).entries]


def test_a_maxwell_slip_fit_of_six_elements_is_reported(tmp_path):
    # the run directory's model is rebuilt from fit.json's spec: it must keep the elements
    from fitstiff.cli import main
    from fitstiff.present.report import write_report

    log = Path(__file__).resolve().parents[1] / "data/synthetic/fig4/p2bar_x350mm.csv"
    assert main(["fit", str(log), "--model", "chamber+maxwell_slip:6", "--out",
                 str(tmp_path)]) == 0
    assert json.loads((tmp_path / "fit.json").read_text())["model"] == "chamber+maxwell_slip:6"
    assert write_report(tmp_path).is_file()


def test_pressure_friction_reference_can_be_set_and_is_kept_in_the_spec():
    from fitstiff.data import paper_rig
    from fitstiff.io.log import Rig

    rig = Rig.from_mapping(paper_rig())
    t, x = polyline([0.0, 10e-3], rate=10e-3)      # far beyond the pre-sliding range
    drive = make_drive(displacement=x, time=t, rig=rig, needs_chamber=True)
    assert build_model("dahl+pressure_friction", drives=[drive]).settings()[
        "pressure_friction"] == {"p_ref": 6e5}                     # the logs' mean
    given = build_model("dahl+pressure_friction:p_ref=3", drives=[drive])
    assert given.settings()["pressure_friction"] == {"p_ref": 3e5}
    assert given.spec == "dahl+pressure_friction:p_ref=3"
    # Fc is the level at 3 bar: at 6 bar the friction is exp(3 beta) times it
    given = Parameterization(given).with_values(given, {"beta": 0.1e-5, "Fc": 10.0})
    assert float(given.predict(drive)[-1]) == pytest.approx(10.0 * np.exp(0.3), rel=1e-3)
    with pytest.raises(InputError, match="p_ref=BAR"):
        build_model("dahl+pressure_friction:3")
