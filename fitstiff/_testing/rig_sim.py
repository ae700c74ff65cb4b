"""An independent NumPy rig simulator for the withheld-effect datasets (issue 12).

The data of the withheld-effect benchmark (:mod:`fitstiff._testing.withheld`, run by
``benchmarks/withheld.py``) must not come from the code path the fit uses: this module shares
no physics code with :mod:`fitstiff` (it only builds :class:`fitstiff.io.log.Log` objects at the
end). It differs from :func:`fitstiff.physics.simulate.simulate` on purpose:

- the displacement program is rendered on a grid ``substeps`` (default 15) times finer than
  the logged samples, its corners rounded by a short Hann smoothing (finite accelerations, as
  a real actuator gives), and the logged channels are decimated from it;
- the state ``(p_A, p_B, T_A, T_B, F_dahl)`` is integrated by classical RK4 in time per
  sub-step, from the ODE form of every law (fitstiff steps exact per-sample solutions):

      dp_A/dt = -n p_A v / L_A - h p_A (T_A - 1) / T_A - lambda (p_A - p_eq)
      dT_A/dt = -(n - 1) T_A v / L_A - h (T_A - 1)            (B: v -> -v, L_B = L_B0 - u)
      dF/dt   = sigma0 s v (1 - F / (Fc l) sgn v)             (Dahl, alpha = 1)

  with ``p_eq = (p_A V_A + p_B V_B) / (V_A + V_B)`` (a leak conserves ``p_A V_A + p_B V_B``),
  ``T`` the gas temperature over the wall's, ``l`` and ``s`` the friction level and slope
  factors of the modifiers;
- Maxwell-slip elements are clipped per sub-step, the rig compliance is integrated in its
  differential form ``du = dx_sensor / (1 + C K)`` with ``K`` the tangent stiffness of the
  force (fitstiff solves ``x_p = x_s - C F`` by Newton per sample), the time delay is applied
  by interpolating the fine force at ``t - delay``;
- sensor noise: AR(1) force noise, displacement noise quantised to the encoder step,
  pressure noise; out-of-library effects (guide ripple, load-cell hysteresis, force
  quantisation) act on the fine force or on the force channel.

Every effect has the parameter meaning of the fitstiff term of the same name (SI here):

=================  ===========================================================================
viscous            ``c`` N s/m: force ``c v``
stribeck           ``ratio``, ``vs`` m/s: level ``1 + (ratio - 1) exp(-(v/vs)^2)``
asymmetry          ``level``, ``slope``: factors ``1 + a d``, ``1 + b d`` (d: last direction)
pressure_friction  ``beta`` 1/Pa, ``p_ref`` Pa gauge: level ``exp(beta (p_supply - p_ref))``
dwell_stiction     ``gain`` N, ``tau`` s, ``decay`` m: a junction that forms at the position
                   where a standstill starts, of strength ``S = gain ln(1 + t_dwell/tau)``;
                   it loads elastically (stiffness ``S / decay``) from that position
                   whichever way the motion resumes, breaks at ``S`` and releases over
                   ``decay / 5`` of further travel (fitstiff's term is a smooth peak instead);
                   ``kind="level"``: a friction level factor
                   ``1 + gain (1 - exp(-t_dwell/tau)) exp(-travel/decay)`` instead
heat_transfer      ``rate`` 1/s (gas temperature relaxes to the wall's; ``n`` is then 1.4)
leakage            ``rate`` 1/s (pressure difference relaxes, ``p_A V_A + p_B V_B`` kept)
inertia            ``mass`` kg: force ``m a``
force_drift        ``drift`` N/s: force channel offset ``drift (t - t0)``
time_delay         ``delay`` s: the force channel shows the force of ``t - delay``
rig_compliance     ``compliance`` m/N: piston ``u = x_sensor - C F``
maxwell_slip       ``k`` N/m, ``delta`` m per element (slip force ``k delta``), beside the Dahl
chamber            (present or not: the ``dahl`` baseline's withheld effect)
=================  ===========================================================================

Out of the library (``out_of_library``; none of them is a fitstiff term):

=====================  =======================================================================
ripple                 ``amplitude`` N, ``wavelength`` m, ``phase``: a force
                       ``A sin(2 pi x / wavelength + phase)`` of the absolute position ``x``
tight_spot             ``gain``, ``centre`` m, ``width`` m: friction level
                       ``1 + gain exp(-((x - centre) / width)^2 / 2)`` (a narrow bore)
friction_drift         ``gain``, ``tau`` s: friction level ``1 + gain (1 - exp(-t / tau))``
                       over each log's time (warm-up, or wear-in)
saturating_pressure    ``p_sat`` Pa: friction level ``(1 - exp(-p / p_sat)) / (1 - exp(-p_ref
                       / p_sat))`` of the supply gauge pressure ``p`` (the seal's contact
                       saturates; not the library's exponential law)
rate_stiffness         ``gamma``, ``v_ref`` m/s: presliding stiffness factor
                       ``(max(|v|, v_ref / 20) / v_ref)^gamma`` (a rate-dependent seal)
load_cell_hysteresis   ``width`` N, ``span`` N: the force channel lags the force (Dahl-like
                       in force)
force_quantisation     ``step`` N: the force channel is rounded to ``step``
=====================  =======================================================================
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence

import numpy as np

from fitstiff.io.log import Log, Rig

__all__ = ["Segment", "Program", "Base", "SensorNoise", "render", "rounded", "simulate_log",
           "leg", "pause", "sweep", "BORE", "STROKE"]

BORE = 0.032
STROKE = 0.7
AMBIENT = 101_325.0
_STILL = 1e-7        # m/s: below this the piston stands still (only inside pauses)


# ------------------------------------------------------------------------------ programs

@dataclasses.dataclass(frozen=True)
class Segment:
    """One piece of a displacement program: a ``leg`` to ``target`` at ``speed``, a
    ``pause`` of ``duration``, or a ``sweep`` (sine, ``amplitude`` from ``f0`` to ``f1`` Hz,
    a whole number of cycles about the current position)."""

    kind: str
    target: float = 0.0      # m, legs
    speed: float = 0.0       # m/s, legs
    duration: float = 0.0    # s, pauses and sweeps
    amplitude: float = 0.0   # m, sweeps
    f0: float = 0.0
    f1: float = 0.0


def leg(target_mm: float, speed_mm_s: float) -> Segment:
    return Segment("leg", target=target_mm * 1e-3, speed=speed_mm_s * 1e-3)


def pause(seconds: float) -> Segment:
    return Segment("pause", duration=seconds)


def sweep(amplitude_mm: float, f0: float, f1: float, seconds: float) -> Segment:
    cycles = max(1, round(seconds * (f0 + f1) / 2))
    return Segment("sweep", amplitude=amplitude_mm * 1e-3, f0=f0, f1=f1,
                   duration=2 * cycles / (f0 + f1))


@dataclasses.dataclass(frozen=True)
class Program:
    """A sequence of segments from displacement 0, and what it was built for."""

    segments: tuple[Segment, ...]
    description: str = ""

    def duration(self) -> float:
        x, total = 0.0, 0.0
        for s in self.segments:
            if s.kind == "leg":
                total += abs(s.target - x) / s.speed
                x = s.target
            else:
                total += s.duration
        return total


def render(program: Program, rate_hz: float, substeps: int, *,
           smooth_s: float = 0.006) -> tuple[np.ndarray, np.ndarray]:
    """Fine time grid and sensor displacement (m): ``substeps`` points per logged sample,
    corners rounded by a Hann window of ``smooth_s`` (pauses stay exactly still inside)."""
    dt = 1.0 / (rate_hz * substeps)
    pieces = [np.zeros(1)]
    x = 0.0
    for s in program.segments:
        if s.kind == "leg":
            n = max(1, int(math.ceil(abs(s.target - x) / (s.speed * dt))))
            pieces.append(np.linspace(x, s.target, n + 1)[1:])
            x = s.target
        elif s.kind == "pause":
            pieces.append(np.full(max(1, int(round(s.duration / dt))), x))
        elif s.kind == "sweep":
            n = max(1, int(round(s.duration / dt)))
            t = np.arange(1, n + 1) * dt
            t[-1] = s.duration
            phase = 2 * np.pi * (s.f0 * t + (s.f1 - s.f0) * t**2 / (2 * s.duration))
            pieces.append(x + s.amplitude * np.sin(phase))
        else:
            raise ValueError(f"unknown segment kind {s.kind!r}")
    lead = int(round(smooth_s / dt)) + 2       # still before and after: exact 0 at the start
    xf = np.concatenate([np.zeros(lead)] + pieces)
    xf = np.concatenate([xf, np.full(lead, xf[-1])])
    # whole logged samples
    n_log = (xf.size - 1) // substeps + 1
    xf = xf[: (n_log - 1) * substeps + 1]
    return rounded(np.arange(xf.size) * dt, xf, smooth_s=smooth_s)


def fine_turns(fine: np.ndarray, substeps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The turns of a fine path (:func:`render`'s): per turn its extreme displacement (m),
    its sign (+1 a peak, -1 a trough) and the logged sample nearest to it (every
    ``substeps``-th fine point is logged). What a turning-point estimate is checked against."""
    step = np.sign(np.diff(fine))
    moving = np.flatnonzero(step)
    apex, sign, sample = [], [], []
    for c in moving[1:][np.diff(step[moving]) != 0]:
        lo, hi = max(c - substeps, 0), min(c + substeps, fine.size - 1)
        up = step[moving[moving < c][-1]] > 0
        k = lo + int(np.argmax(fine[lo:hi + 1]) if up else np.argmin(fine[lo:hi + 1]))
        apex.append(fine[k])
        sign.append(1.0 if up else -1.0)
        sample.append(round(k / substeps))
    return np.asarray(apex), np.asarray(sign), np.asarray(sample, dtype=int)


