"""The Kalman filter + Rauch–Tung–Striebel smoother of `analysis.signals.differentiate` ('rts').

An integrated-Wiener model of order p (p = 3: white jerk; 4: white snap; 5)
whose process noise puts the smoother's half-amplitude point at the cutoff fc:
its response is 1/(1 + (f/fc)^(2p)). `rts_grid` and `rts_q` are what
`analysis.signals.differentiate` uses.
"""

from __future__ import annotations

from collections.abc import Callable
from math import factorial

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import signal

DIFFUSE = 1e8  # prior variance of the first state, in units of σ²: data dominate at once
RTS_ORDERS = (3, 4, 5)
TINY = 1e-200  # below this a number is as good as zero and far cheaper
Triple = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]


# ---------------------------------------------------------------- RTS smoother
# State s = (x, τẋ, τ²ẍ, …) with τ = 1/(2π fc) and step h = dt/τ: in these units every
# covariance entry is of order h, which keeps the recursions accurate where the
# information form (one banded normal-equation solve) loses digits. Variances are in
# units of the measurement noise σ². The covariances do not depend on the data; they
# are computed for a whole grid of cutoffs in one loop that stops once they settle.


def rts_q(sigma: float, dt: float, fc: float, p: int) -> float:
    """Intensity of the white p-th derivative (m²/s^(2p-1)) that puts the cutoff at fc."""
    return sigma**2 * dt * (2 * np.pi * fc) ** (2 * p)


def _rts_model(h: NDArray, p: int) -> tuple[NDArray, NDArray]:
    """Transition F and process noise Q, shape (G, p, p), for steps h, shape (G,)."""
    i, j = np.indices((p, p))
    fact = np.array([factorial(k) for k in range(p)], dtype=float)
    lag, a, b = np.abs(j - i), p - 1 - i, p - 1 - j
    h = np.asarray(h, dtype=float)[:, None, None]
    F = np.where(j >= i, h**lag / fact[lag], 0.0)
    return F, h ** (a + b + 2) / ((a + b + 1) * fact[a] * fact[b])


def _rts_gains(F: NDArray, Q: NDArray, n: int) -> tuple[NDArray, NDArray, NDArray]:
    """Prior and posterior covariances (m, G, p, p) and the step (G,) where each settled."""
    G, p, _ = F.shape
    eye = np.eye(p)
    P = np.repeat(DIFFUSE * eye[None], G, axis=0)
    prior, post, settled = [], [], np.full(G, n)
    for k in range(n):
        if k:
            P = F @ P @ F.transpose(0, 2, 1) + Q
        g = P[:, :, 0] / (P[:, 0, 0] + 1.0)[:, None]
        J = eye - g[:, :, None] * eye[0]
        prior.append(P)
        post.append(J @ P @ J.transpose(0, 2, 1) + g[:, :, None] * g[:, None, :])  # Joseph form
        if k > p:
            still = np.abs(P - prior[-2]).max(axis=(1, 2)) <= 1e-12 * np.abs(P).max(axis=(1, 2))
            settled = np.where(still & (settled == n), k + 1, settled)
            if (settled < n).all():
                break
        P = post[-1]
    return np.array(prior), np.array(post), settled


def _scan(A: NDArray, u: NDArray, s0: NDArray) -> NDArray:
    """s_k = A_k s_(k-1) + u_k for k = 0…N-1 from s_(-1) = s0, in log2 N vector steps."""
    A, b = A.copy(), u.copy()
    b[0] += A[0] @ s0
    d = 1
    while d < len(b):
        b[d:] = b[d:] + np.einsum("kij,kj->ki", A[d:], b[:-d])
        A[d:] = A[d:] @ A[:-d]
        A[np.abs(A) < TINY] = 0.0  # products of contractions: keep them out of subnormals
        d *= 2
    return b


