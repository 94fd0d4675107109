"""The table's motion estimated from its noisy sensor by a model of the command.

Errors in variables: the table displacement that drives the isolator model is
measured with the same noise as the response. A smoothing spline removes most
of it, but what is left is enough to move the instant static friction lets go
and the place the mass comes to rest in the dead band, and a mass resting
20 µm off for two seconds costs more than all the noise: measured on runs A–C
with 25 µm sensor noise, a 50 Hz spline leaves the true model 3–6 times the
noise from the data, the exact input 1.0 times.

A step-pulse table moves in minimum-jerk ramps between rests (rig.profile), a
handful of numbers per ramp. Fitting those numbers to the thousands of samples
estimates the input far better than the noise of any one sample. This module
fits them: rests are found from the data, each moving stretch is one ramp or
several back to back (split where the motion turns), and the fit is accepted
only if what is left is the sensor's noise (RMS within 10 % of σ). Otherwise
the table did not follow a step-pulse profile (a lagging actuator, another
rig's excitation) and the caller falls back to the smoothing spline.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PPoly
from scipy.optimize import least_squares

from analysis.identify.output_error import noise_sigma, smooth_motion, table_at_rest
from rig.profile import Profile, Segment

ACCEPT_RATIO = 1.10  # residual RMS over σ_u for the command model to be believed
MAX_RAMPS = 4  # per moving stretch


@dataclass(frozen=True)
class TableMotion:
    """The estimated u(t) that drives the model, and how it was obtained."""

    motion: PPoly
    method: str  # "step-pulse fit" or "smoothing spline"
    residual_over_noise: float  # RMS(u_meas − u_est)/σ_u
    sigma: float  # m, the table sensor's noise
    # the fitted (start s, duration s, from m, to m) of each ramp; () for a spline
    ramps: tuple[tuple[float, float, float, float], ...] = ()


def estimate_table_motion(t: np.ndarray, u: np.ndarray) -> TableMotion:
    """The best input estimate the data support: a fitted step-pulse, else a spline."""
    t, u = np.asarray(t, float), np.asarray(u, float)
    sigma = noise_sigma(u)
    ramps = fit_ramps(t, u, sigma)
    if ramps:
        fitted = ramps_motion(t, ramps)
        ratio = _ratio(fitted, t, u, sigma)
        if ratio <= ACCEPT_RATIO:
            return TableMotion(fitted, "step-pulse fit", ratio, sigma, tuple(ramps))
    spline = smooth_motion(t, u)
    return TableMotion(spline, "smoothing spline", _ratio(spline, t, u, sigma), sigma)


def _ratio(motion: PPoly, t: np.ndarray, u: np.ndarray, sigma: float) -> float:
    return float(np.sqrt(np.mean((motion(t) - u) ** 2)) / max(sigma, 1e-300))


def fit_step_pulse(t: np.ndarray, u: np.ndarray, sigma: float) -> PPoly | None:
    """Rests and minimum-jerk ramps fitted to u; None when no motion is found."""
    ramps = fit_ramps(t, u, sigma)
    return ramps_motion(t, ramps) if ramps else None


def fit_ramps(t: np.ndarray, u: np.ndarray, sigma: float
              ) -> list[tuple[float, float, float, float]]:
    """(start, duration, from, to) of each minimum-jerk ramp fitted to u; [] if no motion."""
    dt = float(t[1] - t[0])
    rest = table_at_rest(u, dt, sigma)
    stretches = _moving_stretches(rest)
    segments: list[tuple[float, float, float, float]] = []  # (start, duration, from, to)
    for i0, i1 in stretches:
        segments.extend(_fit_stretch(t, u, i0, i1, sigma))
    return segments


def _moving_stretches(rest: np.ndarray) -> list[tuple[int, int]]:
    edges = np.flatnonzero(np.diff(np.r_[0, (~rest).astype(int), 0]))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]


def _fit_stretch(t, u, i0, i1, sigma) -> list[tuple[float, float, float, float]]:
    """One stretch of motion (samples i0:i1, rest on both sides): 1..MAX_RAMPS ramps."""
    lo, hi = max(i0 - 1, 0), min(i1, t.size - 1)
    best = None
    for n in range(1, MAX_RAMPS + 1):
        fit = _fit_ramps(t[lo:hi + 1], u[lo:hi + 1], n)
        if fit is None:
            continue
        ramps, rms = fit
        if best is None or rms < best[1]:
            best = (ramps, rms)
        if rms <= ACCEPT_RATIO * sigma:
            break
    return best[0] if best else []


def _fit_ramps(t, u, n):
    """n back-to-back minimum-jerk ramps from u[0] to u[-1] through n − 1 turning levels."""
    levels0 = _turning_levels(u, n)
    if levels0 is None:
        return None
    t0, t1 = float(t[0]), float(t[-1])
    cuts = np.linspace(t0, t1, n + 1)
    x0 = np.r_[cuts, levels0]

    def residual(p):
        return _ramps_value(t, p[: n + 1], p[n + 1:]) - u

    lower = np.r_[np.full(n + 1, t0), np.full(n + 1, -np.inf)]
    upper = np.r_[np.full(n + 1, t1), np.full(n + 1, np.inf)]
    sol = least_squares(residual, x0, bounds=(lower, upper), method="trf",
                        x_scale=np.r_[np.full(n + 1, 0.01), np.full(n + 1, 1e-3)])
    times, levels = np.sort(sol.x[: n + 1]), sol.x[n + 1:]
    if np.any(np.diff(times) <= 0):
        return None
    ramps = [(times[k], times[k + 1] - times[k], levels[k], levels[k + 1]) for k in range(n)]
    return ramps, float(np.sqrt(np.mean(sol.fun**2)))


def _turning_levels(u, n):
    """Start, n − 1 turning points (largest excursions, in time order), end."""
    if n == 1:
        return np.array([u[0], u[-1]])
    idx = np.sort(np.argsort(-np.abs(u - u[0]))[: max(1, u.size // 50)])
    if n - 1 > idx.size:
        return None
    picks = idx[np.linspace(0, idx.size - 1, n - 1).astype(int)]
    return np.r_[u[0], u[picks], u[-1]]


def _ramps_value(t, times, levels):
    out = np.full(t.shape, levels[0], float)
    for k in range(len(times) - 1):
        T = max(times[k + 1] - times[k], 1e-9)
        tau = np.clip((t - times[k]) / T, 0.0, 1.0)
        shape = tau**3 * (10 - 15 * tau + 6 * tau**2)
        inside = t >= times[k]
        out[inside] = levels[k] + (levels[k + 1] - levels[k]) * shape[inside]
    return out


def ramps_motion(t: np.ndarray, ramps) -> PPoly:
    """Rests and ramps as a rig.profile Profile, whose motion is an exact quintic PPoly."""
    segments, now = [], float(t[0])
    start = ramps[0][2]
    for begin, duration, _, to in ramps:
        if begin > now + 1e-9:
            segments.append(Segment(begin - now))
        segments.append(Segment(duration, to))
        now = begin + duration
    if t[-1] > now + 1e-9:
        segments.append(Segment(float(t[-1]) - now))
    m = Profile("estimated", tuple(segments), start).motion()
    return PPoly(m.c, m.x + float(t[0]))
