"""The table's motion estimated from its noisy sensor by a model of the command.

Errors in variables: the table displacement that drives the isolator model is
measured with the same noise as the response. A smoothing spline removes most
of it, but what is left is enough to move the instant static friction lets go
and the place the mass comes to rest in the dead band, and a mass resting
20 µm off for two seconds costs more than all the noise: measured on runs A–C
with 25 µm sensor noise, a 50 Hz spline leaves the true model 3–6 times the
noise from the data, the exact input 1.0 times.

A step-pulse table moves in ramps between rests, a handful of numbers per ramp.
This rig's ramps are minimum-jerk (rig.profile); other rigs' motion controllers
use the other standard motion laws: cycloidal, harmonic (half-cosine) or
parabolic (constant acceleration). The shape is one more choice of the fit:
minimum-jerk is tried first, and where it does not reach the noise every shape
of `RAMP_SHAPES` is fitted and the one with the least residual is kept (a wrong
shape misses a 0.14 m ramp by hundreds of µm: the choice is never close). Fitting
those numbers to the thousands of samples estimates the input far better than the
noise of any one sample. This module fits them: rests are found from the data,
each moving stretch is one ramp or several back to back (split where the motion
turns), and the fit is accepted only if what is left is the sensor's noise (RMS
within 10 % of σ). Otherwise the table did not follow a step-pulse profile
(another rig's excitation, a resonance) and the caller falls back to the
smoothing spline.

Servo lag. Servo-hydraulic actuators follow their setpoints through a lag:
the table is the commanded ramps passed through p' = (r − p)/τ, which a plain
minimum-jerk ramp misses by τ²/2·ü (250 µm on run A at τ = 5 ms, ten times the
noise). The lag τ is one more number per run, fitted with the ramps; it is
kept when it lowers the residual sum of squares by more than LAG_CHI2 σ² (a
5 σ improvement for one parameter), so an exact profile keeps τ = 0 and the
plain model. The lagged motion is exact (`lag_response`: the polynomial
particular solution plus the decaying transient, piece by piece) and handed to
the simulator as the quintic Hermite through its position, velocity and
acceleration at the data's samples.

Noise. σ_u is the spread of second differences three samples apart, over the
table's rests, when that exceeds the plain (adjacent) second-difference reading
by more than 5 %: a channel interpolated onto another sensor's clock (run files,
`analysis.identify.loading`) has neighbouring samples correlated, which plain
second differences read as up to 2.4× less noise than each sample carries.
White noise keeps the plain reading.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise

import numpy as np
from scipy.interpolate import PPoly
from scipy.optimize import least_squares

from analysis.identify.output_error import noise_sigma, smooth_motion, table_at_rest
from analysis.simulate.motion import quintic_hermite
from rig.profile import Profile, Segment

ACCEPT_RATIO = 1.10  # residual RMS over σ_u for the command model to be believed
MAX_RAMPS = 4  # per moving stretch
MAX_LAG = 0.05  # s: the slowest servo lag fitted (a 3 Hz servo is no step-pulse rig)
LAG_START = 0.003  # s: where the lag's fit starts (the start times shifted back by it)
LAG_CHI2 = 25.0  # σ²: the lag must lower the residual sum of squares by this much
NOISE_SPACING = 3  # samples between the points of the second differences σ_u is read from
CORRELATED = 1.05  # σ_u three samples apart over adjacent ones beyond which noise is not white
TIE = 1e-6  # s: ramps closer than this are back to back
MINIMUM_JERK = "minimum-jerk"
RAMP_SHAPES = (MINIMUM_JERK, "cycloidal", "harmonic", "parabolic")


def ramp_shape(shape: str, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The motion law s(τ) of a ramp and its first two derivatives, τ clipped to [0, 1].

    All rise from 0 to 1 with zero velocity at both ends; minimum-jerk and cycloidal
    also with zero acceleration, harmonic and parabolic with a step in it.
    """
    tau = np.clip(np.asarray(tau, float), 0.0, 1.0)
    if shape == MINIMUM_JERK:
        return (tau**3 * (10 - 15 * tau + 6 * tau**2), 30 * tau**2 * (1 - tau) ** 2,
                60 * tau * (1 - tau) * (1 - 2 * tau))
    if shape == "cycloidal":
        w = 2 * np.pi * tau
        return tau - np.sin(w) / (2 * np.pi), 1 - np.cos(w), 2 * np.pi * np.sin(w)
    if shape == "harmonic":
        w = np.pi * tau
        return (1 - np.cos(w)) / 2, np.pi / 2 * np.sin(w), np.pi**2 / 2 * np.cos(w)
    if shape == "parabolic":
        first = tau < 0.5
        return (np.where(first, 2 * tau**2, 1 - 2 * (1 - tau) ** 2),
                np.where(first, 4 * tau, 4 * (1 - tau)), np.where(first, 4.0, -4.0))
    raise ValueError(f"unknown ramp shape {shape!r}; known: {', '.join(RAMP_SHAPES)}")


