"""The cubic Hermite on one step, in plain floats: the served mass position between grid points.

Called per sensor sample (thousands a second on a shared core), where numpy's
per-call cost on scalars is larger than the arithmetic. The table's quintic on one
step is `analysis.simulate.motion.quintic_at`, beside the PPoly the integrator reads.
"""

from __future__ import annotations


def cubic_at(w: float, h: float, p0: float, v0: float, p1: float, v1: float) -> float:
    """The cubic Hermite through (p, v) at both ends of a step h, at its fraction w."""
    w2, w3 = w * w, w * w * w
    return ((2 * w3 - 3 * w2 + 1) * p0 + (w3 - 2 * w2 + w) * h * v0
            + (-2 * w3 + 3 * w2) * p1 + (w3 - w2) * h * v1)
