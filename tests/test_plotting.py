"""fitstiff.present.plotting: artists, labels with units, closed-form numbers, errors, baseline
images.

Everything draws on fresh :class:`~matplotlib.figure.Figure` objects (Agg, no pyplot state).
The fitted example comes from ``make_baselines.example_fit`` (module-scoped: one fit).
"""

from __future__ import annotations

import dataclasses
import math

import matplotlib
import numpy as np
import pytest
from make_baselines import BASELINE_DIR, FIGURES, example_fit, render
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure
from matplotlib.testing.compare import compare_images

from fitstiff.errors import InputError
from fitstiff.physics.model import build_model
from fitstiff.physics.params import Parameterization
from fitstiff.physics.stiffness import chamber_stiffness
from fitstiff.present import plotting
from fitstiff.segments.segmentation import REGIONS

IMAGE_TOLERANCE = 5.0
"""RMS pixel difference (0..255) allowed: a rerun gives 0, text rendering of another FreeType a
few; dropping the per-term forces of the loop figure costs 16, a 0.5 N shift of the fitted
curve 25, losing the dwell shading 53."""


@pytest.fixture(scope="module")
def ex():
    return example_fit()


def new_axes():
    return Figure().add_subplot()


def legend_texts(ax):
    return [t.get_text() for t in ax.get_legend().get_texts()]


def ar1_chain(phi: float, steps: int, walkers: int, seed: int = 0) -> np.ndarray:
    """Stationary AR(1) walkers with unit variance; tau = (1 + phi) / (1 - phi)."""
    rng = np.random.default_rng(seed)
    chain = np.empty((steps, walkers))
    chain[0] = rng.standard_normal(walkers)
    for i in range(1, steps):
        chain[i] = phi * chain[i - 1] + math.sqrt(1 - phi**2) * rng.standard_normal(walkers)
    return chain


# -- loops ----------------------------------------------------------------------------------------
def test_loop_draws_measured_model_band_and_terms(ex):
    ax = new_axes()
    band = (ex.force - 0.5, ex.force + 0.5)
    out = plotting.plot_loop(ax, ex.log, ex.force, band=band, contributions=ex.contributions)
    assert out is ax
    assert len(ax.lines) == 2 + len(ex.contributions)
    assert len(ax.collections) == 1 and isinstance(ax.collections[0], PolyCollection)
    assert ax.get_xlabel() == "displacement [mm]" and ax.get_ylabel() == "force [N]"
    assert legend_texts(ax) == ["predictive band", "measured", "model", "chamber",
                                "seal (Dahl)"]
    x, y = ax.lines[0].get_data()
    np.testing.assert_allclose(x, ex.log.displacement * 1e3)
    np.testing.assert_allclose(y, ex.log.force)


def test_reversal_zoom_window_picks_the_most_saturated_reversal(ex):
    """Default: the -1 mm reversal (2 mm of travel before it, 1 mm after it), 0.5 mm of travel
    after it, 15 % margins. With 1.5 mm to show, only the +1 mm reversal qualifies."""
    x = ex.log.displacement * 1e3
    low, high = plotting.reversal_zoom_window(ex.segmentation, ex.log)
    turn = x[ex.segmentation.reversals].min()
    assert turn == pytest.approx(-1.0, abs=0.025)    # within a sample (20 um) of the turn
    assert (low, high) == pytest.approx((turn - 0.075, turn + 0.5 + 0.075))
    low, high = plotting.reversal_zoom_window(ex.segmentation, ex.log, travel_mm=1.5, margin=0)
    assert (low, high) == pytest.approx((x[ex.segmentation.reversals].max() - 1.5,
                                         x[ex.segmentation.reversals].max()))
    # the first reversal is at +0.2 mm and turns back down; a negative one turns back up
    r0, r1 = x[ex.segmentation.reversals[:2]]
    assert plotting.reversal_zoom_window(ex.segmentation, ex.log, reversal=0, travel_mm=0.1,
                                         margin=0) == pytest.approx((r0 - 0.1, r0))
    assert r1 < 0
    assert plotting.reversal_zoom_window(ex.segmentation, ex.log, reversal=1, travel_mm=0.1,
                                         margin=0) == pytest.approx((r1, r1 + 0.1))


