"""Shared test helpers."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:   # small versions of the benchmarks run in the suite
    sys.path.insert(0, str(REPO))
SHARED = REPO.parent / "shared"
REALDATA = SHARED / "realdata" / "pneumatic-seal-friction"


def triangle(amplitudes, *, rate=1e-3, fs=1000.0):
    """Time and displacement (SI) of a triangle program: 0 -> +a1 -> -a1 -> +a2 ... -> 0."""
    points = [0.0]
    for a in amplitudes:
        points += [a, -a]
    return polyline(points + [0.0], rate=rate, fs=fs)


def polyline(points, *, rate=1e-3, fs=1000.0):
    """Piecewise-linear displacement through ``points`` (m) at ``rate`` (m/s)."""
    t = [np.zeros(1)]
    x = [np.array([points[0]], dtype=float)]
    t0 = 0.0
    for p0, p1 in zip(points[:-1], points[1:]):
        n = max(2, int(round(abs(p1 - p0) / rate * fs)))
        u = np.linspace(0, 1, n + 1)[1:]
        t.append(t0 + u * abs(p1 - p0) / rate)
        x.append(p0 + u * (p1 - p0))
        t0 = t[-1][-1]
    return np.concatenate(t), np.concatenate(x)


@pytest.fixture
def paper_rig():
    from fitstiff.log import Rig

    return Rig.from_mapping({"bore_mm": 32, "rod_mm": 0, "stroke_mm": 700,
                             "start_position_mm": 350, "supply_bar": 6})
