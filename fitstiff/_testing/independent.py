"""Independent seal sets of issue 31: one physical effect each, simulated by the NumPy rig
simulator (:mod:`fitstiff._testing.rig_sim`, no physics code shared with the fit) in a form
the diagnosis' term only approximates.

``junction_dwell``  pauses at the turning points, the motion continuing or reversing after
                    them, and stiction that ages with the pause: a junction that loads from the
                    pause position and breaks at ``gain ln(1 + pause / tau)`` (the term is a
                    smooth peak).
``maxwell_seal``    a seal whose friction is a Maxwell-slip law of a few unequal elements, no
                    Dahl; the candidate sits on a Dahl baseline and must take over.
``leaky_chambers``  a leak past the piston (time constant 4 s) with the chamber pressures
                    not logged, rates 0.2-20 mm/s, displaced holds: the leak rate enters
                    strongly nonlinearly, far beyond a one-step value.

``benchmarks/independent_sets.py`` diagnoses the full-size sets; the suite runs a small one.
"""

from __future__ import annotations

import numpy as np

from fitstiff._testing import rig_sim as rs

__all__ = ["junction_dwell", "leaky_chambers", "maxwell_seal"]


def junction_dwell(*, gain: float = 4.0, tau: float = 0.5, decay: float = 0.1e-3,
                   noise_N: float = 0.2, rate_hz: float = 500.0, small: bool = False,
                   seed: int = 0) -> list:
    """Logs with pauses at turning points and a junction-type dwell stiction (``gain`` N per
    unit of ``ln(1 + pause / tau)``, breaking ``decay`` m from the pause position). Four logs
    with pauses of 0.5-20 s (about 21 000 samples at 500 Hz), or ``small``: three logs with
    pauses of 0.5-5 s at 250 Hz (about 5 000 samples). ``gain = 0``: the same logs without
    the effect."""
    rng = np.random.default_rng([seed, 31])
    pauses = ([(0.5, 2.0, 5.0), (1.0, 3.0, 0.7), (4.0, 0.5, 1.5)] if small else
              [(0.5, 2.0, 8.0), (1.0, 4.0, 20.0), (0.7, 3.0, 12.0), (1.5, 6.0, 15.0)])
    speeds = (1.0, 2.0, 4.0, 1.5)
    supplies = (4e5, 5e5, 6e5, 4.5e5)
    logs = []
    for i, (p1, p2, p3) in enumerate(pauses):
        v = speeds[i]
        segs = rs.triangles((0.3,), v)
        # reverses after the first two pauses, continues after the third
        segs += [rs.leg(1.0, v), rs.pause(p1), rs.leg(-1.0, v), rs.pause(p2),
                 rs.leg(-2.0, v), rs.leg(0.5, v), rs.pause(p3), rs.leg(2.0, v),
                 rs.leg(0.0, v)]
        base = rs.Base(sigma0=40e3, Fc=18.0, n=1.3, x0=(0.2, 0.35, 0.5, 0.3)[i],
                       supply=supplies[i])
        effects = ({"dwell_stiction": {"gain": gain, "tau": tau, "decay": decay}}
                   if gain else {})
        log, _ = rs.simulate_log(rs.Program(tuple(segs), description=f"junction dwell {i}"),
                                 base=base, effects=effects,
                                 noise=rs.SensorNoise(force_N=noise_N), rate_hz=rate_hz,
                                 rng=rng, name=f"junction_dwell_{i}", p_ref=5e5)
        logs.append(log)
    return logs


def maxwell_seal(*, k: tuple[float, ...] = (25e3, 10e3, 5e3),
                 delta: tuple[float, ...] = (0.1e-3, 0.4e-3, 1.0e-3), noise_N: float = 0.2,
                 rate_hz: float = 250.0, small: bool = False, seed: int = 0) -> list:
    """Logs of a seal whose friction **is** a Maxwell-slip law (no Dahl): elements of
    stiffness ``k`` (N/m) and slip displacement ``delta`` (m), unequal, on four logs (three,
    shorter, when ``small``) of growing triangles with nested minor loops at 1-8 mm/s."""
    rng = np.random.default_rng([seed, 32])
    speeds = (1.0, 3.0, 8.0, 2.0)[: 3 if small else 4]
    logs = []
    for i, v in enumerate(speeds):
        segs = rs.triangles((0.2, 0.6) if small else (0.2, 0.6, 1.5), v)
        # a large loop with nested minor loops (non-local memory)
        segs += [rs.leg(1.2, v), rs.leg(0.6, v), rs.leg(1.0, v), rs.leg(-1.2, v),
                 rs.leg(-0.5, v), rs.leg(-0.9, v), rs.leg(0.3, v), rs.leg(0.0, v)]
        base = rs.Base(Fc=0.0, n=1.3, x0=(0.2, 0.35, 0.5, 0.3)[i],
                       supply=(3e5, 4.5e5, 6e5, 5e5)[i])
        log, _ = rs.simulate_log(rs.Program(tuple(segs), description=f"maxwell seal {i}"),
                                 base=base,
                                 effects={"maxwell_slip": {"k": list(k), "delta": list(delta)}},
                                 noise=rs.SensorNoise(force_N=noise_N), rate_hz=rate_hz,
                                 rng=rng, name=f"maxwell_seal_{i}", p_ref=4.5e5)
        logs.append(log)
    return logs


def leaky_chambers(*, rate: float = 0.25, noise_N: float = 0.2, small: bool = False,
                   seed: int = 0) -> list:
    """Logs of closed chambers that leak past the piston (``rate`` 1/s: the pressure
    difference relaxes with time constant ``1 / rate``), pressures not logged: per log a
    stroke of 3 mm held for 3 s (8 s unless ``small``), back, and triangles of 0.3 mm (and
    1 mm unless ``small``), at 0.2, 2 and 20 mm/s (and 5 mm/s unless ``small``)."""
    rng = np.random.default_rng([seed, 33])
    speeds = (0.2, 2.0, 20.0) if small else (0.2, 2.0, 20.0, 5.0)
    hold = 3.0 if small else 8.0
    logs = []
    for i, v in enumerate(speeds):
        side = 3.0 if i % 2 == 0 else -3.0
        segs = [rs.leg(side, max(v, 2.0)), rs.pause(hold), rs.leg(0.0, max(v, 2.0)),
                rs.pause(1.0)]
        segs += rs.triangles((0.3,) if small else (0.3, 1.0), v)
        base = rs.Base(n=1.3, x0=(0.15, 0.35, 0.55, 0.25)[i],
                       supply=(6e5, 4e5, 5e5, 6e5)[i])
        log, _ = rs.simulate_log(rs.Program(tuple(segs), description=f"leaky chambers {i}"),
                                 base=base, effects={"leakage": {"rate": rate}},
                                 noise=rs.SensorNoise(force_N=noise_N, log_pressures=False),
                                 rate_hz=200.0 if v < 5 else 500.0, rng=rng,
                                 name=f"leaky_chambers_{i}", p_ref=5e5)
        logs.append(log)
    return logs