@dataclass(frozen=True)
class TableMotion:
    """The estimated u(t) that drives the model, and how it was obtained."""

    motion: PPoly
    method: str  # "step-pulse fit" or "smoothing spline"
    residual_over_noise: float  # RMS(u_meas − u_est)/σ_u
    sigma: float  # m, the table sensor's noise
    # the fitted (start s, duration s, from m, to m) of each commanded ramp; () for a spline
    ramps: tuple[tuple[float, float, float, float], ...] = ()
    lag: float = 0.0  # s, servo lag τ the table follows the ramps with; 0: exactly
    shape: str = "minimum-jerk"  # the ramps' motion law (RAMP_SHAPES)
    # m, the white noise of the same low-frequency power (what slow parameters see):
    # above `sigma` when neighbouring samples are correlated (interpolation); 0: = sigma
    sigma_lowfreq: float = 0.0


def estimate_table_motion(t: np.ndarray, u: np.ndarray) -> TableMotion:
    """The best input estimate the data support: a fitted step-pulse, else a spline."""
    t, u = np.asarray(t, float), np.asarray(u, float)
    sigma, lowfreq = table_noise_levels(t, u)
    if sigma <= CORRELATED * noise_sigma(u):  # white: adjacent differences, as always
        sigma = lowfreq = noise_sigma(u)
    # plain ramps of each shape before any lag: a lagged minimum-jerk ramp can pass for
    # a cycloidal one (a 14 ms lag fitted one to the noise), and this rig's own plain
    # ramps are found at the cost of one fit
    best = _best_step_pulse(t, u, sigma, MINIMUM_JERK, lagged=False)
    look = _shapes_by_fit(t, u, sigma)
    other = next(s for s in look if s != MINIMUM_JERK)
    if look[0] != MINIMUM_JERK or not _accepted(best):
        # at 4× the rig's noise a minimum-jerk fit of cycloidal ramps passes the accept
        # rule (1.07 σ) and leaves the isolator model 490× the noise from run C: the
        # other shape is fitted whenever one ramp of it fits the stretches better, and
        # kept when it is better by more than LAG_CHI2 σ²
        alt = _best_step_pulse(t, u, sigma, other, lagged=False)
        if alt is not None and (best is None or alt[4] < best[4] - LAG_CHI2 * sigma**2):
            best = alt
    tries = [best]
    for shape in (MINIMUM_JERK, other):  # a lagged servo: this rig's ramps first
        if _accepted(best):
            break
        tries.append(_best_step_pulse(t, u, sigma, shape))
        best = min([b for b in tries if b is not None], key=lambda b: b[4], default=None)
    if best is not None and best[3] <= ACCEPT_RATIO:
        ramps, lag, shape, ratio, _ = best
        return TableMotion(step_pulse_motion(t, ramps, lag, shape), "step-pulse fit", ratio,
                           sigma, tuple(ramps), lag, shape, lowfreq)
    spline = smooth_motion(t, u)
    return TableMotion(spline, "smoothing spline", _ratio(spline, t, u, sigma), sigma)


