"""Closed-chamber polytropic gas spring (DESIGN §1.1): exact law and linearisation.

Pure functions of JAX (or NumPy) scalars / arrays, differentiable, SI units, **absolute**
pressures. ``u`` is the piston displacement from the closing position ``x0``, positive toward
the B cap (chamber A grows). ``l_a0 = x0 + d_A`` and ``l_b0 = L - x0 + d_B`` are the effective
chamber lengths at closing (dead volume counted as extra length).

    p_A(u) = p_A0 (l_A0 / (l_A0 + u))**n          p_B(u) = p_B0 (l_B0 / (l_B0 - u))**n
    F(u)   = A_B (p_B(u) - p_amb) - A_A (p_A(u) - p_amb)     (external force that holds u)
    k      = n (p_A0 A_A / l_A0 + p_B0 A_B / l_B0)            (dF/du at u = 0)

With equal pressures and areas and no dead volume, ``k = p n A L / (x (L - x))`` (the paper's
eq. 15) and the relative return pressure is ``dp/p = n dx L / (x (L - x))`` (eq. 14).
"""

from __future__ import annotations

__all__ = [
    "effective_lengths",
    "chamber_pressures",
    "chamber_force",
    "chamber_force_linear",
    "linear_stiffness",
    "relative_return_pressure",
]


def effective_lengths(x0, *, stroke, dead_length_a=0.0, dead_length_b=0.0):
    """``(l_A0, l_B0)``: effective chamber lengths at piston position ``x0``."""
    return x0 + dead_length_a, stroke - x0 + dead_length_b


def chamber_pressures(u, *, p_a0, p_b0, l_a0, l_b0, n):
    """Absolute chamber pressures ``(p_A, p_B)`` after a displacement ``u`` (exact law)."""
    p_a = p_a0 * (l_a0 / (l_a0 + u)) ** n
    p_b = p_b0 * (l_b0 / (l_b0 - u)) ** n
    return p_a, p_b


def chamber_force(u, *, p_a0, p_b0, l_a0, l_b0, area_a, area_b, n, p_amb):
    """External force (N, + toward B) that holds the piston at displacement ``u`` (exact law).

    At ``u = 0`` this is the static pre-load ``A_B (p_B0 - p_amb) - A_A (p_A0 - p_amb)``;
    the restoring force of a displacement is ``chamber_force(u) - chamber_force(0)``.
    """
    p_a, p_b = chamber_pressures(u, p_a0=p_a0, p_b0=p_b0, l_a0=l_a0, l_b0=l_b0, n=n)
    return area_b * (p_b - p_amb) - area_a * (p_a - p_amb)


def linear_stiffness(*, p_a0, p_b0, l_a0, l_b0, area_a, area_b, n):
    """Linearised chamber stiffness ``dF/du`` at the closing position (N/m)."""
    return n * (p_a0 * area_a / l_a0 + p_b0 * area_b / l_b0)


def chamber_force_linear(u, *, p_a0, p_b0, l_a0, l_b0, area_a, area_b, n, p_amb):
    """Linearised law: pre-load + ``linear_stiffness * u``."""
    f0 = area_b * (p_b0 - p_amb) - area_a * (p_a0 - p_amb)
    return f0 + linear_stiffness(p_a0=p_a0, p_b0=p_b0, l_a0=l_a0, l_b0=l_b0,
                                 area_a=area_a, area_b=area_b, n=n) * u


def relative_return_pressure(dx, *, x, stroke, n, dead_length_a=0.0, dead_length_b=0.0):
    """Eq. 14: ``dp/p = n dx L / (x (L - x))`` for equal closing pressures (linearised).

    The pressure *difference* across the piston that a displacement ``dx`` creates, relative to
    the closing pressure. Dead volume acts as an extended stroke:
    ``n dx (1/(x + d_A) + 1/(L - x + d_B))``.
    """
    l_a = x + dead_length_a
    l_b = stroke - x + dead_length_b
    return n * dx * (1.0 / l_a + 1.0 / l_b)
