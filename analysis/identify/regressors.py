"""The regressor matrix of Eq 10: one column per term, from the model's own basis.

Row i, column j is term j's basis at sample i (0 where a gated term sits in
the dead band), so that the isolator force is Z @ coefs. Built by the same
compiled `basis` the simulator integrates, so the fitted equation is the
simulated one. Stateful terms are not linear regressors (their state depends
on the history through their shape constants) and are refused here.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from analysis.model.isolator import IsolatorModel
from analysis.model.terms import basis, kind


@njit(cache=True)
def _columns(kinds, gated, shapes, z, zd, delta, out):
    for i in range(z.shape[0]):
        outside = abs(z[i]) > delta if delta > 0.0 else True
        sz = 1.0 if z[i] > 0 else (-1.0 if z[i] < 0 else 0.0)
        szd = 1.0 if zd[i] > 0 else (-1.0 if zd[i] < 0 else 0.0)
        for j in range(kinds.shape[0]):
            if gated[j] and not outside:
                out[i, j] = 0.0
            else:
                out[i, j] = basis(kinds[j], z[i], zd[i], sz, szd, 0.0, shapes[j, 0],
                                  shapes[j, 1], shapes[j, 2])


def regressor_matrix(model: IsolatorModel, z: np.ndarray, zd: np.ndarray) -> np.ndarray:
    """Z (n, J): each term's basis at every sample, with the model's dead band and shapes."""
    for t in model.terms:
        if kind(t.kind).has_state:
            raise ValueError(f"term {t.name!r} ({t.kind}) has internal state; it is "
                             "identified by output error, not as a linear regressor")
    kinds, gated = model.structure()
    shapes = np.zeros((len(model.terms), 3))
    for j, t in enumerate(model.terms):
        shapes[j, :len(t.shape)] = t.shape
    z = np.ascontiguousarray(z, float)
    zd = np.ascontiguousarray(zd, float)
    out = np.empty((z.size, len(model.terms)))
    _columns(kinds, gated, shapes, z, zd, model.dead_band, out)
    return out