def _accepted(fit) -> bool:
    return fit is not None and fit[3] <= ACCEPT_RATIO


def _shapes_by_fit(t, u, sigma) -> list[str]:
    """The shapes, those whose one-ramp fits of the record's moving stretches leave the
    least residual first: a cheap look before the full fit."""
    rest = table_at_rest(u, float(t[1] - t[0]), sigma)
    ss = {}
    for shape in RAMP_SHAPES:
        total = 0.0
        for i0, i1 in _moving_stretches(rest):
            lo, hi = max(i0 - 1, 0), min(i1, t.size - 1)
            fit = _fit_ramps(t[lo:hi + 1], u[lo:hi + 1], 1, shape)
            total += np.inf if fit is None else fit[1] ** 2 * (hi + 1 - lo)
        ss[shape] = total
    return sorted(ss, key=ss.get)


def _best_step_pulse(t, u, sigma, shape, lagged: bool = True):
    """(ramps, lag, shape, RMS/σ, sum of squares m²) of the best step-pulse fit with ramps
    of `shape`,
    through a servo lag where `lagged` and the lag earns its place; None: no motion."""
    plain, lagged = _fit_all(t, u, sigma, lagged, shape)
    best = None
    if plain:
        best = (plain, 0.0, _sum_squares(t, u, plain, 0.0, shape))
    if lagged is not None:
        ramps, lag = refine_step_pulse(t, u, *lagged, free_lag=True, shape=shape)
        ss = _sum_squares(t, u, ramps, lag, shape)
        # the lag against the plain ramps fitted as jointly (the per-stretch fit is a
        # little off: measured 2·25 σ² on an exact run A, which took a 1 ms lag for it)
        # (a few iterations: a lagged table leaves the plain ramps far off however refined)
        ss_plain = (_sum_squares(t, u, refine_step_pulse(t, u, plain, 0.0, free_lag=False,
                                                         max_nfev=40, shape=shape)[0],
                                 0.0, shape)
                    if plain else np.inf)
        if ss_plain - ss > LAG_CHI2 * sigma**2:
            best = (ramps, lag, ss)
    if best is None:
        return None
    ramps, lag, ss = best
    return ramps, lag, shape, float(np.sqrt(ss / u.size) / max(sigma, 1e-300)), ss


def table_noise(t: np.ndarray, u: np.ndarray) -> float:
    """σ of the table sensor's samples, read where the table rests (m)."""
    return table_noise_levels(t, u)[0]


def table_noise_levels(t: np.ndarray, u: np.ndarray) -> tuple[float, float]:
    """(σ of each sample, σ of the white noise with the same low-frequency power), m.

    Second differences NOISE_SPACING samples apart share no sample, so their spread
    is √6 σ whether or not neighbours are correlated (linear interpolation onto
    another clock makes them so); taken over the rests only, the ramps' curvature
    (9× larger at this spacing) does not inflate it. Without rests (no step pulse):
    the plain second-difference estimate, for both.

    Low frequency: a fit of a few slow parameters averages the noise, and what it
    averages is its spectrum at 0, γ0 + 2γ1 for neighbours correlated one apart
    (an interpolation between two samples). With v1 the variance of adjacent
    second differences (6γ0 − 8γ1): (10γ0 − v1)/4; σ² for white noise, and the
    sensor's own σ² for any linear interpolation of it, where γ0 is as low as σ²/2.
    """
    u = np.asarray(u, float)
    L = NOISE_SPACING
    if u.size < 10 * L:
        return noise_sigma(u), noise_sigma(u)
    d2 = u[2 * L:] - 2 * u[L:-L] + u[:-2 * L]
    dt = float(t[1] - t[0])
    first = _robust_sigma(d2)  # ramps inflate it a little: rests are found generously
    rest = table_at_rest(u, dt, first)
    still = rest[2 * L:] & rest[L:-L] & rest[:-2 * L]
    if np.count_nonzero(still) < 100:
        return first, first
    d2 = d2[still]
    d2 = d2[np.abs(d2 - np.median(d2)) <= 5 * np.sqrt(6.0) * _robust_sigma(d2)]  # spikes
    var = float(np.mean(d2**2) / 6.0)  # at rest: the efficient estimate
    a2 = np.diff(u, 2)[rest[2:] & rest[1:-1] & rest[:-2]]
    a2 = a2[np.abs(a2 - np.median(a2)) <= 5 * np.sqrt(6.0 * var)]
    lowfreq = max((10.0 * var - float(np.mean(a2**2))) / 4.0, var) if a2.size else var
    return float(np.sqrt(var)), float(np.sqrt(lowfreq))