def test_zoom_fits_the_force_axis_to_the_window(ex):
    ax = new_axes()
    window = plotting.reversal_zoom_window(ex.segmentation, ex.log)
    plotting.plot_loop(ax, ex.log, ex.force, zoom=window)
    assert ax.get_xlim() == pytest.approx(window)
    x = ex.log.displacement * 1e3
    inside = (x >= window[0]) & (x <= window[1])
    lo, hi = ax.get_ylim()
    assert lo < min(ex.log.force[inside].min(), ex.force[inside].min())
    assert hi > max(ex.log.force[inside].max(), ex.force[inside].max())
    assert hi - lo < 1.2 * np.ptp(np.r_[ex.log.force[inside], ex.force[inside]])


LOOP_ERRORS = {
    "short prediction": "example: prediction: has shape ({m},), the log {n} samples; give one "
                        "value per sample of the log",
    "swapped band": "example: band: lower above upper at {n} samples; give (lower, upper) in "
                    "that order",
    "one-sided band": "example: band: has 1 arrays; give (lower, upper), one force array each",
    "short contribution": "example: contribution 'chamber': has shape ({m},)",
    "zoom outside": "example: zoom window 5..6 mm: holds no sample; choose a window within",
    "zoom reversed": "example: zoom window: found (1.0, 0.5); give (low_mm, high_mm) with "
                     "low < high",
}


@pytest.mark.parametrize("case", LOOP_ERRORS)
def test_loop_rejects_bad_input(ex, case):
    f = ex.force
    prediction, options = {
        "short prediction": (f[:-1], {}),
        "swapped band": (f, {"band": (f + 1, f - 1)}),
        "one-sided band": (f, {"band": (f,)}),
        "short contribution": (f, {"contributions": {"chamber": f[:-1]}}),
        "zoom outside": (f, {"zoom": (5.0, 6.0)}),
        "zoom reversed": (f, {"zoom": (1.0, 0.5)}),
    }[case]
    with pytest.raises(InputError) as err:
        plotting.plot_loop(new_axes(), ex.log, prediction, **options)
    n = len(ex.log)
    assert str(err.value).startswith(LOOP_ERRORS[case].format(n=n, m=n - 1))


def test_reversal_zoom_window_rejects_bad_input(ex):
    with pytest.raises(InputError, match=r"reversal 99: is not a reversal index; give a whole "
                                         r"number from -\d+ to \d+"):
        plotting.reversal_zoom_window(ex.segmentation, ex.log, reversal=99)
    with pytest.raises(InputError, match="zoom travel_mm: found -1"):
        plotting.reversal_zoom_window(ex.segmentation, ex.log, travel_mm=-1)
    with pytest.raises(InputError, match="segmentation of 'example': has \\d+ samples, the log"):
        plotting.reversal_zoom_window(ex.segmentation, ex.log.slice(0, 100))
    still = ex.log.slice(0, 5)
    from fitstiff.segments.segmentation import segment
    with pytest.raises(InputError, match="the log has no direction reversal"):
        plotting.reversal_zoom_window(segment(still), still)


# -- residuals ------------------------------------------------------------------------------------
def test_residuals_over_time_shade_every_region(ex):
    ax = new_axes()
    plotting.plot_residuals(ax, ex.log, ex.residual, ex.segmentation, against="time")
    regions = ["presliding", "sliding", "dwell", "standstill"]
    assert legend_texts(ax) == regions       # the example has all four
    assert ax.get_legend().get_title().get_text() == "region"
    shades = [c for c in ax.collections if isinstance(c, PolyCollection)]
    assert [c.get_label() for c in shades] == regions
    # the shaded spans tile the time axis: their widths add up to the log's duration
    width = sum(np.ptp(p.vertices[:, 0]) for c in shades for p in c.get_paths())
    assert width == pytest.approx(ex.log.duration)
    assert ax.get_xlabel() == "time [s]" and ax.get_ylabel() == "residual, model − measured [N]"
    np.testing.assert_allclose(ax.lines[0].get_ydata(), ex.residual)


def test_residuals_over_displacement_colour_points_by_region(ex):
    ax = new_axes()
    plotting.plot_residuals(ax, ex.log, ex.residual, ex.segmentation)
    points = [line for line in ax.lines if line.get_label() in plotting.REGION_COLORS]
    assert [p.get_label() for p in points] == legend_texts(ax)
    assert sum(len(p.get_xdata()) for p in points) == len(ex.log)
    assert {p.get_color() for p in points} == {plotting.REGION_COLORS[p.get_label()]
                                               for p in points}
    assert ax.get_xlabel() == "displacement [mm]"


