"""The transform layer, parameter by parameter (in the style of lmfit's bounds tests): for every
parameter of every registered term and every per-log nuisance of a problem, the bijection to the unconstrained space, its log
Jacobian against autodiff, the bounds it honours, the display-unit boundary and the null value
of effects; then the name-based conversions and the derived quantities' unit table."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fitstiff.errors import InputError
from fitstiff.inference.nuisances import NUISANCE_PARAMS
from fitstiff.physics import derived
from fitstiff.physics.model import build_model
from fitstiff.physics.params import (TRANSFORMS, Param, Parameterization, named_params, to_display,
                                     to_si)
from fitstiff.physics.terms import TERMS

#: every term with its default spec, plus the spec options that declare more parameters
SPECS = [(name, None) for name in TERMS] + [("maxwell_slip", "3"), ("maxwell_slip", "1"),
                                            ("chamber", "gated"), ("dahl", "alpha"),
                                            ("rig_compliance", "measured")]


def _params():
    out = []
    for name, arg in SPECS:
        term = TERMS[name].from_spec(arg)
        for p in term.params():
            out.append(pytest.param(p, id=f"{name}{'' if arg is None else ':' + arg}.{p.field}"))
    for name, p in NUISANCE_PARAMS.items():      # one element per log: here three logs
        out.append(pytest.param(dataclasses.replace(p, size=3), id=f"nuisance.{name}"))
    return out


PARAMS = _params()


def test_every_term_declares_parameters_here():
    """The list above reaches the parameters of every term that has any (a term whose
    parameters only a spec option declares must be listed with that option)."""
    covered = {p.id.split(".")[0].split(":")[0] for p in PARAMS}
    with_params = {name for name, cls in TERMS.items() if cls.from_spec(None).params()}
    assert with_params <= covered
    assert set(TRANSFORMS) == {p.values[0].transform for p in PARAMS}


def _inside(p: Param) -> list[np.ndarray]:
    """SI values strictly inside the bounds, near each finite bound and in the middle, each of
    the parameter's length (ordered vectors increasing)."""
    unit = p.scale                   # one display unit, in SI: a realistic magnitude
    lo, hi = p.lower, p.upper
    if p.transform in ("identity", "scaled"):
        scalars = [-1e3 * unit, -unit, 0.0, 0.37 * unit, 1e3 * unit]
    elif p.transform in ("log", "ordered"):
        near = 1e-6 * max(unit, abs(lo))
        scalars = [lo + near, lo + 1e-3 * unit, lo + unit, lo + 1e4 * unit]
    else:
        span = hi - lo
        scalars = [lo + 1e-6 * span, lo + 0.01 * span, lo + 0.5 * span, hi - 0.01 * span,
                   hi - 1e-6 * span]
    if p.transform == "ordered":
        steps = np.array([0.3, 1.0, 2.5, 0.01, 7.0, 1.2] * 6)[:p.length] * unit
        return [s + np.concatenate([[0.0], np.cumsum(steps[1:])]) for s in scalars]
    return [np.full(p.length, s) for s in scalars]


def _unconstrained(p: Param) -> list[np.ndarray]:
    rng = np.random.default_rng(7)
    grid = [np.full(p.length, v) for v in (-6.0, -1.0, 0.0, 0.5, 4.0)]
    return grid + [rng.uniform(-5.0, 5.0, p.length) for _ in range(3)]


# -- (1) the bijection round trips ------------------------------------------------------------
@pytest.mark.parametrize("p", PARAMS)
def test_forward_of_inverse_is_identity_inside_the_bounds(p):
    for x in _inside(p):
        back = np.asarray(p.forward(p.inverse(x)))
        # near a bound the unconstrained value is large: what comes back is exact relative
        # to the distance from the bound, not only to x
        ref = np.abs(x - p.lower) if math.isfinite(p.lower) else np.abs(x)
        np.testing.assert_allclose(back, x, rtol=1e-12, atol=1e-12 * float(np.max(ref)) + 1e-300,
                                   err_msg=f"{p.field} at {x}")


@pytest.mark.parametrize("p", PARAMS)
def test_inverse_of_forward_is_identity(p):
    for y in _unconstrained(p):
        np.testing.assert_allclose(np.asarray(p.inverse(p.forward(jnp.asarray(y)))), y,
                                   rtol=1e-10, atol=1e-10, err_msg=f"{p.field} at y={y}")


