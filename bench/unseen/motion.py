"""The table's commanded motion for the independent campaign generator.

A run is rest, a ramp up by STEP, a hold, a ramp back down and rest again; the ramp
follows one of three shapes s(tau), tau in [0, 1] -> [0, 1] (cycloidal, half-cosine,
minimum-jerk), each given with its first and second derivative. The three runs of a
campaign differ only in the ramp's duration (RAMPS).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

IN = 0.0254  # m

STEP = 5.5 * IN  # 0.1397 m

RAMPS = {"A": 0.20, "B": 0.16, "C": 0.12}
REST = 0.1
HOLD = 1.3


def _cycloidal(tau: float) -> tuple[float, float, float]:
    w = 2.0 * math.pi
    return (tau - math.sin(w * tau) / w, 1.0 - math.cos(w * tau), w * math.sin(w * tau))


def _half_cosine(tau: float) -> tuple[float, float, float]:
    p = math.pi
    return ((1.0 - math.cos(p * tau)) / 2.0, p * math.sin(p * tau) / 2.0,
            p * p * math.cos(p * tau) / 2.0)


def _min_jerk(tau: float) -> tuple[float, float, float]:
    t2, t3 = tau * tau, tau * tau * tau
    return (
        10 * t3 - 15 * t3 * tau + 6 * t3 * t2,
        30 * t2 - 60 * t3 + 30 * t2 * t2,
        60 * tau - 180 * t2 + 120 * t3,
    )


SHAPES: dict[str, Callable[[float], tuple[float, float, float]]] = {
    "cycloidal": _cycloidal,
    "half_cosine": _half_cosine,
    "min_jerk": _min_jerk,
}


def shape(name: str, tau: np.ndarray | float) -> np.ndarray:
    """The ramp shape s(tau), tau in [0, 1] -> [0, 1] (clipped outside)."""
    f = SHAPES[name]
    return np.array([f(min(1.0, max(0.0, float(v))))[0] for v in np.atleast_1d(tau)])


class Profile:
    """Commanded table motion: rest, ramp up STEP, hold, ramp back, rest."""

    def __init__(self, shape_name: str, ramp: float, rest: float = REST, hold: float = HOLD):
        self.f = SHAPES[shape_name]
        self.ramp = ramp
        self.t1 = rest
        self.t2 = rest + ramp
        self.t3 = rest + ramp + hold
        self.t4 = rest + 2 * ramp + hold
        self.breaks = (self.t1, self.t2, self.t3, self.t4)

    def piece_at(self, t: float) -> int:
        """Which piece (rest, up, hold, down, rest) holds t; right-continuous at breaks."""
        return sum(t >= b for b in self.breaks)

    def __call__(self, t: float, piece: int | None = None) -> tuple[float, float, float]:
        """(u, u', u'') of the command at t, on the given piece (u'' jumps at the breaks
        of a half-cosine ramp: an integration segment keeps its own piece to its end)."""
        r = self.ramp
        if piece is None:
            piece = self.piece_at(t)
        if piece == 1:
            s, sd, sdd = self.f(min(1.0, max(0.0, (t - self.t1) / r)))
            return STEP * s, STEP * sd / r, STEP * sdd / (r * r)
        if piece == 2:
            return STEP, 0.0, 0.0
        if piece == 3:
            s, sd, sdd = self.f(min(1.0, max(0.0, (t - self.t3) / r)))
            return STEP * (1.0 - s), -STEP * sd / r, -STEP * sdd / (r * r)
        return 0.0, 0.0, 0.0
