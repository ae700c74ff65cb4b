"""Baseline images of ``tests/test_plotting.py``: the example fit, the figures, the rendering.

After an intended change to one of these figures, rewrite the baselines and look at them::

    python tests/make_baselines.py

Every baseline is a figure of :mod:`fitstiff.present.plotting` drawn from :func:`example_fit` (a
fixed-seed synthetic log fitted with ``fitstiff.inference.fitting.fit``) by :func:`render`, which
fixes what makes a PNG differ from run to run: matplotlib's default style (no user rc file), the
DejaVu Sans font that ships with matplotlib, the figure size and resolution, and no software
tag in the file. The tests draw the same figures the same way and compare them with
:func:`matplotlib.testing.compare.compare_images`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import matplotlib
import matplotlib.style
import numpy as np
from matplotlib.figure import Figure

from fitstiff.data import paper_rig
from fitstiff.inference.fitting import FitResult, fit
from fitstiff.io.log import Log, Rig
from fitstiff.physics.programs import TriangleCycles
from fitstiff.physics.simulate import simulate
from fitstiff.present import plotting
from fitstiff.segments.segmentation import Segmentation

BASELINE_DIR = Path(__file__).resolve().with_name("baseline_images")
DPI = 80
RC = {"font.family": "DejaVu Sans", "text.hinting": "default"}


@dataclasses.dataclass(frozen=True)
class Example:
    """A fitted log and what the figures need from the fit (forces in N per sample)."""

    result: FitResult
    log: Log
    segmentation: Segmentation
    force: np.ndarray
    contributions: dict[str, np.ndarray]
    residual: np.ndarray


def example_fit() -> Example:
    """The paper's cylinder at 6 bar, mid-stroke, with a dwell effect the fit leaves out.

    Triangle cycles of 0.2, 0.5 and 1 mm at 2 mm/s with 0.5 s pauses at the zero crossings,
    simulated as ``chamber+dahl+dwell_stiction`` and fitted as ``chamber+dahl``: the residuals
    show the unmodelled stiction peak after every pause (region ``dwell``).
    """
    rig = Rig.from_mapping(paper_rig())
    program = TriangleCycles(amplitudes_mm=(0.2, 0.5, 1.0), rate_mm_s=2.0, pause_s=(0.5,),
                             pause_at="passes")
    sim = simulate("chamber+dahl+dwell_stiction", program, rig=rig, seed=11, rate_hz=100.0,
                   params={"n": 1.4, "sigma0": 40, "Fc": 18, "dwell_gain": 7.0},
                   name="example")
    result = fit([sim.log], "chamber+dahl")
    predicted = result.problem.per_log(result.theta)[0]
    log = result.problem.logs[0]
    return Example(result=result, log=log, segmentation=result.problem.segmentations[0],
                   force=predicted["force"],
                   contributions=dict(zip(("chamber", "seal (Dahl)"),
                                          predicted["contributions"].T, strict=True)),
                   residual=predicted["force"] - log.force)


def draw_loop_zoom(fig: Figure, ex: Example) -> None:
    """The whole loop with per-term forces, and the zoom after the -1 mm reversal."""
    full, zoomed = fig.subplots(1, 2)
    noise = ex.result.problem.force_noise[0]
    band = (ex.force - 2 * noise, ex.force + 2 * noise)
    plotting.plot_loop(full, ex.log, ex.force, band=band, contributions=ex.contributions,
                       label="fit chamber+dahl")
    window = plotting.reversal_zoom_window(ex.segmentation, ex.log)
    plotting.plot_loop(zoomed, ex.log, ex.force, band=band, zoom=window,
                       label="fit chamber+dahl")
    zoomed.set_title("0.5 mm after the reversal at -1 mm", fontsize="medium")


def draw_residuals(fig: Figure, ex: Example) -> None:
    """Residuals over time and over displacement, by region."""
    over_time, over_x = fig.subplots(1, 2)
    plotting.plot_residuals(over_time, ex.log, ex.residual, ex.segmentation, against="time")
    plotting.plot_residuals(over_x, ex.log, ex.residual, ex.segmentation)


FIGURES: dict[str, tuple[Callable[[Figure, Example], None], tuple[float, float]]] = {
    "loop_zoom": (draw_loop_zoom, (10.0, 4.0)),
    "residuals_regions": (draw_residuals, (10.0, 4.2)),
}
"""Baseline name -> (drawing function, figure size in inches)."""


def render(name: str, ex: Example, path: Path) -> Path:
    """Draw figure ``name`` of :data:`FIGURES` for ``ex`` and write it as a PNG to ``path``."""
    draw, size = FIGURES[name]
    with matplotlib.style.context("default"), matplotlib.rc_context(RC):
        fig = Figure(figsize=size, dpi=DPI, layout="constrained")
        draw(fig, ex)
        fig.savefig(path, dpi=DPI, metadata={"Software": None})
    return path


def main() -> None:
    BASELINE_DIR.mkdir(exist_ok=True)
    ex = example_fit()
    for name in FIGURES:
        print(f"wrote {render(name, ex, BASELINE_DIR / f'{name}.png')}")


if __name__ == "__main__":
    main()
