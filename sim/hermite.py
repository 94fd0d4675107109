"""Hermite interpolation on one step, in plain floats: the simulator's hot path.

Called per sensor sample and per plant step (thousands a second on a shared
core), where numpy's per-call cost on scalars is larger than the arithmetic.
"""

from __future__ import annotations


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


def cubic_at(w: float, h: float, p0: float, v0: float, p1: float, v1: float) -> float:
    """The cubic Hermite through (p, v) at both ends of a step h, at its fraction w."""
    w2, w3 = w * w, w * w * w
    return ((2 * w3 - 3 * w2 + 1) * p0 + (w3 - 2 * w2 + w) * h * v0
            + (-2 * w3 + 3 * w2) * p1 + (w3 - w2) * h * v1)
