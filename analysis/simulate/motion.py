"""The quintic Hermite motion: the C² table motion the simulator reads between samples.

Through each pair of neighbouring samples (t₀, t₁ = t₀ + h) the quintic

    p(s) = p₀ + v₀ s + a₀ s²/2 + c₃ s³ + c₄ s⁴ + c₅ s⁵,   s = t − t₀,

matches position, velocity and acceleration at both ends, so the motion is C²: the
integrator's last RK4 stage of a step reads ü at the step's end, which both pieces
agree on. With d = p₁ − (p₀ + v₀h + a₀h²/2), e = v₁ − (v₀ + a₀h), f = a₁ − a₀:

    c₃ = (10d − 4eh + fh²/2)/h³,  c₄ = (−15d + 7eh − fh²)/h⁴,  c₅ = (6d − 3eh + fh²/2)/h⁵.

Two evaluations of the one formula: `quintic_hermite`, every piece at once as a
scipy PPoly (identification's input models, the simulated plant's chunks), and
`quintic_at`, one piece at one instant in plain floats (the simulated rig's hot path,
per sensor sample and per setpoint, where numpy's per-call cost on scalars is larger
than the arithmetic). Each keeps its own order of the floating-point operations
(a₀h² as a₀·(h·h) in one, (a₀·h)·h in the other), so that what either returns stays
the same to the last bit.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import PPoly


def quintic_hermite(t: np.ndarray, p: np.ndarray, v: np.ndarray, a: np.ndarray) -> PPoly:
    """The C² piecewise quintic through position, velocity and acceleration at `t`."""
    h = np.diff(t)
    p0, v0, a0, p1, v1, a1 = p[:-1], v[:-1], a[:-1], p[1:], v[1:], a[1:]
    d = p1 - (p0 + v0 * h + 0.5 * a0 * h**2)
    e = v1 - (v0 + a0 * h)
    f = a1 - a0
    c = np.array([(6 * d - 3 * e * h + 0.5 * f * h**2) / h**5,
                  (-15 * d + 7 * e * h - f * h**2) / h**4,
                  (10 * d - 4 * e * h + 0.5 * f * h**2) / h**3,
                  0.5 * a0, v0, p0])
    return PPoly(c, np.asarray(t, float))


def quintic_at(w: float, h: float, p0: float, v0: float, a0: float, p1: float, v1: float,
               a1: float) -> float:
    """The quintic Hermite through (p, v, a) at both ends of a step h, at its fraction w."""
    d = p1 - (p0 + v0 * h + 0.5 * a0 * h * h)
    e = v1 - (v0 + a0 * h)
    f = a1 - a0
    s = w * h
    c3 = (10 * d - 4 * e * h + 0.5 * f * h * h) / h**3
    c4 = (-15 * d + 7 * e * h - f * h * h) / h**4
    c5 = (6 * d - 3 * e * h + 0.5 * f * h * h) / h**5
    return p0 + s * (v0 + s * (0.5 * a0 + s * (c3 + s * (c4 + s * c5))))
