"""Step-pulse ramps fitted to the table's noisy samples (the model: `analysis.identify.step_pulse`).

Rests are found from the data; each moving stretch is one ramp or several back
to back (split where the motion turns), fitted on its own samples, then every
ramp at once on the whole record (`refine_step_pulse`). Fitting a handful of
numbers per ramp to the thousands of samples estimates the input far better
than the noise of any one sample. The ramps' shape is one more choice of the
fit (`best_step_pulse` fits one shape, `shapes_by_fit` orders them by a cheap
look), and so is the servo lag τ, one number per run fitted with the ramps; it
is kept when it lowers the residual sum of squares by more than LAG_CHI2 σ² (a
5 σ improvement for one parameter), so an exact profile keeps τ = 0 and the
plain model.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from analysis.identify.run_data import table_at_rest
from analysis.identify.step_pulse import (
    MINIMUM_JERK,
    RAMP_SHAPES,
    back_to_back_value,
    lagged_ramps_value,
    params_ramps,
    step_pulse_params,
    step_pulse_value,
    tied_ramps,
)

ACCEPT_RATIO = 1.10  # residual RMS over σ_u for the command model to be believed
MAX_RAMPS = 4  # per moving stretch
MAX_LAG = 0.05  # s: the slowest servo lag fitted (a 3 Hz servo is no step-pulse rig)
LAG_START = 0.003  # s: where the lag's fit starts (the start times shifted back by it)
LAG_CHI2 = 25.0  # σ²: the lag must lower the residual sum of squares by this much


def shapes_by_fit(t, u, sigma) -> list[str]:
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


def best_step_pulse(t, u, sigma, shape, lagged: bool = True):
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


def _sum_squares(t, u, ramps, lag, shape=MINIMUM_JERK) -> float:
    return float(np.sum((step_pulse_value(t, ramps, lag, shape) - u) ** 2))


# -- each moving stretch on its own samples --------------------------------------

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
        return back_to_back_value(t, np.sort(p[: n + 1]), p[n + 1:], shape) - u

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
        return lagged_ramps_value(t, tm, p[n + 1:2 * n + 2], p[-1], shape) - u

    lower = np.r_[np.full(n + 1, t0), np.full(n + 1, -np.inf), 0.0]
    upper = np.r_[np.full(n + 1, t1), np.full(n + 1, np.inf), MAX_LAG]
    sol = least_squares(residual, x0, bounds=(lower, upper), method="trf",
                        x_scale=np.r_[np.full(n + 1, 0.01), np.full(n + 1, 1e-3), 1e-3])
    tm, lv, lag = np.sort(sol.x[: n + 1]), sol.x[n + 1:2 * n + 2], float(sol.x[-1])
    if np.any(np.diff(tm) <= 0):
        return None
    out = [(tm[k], tm[k + 1] - tm[k], lv[k], lv[k + 1]) for k in range(n)]
    return out, lag, float(np.sqrt(np.mean(sol.fun**2)))


def _turning_levels(u, n):
    """Start, n − 1 turning points (largest excursions, in time order), end."""
    if n == 1:
        return np.array([u[0], u[-1]])
    idx = np.sort(np.argsort(-np.abs(u - u[0]))[: max(1, u.size // 50)])
    if n - 1 > idx.size:
        return None
    picks = idx[np.linspace(0, idx.size - 1, n - 1).astype(int)]
    return np.r_[u[0], u[picks], u[-1]]


# -- every ramp at once, on the whole record -------------------------------------

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
