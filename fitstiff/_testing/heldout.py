"""Held-out figures by plain public calls: the independent path that the diagnosis' folds are
checked against (issue 31).

Nothing here shares code with :mod:`fitstiff.diagnosis`: no super-model, no masks, no fold
starts. Leave one log out is :func:`fitstiff.inference.comparison.held_out_rms` (``fit`` on the
other logs; the left-out log predicted with the model held and only its own nuisances fitted).
Leave one block out is ``fit`` of the one log with the block excluded (``exclude=``), the
block predicted by the fitted model; the block that starts the log has its initial friction
state fitted to it (the model and the trained offset held), as a left-out log has.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Sequence

import numpy as np

from fitstiff.inference.comparison import held_out_rms
from fitstiff.inference.fitting import fit
from fitstiff.io.log import Log
from fitstiff.physics.params import named_params

__all__ = ["leave_one_log_out", "leave_one_block_out", "blocks_of", "pooled"]


def leave_one_log_out(logs: Sequence[Log], spec: str, **fit_kw) -> list[float]:
    """Per log, the RMS force error (N) of ``spec`` fitted to the other logs."""
    return held_out_rms(list(logs), spec, **fit_kw)


def leave_one_block_out(log: Log, spec: str, blocks: Sequence[tuple[int, int]],
                        **fit_kw) -> np.ndarray:
    """The held-out residual (model - measured, N) of ``log``: each block ``(start, stop)``
    predicted by ``spec`` fitted to the rest of the log."""
    residual = np.full(len(log), np.nan)
    force = np.asarray(log.force)
    for start, stop in blocks:
        result = fit([log], spec, exclude=[(start, stop)], **fit_kw)
        predicted = result.problem.per_log(result.theta)[0]["force"]
        if start == 0 and "friction_state0" in result.problem.nuisance_names:
            # the first block owns the initial friction state (the rest of the log does not
            # inform it): fitted to the block with the model and the trained offset held
            offset = float(result.per_log[0]["offset_N"])
            shifted = dataclasses.replace(log, force=force - offset)
            held = [n for _, _, names in named_params(result.model) for n in names]
            own = fit([shifted], result.model, fix=[*held, "offset"],
                      sample_range=(start, stop), **fit_kw)
            predicted = own.problem.per_log(own.theta)[0]["force"] + offset
        residual[start:stop] = predicted[start:stop] - force[start:stop]
    return residual


def blocks_of(folds: Sequence[str]) -> list[tuple[int, int]]:
    """``(start, stop)`` of the blocks a diagnosis of one log held out, read from its fold
    descriptions (``"leave out samples 0-1234 of log x"``)."""
    out = []
    for text in folds:
        found = re.match(r"leave out samples (\d+)-(\d+) of log", text)
        if found is None:
            raise ValueError(f"not a block fold: {text!r}")
        out.append((int(found.group(1)), int(found.group(2)) + 1))
    return out


def pooled(per_log: Sequence[float], counts: Sequence[int]) -> float:
    """The RMS over all samples from per-log RMS values and their sample counts."""
    counts = np.asarray(counts, dtype=float)
    return math.sqrt(float(np.sum(counts * np.square(per_log)) / counts.sum()))
