"""The identification problem: an immutable value, segmentation as an input, compilation."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fitstiff._testing.recovery import dataset
from fitstiff.errors import InputError
from fitstiff.inference.problem import Problem
from fitstiff.inference.selection import PROBLEM_OPTIONS, Selection
from fitstiff.segments.segmentation import segment


@pytest.fixture(scope="module")
def logs():
    return dataset("dahl", 5)[0][:2]


def test_a_problem_is_immutable(logs):
    problem = Problem(logs, "chamber+dahl")
    with pytest.raises(AttributeError, match="a Problem is immutable: cannot set 'model'"):
        problem.model = None
    with pytest.raises(AttributeError, match="cannot set 'segmentations'"):
        problem.segmentations = []


def test_a_segmentation_given_is_the_one_used(logs):
    """The default is segment(log); one made with other options (a wider pre-sliding range)
    reaches the region weights."""
    wide = [segment(log, presliding_range=2e-3) for log in logs]
    default = Problem(logs, "chamber+dahl", weights={"presliding": 4.0})
    given = Problem(logs, "chamber+dahl", weights={"presliding": 4.0}, segmentations=wide)
    assert given.segmentations == wide
    assert [s.reversals.tolist() for s in default.segmentations] == \
        [s.reversals.tolist() for s in wide]
    heavier = [np.count_nonzero(w == 4.0) for w in given.sample_weights]
    assert all(h > np.count_nonzero(w == 4.0)
               for h, w in zip(heavier, default.sample_weights))


@pytest.mark.parametrize("bad, message", [
    (lambda logs: [segment(logs[0])], "segmentations: 1 given for 2 logs; give one "
     "Segmentation per log"),
    (lambda logs: [segment(logs[0].slice(0, len(logs[0]) // 2)), segment(logs[1])],
     "found one of .* samples for a log of"),
    (lambda logs: ["reversals", segment(logs[1])], "found str for a log of"),
])
def test_a_segmentation_that_does_not_fit_the_logs_is_refused(logs, bad, message):
    segs = bad(logs)
    with pytest.raises(InputError, match=message):
        Problem(logs, "chamber+dahl", segmentations=segs)


def test_compiled_functions_are_made_once_per_function_and_options(logs):
    problem = Problem(logs, "chamber+dahl")
    residuals = problem.compiled(Problem.residuals)
    assert problem.compiled(Problem.residuals) is residuals
    theta = problem.pack(problem.model)
    np.testing.assert_allclose(residuals(theta), problem.residuals(theta), rtol=1e-12,
                               atol=1e-12)

    def scaled(p, theta, *, factor):
        return factor * p.residuals(theta)

    twice = problem.compiled(scaled, factor=2.0)
    assert problem.compiled(scaled, factor=2.0) is twice
    assert problem.compiled(scaled, factor=3.0) is not twice
    np.testing.assert_allclose(twice(theta), 2.0 * residuals(theta), rtol=1e-12, atol=1e-12)


def test_the_per_log_nuisances_go_through_the_transform_layer(logs):
    """theta holds the offsets as they are, the initial states through tanh and the closing
    pressures in bar (NUISANCE_PARAMS); the log-Jacobian adds the states' non-constant part,
    checked against autodiff of the physical values."""
    import jax

    problem = Problem(logs, "chamber+dahl", free=["closing_pressure"])
    given = {"offset": [0.5, -0.2], "friction_state0": [0.3, -0.5],
             "closing_pressure": [5.0e5, 6.2e5]}
    theta = problem.pack(problem.model, given)
    for name, values in problem.nuisances(theta).items():
        np.testing.assert_allclose(values, given[name], rtol=1e-12, err_msg=name)
    n = problem.par.size
    blocks = {name: np.asarray(theta[n + k * 2:n + k * 2 + 2])
              for k, name in enumerate(problem.nuisance_names)}
    np.testing.assert_allclose(blocks["closing_pressure"], [5.0, 6.2], rtol=1e-12)
    np.testing.assert_allclose(np.tanh(blocks["friction_state0"]), [0.3, -0.5], rtol=1e-12)
    jac = np.asarray(jax.jacfwd(problem.physical)(theta))
    state = [n + 2 + i for i in range(2)]          # offset block, then the state block
    expected = float(problem.par.log_jacobian(theta[:n])) + float(
        np.sum(np.log(np.diag(jac)[state])))
    assert float(problem.log_jacobian(theta)) == pytest.approx(expected, rel=1e-12)


def test_unpack_physical_is_unpack_without_the_transforms(logs):
    """The fit's summary reads the fitted model and the per-log nuisances from the physical
    values it computed (unpack_physical): the same model and nuisances as unpack, in NumPy."""
    from fitstiff.physics.params import Parameterization

    problem = Problem(logs, "chamber+dahl", free=["closing_pressure"])
    theta = problem.pack(problem.model, {"offset": [0.5, -0.2], "friction_state0": [0.3, -0.5],
                                         "closing_pressure": [5.0e5, 6.2e5]})
    model, nuisances = problem.unpack(theta)
    model_np, nuisances_np = problem.unpack_physical(np.asarray(problem.physical(theta)))
    par = Parameterization(problem.model)
    assert par.values(model_np) == pytest.approx(par.values(model), rel=1e-14)
    assert model_np.spec == model.spec
    assert list(nuisances_np) == list(nuisances) == list(problem.nuisance_names)
    for name, values in nuisances.items():
        assert isinstance(nuisances_np[name], np.ndarray)
        np.testing.assert_allclose(nuisances_np[name], values, rtol=1e-14, err_msg=name)


def test_the_data_options_travel_as_one_record(logs):
    """Issue 35: the six data options are one frozen Selection, passed whole; the keywords
    build the same record, a re-opened run's JSON options give it back, and a problem keeps
    the one it was given."""
    options = {"denoise": False, "sample_range": [10, 900], "weights": {"presliding": 2.0},
               "skip": 5, "free": ["closing_pressure"], "exclude": [[100, 200]]}
    selection, rest = Selection.pick(options | {"solver": "lm", "starts": 2})
    assert rest == {"solver": "lm", "starts": 2}
    assert selection.sample_range == (10, 900) and selection.exclude == ([100, 200],)
    with pytest.raises(dataclasses.FrozenInstanceError):
        selection.skip = 0
    assert Selection.pick(selection.to_dict())[0] == selection           # the JSON round trip
    assert set(selection.keywords()) == set(PROBLEM_OPTIONS)
    whole = Problem(logs, "chamber+dahl", selection=selection)
    keywords = Problem(logs, "chamber+dahl", **options)
    assert whole.selection is selection and keywords.selection == selection
    assert whole.denoised == [False, False]
    for a, b in zip(whole.sample_weights, keywords.sample_weights):
        np.testing.assert_array_equal(a, b)
    w = whole.sample_weights[0]
    assert not w[:10].any() and not w[900:].any() and not w[100:200].any()
    assert np.all(w[300:400][np.asarray(whole.segmentations[0].mask("presliding"))[300:400]]
                  == 2.0)
    assert "closing_pressure" in whole.nuisance_names
    with pytest.raises(TypeError, match="either as a Selection or as keywords"):
        Problem(logs, "chamber+dahl", selection=selection, skip=3)
    with pytest.raises(TypeError, match="unexpected keyword argument.*skipp"):
        Problem(logs, "chamber+dahl", skipp=3)
    with pytest.raises(InputError, match="denoise 'off': is not True, False or 'auto'"):
        Selection(denoise="off")
    with pytest.raises(InputError, match="exclude \\(5, 2\\).*0 <= start < stop"):
        Problem(logs, "chamber+dahl", selection=Selection(exclude=[(5, 2)]))


def test_a_stack_whose_entries_all_weigh_zero_is_not_run_and_changes_nothing():
    """``weighted_residuals`` is ``residuals_physical * weights`` to the bit, with or without
    a stack left out, and so are its derivatives; the left-out stack sits behind a
    ``cond`` on its weights (a held-out fold that leaves the long log out does not run it)."""
    import jax
    import jax.numpy as jnp

    from fitstiff.io.log import Rig
    from fitstiff.physics.programs import TriangleCycles
    from fitstiff.physics.simulate import Noise, simulate

    rig = Rig(bore=0.032, rod=0.0, stroke=0.7, start_position=0.35, supply_pressure=4e5)
    two = [simulate("chamber+dahl", TriangleCycles(amplitudes_mm=(0.2, 1.0), rate_mm_s=2.0),
                    rig=rig, seed=k, rate_hz=rate, name=f"log{k}",
                    noise=Noise(force_N=0.1, displacement_um=0.0, pressure_mbar=0.0)).log
           for k, rate in enumerate((400.0, 100.0))]
    p = Problem(two, "chamber+dahl")
    assert len(p.groups) == 2                          # 4:1 in length: a stack each
    theta = jnp.asarray(p.pack(p.model))
    x = p.par.physical(theta[:p.par.size])
    n = max(s.span.stop for s in p.residual_series())
    long_out = np.ones(n)
    for s in p.residual_series():
        if s.log == 0:
            long_out[s.span] = 0.0
    weighted = jax.jit(p.weighted_residuals)
    plain = jax.jit(lambda x, theta, w: p.residuals_physical(x, theta) * w)
    for w in (np.ones(n), long_out, np.zeros(n)):
        w = jnp.asarray(w)
        expected = np.asarray(plain(x, theta, w))
        scale = np.abs(np.asarray(plain(x, theta, jnp.ones(n)))).max()
        np.testing.assert_allclose(weighted(x, theta, w), expected, rtol=1e-10,
                                   atol=1e-10 * scale)
        assert np.all(np.asarray(weighted(x, theta, w))[np.asarray(w) == 0] == 0.0)
        jg = jax.jacfwd(weighted)(x, theta, w)
        je = jax.jacfwd(plain)(x, theta, w)
        np.testing.assert_allclose(jg, je, rtol=1e-10, atol=1e-10 * np.abs(np.asarray(je)).max())
    assert "cond" in str(jax.make_jaxpr(p.weighted_residuals)(x, theta, jnp.asarray(long_out)))