def rounded(t: np.ndarray, xf: np.ndarray, *, smooth_s: float = 0.006
            ) -> tuple[np.ndarray, np.ndarray]:
    """A fine motion with its corners rounded by a Hann window of ``smooth_s`` (what the
    rig's actuator makes of sharp setpoints; constant stretches stay constant inside)."""
    dt = float(t[1] - t[0])
    width = max(3, int(round(smooth_s / dt)) | 1)
    if width > 3 and xf.size > 2 * width:
        kernel = np.hanning(width + 2)[1:-1]
        kernel /= kernel.sum()
        pad = width // 2
        xp = np.concatenate([np.full(pad, xf[0]), xf, np.full(pad, xf[-1])])
        xf = np.convolve(xp, kernel, mode="valid")
    return t, xf


# ---------------------------------------------------------------------------- the rig

@dataclasses.dataclass(frozen=True)
class Base:
    """The baseline physics of one log (SI): Dahl friction, closed chambers."""

    sigma0: float = 40e3       # N/m
    Fc: float = 18.0           # N (0: no Dahl friction, e.g. a Maxwell-slip seal instead)
    n: float = 1.3             # polytropic exponent
    x0: float = 0.35           # m, chamber A length at the start
    supply: float = 6e5        # Pa gauge, both chambers closed at it
    dead_a: float = 0.02       # m
    dead_b: float = 0.02       # m
    chamber: bool = True       # the gas spring acts (False: vented, no chamber force)