def _robust_sigma(d2: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))


def _ratio(motion: PPoly, t: np.ndarray, u: np.ndarray, sigma: float) -> float:
    return float(np.sqrt(np.mean((motion(t) - u) ** 2)) / max(sigma, 1e-300))


def _sum_squares(t, u, ramps, lag, shape=MINIMUM_JERK) -> float:
    return float(np.sum((step_pulse_value(t, ramps, lag, shape) - u) ** 2))


# -- the model: commanded ramps, through the servo lag ----------------------------------

def step_pulse_value(t: np.ndarray, ramps, lag: float = 0.0,
                     shape: str = MINIMUM_JERK) -> np.ndarray:
    """u at `t` (≥ t[0]) of the ramps followed through the lag τ (s); 0: the ramps."""
    if lag <= 0.0 and shape != MINIMUM_JERK:
        return _ramps_value(np.asarray(t, float), *_times_levels(ramps), shape)
    command = command_motion(t, ramps, shape)
    if lag <= 0.0:
        return command(t)
    return lag_response(t, command, lag)[0]


def step_pulse_motion(t: np.ndarray, ramps, lag: float = 0.0,
                      shape: str = MINIMUM_JERK) -> PPoly:
    """The fitted table motion the simulator reads, on [t[0], t[-1]].

    Minimum-jerk without lag: the ramps' exact quintic PPoly. Otherwise the quintic
    Hermite through the motion's position, velocity and acceleration at the data's
    samples `t` (C²: a harmonic ramp's step in acceleration is spread over one
    sample; a lagged or cycloidal motion is off by far less than a nanometre).
    """
    command = command_motion(t, ramps, shape)
    if lag <= 0.0:
        return command
    t = np.asarray(t, float)
    p, v, a = lag_response(t, command, lag)
    return quintic_hermite(t, p, v, a)


def command_motion(t: np.ndarray, ramps, shape: str = MINIMUM_JERK) -> PPoly:
    """The commanded ramps as a PPoly: exact quintic pieces for minimum-jerk ramps,
    else the quintic Hermite through the motion law at the samples `t`."""
    if shape == MINIMUM_JERK:
        return ramps_motion(t, ramps)
    t = np.asarray(t, float)
    return quintic_hermite(t, *_ramps_derivatives(t, *_times_levels(ramps), shape))


def _times_levels(ramps) -> tuple[list[tuple[float, float]], list[tuple[float, float]]]:
    """((begin, end) s, (from, to) m) of each ramp."""
    return [(r[0], r[0] + r[1]) for r in ramps], [(r[2], r[3]) for r in ramps]


