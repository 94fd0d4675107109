"""Velocity and acceleration from noisy sampled displacement (SI: m, m/s, m/s²).

Four smoothers, each indexed by one number, its cutoff `fc` (Hz): the frequency
where its amplitude response to x is ½.

- ``savgol``: Savitzky–Golay, polynomial order 5, odd window from `fc` (Schafer 2011).
- ``butter``: 4th-order Butterworth run forwards and backwards (odd padding over
  3/fc), then central differences.
- ``spline``: cubic smoothing spline (scipy), λ = 1/(dt·(2π fc)⁴).
- ``rts``: Kalman filter + Rauch–Tung–Striebel smoother of an integrated-Wiener
  model of order p (p = 3: white jerk, the "Wiener acceleration" model; 4: white
  snap; 5), with the process noise set so that the smoother's response is
  1/(1 + (f/fc)^(2p)); the smoother is `analysis.signals.rts`.

Settings come from the data: σ from `estimate_noise`, then `fc` minimises
Mallows' Cp, the unbiased estimate of the mean squared error of the smoothed x,
    Cp(fc) = ‖y − S y‖² + 2σ² tr S − nσ².
For a sharp filter the fc that minimises the error of x is also the one that
minimises the error of every derivative (both put fc where the signal spectrum
meets the noise floor), which is why one rule serves v and a. The order p of the
rts model is the one with the largest marginal likelihood (evidence).
docs/analysis.md has the comparison that makes ``butter`` the 'auto' choice: on
simulated runs A and C at 5–100 µm noise it is within ~5 % of the most accurate
method for v and a and 3–5 times faster than ``rts`` or ``spline``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import signal
from scipy.interpolate import make_smoothing_spline

from analysis.signals.rts import RTS_ORDERS, rts_grid, rts_q

METHODS = ("savgol", "butter", "spline", "rts")
AUTO = "butter"
MAD_TO_SIGMA = 1.482602218505602  # σ / MAD for a Gaussian
THIRD_DIFF_VAR = 20.0  # var(Δ³e) / σ² for white e: 1 + 9 + 9 + 1
SAVGOL_ORDER = 5
BUTTER_ORDER = 4
GRID_RATIO = 1.2  # fc grid step: Cp and the errors are flat near the minimum
Triple = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]


@dataclass(frozen=True)
class Derivatives:
    """Smoothed displacement x (m), velocity v (m/s), acceleration a (m/s²), shape (n,).

    `method` is the smoother used, `settings` how it was set (cutoff_hz always,
    plus the method's own numbers and the rule), `noise` the σ of the measured
    displacement (m), `noise_v` and `noise_a` the standard deviation that σ leaves
    in v (m/s) and a (m/s²) away from the ends.
    """

    x: NDArray[np.float64]
    v: NDArray[np.float64]
    a: NDArray[np.float64]
    method: str
    settings: dict[str, Any] = field(default_factory=dict)
    noise: float = 0.0
    noise_v: float = 0.0
    noise_a: float = 0.0


def estimate_noise(x: ArrayLike, dt: float) -> float:
    """Standard deviation (m) of white measurement noise in samples x (m), shape (n,).

    The third difference removes a smooth signal (what is left is jerk·dt³) and
    turns white noise of σ into a sequence of variance 20σ²; the median absolute
    deviation makes the estimate ignore the few samples where the signal's jerk
    is large. Quantised data whose differences are mostly exactly zero fall back
    to the quantisation floor, step/√12. `dt` (s) is only checked.
    """
    y = _as_signal(x, dt, minimum=8)
    d3 = np.diff(y, 3)
    sigma = MAD_TO_SIGMA * float(np.median(np.abs(d3 - np.median(d3)))) / np.sqrt(THIRD_DIFF_VAR)
    steps = np.abs(np.diff(y))
    steps = steps[steps > 0]
    floor = float(steps.min()) / np.sqrt(12.0) if steps.size else 0.0
    return max(sigma, floor)


def differentiate(
    x: ArrayLike,
    dt: float,
    method: str = "auto",
    noise: float | None = None,
    settings: Mapping[str, Any] | None = None,
) -> Derivatives:
    """Smooth x (m, shape (n,), uniform step dt in s) and differentiate it twice.

    `method` is 'auto' (= 'butter') or one of METHODS; `noise` is σ (m) if known,
    else estimated. `settings` pins what would otherwise be chosen from the data
    (e.g. {'cutoff_hz': 12.0}, {'window': 41}, {'order': 3}); a Derivatives'
    settings can be passed back to repeat a run exactly.
    """
    y = _as_signal(x, dt, minimum=2 * SAVGOL_ORDER + 2)
    name = AUTO if method == "auto" else method
    if name not in METHODS:
        raise ValueError(f"unknown method {method!r} (known: auto, {', '.join(METHODS)})")
    sigma = estimate_noise(y, dt) if noise is None else float(noise)
    if not np.isfinite(sigma) or sigma < 0:
        raise ValueError(f"noise must be a finite σ >= 0 m, got {noise!r}")
    chosen = _SELECT[name](y, dt, sigma, dict(settings or {}))
    smooth = _smoother(name, dt, chosen, len(y))
    xs, v, a = smooth(y)
    _, iv, ia = smooth(_impulse(len(y)))
    chosen["rule"] = f"pinned {sorted(settings)}" if settings else "Cp"
    if method == "auto":
        chosen["requested"] = "auto"
    return Derivatives(xs, v, a, name, chosen, sigma,
                       sigma * float(np.linalg.norm(iv)), sigma * float(np.linalg.norm(ia)))


# ---------------------------------------------------------------- selection
Costs = Callable[[NDArray], Sequence[float]]


def _cp(smooth: Callable[[NDArray], Triple], y: NDArray, sigma: float,
        df: float | None = None) -> float:
    """Mallows' Cp, the unbiased estimate of ‖S y − x‖² for a linear smoother S.

    tr S (df) is by default n times the middle diagonal element, read off the
    response to an impulse: exact for the time-invariant interior.
    """
    n = len(y)
    resid = y - smooth(y)[0]
    if df is None:
        df = n * float(smooth(_impulse(n))[0][n // 2])
    return float(resid @ resid + 2 * sigma**2 * df - n * sigma**2)


def _search(costs: Costs, lo: float, hi: float, ratio: float = GRID_RATIO) -> float:
    """The cutoff on a grid log-spaced by `ratio` over [lo, hi] with the least cost."""
    grid = np.exp(np.arange(np.log(lo), np.log(hi) + 1e-9, np.log(ratio)))
    return float(grid[int(np.argmin(costs(grid)))])


def _bounds(n: int, dt: float) -> tuple[float, float]:
    # below ~2 cycles per record a "smoothed" signal is a trend; 0.44/dt is about
    # the highest cutoff a 4th-order Butterworth design accepts
    return 2.0 / (n * dt), 0.44 / dt


def _bracket(costs: Costs, pilot: float, n: int, dt: float) -> float:
    """Search ±2× around a pilot cutoff; recentre while the best is on an edge."""
    lo_b, hi_b = _bounds(n, dt)
    centre = pilot
    for _ in range(6):
        lo, hi = max(lo_b, centre / 2), min(hi_b, centre * 2)
        best = _search(costs, lo, hi)
        inside = (best / GRID_RATIO >= lo or lo <= lo_b) and (best * GRID_RATIO <= hi or hi >= hi_b)
        if inside:
            break
        centre = best
    return best


def _each(make: Callable[[float], Callable[[NDArray], Triple]], y: NDArray, sigma: float,
          df: Callable[[float], float] | None = None) -> Costs:
    return lambda grid: [_cp(make(f), y, sigma, df and df(f)) for f in grid]


def _select_butter(y: NDArray, dt: float, sigma: float, fixed: dict) -> dict:
    if "cutoff_hz" not in fixed:  # coarse over the whole band, then fine: Cp is cheap here
        lo, hi = _bounds(len(y), dt)
        costs = _each(lambda f: _butter(dt, f), y, sigma, lambda f: _butter_df(dt, f, len(y)))
        coarse = _search(costs, lo, hi, 1.5)
        fixed["cutoff_hz"] = _search(costs, max(lo, coarse / 1.5), min(hi, coarse * 1.5))
    return {"cutoff_hz": float(fixed["cutoff_hz"]), "order": BUTTER_ORDER}


def _pilot(y: NDArray, dt: float, sigma: float, fixed: dict) -> float:
    """Where the slower smoothers start looking: the Butterworth choice."""
    return float(fixed.get("cutoff_hz") or _select_butter(y, dt, sigma, {})["cutoff_hz"])


def _select_savgol(y: NDArray, dt: float, sigma: float, fixed: dict) -> dict:
    if "window" not in fixed:
        n, fc = len(y), _pilot(y, dt, sigma, fixed)
        windows = sorted({_window(f, dt, n) for f in np.geomspace(fc / 2, fc * 2, 25)})

        def cost(w: int) -> float:  # x only, and tr S from the centre coefficient
            x = (signal.savgol_filter(y, w, SAVGOL_ORDER, mode="interp"), None, None)
            centre = signal.savgol_coeffs(w, SAVGOL_ORDER)[w // 2]
            return _cp(lambda _: x, y, sigma, n * float(centre))

        fixed["window"] = min(windows, key=cost)
    w = int(fixed["window"])
    return {"window": w, "polyorder": SAVGOL_ORDER, "cutoff_hz": _window_cutoff(w, dt)}


def _select_spline(y: NDArray, dt: float, sigma: float, fixed: dict) -> dict:
    if "cutoff_hz" not in fixed:
        # the spline is slow: its tr S from its known response 1/(1 + (f/fc)⁴) instead
        f = np.fft.fftfreq(len(y), dt)
        costs = _each(lambda c: _spline(dt, c), y, sigma, lambda c: np.sum(1 / (1 + (f / c) ** 4)))
        fixed["cutoff_hz"] = _bracket(costs, _pilot(y, dt, sigma, fixed), len(y), dt)
    fc = float(fixed["cutoff_hz"])
    return {"cutoff_hz": fc, "lam": _spline_lam(dt, fc)}


def _select_rts(y: NDArray, dt: float, sigma: float, fixed: dict) -> dict:
    n, pilot = len(y), _pilot(y, dt, sigma, fixed)
    evidence = {}
    if "order" not in fixed:  # the order whose prior best explains the data
        yn = (y - y[0]) / sigma if sigma > 0 else y - y[0]
        lo, hi = _bounds(n, dt)
        grid = np.geomspace(max(lo, pilot / 2), min(hi, pilot * 2), 7)
        evidence = {p: max(e for _, e in rts_grid(yn, dt, grid, p)) for p in RTS_ORDERS}
        fixed["order"] = max(evidence, key=evidence.get)
    p = int(fixed["order"])
    if "cutoff_hz" not in fixed:
        def costs(grid):
            return [_cp(run, y, sigma) for run, _ in rts_grid(y, dt, grid, p, False)]

        fixed["cutoff_hz"] = _bracket(costs, pilot, n, dt)
    fc = float(fixed["cutoff_hz"])
    out = {"cutoff_hz": fc, "order": p, "q": rts_q(sigma, dt, fc, p)}
    if evidence:
        out["log_evidence"] = {k: round(float(v), 3) for k, v in evidence.items()}
    return out


_SELECT = {"butter": _select_butter, "savgol": _select_savgol,
           "spline": _select_spline, "rts": _select_rts}


def _smoother(name: str, dt: float, s: dict, n: int) -> Callable[[NDArray], Triple]:
    if name == "savgol":
        return _savgol(dt, int(s["window"]))
    if name == "rts":
        return rts_grid(np.zeros(n), dt, [float(s["cutoff_hz"])], int(s["order"]), False)[0][0]
    return {"butter": _butter, "spline": _spline}[name](dt, float(s["cutoff_hz"]))


def _impulse(n: int) -> NDArray[np.float64]:
    e = np.zeros(n)
    e[n // 2] = 1.0
    return e


# ---------------------------------------------------------------- smoothers


def _central(s: NDArray, dt: float) -> Triple:
    v = np.gradient(s, dt, edge_order=2)
    a = np.empty_like(s)
    a[1:-1] = (s[2:] - 2 * s[1:-1] + s[:-2]) / dt**2
    a[0], a[-1] = 2 * a[1] - a[2], 2 * a[-2] - a[-3]
    return s, v, a


@lru_cache(maxsize=512)
def _butter_sos(dt: float, fc: float) -> np.ndarray:
    # the design costs more than filtering a run; the cutoff grid is the same for
    # every run of one sample rate and length, so each design is made once
    # filtfilt squares the response: put each pass's -3 dB point where |H|² = ½ at fc
    f3 = min(fc / (np.sqrt(2) - 1) ** (1 / (2 * BUTTER_ORDER)), 0.499 / dt)
    return signal.butter(BUTTER_ORDER, f3, fs=1 / dt, output="sos")


@lru_cache(maxsize=512)
def _butter_df(dt: float, fc: float, n: int) -> float:
    """tr S of the zero-phase Butterworth (Cp's degrees of freedom): data-independent."""
    return n * float(_butter(dt, fc)(_impulse(n))[0][n // 2])


def _butter(dt: float, fc: float) -> Callable[[NDArray], Triple]:
    sos = _butter_sos(dt, fc).copy()  # scipy's filter wants a writable buffer

    def run(y: NDArray) -> Triple:
        # the default 27 samples is shorter than the transient
        pad = min(len(y) - 1, int(3 / (fc * dt)))
        return _central(signal.sosfiltfilt(sos, y, padlen=pad), dt)

    return run


def _window(fc: float, dt: float, n: int) -> int:
    """Odd Savitzky–Golay window whose -3 dB point is near fc (Schafer 2011, eq. 11)."""
    half = round(((SAVGOL_ORDER + 1) / (2 * fc * dt) + 4.6) / 3.2)
    half = min(max(half, SAVGOL_ORDER // 2 + 1), (n - 1) // 2)
    return 2 * half + 1


def _window_cutoff(window: int, dt: float) -> float:
    return (SAVGOL_ORDER + 1) / (3.2 * (window // 2) - 4.6) / (2 * dt)


def _savgol(dt: float, window: int) -> Callable[[NDArray], Triple]:
    def run(y: NDArray) -> Triple:
        return tuple(signal.savgol_filter(y, window, SAVGOL_ORDER, deriv=d, delta=dt,
                                          mode="interp") for d in range(3))  # type: ignore[return-value]

    return run


def _spline_lam(dt: float, fc: float) -> float:
    # scipy penalises Σ(y − f)² + λ∫f''²; as Σ ≈ ∫/dt the response is 1/(1 + λ dt ω⁴)
    return 1.0 / (dt * (2 * np.pi * fc) ** 4)


def _spline(dt: float, fc: float) -> Callable[[NDArray], Triple]:
    def run(y: NDArray) -> Triple:
        t = np.arange(len(y)) * dt
        sp = make_smoothing_spline(t, y, lam=_spline_lam(dt, fc))
        return sp(t), sp(t, 1), sp(t, 2)

    return run


def _as_signal(x: ArrayLike, dt: float, minimum: int) -> NDArray[np.float64]:
    y = np.asarray(x, dtype=np.float64)
    if y.ndim != 1 or y.size < minimum:
        raise ValueError(f"need a 1-D signal of at least {minimum} samples, got shape {y.shape}")
    bad = np.flatnonzero(~np.isfinite(y))
    if bad.size:
        raise ValueError(f"signal is not finite at sample {bad[0]} ({y[bad[0]]})")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
    return y