def _lti(A: NDArray, u: NDArray, s0: NDArray) -> NDArray:
    """As `_scan` for a constant A: one first-order lfilter per eigenvalue.

    Products with the long axis go through einsum, not BLAS: a threaded BLAS on a
    busy machine made these (p × p)·(p × n) products 100 times slower.
    """
    lam, V = np.linalg.eig(A)
    Vi = np.linalg.inv(V)
    w = np.einsum("ij,kj->ik", Vi, u)
    w0 = Vi @ s0
    for i, z in enumerate(lam):
        w[i] = signal.lfilter([1.0], [1.0, -z], w[i], zi=[z * w0[i]])[0]
    w[np.abs(w) < TINY] = 0.0  # decayed tails are subnormal, and subnormals are 100× slower
    return np.einsum("ij,jk->ki", V, w).real


def _rts_pass(y: NDArray, F: NDArray, prior: NDArray, post: NDArray,
              smooth: bool) -> tuple[NDArray | None, float]:
    """Smoothed scaled states (n, p) of y − y[0] and the log-evidence of y (in units of σ)."""
    n, m, p = len(y), len(prior), len(F)
    yc = y - y[0]
    g = prior[:, :, 0] / (prior[:, 0, 0] + 1.0)[:, None]
    A = (np.eye(p) - g[:, :, None] * np.eye(p)[0]) @ F
    filt = np.empty((n, p))
    filt[:m] = _scan(A, g * yc[:m, None], np.zeros(p))
    if m < n:
        filt[m:] = _lti(A[-1], np.outer(yc[m:], g[-1]), filt[m - 1])
    innov = yc - np.concatenate([[0.0], np.einsum("kj,j->k", filt[:-1], F[0])])
    var = np.concatenate([prior[:, 0, 0], np.full(n - m, prior[-1, 0, 0])]) + 1.0
    k = max(RTS_ORDERS)  # every order conditioned on the same first samples
    evidence = -0.5 * float(np.sum(np.log(2 * np.pi * var[k:]) + innov[k:] ** 2 / var[k:]))
    if not smooth:
        return None, evidence
    nxt = np.concatenate([prior[1:], prior[-1:]])
    C = np.linalg.solve(nxt, F @ post).transpose(0, 2, 1)  # post_k Fᵀ prior_(k+1)⁻¹
    sm = np.empty((n, p))
    sm[-1], last = filt[-1], n - 1
    if m < n - 1:
        ks = np.arange(n - 2, m - 1, -1)
        sm[ks] = _lti(C[-1], filt[ks] - np.einsum("ij,kj->ki", C[-1] @ F, filt[ks]), sm[-1])
        last = m
    ks = np.arange(last - 1, -1, -1)
    if ks.size:
        sm[ks] = _scan(C[ks], filt[ks] - np.einsum("kij,kj->ki", C[ks] @ F, filt[ks]), sm[last])
    return sm, evidence


def rts_grid(y: NDArray, dt: float, fcs: ArrayLike, p: int,
             evidence: bool = True) -> list[tuple[Callable[[NDArray], Triple], float]]:
    """For each cutoff: the smoother as a function of any signal, and the evidence of y."""
    fcs = np.atleast_1d(np.asarray(fcs, dtype=float))
    F, Q = _rts_model(2 * np.pi * fcs * dt, p)
    prior, post, settled = _rts_gains(F, Q, len(y))
    out = []
    for i, fc in enumerate(fcs):
        pr, po, tau = prior[: settled[i], i], post[: settled[i], i], 1.0 / (2 * np.pi * fc)

        def run(z: NDArray, F=F[i], pr=pr, po=po, tau=tau) -> Triple:
            sm = _rts_pass(z, F, pr, po, smooth=True)[0]
            return z[0] + sm[:, 0], sm[:, 1] / tau, sm[:, 2] / tau**2

        out.append((run, _rts_pass(y, F[i], pr, po, smooth=False)[1] if evidence else np.nan))
    return out