@pytest.mark.parametrize("p", PARAMS)
def test_a_value_on_a_bound_is_nudged_inside(p):
    """``inverse`` of a value on a finite bound is finite and comes back next to the bound."""
    for bound in (p.lower, p.upper):
        if not math.isfinite(bound) or (p.transform == "ordered" and bound == p.upper):
            continue
        x = np.full(p.length, bound) if p.transform != "ordered" else bound + np.zeros(p.length)
        y = np.asarray(p.inverse(x))
        assert np.all(np.isfinite(y)), (p.field, bound, y)
        back = np.asarray(p.forward(jnp.asarray(y)))
        span = p.upper - p.lower if math.isfinite(p.upper - p.lower) else 1.0 + abs(bound)
        assert np.all(np.abs(back - bound) <= 1e-8 * span), (p.field, bound, back)


# -- (2) the log Jacobian against autodiff ----------------------------------------------------
@pytest.mark.parametrize("p", PARAMS)
def test_log_jacobian_matches_autodiff(p):
    for y in _unconstrained(p)[:6]:
        y = jnp.asarray(y)
        jac = np.asarray(jax.jacfwd(p.forward)(y)).reshape(p.length, p.length)
        if p.transform != "ordered":     # elementwise: a diagonal Jacobian
            np.testing.assert_array_equal(jac - np.diag(np.diag(jac)), 0.0)
            expected = float(np.sum(np.log(np.abs(np.diag(jac)))))
        else:                            # x_i = lower + sum_{j<=i} e^{y_j}: lower triangular
            np.testing.assert_array_equal(np.triu(jac, 1), 0.0)
            sign, expected = np.linalg.slogdet(jac)
            assert sign != 0
        assert float(p.log_jacobian(y)) == pytest.approx(expected, rel=1e-12, abs=1e-12), (
            p.field, y)


# -- (3) forward honours the bounds -----------------------------------------------------------
@pytest.mark.parametrize("p", PARAMS)
def test_forward_maps_any_finite_value_inside_the_bounds(p):
    """Also where the transform saturates: ``lower + (upper - lower) * sigmoid(y)`` rounded
    one ulp past the upper bound before it was clipped (beta: -2e-5 + 7e-5 =
    5.000000000000001e-5 > 5e-5), and a saturated fitted value then failed Param.check."""
    rng = np.random.default_rng(11)
    values = [-700.0, -40.0, -1e-3, 0.0, 1e-3, 40.0, 700.0]
    ys = [np.full(p.length, v) for v in values] + [rng.normal(0.0, 30.0, p.length)
                                                   for _ in range(20)]
    for y in ys:
        x = np.asarray(p.forward(jnp.asarray(y)))
        assert x.shape == (p.length,)
        assert np.all(np.isfinite(x)), (p.field, y, x)
        assert np.all(x >= p.lower) and np.all(x <= p.upper), (p.field, y, x)
        if p.transform == "ordered":
            assert np.all(np.diff(x) >= 0), (p.field, y, x)


# -- (4) display units ------------------------------------------------------------------------
@pytest.mark.parametrize("p", PARAMS)
def test_display_round_trip(p):
    for x in _inside(p):
        display = p.to_display(x)
        assert isinstance(display, np.ndarray) and display.shape == x.shape
        np.testing.assert_allclose(display, x / p.scale, rtol=0, atol=0)
        np.testing.assert_array_max_ulp(p.to_si(display), x, maxulp=1)
        assert p.to_display(float(x[0])) == float(x[0]) / p.scale       # a number stays one
        np.testing.assert_array_equal(p.to_display(list(x)), display)   # lists as arrays


def test_display_units_of_known_parameters():
    """The scale's direction: SI = display * scale (40 N/mm is 40 000 N/m)."""
    dahl = TERMS["dahl"].from_spec(None)
    sigma0, fc = dahl.params()
    assert (sigma0.unit, sigma0.to_display(40e3), sigma0.to_si(40.0)) == ("N/mm", 40.0, 40e3)
    assert (fc.unit, fc.to_display(18.0)) == ("N", 18.0)
    delta = TERMS["maxwell_slip"].from_spec("3").params()[1]
    np.testing.assert_array_equal(delta.to_display(np.array([1e-4, 2e-4, 5e-4])),
                                  np.array([1e-4, 2e-4, 5e-4]) / 1e-3)
    assert delta.unit == "mm"


