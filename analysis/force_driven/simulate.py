"""Output simulation of an identified force-driven model: q from the measured force alone.

Equation error (what the fit minimises) says how well the model explains the
force at the measured motion; simulation error says how well it predicts the
motion from the force, the figure of merit of output benchmarks such as
Silverbox. The model m q̈ = F − Σ θ_k φ_k(q, q̇) is integrated by classical RK4
with `substeps` steps per sample. RK4 needs the force between samples; a
sampled force is band-limited (Silverbox: content to 200 Hz at 610 Hz), so it is
interpolated band-limited (polyphase FIR, scipy.signal.resample_poly), not
linearly: linear interpolation would low-pass it by up to 30 % near 200 Hz.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy import signal

from analysis.force_driven.model import MASS, term

SUBSTEPS = 4
SKIP = 50  # samples for state initialisation before scoring (the Silverbox convention)


@njit(cache=True)
def _resisting(codes: np.ndarray, theta: np.ndarray, q: float, v: float) -> float:
    # one branch per model.Term.code; keep in step with model.py's regressors
    f = 0.0
    for i in range(codes.size):
        c = codes[i]
        if c == 0:
            phi = v
        elif c == 1:
            phi = q
        elif c == 2:
            phi = 1.0 if v > 0 else (-1.0 if v < 0 else 0.0)
        elif c == 3:
            phi = 1.0
        elif c == 4:
            phi = max(v, 0.0)
        elif c == 5:
            phi = v * abs(v)
        elif c == 6:
            phi = q * q * q
        else:
            phi = max(q, 0.0)
        f += theta[i] * phi
    return f


@njit(cache=True)
def _rk4(codes: np.ndarray, theta: np.ndarray, mass: float, fine: np.ndarray, per: int,
         h: float, q0: float, v0: float, n: int) -> np.ndarray:
    # fine: the force at half-substep spacing, 2·per points per sample interval
    out = np.empty(n)
    q, v = q0, v0
    out[0] = q
    for k in range(n - 1):
        for s in range(per):
            j = 2 * (k * per + s)
            f0, f1, f2 = fine[j], fine[j + 1], fine[j + 2]
            a1 = (f0 - _resisting(codes, theta, q, v)) / mass
            q2, v2 = q + 0.5 * h * v, v + 0.5 * h * a1
            a2 = (f1 - _resisting(codes, theta, q2, v2)) / mass
            q3, v3 = q + 0.5 * h * v2, v + 0.5 * h * a2
            a3 = (f1 - _resisting(codes, theta, q3, v3)) / mass
            q4, v4 = q + h * v3, v + h * a3
            a4 = (f2 - _resisting(codes, theta, q4, v4)) / mass
            q += h / 6.0 * (v + 2.0 * v2 + 2.0 * v3 + v4)
            v += h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        out[k + 1] = q
        if not np.isfinite(q):
            out[k + 1:] = np.nan
            break
    return out


def simulate_position(params: dict[str, float], force: np.ndarray, dt: float, q0: float,
                      v0: float, substeps: int = SUBSTEPS) -> np.ndarray:
    """q (m) at the force's samples, from rest state (q0, v0); params keyed by term name."""
    mass = float(params[MASS])
    if not mass > 0:
        raise ValueError(f"cannot simulate with mass {mass}")
    names = [n for n in params if n != MASS]
    codes = np.array([term(n).code for n in names], dtype=np.int64)
    theta = np.array([params[n] for n in names], float)
    force = np.asarray(force, float)
    up = 2 * substeps
    # one extra sample so the last interval has its end point; resample_poly's edges are
    # a few samples of FIR transient, inside the benchmark's initialisation window
    padded = np.concatenate([force, force[-1:]])
    fine = signal.resample_poly(padded, up, 1)[: (force.size - 1) * up + 1]
    return _rk4(codes, theta, mass, fine, substeps, dt / substeps, float(q0), float(v0),
                force.size)


def initial_state(q: np.ndarray, dt: float, samples: int = 7) -> tuple[float, float]:
    """(q, q̇) at the first sample from a cubic through the first `samples` measured values."""
    t = np.arange(samples) * dt
    c = np.polyfit(t, q[:samples], 3)
    return float(np.polyval(c, 0.0)), float(np.polyval(np.polyder(c), 0.0))


def rms_error(simulated: np.ndarray, measured: np.ndarray, skip: int = 0) -> float:
    """RMS of simulated − measured after the first `skip` samples (state initialisation)."""
    e = np.asarray(simulated)[skip:] - np.asarray(measured)[skip:]
    return float(np.sqrt(np.mean(e**2))) if np.all(np.isfinite(e)) else float("inf")
