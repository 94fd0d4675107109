"""Which samples carry relative motion: the rest segments appendix A dropped.

Appendix A: "eliminating many of the points where the relative motion was zero
produced a better-fitting curve" — a long rest fits trivially and, left in,
outweighs the short stretches that determine the constants. The report chose
them by eye; the rule here is stated and uses only the data:

    a sample is at rest when |ż| < REST_SIGMAS · σ_ż (σ_ż: the noise the
    differentiation leaves in ż) for at least MIN_REST seconds;
    every moving sample keeps MARGIN seconds either side (onsets and stops).

Short pauses (the zero crossing of ż at a turning point) are motion: MIN_REST
is longer than any of them in a step-pulse response.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

REST_SIGMAS = 4.0  # white noise exceeds 4σ in 6e-5 of samples: rest is not cut up by noise
MIN_REST = 0.05  # s
MARGIN = 0.02  # s


def active_mask(zd: NDArray[np.float64], dt: float, noise_v: float) -> NDArray[np.bool_]:
    """True where the relative velocity zd (m/s, shape (n,)) shows motion; dt in s."""
    zd = np.asarray(zd, float)
    still = np.abs(zd) < REST_SIGMAS * max(noise_v, 1e-300)
    still = _drop_short(still, max(round(MIN_REST / dt), 1))
    moving = ~still
    pad = round(MARGIN / dt)
    if pad:
        moving = np.convolve(moving, np.ones(2 * pad + 1), mode="same") > 0.5
    return moving


def _drop_short(flags: NDArray[np.bool_], minimum: int) -> NDArray[np.bool_]:
    """flags with every True run shorter than `minimum` samples cleared."""
    out = flags.copy()
    edges = np.flatnonzero(np.diff(np.r_[0, flags.astype(np.int8), 0]))
    for a, b in zip(edges[::2], edges[1::2]):
        if b - a < minimum:
            out[a:b] = False
    return out
