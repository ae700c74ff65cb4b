"""Segmentation: reversals, loops, pauses and regions on synthetic programs with known truth.

Every program is piecewise linear in the *sample index* with knots on whole samples, so each
true turning point and each true pause span is a whole sample. Noise is Gaussian with a
standard deviation of 5 % of the smallest amplitude (5 um against 0.1 mm).

What "exact" means for reversals: the detected count equals the true count, and the k-th
detected reversal lies within ``tol`` samples of the k-th true turning point (so each detected
reversal is the one nearest its turning point). With noise the extremum sample wanders: near a
triangle peak the signal falls by one step ``s`` per sample, so a sample ``k`` away beats the
peak only if the difference of two noise values (standard deviation ``sigma * sqrt(2)``)
exceeds ``k * s``; at ``k * s >= 5 sigma`` that is a 3.5-sigma event (p ~ 2e-4 per sample pair),
rare over all reversals and seeds here. One more sample for the running median of 3:
``tol = ceil(5 sigma / s) + 1``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from conftest import REALDATA

from fitstiff.errors import InputError
from fitstiff.io.log import Log, Rig
from fitstiff.segments.segmentation import REGIONS, SPEED_BANDS, segment
from fitstiff.signal.noise import estimate_noise

FS = 1000.0          # Hz
SIGMA = 5e-6         # m: 5 % of the smallest amplitude, 0.1 mm
SEEDS = range(5)


@dataclasses.dataclass
class Program:
    time: np.ndarray
    displacement: np.ndarray          # noise-free
    turning: np.ndarray               # sample index of each true turning point (the knot)
    pauses: np.ndarray                # (n, 2) true [start, stop) of each hold
    turning_pause: np.ndarray         # per turning point: index into pauses, -1 if none


def program(points_mm, *, speed=10e-3, holds_s=None) -> Program:
    """Piecewise-linear program through ``points_mm`` at ``speed`` (m/s), sampled at FS.

    ``holds_s`` maps a point index to a dwell (s) at that point.
    """
    holds_s = holds_s or {}
    points = np.asarray(points_mm, dtype=float) * 1e-3
    step = speed / FS
    knots_i, knots_x, pauses, turning, turning_pause = [0], [points[0]], [], [], []
    for j in range(1, len(points)):
        knots_i.append(knots_i[-1] + round(abs(points[j] - points[j - 1]) / step))
        knots_x.append(points[j])
        at = knots_i[-1]
        is_turn = j < len(points) - 1 and (points[j] - points[j - 1]) * (points[j + 1] - points[j]) < 0
        if j in holds_s:
            hold = round(holds_s[j] * FS)
            pauses.append((at, at + hold + 1))
            knots_i.append(at + hold)
            knots_x.append(points[j])
        if is_turn:
            turning.append(at)
            turning_pause.append(len(pauses) - 1 if j in holds_s else -1)
    n = knots_i[-1] + 1
    i = np.arange(n)
    return Program(time=i / FS, displacement=np.interp(i, knots_i, knots_x),
                   turning=np.array(turning), pauses=np.array(pauses, dtype=int).reshape(-1, 2),
                   turning_pause=np.array(turning_pause, dtype=int))


def noisy_log(prog: Program, seed: int, *, sigma=SIGMA, with_time=True, **kwargs) -> Log:
    rng = np.random.default_rng(seed)
    x = prog.displacement + rng.normal(0.0, sigma, prog.displacement.size)
    return Log(name=f"synthetic{seed}", displacement=x, force=np.zeros_like(x),
               time=prog.time if with_time else None, **kwargs)


def triangle_tolerance(speed: float) -> int:
    return math.ceil(5 * SIGMA / (speed / FS)) + 1


def assert_reversals(found: np.ndarray, true: np.ndarray, tol: int) -> None:
    assert found.size == true.size, (found, true)
    assert np.max(np.abs(found - true), initial=0) <= tol, (found - true)


GROWING = [0, 0.1, -0.1, 0.2, -0.2, 0.5, -0.5, 1, -1, 2, -2, 0]
NESTED = [0, 2, -1, 1, 0.4, 0.5, -2, -0.5, -1.5, -0.6, -0.7, 2, 1.9, 2.0, 0]


# ------------------------------------------------------------------------------ reversals

@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("points", [GROWING, NESTED], ids=["growing", "nested"])
def test_triangle_reversals_exact(points, seed):
    prog = program(points)
    seg = segment(noisy_log(prog, seed))
    assert_reversals(seg.reversals, prog.turning, triangle_tolerance(10e-3))


def test_noise_free_reversals_on_the_knot():
    prog = program(NESTED)
    seg = segment(Log(name="clean", displacement=prog.displacement,
                      force=np.zeros_like(prog.time), time=prog.time))
    assert seg.noise == 0.0
    assert seg.threshold == pytest.approx(1e-6)        # the floor
    assert_reversals(seg.reversals, prog.turning, 1)  # the running median may shift by one


def test_threshold_floor():
    t = np.arange(2000) / FS
    x = 1e-3 * np.sin(2 * np.pi * t)                    # smooth, noise-free, tiny steps at peaks
    seg = segment(Log(name="sine", displacement=x, force=np.zeros_like(x), time=t))
    assert seg.threshold == pytest.approx(1e-6)
    assert_reversals(seg.reversals, np.array([250, 750, 1250, 1750]), 1)


@pytest.mark.parametrize("seed", SEEDS)
def test_sine_reversals_exact(seed):
    """Near a sine peak x ~ A (1 - (w t)^2 / 2): a sample at k dt is below the peak by
    A w^2 (k dt)^2 / 2, so the same 5-sigma argument gives tol = sqrt(10 sigma / (A w^2)) / dt."""
    amplitude, freq, cycles = 1e-3, 0.5, 4
    t = np.arange(round(cycles / freq * FS) + 1) / FS
    w = 2 * np.pi * freq
    x = amplitude * np.sin(w * t) + np.random.default_rng(seed).normal(0, SIGMA, t.size)
    seg = segment(Log(name="sine", displacement=x, force=np.zeros_like(x), time=t))
    true = np.round((np.arange(2 * cycles) + 0.5) / (2 * freq) * FS).astype(int)
    tol = math.ceil(math.sqrt(10 * SIGMA / (amplitude * w**2)) * FS) + 1
    assert_reversals(seg.reversals, true, tol)


def test_loops_are_every_second_reversal():
    prog = program(GROWING)
    seg = segment(noisy_log(prog, 0))
    r = seg.reversals
    assert seg.loops.tolist() == [[r[k], r[k + 2] + 1] for k in range(0, r.size - 2, 2)]


def test_direction_per_leg():
    prog = program(GROWING)
    seg = segment(noisy_log(prog, 0))
    r = seg.reversals
    assert np.all(seg.direction[: r[0]] == 1)  # GROWING starts upwards, at once
    for k in range(r.size):
        leg = seg.direction[r[k]: r[k + 1] if k + 1 < r.size else None]
        assert np.all(leg == (-1 if k % 2 == 0 else 1))


def test_direction_zero_before_the_first_leg_without_time():
    prog = program([0, 0, 1], holds_s={1: 0.5})       # still, then up; no time: no pause
    log = noisy_log(prog, 0, with_time=False)
    seg = segment(log)
    start = int(np.flatnonzero(seg.direction)[0])
    assert start <= prog.pauses[0, 1] + triangle_tolerance(10e-3)
    assert np.all(seg.direction[start:] == 1) and seg.reversals.size == 0


def test_spikes_make_no_reversals():
    """Single-sample sensor spikes (as in the real O-ring logs) are removed by the median."""
    prog = program([0, 5, 0])
    log = noisy_log(prog, 0)
    x = np.array(log.displacement)
    x[[100, 250, 400, 600, 850]] -= 0.5e-3   # 0.5 mm back-steps on both ramps
    spiky = log.replace(displacement=x)
    assert_reversals(segment(spiky).reversals, prog.turning, triangle_tolerance(10e-3))
    assert segment(spiky, median_window=1).reversals.size > prog.turning.size


# ----------------------------------------------------------------------- noise, threshold

@pytest.mark.parametrize("seed", SEEDS)
def test_noise_estimate_ignores_the_motion(seed):
    prog = program(GROWING)
    noise = estimate_noise(noisy_log(prog, seed).displacement)
    assert noise == pytest.approx(SIGMA, rel=0.05)


def test_default_threshold_rule():
    prog = program(GROWING)
    seg = segment(noisy_log(prog, 0))
    assert seg.threshold == pytest.approx(10 * seg.noise)


def test_quantised_standstill_flicker_is_not_a_reversal():
    """A still, quantised sensor flickering by one count now and then: the MAD of the second
    differences is 0, the resolution term of the threshold keeps the flicker out."""
    lsb = 5e-6
    counts = np.zeros(20_000)
    counts[np.random.default_rng(1).choice(counts.size, 300, replace=False)] = 1
    x = counts * lsb
    seg = segment(Log(name="still", displacement=x, force=np.zeros_like(x),
                      time=np.arange(x.size) / FS))
    assert seg.noise == 0.0
    assert seg.threshold == pytest.approx(4 * lsb)
    assert seg.reversals.size == 0
    assert seg.pauses.tolist() == [[0, x.size]]


def test_pure_noise_standstill_is_one_pause_without_reversals():
    x = np.random.default_rng(2).normal(0, SIGMA, 50_000)
    seg = segment(Log(name="still", displacement=x, force=np.zeros_like(x),
                      time=np.arange(x.size) / FS))
    assert seg.reversals.size == 0
    assert seg.pauses.tolist() == [[0, x.size]]
    assert np.all(seg.direction == 0)
    assert "never moved" in " ".join(seg.notes)


# ---------------------------------------------------------------------------------- pauses

PAUSED = [0, 1, 0.5, 2, -1, 1.5, 0]
HOLDS = {1: 0.3, 2: 1.0, 3: 0.25, 4: 2.0, 5: 0.5}   # 1 and 5 mid-ramp, 2-4 at turning points


@pytest.mark.parametrize("seed", SEEDS)
def test_pauses_and_dwell_times_recovered(seed):
    """Edges within 2 samples: a pause's ends are trimmed to the samples within a third of the
    band (threshold, ~50 um) of its level; at 20 mm/s one step is 20 um, so at most one ramp
    sample stays in, plus one for noise. Dwell times within two samples (over 200 seeds the
    worst seen was one sample on an edge and two on a duration)."""
    prog = program([0, 1, 0.5, 2, 2.2, -1, 1.5, 0], speed=20e-3,
                   holds_s={1: 0.3, 2: 1.0, 3: 0.25, 5: 2.0, 6: 0.5})
    seg = segment(noisy_log(prog, seed))
    assert seg.pauses.shape == prog.pauses.shape
    assert np.max(np.abs(seg.pauses - prog.pauses)) <= 2
    true_durations = (prog.pauses[:, 1] - 1 - prog.pauses[:, 0]) / FS
    np.testing.assert_allclose(seg.pause_durations, true_durations, atol=2.5 / FS)
    assert np.all(seg.direction[seg.mask("standstill")] == 0)


@pytest.mark.parametrize("seed", SEEDS)
def test_standstill_creates_no_reversals(seed):
    """Pauses mid-ramp add no reversal; a pause at a turning point is one reversal, inside it."""
    prog = program(PAUSED, holds_s=HOLDS)
    seg = segment(noisy_log(prog, seed))
    assert seg.reversals.size == prog.turning.size
    tol = triangle_tolerance(10e-3)
    for found, true, k in zip(seg.reversals, prog.turning, prog.turning_pause):
        if k < 0:
            assert abs(found - true) <= tol
        else:
            start, stop = prog.pauses[k]
            assert start - tol <= found < stop + tol


def test_short_hold_is_not_a_pause():
    prog = program([0, 1, 2], holds_s={1: 0.1})
    assert segment(noisy_log(prog, 0), min_pause=0.2).pauses.size == 0
    assert segment(noisy_log(prog, 0), min_pause=0.05).pauses.shape == (1, 2)


# --------------------------------------------------------------------------------- regions

def test_presliding_share_of_a_triangle():
    """Constant speed: each leg (from the log start or a reversal) begins with
    min(leg, presliding_range / step) samples of presliding (travel < 0.5 mm); the rest is
    sliding. GROWING's first four legs are shorter than 0.5 mm: presliding throughout."""
    prog = program(GROWING)
    seg = segment(noisy_log(prog, 0, sigma=0.2e-6))
    per_leg = round(seg.presliding_range / (10e-3 / FS))
    legs = np.diff(np.concatenate([[0], prog.turning, [prog.time.size]]))
    expected = np.minimum(legs, per_leg).sum()
    assert expected == 10 + 20 + 30 + 40 + 7 * 50
    assert np.count_nonzero(seg.mask("presliding")) == pytest.approx(expected, abs=legs.size)
    shares = seg.shares()
    assert shares["presliding"] + shares["sliding"] == pytest.approx(1.0)
    assert shares["dwell"] == shares["standstill"] == 0.0
    # presliding right after each long leg's reversal, sliding once 0.5 mm has been travelled
    for r in seg.reversals[4:]:
        assert seg.mask("presliding")[r: r + 45].all()
        assert not seg.mask("presliding")[r + 55]


