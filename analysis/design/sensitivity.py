"""How precisely the optimum's constants must be met: each one's tolerance.

The report's point (chapter 1): near the optimum the response changes little
with the constants, so they need not be specified precisely. Turned into numbers,
for each free constant with the others at the optimum:

- `limits`: how far it may move down and up before a limit is crossed (the stroke
  or the acceleration), and which one. At an optimum the stroke limit usually
  binds, so one side is near 0: that side of the interval is the specification
  (a spring at least this stiff), the other its latitude.
- `within`: how far it may move before either peak grows by more than `tolerance`
  (5 %) of the optimum's own: how flat the optimum is.

One parallel call: every constant, both directions, at changes of 0.2 % to 100 %
spaced by a factor of two (`STEPS`). The crossing is interpolated linearly in the
margin between the last change that keeps it and the first that does not, which
is as precise as a tolerance needs (a tenth of a step or so where the peaks are
smooth). A constant at 0 has no relative tolerance and is left out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from analysis.design.objective import Evaluator
from analysis.design.problem import Limits
from analysis.design.space import DesignSpace

STEPS = np.geomspace(0.002, 1.0, 10)  # relative changes tried, each way
MAX_DOWN = 0.95  # a constant is not taken below 5 % of its value
TOLERANCE = 0.05  # `within`: the peaks may grow by this fraction of the optimum's


@dataclass(frozen=True)
class Tolerance:
    """One constant's tolerances: relative changes down and up (≥ 0); inf: beyond the
    largest change tried; `limits` None when the optimum itself misses a limit."""

    name: str
    value: float  # SI, at the optimum
    limits: tuple[float, float] | None
    crossed: tuple[str, str]  # the limit crossed at each end: "stroke", "accel" or ""
    within: tuple[float, float]


def tolerances(space: DesignSpace, evaluate: Evaluator, optimum: np.ndarray,
               limits: Limits, tolerance: float = TOLERANCE) -> list[Tolerance]:
    """Tolerances of every free constant of `optimum` (d,) SI."""
    changes = [(i, sign) for i in range(optimum.size) if optimum[i] != 0 for sign in (-1, 1)]
    steps = {-1: np.minimum(STEPS, MAX_DOWN), 1: STEPS}
    values = [optimum]
    for i, sign in changes:
        for rho in steps[sign]:
            v = optimum.copy()
            v[i] *= 1.0 + sign * rho
            values.append(v)
    peaks = evaluate(space.rows(np.array(values)))
    a, z = peaks.worst_accel, peaks.worst_stroke
    limit_margin = np.minimum(limits.accel / a, limits.stroke / z) - 1.0
    within_margin = np.minimum((1 + tolerance) * a[0] / a, (1 + tolerance) * z[0] / z) - 1.0
    which = np.where(limits.accel / a < limits.stroke / z, "accel", "stroke")
    out: dict[int, dict[int, tuple[float, str, float]]] = {}
    n = STEPS.size
    for k, (i, sign) in enumerate(changes):
        rows = np.r_[0, 1 + k * n + np.arange(n)]
        rho = np.r_[0.0, steps[sign]]
        lim, crossed = _crossing(rho, limit_margin[rows]), _first_bad(which[rows],
                                                                      limit_margin[rows])
        out.setdefault(i, {})[sign] = (lim, crossed, _crossing(rho, within_margin[rows]))
    feasible = limit_margin[0] >= 0
    return [Tolerance(space.names[i], float(optimum[i]),
                      (out[i][-1][0], out[i][1][0]) if feasible else None,
                      (out[i][-1][1], out[i][1][1]) if feasible else ("", ""),
                      (out[i][-1][2], out[i][1][2]))
            for i in sorted(out)]


def _crossing(rho: np.ndarray, margin: np.ndarray) -> float:
    """The change where `margin` first turns negative, interpolated; inf if it never does."""
    bad = np.flatnonzero(~(margin >= 0))  # a diverged design (nan) crosses too
    if bad.size == 0:
        return float("inf")
    j = int(bad[0])
    if j == 0:
        return 0.0
    m0, m1 = margin[j - 1], margin[j]
    w = m0 / (m0 - m1) if np.isfinite(m1) else 0.0
    return float(rho[j - 1] + w * (rho[j] - rho[j - 1]))


def _first_bad(which: np.ndarray, margin: np.ndarray) -> str:
    bad = np.flatnonzero(~(margin >= 0))
    return str(which[bad[0]]) if bad.size else ""