# -- (5) the null value of effects ------------------------------------------------------------
@pytest.mark.parametrize("p", [p for p in PARAMS if p.values[0].null is not None])
def test_null_value_is_inside_or_on_the_bounds(p):
    assert p.lower <= p.null <= p.upper
    y = np.asarray(p.inverse(np.full(p.length, p.null)))
    assert np.all(np.isfinite(y))


# -- the name-based boundary -----------------------------------------------------------------
def test_conversions_by_name_free_fixed_and_vector_elements():
    model = build_model("chamber+dahl+lugre+maxwell_slip:3")   # sigma0, Fc qualified
    values = Parameterization(model).values(model)
    assert {"n", "dahl.sigma0", "lugre.Fc", "k_1", "delta_3"} <= set(values)
    display = to_display(model, values)
    for _, p, names in named_params(model):
        for name in names:
            assert display[name] == values[name] / p.scale
    assert display["dahl.sigma0"] == values["dahl.sigma0"] / 1e3
    back = to_si(model, display)
    assert back.keys() == values.keys()
    np.testing.assert_array_max_ulp(np.array([back[n] for n in values]),
                                    np.array(list(values.values())), maxulp=1)
    with pytest.raises(InputError, match="parameter 'sigma0': is not in this model; use one "
                                         "of: n, dahl.sigma0, dahl.Fc, lugre.sigma0, "):
        to_si(model, {"sigma0": 40.0})


def test_flat_vector_conversion_matches_each_parameter():
    model = build_model("chamber+dahl+maxwell_slip:3")
    par = Parameterization(model, fixed=["n"])
    x = np.array(list(par.values(model).values()))
    samples = np.stack([x, 2 * x])           # leading axes: samples
    display = par.to_display(samples)
    assert display.shape == samples.shape
    expected = [[e.param.to_display(v) for e, v in zip(par.entries, row)] for row in samples]
    np.testing.assert_array_equal(display, expected)
    np.testing.assert_array_max_ulp(par.to_si(display), samples, maxulp=1)
    assert "n" not in par.names


def test_check_reports_in_display_units():
    sigma0 = TERMS["dahl"].from_spec(None).params()[0]
    with pytest.raises(InputError, match=r"found \[-40\.0\] N/mm; give a value within "
                                         r"\[0, inf\] N/mm"):
        sigma0.check(-40e3, where="--set")


# -- derived quantities ------------------------------------------------------------------------
def test_derived_units_come_from_one_table():
    for name in derived.DERIVED:
        label, unit = derived.split_unit(name)
        assert unit and name == f"{label}_{unit.replace('/', '_per_')}"
    assert derived.to_display("presliding_slope_N_per_mm", 40e3) == 40.0
    assert derived.to_display("presliding_range_mm", 2e-4) == 2e-4 * 1e3
    assert derived.to_display("breakaway_N", 18.0) == 18.0
    np.testing.assert_array_equal(derived.to_display("total_stiffness_N_per_mm",
                                                     np.array([4e3, 5e4])), [4.0, 50.0])
    with pytest.raises(KeyError):
        derived.to_display("rms", 1.0)


def test_derived_quantities_are_in_display_units():
    """A Dahl base of sigma0 = 40 N/mm, Fc = 18 N: slope 40 N/mm, breakaway 18 N."""
    model = build_model("dahl")
    model = Parameterization(model).with_values(model, {"sigma0": 40e3, "Fc": 18.0})
    d = derived.derived_quantities(model)
    assert float(d["presliding_slope_N_per_mm"]) == pytest.approx(40.0, rel=1e-12)
    assert float(d["breakaway_N"]) == pytest.approx(18.0, rel=1e-12)
    # 95 % of the swing of an exponential of length Fc / sigma0 (0.45 mm): about 1.35 mm
    assert 1.0 < float(d["presliding_range_mm"]) < 1.7
    assert float(d["chamber_stiffness_N_per_mm"]) == 0.0


def test_a_parameterization_is_immutable():
    par = Parameterization(build_model("chamber+dahl"))
    with pytest.raises(AttributeError, match="a Parameterization is immutable: cannot set 'size'"):
        par.size = 2
    assert isinstance(par.entries, tuple)
