"""Gross spikes and implausible scales in a log's channels, found when it is loaded.

A least-squares fit follows a single wild sample: a legal 1e6 N force sample in a log of
+-50 N gave ``converged: true``, Fc = 23 730 N, and warnings that never named it. The loader
screens each channel and says so in :attr:`~fitstiff.io.log.Log.notes`; ``fitstiff inspect``
prints the notes and a fit repeats them among its warnings.

A **spike** is a sample that lies further from the median of its four neighbours than the
whole span of the channel (its 0.5 to 99.5 % quantiles) and more than 100 times the
channel's noise floor (:func:`~fitstiff.signal.noise.noise_floor`). A continuous signal cannot do
that: at a sharp reversal the sample and its neighbours differ by a few steps of the
signal, a small part of its span. Only gross errors are caught (a dropped digit, a sensor
glitch, a unit switch for one row); smaller outliers pass and show in the residuals.

An **implausible force scale**: forces beyond ten times what the supply pressure can hold on
the piston (``p A``, when the rig gives bore and supply pressure) point at a unit error (kN
read as N); the note says by how much.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from fitstiff.signal.noise import noise_floor

__all__ = ["UNTRUSTED", "Spike", "find_spikes", "force_scale_note", "spike_note"]

#: how the notes of this module end: a fit repeats such notes of its logs among its warnings
UNTRUSTED = "is not to be trusted"

#: a spike deviates from its neighbours' median by more than this many spans of the channel
_SPANS = 1.0
#: ... and by more than this many times the channel's noise floor
_NOISE = 100.0
#: forces beyond this multiple of the supply pressure times the piston area are implausible
_PA_MULTIPLE = 10.0
_CHUNK = 1 << 20            # samples per block of the running median (bounded memory)


@dataclasses.dataclass(frozen=True)
class Spike:
    """One spike: its 0-based ``sample``, ``value`` and deviation from its neighbours'
    median as a multiple of the noise floor (``times_noise``, inf without noise)."""

    sample: int
    value: float
    times_noise: float


def find_spikes(values: np.ndarray) -> list[Spike]:
    """The spikes of one channel (see the module docstring), in sample order."""
    v = np.asarray(values, dtype=float)
    if v.size < 9 or not np.all(np.isfinite(v)):
        return []
    low, high = np.quantile(v, [0.005, 0.995])
    span = float(high - low)
    sigma = noise_floor(v).sigma
    limit = max(_SPANS * span, _NOISE * sigma)
    if limit <= 0:
        return []
    padded = np.pad(v, 2, mode="edge")
    out = []
    for start in range(0, v.size, _CHUNK):
        stop = min(start + _CHUNK, v.size)
        window = np.lib.stride_tricks.sliding_window_view(padded[start:stop + 4], 5)
        neighbours = np.delete(window, 2, axis=1)        # the four around each sample
        deviation = np.abs(v[start:stop] - np.median(neighbours, axis=1))
        for k in np.flatnonzero(deviation > limit):
            out.append(Spike(int(start + k), float(v[start + k]),
                             float(deviation[k] / sigma) if sigma > 0 else math.inf))
    return out


def spike_note(channel: str, unit: str, scale: float, spikes: list[Spike], *,
               first_line: int) -> str:
    """One note for a channel's spikes: the first three by sample and file line, and what
    to do. ``scale``: SI per display unit; ``first_line``: the file line of sample 0."""
    shown = "; ".join(
        f"sample {s.sample} (line {s.sample + first_line}) is {s.value / scale:.4g} "
        f"{unit}" + (f", {s.times_noise:,.0f} times the noise floor from its neighbours"
                     if math.isfinite(s.times_noise) else "")
        for s in spikes[:3])
    more = f" and {len(spikes) - 3} more" if len(spikes) > 3 else ""
    return (f"{channel}: {len(spikes)} spike{'s' if len(spikes) > 1 else ''}: {shown}{more}; "
            "fix or remove those rows, or fit a range without them (--sample-range): a fit "
            f"follows such samples and {UNTRUSTED}")


def force_scale_note(force: np.ndarray, *, bore: float | None,
                     supply_pressure: float | None) -> str | None:
    """A note when the force reaches beyond :data:`_PA_MULTIPLE` times the supply pressure
    times the piston area (None when it does not, or the rig does not say)."""
    if not bore or not supply_pressure or supply_pressure <= 0:
        return None
    held = supply_pressure * math.pi / 4 * bore**2
    f = np.asarray(force, dtype=float)
    peak = float(np.max(np.abs(f[np.isfinite(f)]))) if f.size else 0.0
    if peak <= _PA_MULTIPLE * held:
        return None
    return (f"force: reaches {peak:.4g} N, {peak / held:.0f} times what the supply pressure "
            f"holds on the piston (p A = {held:.4g} N at {supply_pressure / 1e5:g} bar on a "
            f"{bore * 1e3:g} mm bore): check the force column's unit (kN read as N?) and the "
            f"rig metadata: a fit of these values {UNTRUSTED}")
