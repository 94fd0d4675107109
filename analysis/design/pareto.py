"""The trade-off: designs no other design beats on both peak acceleration and stroke."""

from __future__ import annotations

import numpy as np


def pareto_front(accel: np.ndarray, stroke: np.ndarray) -> np.ndarray:
    """Indices of the non-dominated points of (accel, stroke) (N,), by increasing stroke.

    A point is dominated when another has no more of either and less of one. Sorted
    by stroke (ties by acceleration), a point is on the front exactly when its
    acceleration is below every acceleration before it: one pass, O(N log N).
    Points with a non-finite peak (a diverged design) are never on it.
    """
    accel, stroke = np.asarray(accel, float), np.asarray(stroke, float)
    finite = np.flatnonzero(np.isfinite(accel) & np.isfinite(stroke))
    order = finite[np.lexsort((accel[finite], stroke[finite]))]
    front, best = [], np.inf
    for i in order:
        if accel[i] < best:
            front.append(i)
            best = accel[i]
    return np.array(front, dtype=int)
