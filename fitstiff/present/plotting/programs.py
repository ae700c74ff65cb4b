"""A planned program (:mod:`fitstiff.planning`): the displacement against time, and where the
rival models' predicted forces on it part."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from matplotlib.axes import Axes
from numpy.typing import ArrayLike

__all__ = ["plot_program"]


def plot_program(ax: Axes, time_s: ArrayLike, displacement_mm: ArrayLike, *,
                 forces_N: Mapping[str, ArrayLike] | None = None,
                 force_ax: Axes | None = None, noise_N: float | None = None) -> Axes:
    """The program's displacement (mm, black) against time on ``ax``; on ``force_ax`` the
    difference between the two rivals' predicted forces on it (N, the first named minus the
    second; the rivals' forces are alike to the eye, their difference is what the program is
    for), with the logs' noise floor ``noise_N`` as a grey band."""
    t = np.asarray(time_s, dtype=float)
    ax.plot(t, np.asarray(displacement_mm, dtype=float), color="black", lw=1.0)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("displacement (mm)")
    if forces_N and force_ax is not None and len(forces_N) >= 2:
        (a, fa), (b, fb) = list(forces_N.items())[:2]
        if noise_N:
            force_ax.axhspan(-noise_N, noise_N, color="0.85", label="noise floor")
        force_ax.plot(t, np.asarray(fa, dtype=float) - np.asarray(fb, dtype=float),
                      color="tab:red", lw=1.0,
                      label=f"{a.replace('_', ' ')} - {b.replace('_', ' ')}")
        force_ax.set_ylabel("predicted force difference (N)")
        force_ax.set_xlabel("time (s)")
        force_ax.legend(loc="upper right", fontsize=8)
    return ax