def test_presliding_range_is_an_option():
    prog = program(GROWING)
    log = noisy_log(prog, 0)
    narrow = segment(log, presliding_range=0.1e-3).shares()["presliding"]
    assert narrow < segment(log).shares()["presliding"] / 3


def test_dwell_follows_a_pause():
    prog = program([0, 1, 2], holds_s={1: 0.5})
    seg = segment(noisy_log(prog, 0))
    (start, stop), = seg.pauses
    dwell = np.flatnonzero(seg.mask("dwell"))
    assert dwell[0] == stop
    assert dwell.size == pytest.approx(50, abs=3)            # 0.5 mm at 10 um per sample
    assert np.all(seg.region[start:stop] == REGIONS.index("standstill"))


def test_dwell_after_a_pause_at_a_turning_point():
    prog = program([0, 1, 0], holds_s={1: 0.5})
    seg = segment(noisy_log(prog, 0))
    (_, stop), = seg.pauses
    assert seg.reversals.size == 1
    assert np.count_nonzero(seg.mask("dwell")) == pytest.approx(50, abs=3)
    assert np.flatnonzero(seg.mask("dwell"))[0] == stop
    assert not seg.mask("presliding")[stop:].any()


def test_regions_partition_the_samples():
    prog = program(PAUSED, holds_s=HOLDS)
    seg = segment(noisy_log(prog, 0))
    total = sum(seg.mask(r).astype(int) for r in REGIONS[:4])
    assert np.all(total == 1)
    assert sum(seg.shares()[r] for r in REGIONS[:4]) == pytest.approx(1.0)


