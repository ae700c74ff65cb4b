"""What to record next when an unexplained structure follows one of two variables the logs
cannot tell apart (issue 33's structure confusion): the two descriptions as rivals on a
proposed program."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fitstiff.diagnosis.structure import Structure
from fitstiff.io.log import Log, Rig
from fitstiff.planning.descriptions import DescribedPair, Residuals
from fitstiff.planning.rivals import confusions, deferred
from fitstiff.planning.separation import Noise, Outputs, Rival
from fitstiff.segments.segmentation import segment

from test_plan import _diagnosis

SIGMA = 0.05
RATE = 200.0


def _triangle(seconds=12.0, amplitude=1e-3, speed=4e-3):
    t = np.arange(int(seconds * RATE)) / RATE
    period = 4 * amplitude / speed
    phase = (t / period) % 1.0
    x = amplitude * np.where(phase < 0.25, 4 * phase, np.where(
        phase < 0.75, 2 - 4 * phase, 4 * phase - 4))
    return t, x


def _level(supply_bar):
    """The residual's friction level at a supply (N): it follows the supply, not the
    position (the final model's friction takes the level common to both logs)."""
    return 0.15 * (supply_bar - 4.5)


def _log(name, start_m, supply_bar, rng):
    t, x = _triangle()
    rig = Rig(bore=0.032, rod=0.0, stroke=0.7, start_position=start_m,
              supply_pressure=supply_bar * 1e5)
    probe = Log(name=name, displacement=x, force=np.zeros_like(x), time=t, rig=rig)
    motion = np.asarray(segment(probe).direction, float)
    residual = _level(supply_bar) * motion + SIGMA * rng.standard_normal(x.size)
    # model force of 10 N s/m times the speed stands in for the final model's prediction
    model = 10.0 * np.gradient(x, t)
    return Log(name=name, displacement=x, force=model - residual, time=t, rig=rig), \
        residual, model


@pytest.fixture(scope="module")
def apart():
    """Two logs far apart along the stroke, each at its own supply: a friction level that
    follows the supply reads as well as a curve along the position."""
    rng = np.random.default_rng(3)
    made = [_log("low", 0.20, 3.0, rng), _log("high", 0.50, 6.0, rng)]
    logs = tuple(m[0] for m in made)
    residuals = Residuals(logs=logs, residual=tuple(m[1] for m in made),
                          force=tuple(m[2] for m in made),
                          counted=tuple(np.ones(len(m[0]), bool) for m in made),
                          segmentations=tuple(segment(log) for log in logs))
    # a final model with no parameter left to refit: the descriptions alone decide
    final = Rival("final", None, None, np.zeros(0, bool), np.zeros((0, 0)), np.zeros(0))
    structure = Structure(variable="position", form="sign-dependent smooth", size_N=1.0,
                          heldout_rms_before_N=1.0, heldout_rms_after_N=0.1, shrink=0.9,
                          accepted=True, description="", suggestion="",
                          confounded_with=("pressure",))
    return (DescribedPair(structure, "pressure", residuals, final, Noise(SIGMA)), logs,
            DescribedPair(structure, "log", residuals, final, Noise(SIGMA)))


def _score(pair, template: Log, *, start_m, supply_bar):
    t, x = _triangle(seconds=8.0)
    rig = Rig(bore=0.032, rod=0.0, stroke=0.7, start_position=start_m,
              supply_pressure=supply_bar * 1e5)
    force = 10.0 * np.gradient(x, t)
    program = Log(name="program", displacement=x, force=force, time=t, rig=rig)
    on = pair.on(program, force)
    n = x.size
    sigma = pair.noise.scale(SIGMA)
    ob = Outputs(y=force / sigma, jac=np.zeros((n, 0)),
                 nuisance=np.column_stack([np.ones(n) / sigma, np.zeros(n)]))
    return pair.separation(ob, on, n), on


def test_the_rival_of_a_level_per_supply_is_a_line_in_the_supply(apart):
    pair, *_ = apart
    assert pair.names == ("position", "pressure")
    assert pair.b.label == "sign-dependent linear"


def test_the_same_positions_at_another_supply_separate_what_a_replay_cannot(apart):
    """Replayed at its own supply, a log is predicted alike by both descriptions (they
    describe the logs alike); at the other log's supply, the position predicts the level of
    the log it was fitted on and the pressure the level of the new supply."""
    pair, logs, _ = apart
    replay, _ = _score(pair, logs[0], start_m=0.20, supply_bar=3.0)
    moved, on = _score(pair, logs[0], start_m=0.20, supply_bar=6.0)
    assert replay["z"] < 3.0 < moved["z"]
    assert moved["z"] == pytest.approx(math.sqrt(min(moved["noncentrality_if"].values())))
    # the two predictions: the level of the 3 bar log (position) and of 6 bar (pressure)
    motion = np.sign(np.gradient(_triangle(seconds=8.0)[1]))
    moving = motion != 0
    level_a = np.median(on[0].f[moving] * motion[moving])
    level_b = np.median(on[1].f[moving] * motion[moving])
    assert level_a == pytest.approx(_level(3.0), rel=0.15)
    assert level_b == pytest.approx(_level(6.0), rel=0.15)
    # the other way round: the 6 bar log's positions at 3 bar
    assert _score(pair, logs[1], start_m=0.50, supply_bar=3.0)[0]["z"] > 3.0
    assert moved["z"] > 200


def test_a_refit_that_can_take_the_difference_leaves_no_separation(apart):
    """The new log's own columns are free in the refit: a level per log (the ``log``
    variable) is taken by the new log whatever it is, so it cannot tell a line in the
    supply from itself."""
    _, logs, own = apart
    assert own.b.label == "sign-dependent step"
    s, on = _score(own, logs[0], start_m=0.20, supply_bar=6.0)
    # the logs' own levels are shared (nothing of them on the program), the new log's free
    assert on[1].own.shape[1] == 1 and np.all(on[1].shared == 0.0)
    assert np.all(on[1].f == 0.0) and np.std(on[0].f) > 0.1
    # a log of its own level: the position's prediction there is a level too, taken but
    # for the wiggles of its fit (the same program separates the position from the supply
    # at z above 200)
    assert s["noncentrality_if"]["position"] < 3.0**2


def test_a_confounded_structure_is_a_confusion_planned_before_undecided_candidates():
    from fitstiff.diagnosis.result import Candidate

    structure = Structure(variable="position", form="smooth", size_N=1.3,
                          heldout_rms_before_N=1.5, heldout_rms_after_N=0.4, shrink=0.8,
                          accepted=True, description="", suggestion="",
                          confounded_with=("log", "pressure"))
    lone = Structure(variable="velocity", form="smooth", size_N=0.3,
                     heldout_rms_before_N=0.4, heldout_rms_after_N=0.3, shrink=0.5,
                     accepted=True, description="", suggestion="")
    d = _diagnosis([Candidate("pressure_friction", 30.0, 1, 1e-8, True,
                              log_p_value=math.log(1e-8))])
    d = type(d).from_dict(d.to_dict() | {"unexplained_structure": [
        structure.to_dict(), lone.to_dict()]})
    found = confusions(d)
    assert [(c.kind, c.separates) for c in found] == [
        ("structure", ("position", "log")), ("structure", ("position", "pressure")),
        ("undecided", ("pressure_friction", "absent"))]
    assert found[0].structure == d.unexplained_structure[0] and found[0].effects == ()
    now, later = deferred(found)
    assert [c.kind for c in now] == ["structure"] * 2 and [c.kind for c in later] == [
        "undecided"]


# -- a plan, end to end -----------------------------------------------------------------------
@pytest.fixture(scope="module")
def friction_per_supply():
    """Two logs far apart along the stroke, at 3 and 6 bar, whose seal's friction level
    follows the supply (14 and 22 N): one Dahl friction fitted to both leaves a level per
    log, which reads as well as a curve along the position."""
    from fitstiff.physics.programs import TriangleCycles
    from fitstiff.physics.simulate import Noise as SimNoise
    from fitstiff.physics.simulate import simulate

    logs = []
    for k, (start, supply, fc) in enumerate(((0.25, 3e5, 14.0), (0.45, 6e5, 22.0))):
        rig = Rig(bore=0.032, rod=0.0, stroke=0.7, start_position=start,
                  supply_pressure=supply)
        sim = simulate("chamber+dahl", TriangleCycles(amplitudes_mm=(0.3, 1.0, 2.0),
                                                      rate_mm_s=4.0),
                       rig=rig, params={"Fc": fc}, seed=k, rate_hz=100.0, name=f"log{k}",
                       noise=SimNoise(force_N=0.1, displacement_um=0.0, pressure_mbar=0.0))
        logs.append(sim.log)
    return logs


def test_a_plan_puts_a_logged_stretch_of_the_stroke_at_another_supply(friction_per_supply):
    from fitstiff.diagnosis.result import Diagnosis
    from fitstiff.planning import Limits, plan

    logs = friction_per_supply
    structure = Structure(variable="position", form="sign-dependent smooth", size_N=3.0,
                          heldout_rms_before_N=4.0, heldout_rms_after_N=0.2, shrink=0.95,
                          accepted=True, description="", suggestion="",
                          confounded_with=("pressure",))
    d = _diagnosis([])
    d = Diagnosis.from_dict(d.to_dict() | {
        "noise_N": {log.name: {"sigma_N": 0.1, "rho": 0.0} for log in logs},
        "gap": {"heldout_rms_N": 4.0, "noise_N": 0.1, "final_heldout_rms_N": 4.0},
        "unexplained_structure": [structure.to_dict()]})
    limits = Limits.from_logs(logs, max_duration_s=8.0, pressures_bar=(3.0, 6.0))
    result = plan(d, logs, limits=limits)
    assert [(p.kind, p.separates) for p in result.programs] == [
        ("structure", ("position", "pressure"))] * 2
    first = result.programs[0]
    e = first.expected
    assert e["forms"] == {"position": "sign-dependent smooth",
                          "pressure": "sign-dependent linear"}
    assert e["z"] == pytest.approx(math.sqrt(min(e["noncentrality_if"].values())))
    # replaying a log (its stretch at its own supply) hardly tells them apart; the plan's
    # program puts a logged stretch of the stroke at the other log's supply
    assert e["z"] > 3.0 and e["z"] > 5 * first.naive["z"]
    spans = [(log.rig.start_position * 1e3, log.rig.supply_pressure / 1e5) for log in logs]
    on_stretch = [s for s in spans if abs(first.start_position_mm - s[0]) < 5.0]
    assert on_stretch and all(first.supply_bar != s[1] for s in on_stretch)
    assert set(first.predicted_N) == {"position", "pressure"}
    assert "follows the position or the pressure" in first.why


def test_a_description_predicts_where_the_logs_hold_its_variable_only():
    from fitstiff.diagnosis._structure_forms import Candidate
    from fitstiff.planning.descriptions import supported

    log_id = np.repeat([0, 1], 3)
    train = np.ones(6, bool)

    def cand(form, old, new):
        values = np.concatenate([old, new]).astype(float)
        return Candidate("v", form, False, values, np.ones_like(values))

    # within a log's own range, not between two logs far apart nor beyond them
    position = cand("smooth", [0, 0.5, 1, 5, 5.5, 6], [0.5, 3.0, 5.5, 7.0])
    assert supported(position, log_id, train, 6).tolist() == [True, False, True, False]
    # one level per log (a supply each): its line holds between the levels
    pressure = cand("linear", [3, 3, 3, 6, 6, 6], [4.5, 3.0, 7.0])
    assert supported(pressure, log_id, train, 6).tolist() == [True, True, False]
    # a level per log is the new log's own: no range to leave
    assert supported(cand("step", [0, 0, 0, 1, 1, 1], [2.0]), log_id, train, 6).all()
    # samples that do not count do not give a range
    assert not supported(position, log_id, np.r_[train[:3], False, False, False], 6)[2]


def test_what_each_description_leaves_of_the_logs_residual_is_reported(apart):
    """Both describe a level per supply alike (the structure's curve a little closer, with
    more columns); a level per log leaves as little: all three well below the residual."""
    pair, logs, own = apart
    rms = pair.rms_on_logs
    assert set(rms) == {"final", "position", "pressure"}
    assert rms["final"] == pytest.approx(0.225, rel=0.1)
    for name in ("position", "pressure"):
        assert rms[name] == pytest.approx(SIGMA, rel=0.2)
    assert own.rms_on_logs["log"] == pytest.approx(SIGMA, rel=0.2)
    s, _ = _score(pair, logs[0], start_m=0.20, supply_bar=6.0)
    assert s["residual_rms_on_logs_N"] == rms
