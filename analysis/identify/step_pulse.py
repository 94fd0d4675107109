"""The step-pulse table motion: commanded ramps of a motion law, followed through a servo lag.

A step-pulse table moves in ramps between rests, a handful of numbers per ramp:
(start s, duration s, from m, to m). This rig's ramps are minimum-jerk
(rig.profile); other rigs' motion controllers use the other standard motion
laws: cycloidal, harmonic (half-cosine) or parabolic (constant acceleration),
`RAMP_SHAPES`.

Servo lag. Servo-hydraulic actuators follow their setpoints through a lag:
the table is the commanded ramps passed through p' = (r − p)/τ, which a plain
minimum-jerk ramp misses by τ²/2·ü (250 µm on run A at τ = 5 ms, ten times the
noise). The lagged motion is exact (`lag_response`: the polynomial particular
solution plus the decaying transient, piece by piece) and handed to the
simulator as the quintic Hermite through its position, velocity and
acceleration at the data's samples.

The ramps and the lag are also one parameter vector (`step_pulse_params`,
`params_ramps`), for the whole-record refit and input_error's Jacobian.
"""

from __future__ import annotations

from itertools import pairwise

import numpy as np
from scipy.interpolate import PPoly

from analysis.simulate.motion import quintic_hermite
from rig.profile import Profile, Segment

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


def lagged_ramps_value(t, times, levels, lag, shape=MINIMUM_JERK):
    """Back-to-back ramps between `levels` at `times`, followed through the lag (s)."""
    if lag <= 0.0:
        return back_to_back_value(t, times, levels, shape)
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


def back_to_back_value(t, times, levels, shape=MINIMUM_JERK):
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