def lag_response(t: np.ndarray, command: PPoly, lag: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, velocity, acceleration of p' = (r − p)/τ driven by the PPoly `command` r.

    p rests at r before r's first break, and r is held after its last. On each piece
    (a polynomial q of s = t − x_i) p = P(s) + C e^(−s/τ) with the particular solution
    P = Σ_k (−τ)^k q^(k) and C carrying p's value across the break: exact.
    """
    t = np.asarray(t, float)
    x, c = command.x, np.asarray(command.c, float)
    pieces, deg = x.size - 1, c.shape[0] - 1
    part, deriv = np.zeros_like(c), c.copy()
    for k in range(deg + 1):
        part += (-lag) ** k * deriv
        deriv = _derivative(deriv)
    h = np.diff(x)
    start = np.empty(pieces + 1)  # p at each break
    start[0] = c[-1, 0]
    for i in range(pieces):
        decay = np.exp(-h[i] / lag)
        start[i + 1] = np.polyval(part[:, i], h[i]) + (start[i] - part[-1, i]) * decay
    end_value = np.polyval(c[:, -1], h[-1])
    consts = np.r_[start[:-1] - part[-1], start[-1] - end_value]
    i = np.searchsorted(x, t, side="right") - 1
    before, after = i < 0, i >= pieces
    j = np.clip(i, 0, pieces - 1)
    s = np.where(after, t - x[-1], t - x[j])
    s = np.where(before, 0.0, s)
    P, dP, ddP = _horner3(part[:, j], s)
    P = np.where(after, end_value, P)
    dP = np.where(after, 0.0, dP)
    ddP = np.where(after, 0.0, ddP)
    C = np.where(after, consts[-1], consts[j])
    e = np.exp(-s / lag)
    p = P + C * e
    v = dP - C / lag * e
    a = ddP + C / lag**2 * e
    p = np.where(before, start[0], p)
    v = np.where(before, 0.0, v)
    a = np.where(before, 0.0, a)
    return p, v, a


def _derivative(c: np.ndarray) -> np.ndarray:
    """d/ds of polynomials with coefficients c (highest first, one column each), same shape."""
    deg = c.shape[0] - 1
    out = np.zeros_like(c)
    out[1:] = c[:-1] * np.arange(deg, 0, -1)[:, None]
    return out


def _horner3(c: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Value, first and second derivative of each column's polynomial at its s."""
    v = np.zeros_like(s)
    d1 = np.zeros_like(s)
    d2 = np.zeros_like(s)
    for row in c:
        d2 = d2 * s + 2.0 * d1
        d1 = d1 * s + v
        v = v * s + row
    return v, d1, d2


# -- fitting --------------------------------------------------------------------------

def fit_ramps(t: np.ndarray, u: np.ndarray, sigma: float
              ) -> list[tuple[float, float, float, float]]:
    """(start, duration, from, to) of each minimum-jerk ramp fitted to u; [] if no motion."""
    return _fit_all(t, u, sigma, lagged=False)[0]


def _fit_all(t, u, sigma, lagged: bool = True, shape: str = MINIMUM_JERK):
    """Plain ramps of every moving stretch, and (ramps, lag) with a lag (None if not fitted).

    The lag starts at the stretches' fitted lags averaged by their length.
    """
    dt = float(t[1] - t[0])
    rest = table_at_rest(u, dt, sigma)
    plain: list[tuple[float, float, float, float]] = []
    slow: list[tuple[float, float, float, float]] = []
    lags, weights = [], []
    for i0, i1 in _moving_stretches(rest):
        ramps, rms = _fit_stretch(t, u, i0, i1, sigma, shape)
        plain.extend(ramps)
        # a plain fit at the noise leaves a lag nothing to explain: skip its fit (~0.1 s
        # a stretch); a 5 ms servo lag misses a ramp by ~250 µm, far above it
        at_noise = rms <= _stretch_accept(min(i1, t.size - 1) + 1 - max(i0 - 1, 0), sigma)
        if lagged and at_noise:
            lagged = False
        if lagged:  # one lag for the table: every stretch must take it, or none does
            fit = _fit_stretch_lagged(t, u, i0, i1, sigma, rms, shape) if ramps else None
            if fit is not None:
                slow.extend(fit[0])
                lags.append(fit[1])
                weights.append(i1 - i0)
            else:
                lagged = False
    if not (lagged and lags):
        return plain, None
    return plain, (slow, float(np.average(lags, weights=weights)))


def _moving_stretches(rest: np.ndarray) -> list[tuple[int, int]]:
    edges = np.flatnonzero(np.diff(np.r_[0, (~rest).astype(int), 0]))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]


