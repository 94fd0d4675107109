"""How far each unit's constants lie from the lot's, judged robustly.

The constants are compared relative to the lot's median (k1 and c1 differ by orders of
magnitude; a lot's spread is a few per cent of each) and standardised by their median
absolute deviation (× 1.4826: σ at the normal). Then, by lot size:

* **Many units** (at least `CORRELATED_UNITS_PER_CONSTANT` per constant): Mahalanobis
  distance under a robust covariance, the orthogonalised Gnanadesikan–Kettenring
  estimate (OGK, Maronna & Zamar 2002: each pair's robust correlation from the MADs of
  the sum and the difference, its eigenvectors as axes, a MAD along each). The
  constants of one fit trade against each other (k2 against α, k1 against k2), and a
  lot's may move together: a unit off across such a correlation is out of family though
  no constant alone is, and one off along it is not twice as odd. OGK is deterministic,
  takes medians only and vectorises over the calibration's lots below (FAST-MCD's
  random starts and concentration steps took 45–90 ms per lot, in a Python loop).
* **Few units**: the correlations are p(p − 1)/2 numbers (28 for eight constants) that
  a handful of units cannot estimate, so each constant keeps its own robust z-score and
  the unit's distance² is their sum of squares. 50 % breakdown per constant.

A unit's own standard error is added to the lot's spread: a unit that could not pin a
constant down is not out of family for it.

The threshold is calibrated, not read from χ²: a median and a MAD from eight units are
themselves noisy, and with χ²'s quantile healthy lots of 8 normal units had a unit
flagged in half the draws (an MCD covariance from 40: in every draw). So the
distance² of units of `CALIBRATION_LOTS` simulated lots of the same size, drawn from
one normal family and judged the same way, gives the 1 − `FAMILY_ALPHA`/n quantile
(seeded: the same lot is judged the same every time): in a lot of healthy units the
chance that any unit at all is flagged is about `FAMILY_ALPHA` (Bonferroni over units).
Under the normal the estimators are equivariant to each constant's location and scale,
so the quantile depends only on the number of units and constants.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

FAMILY_ALPHA = 0.01
CORRELATED_UNITS_PER_CONSTANT = 5
MAD_NORMAL = 1.4826  # MAD × this is σ for a normal sample
CALIBRATION_LOTS = 5000  # × n units: ≥ 50 distances beyond the 1 − α/n quantile
CALIBRATION_SEED = 20


@dataclass(frozen=True)
class Distances:
    """Per unit (rows) and constant (columns), relative to the lot's centre."""

    method: str  # "ogk" (Mahalanobis, robust covariance) or "mad" (per-constant z)
    center: np.ndarray  # (p,) the lot's median of each constant
    scale: np.ndarray  # (p,) the lot's robust std of each constant, relative to center
    z: np.ndarray  # (n, p) each constant's deviation in robust std (the unit's own added)
    d2: np.ndarray  # (n,) squared robust distance
    threshold: float  # d2 beyond this: out of family

    @property
    def outside(self) -> np.ndarray:
        return self.d2 > self.threshold


def robust_distances(values: np.ndarray, stds: np.ndarray, alpha: float = FAMILY_ALPHA
                     ) -> Distances:
    """values, stds: (n units, p constants), SI; a std of 0 where the unit gave none.

    A constant that does not vary across the lot (MAD 0) contributes nothing.
    """
    values, stds = np.asarray(values, float), np.asarray(stds, float)
    n, p = values.shape
    if n < 3:
        raise ValueError(f"a robust distance needs at least 3 units, got {n}")
    median = np.median(values, axis=0)
    ref = np.where(median != 0, np.abs(median), 1.0)
    scale = MAD_NORMAL * np.median(np.abs(values - median), axis=0) / ref
    z = np.zeros((n, p))
    keep = scale > 0  # a constant every unit shares (MAD 0) tells nothing
    q = int(keep.sum())
    Z = (values[:, keep] - median[keep]) / ref[keep] / scale[keep]
    S = stds[:, keep] / ref[keep] / scale[keep]
    z[:, keep] = Z / np.sqrt(1.0 + S**2)
    method = "ogk" if n >= CORRELATED_UNITS_PER_CONSTANT * max(q, 1) else "mad"
    if q == 0:
        return Distances(method, median, scale, z, np.zeros(n), np.inf)
    if method == "mad":
        d2 = np.sum(z**2, axis=1)
    else:
        axes, center, sd = _ogk(Z[None])
        A, Y = axes[0], Z @ axes[0] - center[0]
        d2 = np.array([_mahalanobis2(Y[i], np.diag(sd[0] ** 2) + A.T @ np.diag(S[i] ** 2) @ A)
                       for i in range(n)])
    return Distances(method, median, scale, z, d2, threshold(n, q, method, alpha))


def _mahalanobis2(delta: np.ndarray, cov: np.ndarray) -> float:
    return float(delta @ np.linalg.lstsq(cov, delta, rcond=None)[0])


def _mad(a: np.ndarray, axis: int) -> np.ndarray:
    med = np.median(a, axis=axis, keepdims=True)
    return MAD_NORMAL * np.median(np.abs(a - med), axis=axis)


def _ogk(Z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """OGK of standardised lots Z (..., n, p): the axes (..., p, p), and the median
    (..., p) and robust std (..., p) of the units along them."""
    p = Z.shape[-1]
    R = np.broadcast_to(np.eye(p), Z.shape[:-2] + (p, p)).copy()
    for j in range(p):
        for k in range(j + 1, p):
            su = _mad(Z[..., j] + Z[..., k], -1) ** 2
            sv = _mad(Z[..., j] - Z[..., k], -1) ** 2
            with np.errstate(invalid="ignore", divide="ignore"):
                r = np.nan_to_num((su - sv) / (su + sv))
            R[..., j, k] = R[..., k, j] = r
    _, axes = np.linalg.eigh(R)
    Y = Z @ axes
    sd = _mad(Y, -2)
    return axes, np.median(Y, axis=-2), np.where(sd > 0, sd, np.inf)


@lru_cache(maxsize=32)
def threshold(n: int, p: int, method: str, alpha: float = FAMILY_ALPHA) -> float:
    """The distance² a unit of a healthy normal lot of n units exceeds with chance α/n."""
    rng = np.random.default_rng(CALIBRATION_SEED)
    d2 = []
    for _ in range(0, CALIBRATION_LOTS, 500):  # in batches: (500, n, p) at a time
        X = rng.standard_normal((500, n, p))
        med = np.median(X, axis=1, keepdims=True)
        Z = (X - med) / _mad(X, 1)[:, None, :]
        if method == "mad":
            d2.append(np.sum(Z**2, axis=2).ravel())
        else:
            axes, center, sd = _ogk(Z)
            d2.append(np.sum(((Z @ axes - center[:, None, :]) / sd[:, None, :]) ** 2,
                             axis=2).ravel())
    return float(np.quantile(np.concatenate(d2), 1.0 - alpha / n))
