"""The two problems the local search solves, how it ranks designs, and its model step.

- `within_stroke`: the design problem. The least peak acceleration among the
  designs whose peak stroke is within S.
- `closest`: when no design meets both limits, the design that needs them relaxed
  by the least common factor: the least max(A / a_max, Z / S).

Ranking is the feasibility rule of constrained evolutionary search (Deb): a point
within the stroke limit beats any beyond it; two within, the lower value; two
beyond, the smaller excess. A search that starts beyond the stroke finds the least
stroke first and then trades it for acceleration, with no penalty weight to choose.

The step: at a design on the stroke limit the designs that are both within it and
better lie in a thin wedge between the two peaks' level sets (stiffer: less
stroke, more acceleration), which random samples seldom hit. The round's samples
around the centre also fit a linear model of each peak (least squares, d + 1
unknowns from 2^k samples); the LP "least acceleration within the linearised
stroke limit, inside the round's box" gives one more candidate, evaluated with the
next round's samples. Measured on runs A, B, C at 4 in (six Sobol seeds each,
against the best design any run found): with Eq 10's six constants free the
search ends a median 0.56 % above it (at most 1.1 %), 0.89 % (1.7 %) without the
step; with the dead band free too, 1.1 % (6.8 %) against 4.3 % (10.5 %). The
optimum is flat and has many valleys: the acceleration is known to a per cent or
a few, the constants that give it much less well (see the tolerances).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog


@dataclass(frozen=True)
class Limits:
    """What the equipment tolerates (SI)."""

    accel: float  # m/s², its fragility
    stroke: float  # m, the rattle space


@dataclass(frozen=True)
class Problem:
    """`kind`: "within_stroke" or "closest" (see the module's doc)."""

    kind: str
    limits: Limits

    def score(self, accel: np.ndarray, stroke: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(excess beyond the stroke limit, value) of designs (N,): lower is better."""
        a, z = np.asarray(accel, float), np.asarray(stroke, float)
        if self.kind == "closest":
            return np.zeros_like(a), np.maximum(a / self.limits.accel, z / self.limits.stroke)
        return np.maximum(z / self.limits.stroke - 1.0, 0.0), a

    def step(self, accel: float, stroke: float, grad_accel: np.ndarray,
             grad_stroke: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
        """The best move within [low, high] (d,) by the peaks' linear model."""
        bounds = list(zip(low, high))
        S, a_max = self.limits.stroke, self.limits.accel
        if self.kind == "closest":
            d = grad_accel.size
            res = linprog(np.r_[np.zeros(d), 1.0],
                          A_ub=[np.r_[grad_accel / a_max, -1.0], np.r_[grad_stroke / S, -1.0]],
                          b_ub=[-accel / a_max, -stroke / S], bounds=bounds + [(None, None)],
                          method="highs")
            return res.x[:d] if res.status == 0 else np.zeros(d)
        res = linprog(grad_accel, A_ub=grad_stroke[None, :], b_ub=[S - stroke], bounds=bounds,
                      method="highs")
        if res.status != 0:  # the model sees no way back within the stroke: its least
            res = linprog(grad_stroke, bounds=bounds, method="highs")
        return res.x if res.status == 0 else np.zeros(grad_accel.size)


def within_stroke(limits: Limits) -> Problem:
    return Problem("within_stroke", limits)


def closest(limits: Limits) -> Problem:
    return Problem("closest", limits)


def best(excess: np.ndarray, value: np.ndarray) -> int:
    """Index of the best point by the feasibility rule."""
    return int(np.lexsort((value, excess))[0])


def gradients(dX: np.ndarray, d_accel: np.ndarray, d_stroke: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray] | None:
    """Least-squares slopes (d,) of both peaks from changes dX (N, d) around a centre;
    None when fewer than d + 1 samples are finite."""
    ok = np.isfinite(d_accel) & np.isfinite(d_stroke)
    if ok.sum() < dX.shape[1] + 1:
        return None
    coef = np.linalg.lstsq(dX[ok], np.column_stack([d_accel[ok], d_stroke[ok]]), rcond=None)[0]
    return coef[:, 0], coef[:, 1]