@dataclasses.dataclass(frozen=True)
class SensorNoise:
    force_N: float = 0.2
    ar1: float = 0.3
    displacement_um: float = 0.2
    quantum_um: float = 1.0
    pressure_mbar: float = 3.0
    log_pressures: bool = True


def _ar1(rng, n, std, rho):
    w = rng.standard_normal(n)
    e = np.empty(n)
    e[0] = w[0]
    c = math.sqrt(1 - rho * rho)
    for k in range(1, n):
        e[k] = rho * e[k - 1] + c * w[k]
    return std * e


def still_mask(x: np.ndarray, dt: float, *, min_pause: float = 0.2) -> np.ndarray:
    """Per fine sub-step (``x.size - 1``): True inside a standstill of ``min_pause`` or longer
    (the dwell clock runs only there, like fitstiff's standstill of 0.2 s)."""
    zero = np.abs(np.diff(x)) / dt < _STILL
    out = np.zeros_like(zero)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], zero.astype(int), [0]])))
    for a, b in zip(edges[::2], edges[1::2]):
        if (b - a) * dt >= min_pause:
            out[a:b] = True
    return out


# long: one explicit time loop whose state (pressures, temperatures, friction, junction, slip
# elements) is read top to bottom as the rig's physics; what the sensors record is _record
def simulate_log(program: Program, *, base: Base, effects: Mapping[str, Mapping[str, float]]
                 = {}, noise: SensorNoise = SensorNoise(), rate_hz: float = 500.0,
                 substeps: int = 15, rng: np.random.Generator | None = None,
                 name: str = "log", p_ref: float = 0.0,
                 out_of_library: Mapping[str, Mapping[str, float]] = {},
                 clean: bool = False, fine: tuple[np.ndarray, np.ndarray] | None = None
                 ) -> tuple[Log, dict[str, np.ndarray]]:
    """Simulate one log. Returns the :class:`Log` (what the rig records) and the noise-free
    channels at the logged samples (``force``, ``p_a``, ``p_b`` absolute, ``x_piston``).

    ``fine``: a given fine grid ``(t, x_sensor)`` instead of rendering ``program`` (tests).
    ``clean``: no noise and no quantisation.
    """
    rng = rng or np.random.default_rng(0)
    t, xs = fine if fine is not None else render(program, rate_hz, substeps)
    dt = float(t[1] - t[0])
    area = math.pi / 4 * BORE**2
    la0, lb0 = base.x0 + base.dead_a, STROKE - base.x0 + base.dead_b
    p0 = base.supply + AMBIENT
    e = {k: dict(v) for k, v in effects.items()}

    visc = e.get("viscous", {}).get("c", 0.0)
    mass = e.get("inertia", {}).get("mass", 0.0)
    h = e.get("heat_transfer", {}).get("rate", 0.0)
    lam = e.get("leakage", {}).get("rate", 0.0)
    n_exp = 1.4 if "heat_transfer" in e else base.n
    comp = e.get("rig_compliance", {}).get("compliance", 0.0)
    st = e.get("stribeck")
    asym = e.get("asymmetry")
    dwell = e.get("dwell_stiction")
    junction = dwell is not None and dwell.get("kind", "junction") == "junction"
    u_pause, broken, f_break, past_break = 0.0, True, 0.0, 0.0
    level_p = (math.exp(e["pressure_friction"]["beta"] * (base.supply - p_ref))
               if "pressure_friction" in e else 1.0)
    ms = e.get("maxwell_slip")
    k_ms = np.asarray(ms["k"], float) if ms else np.zeros(0)
    w_ms = k_ms * np.asarray(ms["delta"], float) if ms else np.zeros(0)
    f_ms = np.zeros(k_ms.size)
    ool = {k: dict(v) for k, v in out_of_library.items()}
    tight, warm = ool.get("tight_spot"), ool.get("friction_drift")
    rate_k = ool.get("rate_stiffness")
    if "saturating_pressure" in ool:
        p_sat = ool["saturating_pressure"]["p_sat"]
        level_p *= (-math.expm1(-base.supply / p_sat)) / (-math.expm1(-p_ref / p_sat))

    N = xs.size
    u = np.empty(N)          # piston displacement
    F_dahl = np.empty(N)
    F_ms = np.empty(N)
    F_j = np.zeros(N)
    pa = np.empty(N)
    pb = np.empty(N)
    y = [p0, p0, 1.0, 1.0, 0.0]
    u[0], F_dahl[0], F_ms[0], pa[0], pb[0] = 0.0, 0.0, 0.0, p0, p0
    direction, t_dwell, travel, was_still = 0.0, 0.0, 1.0, False
    sigma0, Fc, chamber = base.sigma0, base.Fc, base.chamber

    def deriv(yv, uu, v, sig, fcl, sgn):
        pa_, pb_, ta, tb, f = yv
        out_f = sig * v * (1.0 - f / fcl * sgn) if fcl else 0.0
        if not chamber:
            return (0.0, 0.0, 0.0, 0.0, out_f)
        la, lb = la0 + uu, lb0 - uu
        ga, gb = v / la, -v / lb
        dpa = -n_exp * pa_ * ga
        dpb = -n_exp * pb_ * gb
        dta = -(n_exp - 1.0) * ta * ga
        dtb = -(n_exp - 1.0) * tb * gb
        if h:
            dpa -= h * pa_ * (ta - 1.0) / ta
            dpb -= h * pb_ * (tb - 1.0) / tb
            dta -= h * (ta - 1.0)
            dtb -= h * (tb - 1.0)
        if lam:
            peq = (pa_ * la + pb_ * lb) / (la + lb)
            dpa -= lam * (pa_ - peq)
            dpb -= lam * (pb_ - peq)
        return (dpa, dpb, dta, dtb, out_f)

    uu = 0.0
    pauses = still_mask(xs, dt)
    for j in range(N - 1):
        dxs = xs[j + 1] - xs[j]
        vs_ = dxs / dt
        still = bool(pauses[j])
        if abs(vs_) >= _STILL and not still:
            direction = 1.0 if dxs > 0 else -1.0
        # modifiers at the start of the sub-step
        level, slope = level_p, 1.0
        if st:
            level *= 1.0 + (st["ratio"] - 1.0) * math.exp(-(vs_ / st["vs"]) ** 2)
        if asym:
            level *= 1.0 + asym["level"] * direction
            slope *= 1.0 + asym["slope"] * direction
        if dwell:
            if still:
                t_dwell = t_dwell + dt if was_still else dt
                travel = 0.0
            else:
                travel += abs(dxs)
            was_still = still
            if not junction:
                level *= 1.0 + (dwell["gain"] * (1.0 - math.exp(-t_dwell / dwell["tau"]))
                                * math.exp(-travel / dwell["decay"]))
        if tight:
            level *= 1.0 + tight["gain"] * math.exp(
                -0.5 * ((base.x0 + uu - tight["centre"]) / tight["width"]) ** 2)
        if warm:
            level *= 1.0 + warm["gain"] * -math.expm1(-(t[j] - t[0]) / warm["tau"])
        if rate_k:
            slope *= (max(abs(vs_), rate_k["v_ref"] / 20.0) / rate_k["v_ref"]) ** rate_k["gamma"]
        sig, fcl = sigma0 * slope, Fc * level
        # piston increment (rig compliance in differential form)
        if comp and dxs != 0.0:
            sgn0 = 1.0 if dxs > 0 else -1.0
            k_tan = sig * (1.0 - y[4] / fcl * sgn0) if fcl else 0.0
            if k_ms.size:
                k_tan += float(np.sum(k_ms * slope * (np.abs(f_ms) < w_ms * level)))
            if chamber:
                k_tan += n_exp * area * (y[0] / (la0 + uu) + y[1] / (lb0 - uu))
            if junction and not (broken or still):
                k_tan += dwell["gain"] * math.log1p(t_dwell / dwell["tau"]) / dwell["decay"]
            du = dxs / (1.0 + comp * k_tan)
        else:
            du = dxs
        v = du / dt
        sgn = 0.0 if v == 0 else (1.0 if v > 0 else -1.0)
        if v != 0.0 or (h or lam):
            k1 = deriv(y, uu, v, sig, fcl, sgn)
            y2 = [a + 0.5 * dt * b for a, b in zip(y, k1)]
            k2 = deriv(y2, uu + 0.5 * du, v, sig, fcl, sgn)
            y3 = [a + 0.5 * dt * b for a, b in zip(y, k2)]
            k3 = deriv(y3, uu + 0.5 * du, v, sig, fcl, sgn)
            y4 = [a + dt * b for a, b in zip(y, k3)]
            k4 = deriv(y4, uu + du, v, sig, fcl, sgn)
            y = [a + dt / 6.0 * (b1 + 2 * b2 + 2 * b3 + b4)
                 for a, b1, b2, b3, b4 in zip(y, k1, k2, k3, k4)]
        if k_ms.size:
            f_ms = np.clip(f_ms + k_ms * slope * du, -w_ms * level, w_ms * level)
        uu += du
        if junction:
            if still:                      # the junction forms (and ages) where it stands
                u_pause, broken, past_break = uu, False, 0.0
            else:
                strength = dwell["gain"] * math.log1p(t_dwell / dwell["tau"])
                load = strength / dwell["decay"] * (uu - u_pause)
                if not broken and abs(load) >= strength:
                    broken, f_break = True, math.copysign(strength, load)
                if broken:
                    past_break += abs(du)
                    F_j[j + 1] = f_break * math.exp(-past_break / (0.2 * dwell["decay"]))
                else:
                    F_j[j + 1] = load
        u[j + 1], pa[j + 1], pb[j + 1], F_dahl[j + 1] = uu, y[0], y[1], y[4]
        F_ms[j + 1] = float(f_ms.sum()) if k_ms.size else 0.0

    F = F_dahl + F_ms + F_j
    if chamber:
        F = F + area * ((pb - AMBIENT) - (pa - AMBIENT))
    else:
        pa[:] = pb[:] = AMBIENT
    if visc or mass:
        vel = np.gradient(u, dt)
        F = F + visc * vel + (mass * np.gradient(vel, dt) if mass else 0.0)
    if "ripple" in ool:
        r = ool["ripple"]
        F = F + r["amplitude"] * np.sin(2 * np.pi * (base.x0 + u) / r["wavelength"] + r["phase"])

    return _record(t, xs, u, F, pa, pb, substeps=substeps, effects=e, ool=ool, base=base,
                   noise=noise, clean=clean, rng=rng, name=name)


