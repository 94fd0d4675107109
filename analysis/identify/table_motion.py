"""The table's motion estimated from its noisy sensor by a model of the command.

Errors in variables: the table displacement that drives the isolator model is
measured with the same noise as the response. A smoothing spline removes most
of it, but what is left is enough to move the instant static friction lets go
and the place the mass comes to rest in the dead band, and a mass resting
20 µm off for two seconds costs more than all the noise: measured on runs A–C
with 25 µm sensor noise, a 50 Hz spline leaves the true model 3–6 times the
noise from the data, the exact input 1.0 times.

A step-pulse table moves in ramps between rests, a handful of numbers per ramp
(`analysis.identify.step_pulse`: the motion laws and the servo lag), fitted to
the samples by `analysis.identify.step_pulse_fit`. The shape is one more choice
of the fit: minimum-jerk (this rig's) is tried first, and where it does not
reach the noise every shape of `RAMP_SHAPES` is fitted and the one with the
least residual is kept (a wrong shape misses a 0.14 m ramp by hundreds of µm:
the choice is never close); a servo lag is fitted where the plain ramps do not
reach the noise. The fit is accepted only if what is left is the sensor's noise
(RMS within 10 % of σ). Otherwise the table did not follow a step-pulse profile
(another rig's excitation, a resonance) and `estimate_table_motion` falls back
to the smoothing spline.

Noise. σ_u is the spread of second differences three samples apart, over the
table's rests, when that exceeds the plain (adjacent) second-difference reading
by more than 5 %: a channel interpolated onto another sensor's clock (run files,
`analysis.identify.loading`) has neighbouring samples correlated, which plain
second differences read as up to 2.4× less noise than each sample carries.
White noise keeps the plain reading.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PPoly

from analysis.identify.run_data import noise_sigma, smooth_motion, table_at_rest
from analysis.identify.step_pulse import MINIMUM_JERK, step_pulse_motion
from analysis.identify.step_pulse_fit import ACCEPT_RATIO, LAG_CHI2, best_step_pulse, shapes_by_fit

NOISE_SPACING = 3  # samples between the points of the second differences σ_u is read from
CORRELATED = 1.05  # σ_u three samples apart over adjacent ones beyond which noise is not white


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
    best = best_step_pulse(t, u, sigma, MINIMUM_JERK, lagged=False)
    look = shapes_by_fit(t, u, sigma)
    other = next(s for s in look if s != MINIMUM_JERK)
    if look[0] != MINIMUM_JERK or not _accepted(best):
        # at 4× the rig's noise a minimum-jerk fit of cycloidal ramps passes the accept
        # rule (1.07 σ) and leaves the isolator model 490× the noise from run C: the
        # other shape is fitted whenever one ramp of it fits the stretches better, and
        # kept when it is better by more than LAG_CHI2 σ²
        alt = best_step_pulse(t, u, sigma, other, lagged=False)
        if alt is not None and (best is None or alt[4] < best[4] - LAG_CHI2 * sigma**2):
            best = alt
    tries = [best]
    for shape in (MINIMUM_JERK, other):  # a lagged servo: this rig's ramps first
        if _accepted(best):
            break
        tries.append(best_step_pulse(t, u, sigma, shape))
        best = min([b for b in tries if b is not None], key=lambda b: b[4], default=None)
    if best is not None and best[3] <= ACCEPT_RATIO:
        ramps, lag, shape, ratio, _ = best
        return TableMotion(step_pulse_motion(t, ramps, lag, shape), "step-pulse fit", ratio,
                           sigma, tuple(ramps), lag, shape, lowfreq)
    spline = smooth_motion(t, u)
    return TableMotion(spline, "smoothing spline", _ratio(spline, t, u, sigma), sigma)


def _accepted(fit) -> bool:
    return fit is not None and fit[3] <= ACCEPT_RATIO


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
