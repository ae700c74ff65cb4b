"""The log of the speed benchmarks (``benchmarks/fit_speed.py``, ``benchmarks/posterior_speed.py``)
and of the test that their NumPy reference is fitstiff's log-posterior."""

from __future__ import annotations

from fitstiff.log import Log, Rig
from fitstiff.programs import TriangleCycles
from fitstiff.simulate import Noise, simulate

RIG = Rig.from_mapping({"bore_mm": 32, "stroke_mm": 700, "start_position_mm": 350,
                        "supply_bar": 6})


def make_log() -> Log:
    """One 4 000-sample ``chamber+dahl`` log (paper cylinder, 6 bar, 1.1 kHz, sigma0 40 N/mm,
    Fc 18 N, n 1.3; 0.2 N, 1 um, 2 mbar noise)."""
    program = TriangleCycles(rate_mm_s=2.0, amplitudes_mm=(0.05, 0.1, 0.2, 0.5, 1.0),
                             cycles=1)
    sim = simulate("chamber+dahl", program, rig=RIG, params={"sigma0": 40, "Fc": 18, "n": 1.3},
                   noise=Noise(force_N=0.2, displacement_um=1.0, pressure_mbar=2.0),
                   seed=1, name="bench", rate_hz=1100.0)   # 4 070 samples
    return sim.log.slice(0, 4000)
