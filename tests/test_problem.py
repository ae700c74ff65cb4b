"""The identification problem: an immutable value, segmentation as an input, compilation."""

from __future__ import annotations

import numpy as np
import pytest

from fitstiff._testing.recovery import dataset
from fitstiff.errors import InputError
from fitstiff.problem import Problem
from fitstiff.segmentation import segment


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
    (lambda logs: [segment(logs[1]), segment(logs[0])], "found one of"),
    (lambda logs: ["reversals", segment(logs[1])], "found str for a log of"),
])
def test_a_segmentation_that_does_not_fit_the_logs_is_refused(logs, bad, message):
    segs = bad(logs)
    if len(segs) == 2 and not isinstance(segs[0], str) and len(segs[0].still) == len(logs[0]):
        pytest.skip("the two logs have one length: the swap is not detectable by length")
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