def test_stroke_end_needs_stroke_and_start_position():
    prog = program(GROWING)
    seg = segment(noisy_log(prog, 0))
    assert seg.stroke_end is None
    assert "stroke_end" not in seg.available_regions
    assert "stroke_end region skipped" in " ".join(seg.notes)
    with pytest.raises(InputError, match="stroke_mm or start_position_mm is unknown"):
        seg.mask("stroke_end")


def test_stroke_end_near_either_cap():
    rig = Rig.from_mapping({"stroke_mm": 20, "start_position_mm": 3})
    prog = program(GROWING)
    log = noisy_log(prog, 0, rig=rig)
    seg = segment(log)
    x = 3e-3 + log.displacement
    np.testing.assert_array_equal(seg.mask("stroke_end"), (x < 2e-3) | (x > 18e-3))
    assert seg.stroke_end_margin == pytest.approx(2e-3)   # 10 % of the stroke
    assert segment(log, stroke_end_margin=1e-3).mask("stroke_end").sum() < seg.mask(
        "stroke_end").sum()


def test_speed_bands():
    slow, fast = program([0, 0.5], speed=1e-3), program([0, 2], speed=50e-3)
    for prog, band in ((slow, "slow"), (fast, "fast")):
        seg = segment(noisy_log(prog, 0))
        middle = seg.speed_band[prog.time.size // 4: -prog.time.size // 4]
        assert np.all(middle == SPEED_BANDS.index(band))
    seg = segment(noisy_log(program(GROWING), 0))
    np.testing.assert_allclose(np.abs(seg.velocity[1000:1005]), 10e-3, rtol=0.05)


def test_pressure_level_tag():
    prog = program(GROWING)
    x = noisy_log(prog, 0)
    assert segment(x).pressure_level is None
    assert segment(x.replace(rig=Rig.from_mapping({"supply_bar": 6}))).pressure_level == 6e5
    logged = x.replace(pressure_a=np.full(x.time.size, 101_325.0 + 3e5))
    assert segment(logged).pressure_level == pytest.approx(3e5)


def test_quasi_static_log():
    prog = program(PAUSED, holds_s=HOLDS)
    seg = segment(noisy_log(prog, 0, with_time=False))
    assert seg.reversals.size == prog.turning.size
    assert seg.velocity is None and seg.pauses.size == 0
    assert np.all(seg.speed_band == SPEED_BANDS.index("unknown"))
    assert "quasi-static" in " ".join(seg.notes)
    assert set(seg.available_regions) == {"presliding", "sliding"}
    with pytest.raises(InputError, match="no time column"):
        seg.mask("dwell")


# ------------------------------------------------------------------------------ result API

def test_result_is_immutable():
    seg = segment(noisy_log(program(GROWING), 0))
    with pytest.raises(dataclasses.FrozenInstanceError):
        seg.threshold = 1.0
    with pytest.raises(ValueError, match="read-only"):
        seg.reversals[0] = 0
    with pytest.raises(ValueError, match="read-only"):
        seg.region[0] = 0


def test_tidy_frame():
    rig = Rig.from_mapping({"supply_bar": 4})
    prog = program(PAUSED, holds_s=HOLDS)
    seg = segment(noisy_log(prog, 0, rig=rig))
    df = seg.to_frame()
    assert list(df.columns) == ["file", "sample", "region", "stroke_end", "direction",
                                "speed_band", "pressure_bar", "loop"]
    assert len(df) == prog.time.size
    assert (df["file"] == "synthetic0").all() and (df["pressure_bar"] == 4.0).all()
    assert df["stroke_end"].isna().all()
    np.testing.assert_array_equal(df["region"] == "dwell", seg.mask("dwell"))
    start, stop = seg.loops[0]
    # loops share their closing reversal, which the tags give to the next loop
    assert (df["loop"].iloc[start:stop - 1] == 0).all() and df["loop"].iloc[stop - 1] == 1
    assert df["loop"].iloc[0] == -1
    counts = df.groupby(["region", "direction"], observed=True).size()
    assert counts.sum() == len(df)


def test_unknown_region_and_bad_options_are_input_errors():
    log = noisy_log(program(GROWING), 0)
    seg = segment(log)
    with pytest.raises(InputError, match="region 'slip': is not a region; use one of: presliding"):
        seg.mask("slip")
    with pytest.raises(InputError, match="synthetic0: segmentation option 'threshold': "
                                         "found -1.0; give a positive number"):
        segment(log, threshold=-1.0)
    with pytest.raises(InputError, match="'median_window'"):
        segment(log, median_window=4)
    with pytest.raises(InputError, match="'speed_edges'"):
        segment(log, speed_edges=(0.01, 0.001))


def test_million_samples_segment():
    """1e6 noisy samples, 200 cycles: every reversal found (speed: benchmarks/segmentation_speed.py)."""
    n, cycles = 1_000_000, 200
    phase = (np.arange(n) % (n / cycles)) / (n / cycles)
    x = 2e-3 * (2 * np.abs(2 * phase - 1) - 1) + np.random.default_rng(0).normal(0, SIGMA, n)
    log = Log(name="big", displacement=x, force=np.zeros(n), time=np.arange(n) / FS)
    seg = segment(log)
    assert seg.reversals.size == 2 * cycles - 1


# ------------------------------------------------------------------------------- real data

@pytest.mark.parametrize("pressure", [1, 3, 5, 7])
def test_real_oring_logs_have_19_reversals(pressure):
    """Each file is 10 out-and-back runs starting at the bottom of the stroke and ending
    mid-way down the 10th return stroke: 20 legs, 19 turning points. The laser has ~50-90
    single-sample dropouts per file (0.2-0.6 mm back-steps) that the running median removes;
    without it they would add over 90 false reversals per file."""
    from fitstiff.io.loading import load_log

    log = load_log(REALDATA / f"O-ring_{pressure}bar.csv", fmt="zillen_oring")
    seg = segment(log)
    assert seg.reversals.size == 19
    assert seg.loops.shape == (9, 2)
    assert seg.pauses.size == 0
    # peaks and valleys alternate about 40 mm apart
    swings = np.abs(np.diff(log.displacement[seg.reversals]))
    assert np.all((swings > 37e-3) & (swings < 42e-3))


def test_one_standstill_definition_for_simulator_and_fit():
    """The simulator's dwell clock and the fit's (the segmentation's standstill region) are
    one definition: on the noise-free log they agree sample for sample, on a noisy one the
    pause edges move by at most two samples each."""
    from fitstiff.io.log import Rig
    from fitstiff.physics.programs import Concat, Pause, Ramp
    from fitstiff.physics.simulate import Noise, simulate

    program = Concat(parts=(Ramp(distance_mm=1.0, rate_mm_s=1.0), Pause(duration_s=1.0),
                            Ramp(distance_mm=-1.0, rate_mm_s=1.0), Pause(duration_s=0.5),
                            Ramp(distance_mm=0.5, rate_mm_s=1.0)))
    rig = Rig(bore=0.032, stroke=0.7, start_position=0.35, supply_pressure=6e5)
    clean = simulate("dahl+dwell_stiction", program, rig=rig, rate_hz=200.0,
                     noise=Noise(force_N=0, displacement_um=0, pressure_mbar=0))
    still = np.asarray(clean.drive.still)
    assert still.sum() > 250
    np.testing.assert_array_equal(segment(clean.log).still, still)
    noisy = simulate("dahl+dwell_stiction", program, rig=rig, rate_hz=200.0, seed=3)
    assert np.count_nonzero(segment(noisy.log).still != still) <= 8