def _fit_stretch(t, u, i0, i1, sigma, shape=MINIMUM_JERK):
    """One stretch of motion (samples i0:i1, rest on both sides): 1..MAX_RAMPS ramps, RMS."""
    lo, hi = max(i0 - 1, 0), min(i1, t.size - 1)
    accept = _stretch_accept(hi + 1 - lo, sigma)
    best = None
    for n in range(1, MAX_RAMPS + 1):
        fit = _fit_ramps(t[lo:hi + 1], u[lo:hi + 1], n, shape)
        if fit is None:
            continue
        ramps, rms = fit
        if best is None or _earns_a_ramp(best[1], rms, hi + 1 - lo, sigma):
            best = (ramps, rms)
        if best[1] <= accept:
            break
    return best if best else ([], np.inf)


def _stretch_accept(k: int, sigma: float) -> float:
    """RMS below which k samples are the sensor's noise: 4 standard errors of the RMS.

    A fixed 1.10 σ refused a right single ramp in ~3 % of noise draws: the RMS of
    the ~330 samples of a 0.2 s ramp has a standard error of 3.9 %, so 1.10 is
    2.5 of them. A second ramp then split the first into two halves that fit the
    noise no better and the motion worse (Monte Carlo, bench/identify.py).
    """
    return max(ACCEPT_RATIO, float(np.sqrt(1.0 + 4.0 * np.sqrt(2.0 / max(k, 1))))) * sigma


def _earns_a_ramp(rms_before: float, rms_after: float, k: int, sigma: float) -> bool:
    """More ramps are kept only when they cut the RSS by more than 25 σ²: three numbers
    more fitted to noise cut it by ~3 σ²."""
    return k * (rms_before**2 - rms_after**2) > 25.0 * sigma**2


def _fit_stretch_lagged(t, u, i0, i1, sigma, plain_rms, shape=MINIMUM_JERK):
    """The stretch as 1..MAX_RAMPS ramps through a lag of its own: (ramps, lag) or None.

    Each start is the plain fit of as many ramps; None when the lag does not lower
    the stretch's RMS below the plain fit's best.
    """
    lo, hi = max(i0 - 1, 0), min(i1, t.size - 1)
    ts, us = t[lo:hi + 1], u[lo:hi + 1]
    best = None
    for n in range(1, MAX_RAMPS + 1):
        fit = _fit_ramps(ts, us, n, shape)
        if fit is None:
            continue
        fit = _fit_ramps_lagged(ts, us, fit[0], shape)
        if fit is None:
            continue
        if best is None or _earns_a_ramp(best[2], fit[2], hi + 1 - lo, sigma):
            best = fit
        if best[2] <= _stretch_accept(hi + 1 - lo, sigma):
            break
    if best is None or best[2] >= plain_rms:
        return None
    return best[0], best[1]


def _fit_ramps(t, u, n, shape=MINIMUM_JERK):
    """n back-to-back ramps from u[0] to u[-1] through n − 1 turning levels."""
    levels0 = _turning_levels(u, n)
    if levels0 is None:
        return None
    t0, t1 = float(t[0]), float(t[-1])
    cuts = np.linspace(t0, t1, n + 1)
    x0 = np.r_[cuts, levels0]

    def residual(p):
        return _back_to_back_value(t, np.sort(p[: n + 1]), p[n + 1:], shape) - u

    lower = np.r_[np.full(n + 1, t0), np.full(n + 1, -np.inf)]
    upper = np.r_[np.full(n + 1, t1), np.full(n + 1, np.inf)]
    sol = least_squares(residual, x0, bounds=(lower, upper), method="trf",
                        x_scale=np.r_[np.full(n + 1, 0.01), np.full(n + 1, 1e-3)])
    times, levels = np.sort(sol.x[: n + 1]), sol.x[n + 1:]
    if np.any(np.diff(times) <= 0):
        return None
    ramps = [(times[k], times[k + 1] - times[k], levels[k], levels[k + 1]) for k in range(n)]
    return ramps, float(np.sqrt(np.mean(sol.fun**2)))