def _record(t, xs, u, F, pa, pb, *, substeps: int, effects, ool, base: Base, noise: SensorNoise,
            clean: bool, rng: np.random.Generator, name: str
            ) -> tuple[Log, dict[str, np.ndarray]]:
    """What the rig's sensors record of the fine-grid channels (time ``t``, sensor position
    ``xs``, piston displacement ``u``, force ``F``, chamber pressures ``pa``, ``pb``): every
    ``substeps``-th sample, the force channel's delay and drift, the out-of-library sensor
    effects, then the noise and quantisation (none when ``clean``). The :class:`Log` and the
    noise-free channels at the logged samples."""
    e = effects
    N = xs.size
    idx = np.arange(0, N, substeps)
    t_log = t[idx]
    delay = e.get("time_delay", {}).get("delay", 0.0)
    force = np.interp(t_log - delay, t, F) if delay else F[idx]
    drift = e.get("force_drift", {}).get("drift", 0.0)
    force = force + drift * (t_log - t_log[0])
    if "load_cell_hysteresis" in ool:
        hy = ool["load_cell_hysteresis"]
        force = force + _force_hysteresis(force, hy["width"], hy["span"])
    truth = {"force": force.copy(), "p_a": pa[idx].copy(), "p_b": pb[idx].copy(),
             "x_piston": u[idx].copy(), "time": t_log.copy(), "x_sensor": xs[idx].copy()}

    n_log = idx.size
    disp = xs[idx].copy()
    p_a, p_b = pa[idx].copy(), pb[idx].copy()
    if not clean:
        force = force + _ar1(rng, n_log, noise.force_N, noise.ar1)
        disp = disp + noise.displacement_um * 1e-6 * rng.standard_normal(n_log)
        q = noise.quantum_um * 1e-6
        if q > 0:
            disp = np.round(disp / q) * q
        p_a = p_a + noise.pressure_mbar * 100.0 * rng.standard_normal(n_log)
        p_b = p_b + noise.pressure_mbar * 100.0 * rng.standard_normal(n_log)
        if "force_quantisation" in ool:
            step = ool["force_quantisation"]["step"]
            force = np.round(force / step) * step
    rig = Rig(bore=BORE, rod=0.0, stroke=STROKE, dead_length_a=base.dead_a,
              dead_length_b=base.dead_b, start_position=base.x0, supply_pressure=base.supply,
              ambient_pressure=AMBIENT)
    pressures = ({"pressure_a": p_a, "pressure_b": p_b}
                 if base.chamber and noise.log_pressures else {})
    log = Log(name=name, displacement=disp, force=force, time=t_log, rig=rig,
              vented=frozenset() if base.chamber else frozenset({"a", "b"}),
              source={"simulated": "fitstiff/_testing/rig_sim.py"}, **pressures)
    return log, truth