def test_residuals_reject_bad_input(ex):
    with pytest.raises(InputError, match=r"example: residual: has shape \(\d+,\)"):
        plotting.plot_residuals(new_axes(), ex.log, ex.residual[1:], ex.segmentation)
    with pytest.raises(InputError, match="residuals against 'stroke': is not an axis; use "
                                         "against='displacement' or against='time'"):
        plotting.plot_residuals(new_axes(), ex.log, ex.residual, ex.segmentation,
                                against="stroke")
    quasi_static = ex.log.replace(time=None)
    with pytest.raises(InputError, match="the log has no time column"):
        plotting.plot_residuals(new_axes(), quasi_static, ex.residual, ex.segmentation,
                                against="time")


def test_residuals_by_direction_colour_each_direction_and_grey_the_unfitted(ex):
    ax = new_axes()
    used = np.zeros(len(ex.log), dtype=bool)
    used[len(ex.log) // 3:] = True
    plotting.plot_residuals(ax, ex.log, ex.residual, ex.segmentation, by="direction", used=used)
    assert ax.get_legend().get_title().get_text() == "direction"
    labels = legend_texts(ax)
    assert labels[-1] == "not fitted" and set(labels[:-1]) <= set(plotting.DIRECTION_COLORS)
    points = {line.get_label(): line for line in ax.lines if line.get_label() in labels}
    assert sum(len(p.get_xdata()) for p in points.values()) == len(ex.log)
    assert len(points["not fitted"].get_xdata()) == np.count_nonzero(~used)
    toward_b = (ex.segmentation.direction == 1) & used
    np.testing.assert_allclose(points["toward B"].get_ydata(), ex.residual[toward_b])
    # the force axis is the fitted residuals' scale
    low, high = ax.get_ylim()
    assert low <= ex.residual[used].min() and high >= ex.residual[used].max()
    assert high - low < 1.2 * (max(ex.residual[used].max(), 0) - min(ex.residual[used].min(), 0))
    with pytest.raises(InputError, match="residuals by 'speed': is not a colouring"):
        plotting.plot_residuals(new_axes(), ex.log, ex.residual, ex.segmentation, by="speed")


def test_loop_draws_one_presliding_curve_and_unfitted_samples_grey(ex):
    seg, log = ex.segmentation, ex.log
    run = plotting.reversal_zoom_samples(seg, log)
    assert run.start in seg.reversals
    x = log.displacement[run] * 1e3
    travel = np.abs(x - x[0])
    assert travel[-1] >= seg.presliding_range * 1e3 > travel[-2]    # stops at the travel
    # the same reversal as the displacement window's
    low, high = plotting.reversal_zoom_window(seg, log, margin=0)
    assert math.isclose(x[0], low) or math.isclose(x[0], high)
    ax = new_axes()
    plotting.plot_loop(ax, log, ex.force, samples=run)
    np.testing.assert_allclose(ax.lines[0].get_ydata(), log.force[run])
    assert ax.get_xlim()[0] >= x.min() - 0.1 * np.ptp(x)    # scaled to the one curve
    used = np.ones(len(log), dtype=bool)
    used[run.start:] = False
    earlier = plotting.reversal_zoom_samples(seg, log, used=used)
    assert earlier.stop <= run.start                        # a curve among the fitted samples
    ax = new_axes()
    plotting.plot_loop(ax, log, ex.force, used=used, measured=log.force - 1.0,
                       measured_label="measured - 1 N")
    assert legend_texts(ax) == ["not fitted", "measured - 1 N", "model"]
    shifted = ax.lines[1].get_ydata()
    assert np.isnan(shifted[~used]).all()
    np.testing.assert_allclose(shifted[used], log.force[used] - 1.0)
    with pytest.raises(InputError, match="is not a run of samples"):
        plotting.plot_loop(new_axes(), log, ex.force, samples=[1, 2, 3])
    with pytest.raises(InputError, match="hold fewer than two samples"):
        plotting.plot_loop(new_axes(), log, ex.force, samples=slice(5, 6))


def test_sliding_friction_level_is_half_the_gap_between_directions(ex):
    seg = ex.segmentation
    level = 3.0
    # a friction square wave plus an offset and a spring: only the friction survives
    force = (level * seg.direction + 7.0 + 2000.0 * ex.log.displacement)
    sliding = seg.region == 1
    assert REGIONS[1] == "sliding" and sliding.any()
    got = plotting.sliding_friction_level(force, seg)
    spring = 2000.0 * ex.log.displacement
    expected = 0.5 * abs(np.median((level + 7 + spring)[sliding & (seg.direction == 1)])
                         - np.median((-level + 7 + spring)[sliding & (seg.direction == -1)]))
    assert got == pytest.approx(expected)
    assert plotting.sliding_friction_level(force, seg, used=np.zeros(len(force), bool)) != \
        plotting.sliding_friction_level(force, seg, used=np.zeros(len(force), bool))   # NaN
    ax = new_axes()
    plotting.plot_friction_levels(ax, [1.0, 3.0, 5.0], [4.0, 5.5, 7.0], [6.0, 6.0, 6.0],
                                  names=["a", "b", "c"])
    assert legend_texts(ax) == ["measured", "model"]
    assert ax.get_xlabel() == "pressure [bar gauge]" and ax.get_ylim()[0] == 0.0


# -- chamber against seal over the stroke ---------------------------------------------------------
def test_contributions_over_stroke_match_closed_forms(ex):
    model, rig = ex.result.model, ex.log.rig
    c = plotting.contributions_over_stroke(model, rig, displacement_mm=0.5)
    sigma0, fc = ex.result.value("sigma0"), ex.result.value("Fc")
    # Dahl from negative saturation: F(u) - F(0) = 2 Fc (1 - exp(-sigma0 u / Fc))
    assert c.seal_N == pytest.approx(2 * fc * -math.expm1(-sigma0 * 0.5e-3 / fc), rel=1e-4)
    mid = np.argmin(abs(c.position_mm - 350))
    exact = chamber_stiffness(rig, position=c.position_mm[mid] * 1e-3, displacement=0.5e-3,
                              n=ex.result.value("n"))
    assert c.chamber_N[mid] == pytest.approx(exact.force_exact)
    # eq. 15, the notebook's number, at the example's true n = 1.4 (the fit's n carries the
    # bias of the stiction peaks it leaves out)
    truth = Parameterization(model).with_values(model, {"n": 1.4})
    at_truth = plotting.contributions_over_stroke(truth, rig, displacement_mm=0.5)
    assert at_truth.chamber_N[mid] == pytest.approx(2.26, abs=0.03)
    assert c.position_mm.min() >= 0.5 and c.position_mm.max() + 0.5 <= 700 - 0.5
    # one crossover near each cap, where the chamber force equals the seal's
    assert c.crossover_mm.shape == (2,)
    assert c.crossover_mm[0] < 50 and c.crossover_mm[1] > 650
    np.testing.assert_allclose(np.interp(c.crossover_mm, c.position_mm, c.chamber_N), c.seal_N,
                               rtol=0.02)


@pytest.mark.parametrize("stiffness, ylabel", [
    (False, "restoring force over 0.5 mm [N]"),
    (True, "secant stiffness over 0.5 mm [N/mm]"),
])
def test_contributions_over_stroke_plot(ex, stiffness, ylabel):
    ax = new_axes()
    plotting.plot_contributions_over_stroke(ax, ex.result, stiffness=stiffness)
    assert ax.get_ylabel() == ylabel and ax.get_yscale() == "log"
    assert ax.get_xlabel() == "piston position x (length of chamber A) [mm]"
    assert legend_texts(ax)[1:] == ["seal (pre-sliding curve)", "total", "crossover",
                                    "closing position 350 mm"]
    c = plotting.contributions_over_stroke(ex.result.model, ex.log.rig)
    assert [t.get_text() for t in ax.texts] == [f"{x:.0f} mm" for x in c.crossover_mm]
    seal = ax.lines[1].get_ydata()
    assert seal[0] == pytest.approx(c.seal_N / (0.5 if stiffness else 1.0))


def test_contributions_over_stroke_reject_bad_input(ex):
    with pytest.raises(InputError, match="model 'dahl': needs a chamber term and a friction base"):
        plotting.contributions_over_stroke(build_model("dahl"), ex.log.rig)
    with pytest.raises(InputError, match="a model was given without a rig"):
        plotting.plot_contributions_over_stroke(new_axes(), ex.result.model)
    with pytest.raises(InputError, match="displacement_mm: found 0"):
        plotting.contributions_over_stroke(ex.result.model, ex.log.rig, displacement_mm=0)
    no_stroke = dataclasses.replace(ex.log.rig, stroke=None)
    with pytest.raises(InputError, match="rig metadata 'stroke_mm'"):
        plotting.contributions_over_stroke(ex.result.model, no_stroke)


# -- posterior ------------------------------------------------------------------------------------
def test_corner_draws_a_grid_with_labels():
    rng = np.random.default_rng(1)
    samples = rng.normal([40.0, 18.0, 1.4], [0.1, 0.05, 0.004], size=(2000, 3))
    names = ["sigma0 [N/mm]", "Fc [N]", "n [-]"]
    fig = plotting.plot_corner(Figure(figsize=(6, 6)), samples, names, truths=[40, 18, 1.4])
    assert len(fig.axes) == 9
    bottom = fig.axes[6:]
    assert [ax.get_xlabel() for ax in bottom] == names
    low, mid, high = np.quantile(samples[:, 0], [0.05, 0.5, 0.95])
    assert fig.axes[0].get_title() == (f"sigma0 [N/mm]\n${mid:.2f}^{{+{high - mid:.2f}}}"
                                       f"_{{-{mid - low:.2f}}}$")   # 0.16: 2 digits
    assert fig.axes[8].get_title() == "n [-]\n$1.3997^{+0.0069}_{-0.0067}$"   # 4 decimals


@pytest.mark.parametrize("samples, names, options, message", [
    (np.zeros((10, 2)), ["a"], {}, r"corner samples: have shape \(10, 2\) for 1 names"),
    (np.ones((10, 2)), ["a", "b"], {"truths": [1.0]}, "corner truths: 1 values for 2 names"),
    (np.full((10, 1), np.nan), ["a"], {}, "corner samples: contain NaN or inf"),
    (np.ones((10, 1)), ["a"], {"quantiles": (0.5, 0.05, 0.95)}, "corner quantiles: found"),
])
def test_corner_rejects_bad_input(samples, names, options, message):
    with pytest.raises(InputError, match=message):
        plotting.plot_corner(Figure(), samples, names, **options)


def test_trace_draws_every_walker_and_the_median():
    chain = 40 + 0.1 * ar1_chain(0.5, 200, 8)
    ax = plotting.plot_trace(new_axes(), chain, "sigma0", unit="N/mm")
    assert len(ax.lines) == 8 + 1
    assert ax.get_ylabel() == "sigma0 [N/mm]" and ax.get_xlabel() == "step"
    assert legend_texts(ax) == ["walkers (8)", "median over walkers"]
    np.testing.assert_allclose(ax.lines[-1].get_ydata(), np.median(chain, axis=1))


def test_autocorr_estimate_levels_off_at_the_ar1_value():
    """AR(1) with phi = 0.8 has tau = 9; 4000 steps x 32 walkers estimate it within 15 %."""
    ax = plotting.plot_autocorr(new_axes(), ar1_chain(0.8, 4000, 32), "Fc", points=8)
    lengths, tau = ax.lines[0].get_data()
    assert lengths[0] == 10 and lengths[-1] == 4000 and len(lengths) == 8
    assert tau[-1] == pytest.approx(9.0, rel=0.15)
    np.testing.assert_allclose(ax.lines[1].get_ydata(), lengths / 50)
    assert ax.get_xscale() == ax.get_yscale() == "log"
    assert ax.get_ylabel() == "integrated autocorrelation time tau [steps]"
    assert legend_texts(ax) == ["tau estimate, Fc", "N / 50"]


@pytest.mark.parametrize("chain, message", [
    (np.zeros(10), r"chain of 'n': has shape \(10,\); give a \(steps, walkers\) array"),
    (np.full((20, 2), np.inf), "chain of 'n': contains NaN or inf"),
])
def test_chain_plots_reject_bad_input(chain, message):
    for draw in (plotting.plot_trace, plotting.plot_autocorr):
        with pytest.raises(InputError, match=message):
            draw(new_axes(), chain, "n")
    with pytest.raises(InputError, match="chain of 'n': has 5 steps; give at least 10 steps"):
        plotting.plot_autocorr(new_axes(), np.zeros((5, 2)), "n")


# -- images ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(FIGURES))
def test_figure_matches_its_baseline(ex, name, tmp_path):
    """Regenerate with ``python tests/make_baselines.py`` after an intended change."""
    actual = render(name, ex, tmp_path / f"{name}.png")
    failure = compare_images(str(BASELINE_DIR / f"{name}.png"), str(actual), tol=IMAGE_TOLERANCE)
    assert failure is None, failure


def test_rendering_leaves_no_global_state(ex, tmp_path):
    import matplotlib.pyplot as plt

    before = dict(matplotlib.rcParams)
    render("loop_zoom", ex, tmp_path / "loop.png")
    assert plt.get_fignums() == []
    assert dict(matplotlib.rcParams) == before