def _fit_ramps_lagged(t, u, ramps, shape=MINIMUM_JERK):
    """Back-to-back ramps (from a plain fit) and a lag refitted together: (ramps, lag, RMS)."""
    n = len(ramps)
    t0, t1 = float(t[0]), float(t[-1])
    times = np.r_[[r[0] for r in ramps], ramps[-1][0] + ramps[-1][1]]
    levels = np.r_[[r[2] for r in ramps], ramps[-1][3]]
    x0 = np.r_[np.clip(times - LAG_START, t0, t1), levels, LAG_START]

    def residual(p):
        tm = np.sort(p[: n + 1])
        return _lagged_ramps_value(t, tm, p[n + 1:2 * n + 2], p[-1], shape) - u

    lower = np.r_[np.full(n + 1, t0), np.full(n + 1, -np.inf), 0.0]
    upper = np.r_[np.full(n + 1, t1), np.full(n + 1, np.inf), MAX_LAG]
    sol = least_squares(residual, x0, bounds=(lower, upper), method="trf",
                        x_scale=np.r_[np.full(n + 1, 0.01), np.full(n + 1, 1e-3), 1e-3])
    tm, lv, lag = np.sort(sol.x[: n + 1]), sol.x[n + 1:2 * n + 2], float(sol.x[-1])
    if np.any(np.diff(tm) <= 0):
        return None
    out = [(tm[k], tm[k + 1] - tm[k], lv[k], lv[k + 1]) for k in range(n)]
    return out, lag, float(np.sqrt(np.mean(sol.fun**2)))


def _lagged_ramps_value(t, times, levels, lag, shape=MINIMUM_JERK):
    if lag <= 0.0:
        return _back_to_back_value(t, times, levels, shape)
    if shape == MINIMUM_JERK:
        command = _back_to_back(times, levels)
    else:
        command = quintic_hermite(t, *_ramps_derivatives(
            t, list(pairwise(times)), list(pairwise(levels)), shape))
    return lag_response(t, command, lag)[0]


def _back_to_back(times, levels) -> PPoly:
    """Minimum-jerk ramps between `levels` at `times` as a quintic PPoly (held outside)."""
    T = np.maximum(np.diff(times), 1e-9)
    d = np.diff(levels)
    z = np.zeros_like(T)
    c = np.array([6 * d / T**5, -15 * d / T**4, 10 * d / T**3, z, z, levels[:-1]])
    return PPoly(c, np.r_[times[0], times[0] + np.cumsum(T)])


