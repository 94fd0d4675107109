"""The regressor matrix of Eq 10: one column per term, from the model's own basis.

Row i, column j is term j's basis at sample i (0 where a gated term sits in
the dead band), so that the isolator force is Z @ coefs. Built by the same
compiled `basis` the simulator integrates, so the fitted equation is the
simulated one. `regressor_matrix` refuses stateful terms (appendix A's fit
has none). `campaign_regressors` admits them for the loop: a state driven by
the motion alone (Bouc–Wen r' = ż − a|ż|r − bż|r|; fluid temperature
θ' = aż² − θ/τ) is integrated along the measured ż, the fluid temperature
carrying from one run into the next as the simulator's campaign prediction does.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numba import njit

from analysis.model.isolator import IsolatorModel, Term
from analysis.model.terms import BOUC_WEN, basis, kind, state_rate

# numba caches this module's compiled code against this file alone, and terms.basis
# and terms.state_rate are compiled into it: a change to them (the Bouc–Wen exponent)
# bumps this, or a cached kernel runs the old formula
TERMS_REVISION = 4


def regressor_matrix(model: IsolatorModel, z: np.ndarray, zd: np.ndarray) -> np.ndarray:
    """Z (n, J): each term's basis at every sample, with the model's dead band and shapes."""
    for t in model.terms:
        if kind(t.kind).has_state:
            raise ValueError(f"term {t.name!r} ({t.kind}) has internal state; it is "
                             "identified by output error, not as a linear regressor")
    # with no stateful term the campaign builder is this matrix exactly
    return campaign_regressors(model, [np.asarray(z, float)], [np.asarray(zd, float)], dt=1.0)


# of a midpoint step: the most its rate may change per unit of state, times the step. The
# midpoint rule is stable up to 2; a Bouc–Wen loop that yields in 1.25 mm with round
# corners (n = 2) turns over at 1600 |ż| 1/s, so at 1 kHz a run past 1.25 m/s took its
# state past 1e300 and its column to NaN (which kernel's last bits got there first
# decided whether naming's least squares failed)
STIFF_STEP = 1.0
# and no more steps than this per sample: a refit's trial that ran away (ż of km/s, a and b
# walked to 1e12) would otherwise take billions, and its prediction is refused anyway
MAX_SUBSTEPS = 64


@njit(cache=True, inline="always")
def _turnover(code, a, b, c, dt):
    """A sample's stiffness per unit |ż|: how fast a Bouc–Wen state turns over, times dt
    (0 for every other kind)."""
    if code != BOUC_WEN or a + b <= 0.0:
        return 0.0
    n = max(c, 1.0)
    # |∂r'/∂r| ≤ n (a + b) |ż| |r|^(n−1), and |r| stays within the yield (a + b)^(−1/n)
    return n * (a + b) ** (1.0 / n) * dt


@njit(cache=True, inline="always")
def _substeps(stiff):
    """Midpoint steps to take across one sample of stiffness `stiff`: one unless stiff."""
    if stiff <= STIFF_STEP:
        return 1
    if not stiff < MAX_SUBSTEPS * STIFF_STEP:  # NaN too
        return MAX_SUBSTEPS
    return int(math.ceil(stiff / STIFF_STEP))


@njit(cache=True)
def _series(code, gated, a, b, c, z, zd, delta, dt, s0, out):
    """Fill `out` with one term's basis along (z, ż); return the state at the end."""
    s = s0
    turnover = _turnover(code, a, b, c, dt)
    for i in range(z.shape[0]):
        outside = abs(z[i]) > delta if delta > 0.0 else True
        sz = 1.0 if z[i] > 0 else (-1.0 if z[i] < 0 else 0.0)
        szd = 1.0 if zd[i] > 0 else (-1.0 if zd[i] < 0 else 0.0)
        if gated and not outside:
            out[i] = 0.0
        else:
            out[i] = basis(code, z[i], zd[i], sz, szd, s, a, b, c)
        # midpoint steps of the state along the sampled motion (dt / 1 is dt exactly)
        m = _substeps(turnover * abs(zd[i]))
        h = dt / m
        for _ in range(m):
            k1 = state_rate(code, z[i], zd[i], s, 1.0, a, b, c)
            k2 = state_rate(code, z[i], zd[i], s + 0.5 * h * k1, 1.0, a, b, c)
            s = s + h * k2
    return s


def state_after(code: int, shape: tuple[float, ...], zd: np.ndarray, dt: float,
                s0: float) -> float:
    """A motion-driven term state (Bouc–Wen r, fluid θ) at the end of the sampled ż."""
    zd = np.ascontiguousarray(zd, float)
    a, b, c = tuple(shape) + (0.0,) * (3 - len(shape))
    return float(_series(code, False, a, b, c, zd, zd, 0.0, dt, s0, np.empty(zd.size)))


def term_column(model: IsolatorModel, j: int, z: np.ndarray, zd: np.ndarray) -> np.ndarray:
    """Term j's column of `regressor_matrix`: its basis at every sample (stateless terms)."""
    t = model.terms[j]
    if kind(t.kind).has_state:
        raise ValueError(f"term {t.name!r} ({t.kind}) has internal state")
    codes, gated = model.structure()
    shape = tuple(t.shape) + (0.0,) * (3 - len(t.shape))
    col = np.empty(z.size)
    _series(codes[j], gated[j], *shape, np.ascontiguousarray(z, float),
            np.ascontiguousarray(zd, float), model.dead_band, 1.0, 0.0, col)
    return col


def carries_state(term: Term) -> bool:
    """Whether the term's state stays into the next run: the fluid stays warm; every
    other state starts each run at zero."""
    return term.kind == "thermal_damper"


def campaign_column(model: IsolatorModel, j: int, z: Sequence[np.ndarray],
                    zd: Sequence[np.ndarray], dt: float, carried: bool = True) -> np.ndarray:
    """Term j's basis on every sample of the runs, in order. A fluid's temperature stays
    into the next run unless `carried` is False; every other state starts each run at
    zero."""
    codes, gated = model.structure()
    t = model.terms[j]
    shape = tuple(t.shape) + (0.0,) * (3 - len(t.shape))
    carry = carried and carries_state(t)
    state, cols = 0.0, []
    for zr, zdr in zip(z, zd):
        zr, zdr = np.ascontiguousarray(zr, float), np.ascontiguousarray(zdr, float)
        col = np.empty(zr.size)
        end = _series(codes[j], gated[j], *shape, zr, zdr, model.dead_band, dt, state, col)
        state = end if carry else 0.0
        cols.append(col)
    return np.concatenate(cols) if cols else np.empty(0)


def campaign_regressors(model: IsolatorModel, z: Sequence[np.ndarray],
                        zd: Sequence[np.ndarray], dt: float) -> np.ndarray:
    """Z (Σn, J): each term's basis on every sample of the runs, in order."""
    n = sum(np.size(zr) for zr in z)
    return np.column_stack([campaign_column(model, j, z, zd, dt)
                            for j in range(len(model.terms))]) if model.terms else np.empty((n, 0))
