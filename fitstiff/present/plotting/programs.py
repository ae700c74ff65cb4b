"""A planned program (:mod:`fitstiff.planning`): the displacement against time, with the rival
models' predicted forces on it."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from matplotlib.axes import Axes
from numpy.typing import ArrayLike

__all__ = ["plot_program"]

_RIVAL_COLORS = ("tab:red", "tab:blue", "tab:green", "tab:purple")


def plot_program(ax: Axes, time_s: ArrayLike, displacement_mm: ArrayLike, *,
                 forces_N: Mapping[str, ArrayLike] | None = None,
                 force_ax: Axes | None = None) -> Axes:
    """The program's displacement (mm, black) against time on ``ax`` and, on ``force_ax``
    (e.g. ``ax.twinx()`` or an axes below), each rival's predicted force (N) on it, one
    colour per rival; where the rivals' forces part is what the program is for."""
    t = np.asarray(time_s, dtype=float)
    ax.plot(t, np.asarray(displacement_mm, dtype=float), color="black", lw=1.0,
            label="displacement")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("displacement (mm)")
    if forces_N and force_ax is not None:
        for (name, force), color in zip(forces_N.items(), _RIVAL_COLORS):
            force_ax.plot(t, np.asarray(force, dtype=float), color=color, lw=1.0,
                          label=name.replace("_", " "))
        force_ax.set_ylabel("predicted force (N)")
        force_ax.set_xlabel("time (s)")
        force_ax.legend(loc="upper right", fontsize=8)
    return ax