def _turning_levels(u, n):
    """Start, n − 1 turning points (largest excursions, in time order), end."""
    if n == 1:
        return np.array([u[0], u[-1]])
    idx = np.sort(np.argsort(-np.abs(u - u[0]))[: max(1, u.size // 50)])
    if n - 1 > idx.size:
        return None
    picks = idx[np.linspace(0, idx.size - 1, n - 1).astype(int)]
    return np.r_[u[0], u[picks], u[-1]]


def _ramps_value(t, spans, moves, shape=MINIMUM_JERK):
    """u at t of ramps over `spans` (begin, end) between `moves` (from, to), held between."""
    return _ramps_derivatives(t, spans, moves, shape, values_only=True)


def _ramps_derivatives(t, spans, moves, shape, values_only: bool = False):
    out = np.full(t.shape, moves[0][0], float)
    v, a = np.zeros(t.shape), np.zeros(t.shape)
    for (b, e), (u0, u1) in zip(spans, moves):
        T = max(e - b, 1e-9)
        inside = t >= b
        s, s1, s2 = ramp_shape(shape, (t[inside] - b) / T)
        d = u1 - u0
        out[inside] = u0 + d * s
        if not values_only:
            on = (t[inside] <= e)
            v[inside] = np.where(on, d / T * s1, 0.0)
            a[inside] = np.where(on, d / T**2 * s2, 0.0)
    return out if values_only else (out, v, a)


def _back_to_back_value(t, times, levels, shape=MINIMUM_JERK):
    """Back-to-back ramps between `levels` at `times`."""
    return _ramps_value(t, list(pairwise(times)), list(pairwise(levels)), shape)


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


# -- the ramps and the lag as one parameter vector (refit, and input_error's Jacobian) --

def step_pulse_params(ramps, lag: float | None = None) -> np.ndarray:
    """[start level, then (begin s, duration s, to m) per ramp, then the lag s if given]."""
    p = [ramps[0][2], *[v for r in ramps for v in (r[0], r[1], r[3])]]
    return np.array(p + ([] if lag is None else [lag]), float)


def tied_ramps(ramps) -> np.ndarray:
    """True for a ramp that starts where the previous one ends (a turn without rest).

    Its start is not a parameter of its own: moving it either way would insert a
    rest or overlap the ramps, a kink no derivative describes.
    """
    return np.array([k > 0 and abs(r[0] - ramps[k - 1][0] - ramps[k - 1][1]) < TIE
                     for k, r in enumerate(ramps)])


def params_ramps(p: np.ndarray, tied: np.ndarray) -> list[tuple[float, float, float, float]]:
    """The ramps of a parameter vector (a trailing lag, if any, is ignored)."""
    out: list[tuple[float, float, float, float]] = []
    level = p[0]
    for j in range(len(tied)):
        k = 1 + 3 * j
        begin = out[-1][0] + out[-1][1] if tied[j] else p[k]
        out.append((begin, p[k + 1], level, p[k + 2]))
        level = p[k + 2]
    return out


def refine_step_pulse(t: np.ndarray, u: np.ndarray, ramps, lag: float, free_lag: bool,
                      max_nfev: int | None = None, shape: str = MINIMUM_JERK
                      ) -> tuple[list[tuple[float, float, float, float]], float]:
    """Every ramp (and the lag, when free) fitted at once on the whole record.

    Per-stretch fits set a level held for 2 s by the few samples next to its
    ramps, and give each stretch a lag of its own; fitted together the levels
    use all the rest they hold for and the table has one lag.
    """
    t, u = np.asarray(t, float), np.asarray(u, float)
    tied = tied_ramps(ramps)
    p0 = step_pulse_params(ramps, lag if free_lag else None)
    n = len(ramps)
    kinds = np.r_[0, np.tile([1, 2, 0], n), [3] * free_lag]  # level, begin, duration, lag
    scale = np.select([kinds == 0, kinds == 3], [1e-3, 1e-3], 1e-2)
    lo = np.select([kinds == 1, kinds == 2, kinds == 3], [t[0], 1e-4, 0.0], -np.inf)
    hi = np.select([kinds == 1, kinds == 2, kinds == 3], [t[-1], t[-1] - t[0], MAX_LAG], np.inf)
    bad = np.full(u.shape, 1e3 * max(float(np.std(u)), 1e-9))

    def residual(p: np.ndarray) -> np.ndarray:
        try:
            return step_pulse_value(t, params_ramps(p, tied), p[-1] if free_lag else lag,
                                    shape) - u
        except ValueError:  # a step that made two ramps overlap: far from the optimum
            return bad

    sol = least_squares(residual, np.clip(p0, lo, hi), x_scale=scale, bounds=(lo, hi),
                        max_nfev=max_nfev)
    out = params_ramps(sol.x, tied)
    if not all(r[1] > 0 for r in out):
        return list(ramps), lag
    return out, float(sol.x[-1]) if free_lag else lag