def _force_hysteresis(force: np.ndarray, width: float, span: float) -> np.ndarray:
    """Load-cell hysteresis: an offset ``h`` that follows the force like a Dahl element in
    force (``dh/dF = (3 width / span) (1 - h / width sgn dF)``): about ``width`` N of
    hysteresis, saturated over a force change of ``span`` N."""
    out = np.zeros_like(force)
    hv = 0.0
    k = 3.0 * width / span
    for i in range(1, force.size):
        d = force[i] - force[i - 1]
        if d != 0:
            s = 1.0 if d > 0 else -1.0
            hv = s * width + (hv - s * width) * math.exp(-k * abs(d) / width)
        out[i] = hv
    return out


def piecewise_linear_fine(t_log: np.ndarray, x_log: np.ndarray,
                          substeps: int) -> tuple[np.ndarray, np.ndarray]:
    """A fine grid on which the displacement is linear between the logged samples (what
    fitstiff's scan assumes): to compare the two simulators on the same motion."""
    n = t_log.size
    tf = np.interp(np.arange((n - 1) * substeps + 1) / substeps, np.arange(n), t_log)
    return tf, np.interp(tf, t_log, x_log)


def triangles(amplitudes_mm: Sequence[float], speed_mm_s: float) -> list[Segment]:
    """Full cycles 0 -> +A -> -A -> 0 of growing amplitude."""
    out = []
    for a in amplitudes_mm:
        out += [leg(a, speed_mm_s), leg(-a, speed_mm_s), leg(0.0, speed_mm_s)]
    return out
