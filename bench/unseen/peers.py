"""Two peer identification methods: the baseline the product's loop must beat.

Both take a campaign's runs {name: (t, u, x)} (1 kHz, metres) and the mass, and name the
effects beyond CERL TR M-226 Eq 10 that they judge present, in the product's vocabulary
(the values of EFFECT_NAMES), in order of selection; [] for a clean campaign.

- `stepwise_bic`: an equation-error tracer. Savitzky-Golay derivatives give z = x - u, z'
  and x''; the force target is y = -m x''. Eq 10's terms (dead-band gated) with alpha,
  beta, delta from a small grid, then forward selection over one regressor per effect by
  BIC, with a stopping margin.
- `sindy_gated`: PySINDy's STLSQ on the same (scaled) dead-band-gated library; the
  effects whose coefficients survive the threshold are named, largest first.

They import nothing from the product (`analysis`, `sim`, `rig`): numpy, scipy, and
pysindy (lazily, in `sindy_gated` only). They are meant as fair, simple peers: nothing
here reads the generator's truth or constants; the small grids (delta, alpha, beta, the
thermal time constant, the hysteresis width) only bracket plausible physical ranges.
Known blind spot: outside the dead band a preload gamma tanh(z/w) (w << delta) is almost
the base term k2 tanh(alpha z), so without priors on k2 it is often missed.

Equation error with a matched filter: the target is SG''(x) = H * x'' where H is the
double running sum of the SG second-derivative kernel (a smoothing kernel with unit
sum). Every regressor phi(z, z', ...) is filtered by the same H, so the jumps of the
spring force at the dead-band edges are smoothed exactly as the target is.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.ndimage import convolve1d, minimum_filter1d
from scipy.signal import savgol_coeffs, savgol_filter

EFFECT_NAMES = {  # generator effect -> the product's vocabulary
    "coulomb": "coulomb_friction", "orifice": "quadratic_damping",
    "hardening": "cubic_stiffness", "asym_stiffness": "asymmetric_stiffness",
    "asym_damping": "asymmetric_damping", "preload": "preload",
    "thermal": "thermal_damping_drift", "bouc_wen": "hysteresis",
    "sensor_delay": "sensor_delay", "sensor_gain": "sensor_gain",
    "force_offset": "force_offset",
}

FS = 1000.0  # Hz, used only if a run has a single sample time
WIN_ACC, ORDER = 51, 3  # x'': 51 ms, cubic (noise ~0.05 m/s^2 at 60 um, band ~25 Hz)
WIN_STATE = 21  # z, z' inside the nonlinearities: 21 ms keeps the edges of the dead band
V_MOVE = 0.005  # m/s: below it the mass may be stuck (static friction is not modelled)
DELTAS = np.arange(0.008, 0.0321, 0.001)  # dead band half-width grid, m
ALPHAS = np.array([30.0, 50.0, 80.0, 120.0, 180.0])  # 1/m
BETAS = np.array([20.0, 40.0, 80.0, 160.0, 320.0])  # s/m
TAUS_T = (0.5, 1.5, 5.0)  # s: thermal time constants tried
WIDTHS_H = (1e-3, 2e-3, 4e-3)  # m: widths of the stop operator (hysteresis)
# Forward selection stops unless BIC drops by more than this. The rows are decimated to
# one per half window (the residual of a 51-sample matched filter is correlated over
# about that), so n ln(RSS/n) behaves roughly like a chi-square; 10 on top of the ln(n)
# per parameter is "very strong" evidence on Kass & Raftery's scale and absorbs the
# structure left by what Eq 10 lacks even on a clean plant (static friction, smoothing).
BIC_MARGIN = 10.0
STRIDE = WIN_ACC // 2
# STLSQ threshold: a term must add 2 % of the RMS force beyond Eq 10 (see sindy_gated);
# about twice the largest coefficient any candidate got on clean campaigns.
SINDY_THRESHOLD = 0.02


def _kernel() -> np.ndarray:
    """H with SG''(x) = H * x'' (symmetric, unit sum, WIN_ACC - 2 taps; in samples)."""
    c = savgol_coeffs(WIN_ACC, ORDER, deriv=2, use="conv")
    return np.cumsum(np.cumsum(c))[:-2]


def _prepare(runs: dict, mass: float) -> list[dict]:
    """Per run: smoothed states, target, and the rows kept (moving, away from the ends)."""
    out = []
    for t, u, x in runs.values():
        t, u, x = (np.asarray(a, dtype=float) for a in (t, u, x))
        if t.size <= 3 * WIN_ACC:
            continue  # too short to differentiate twice
        d, dt = x - u, float(np.median(np.diff(t))) if t.size > 1 else 1.0 / FS
        sg = {"window_length": WIN_STATE, "polyorder": ORDER, "delta": dt}
        st = {
            "dt": dt, "x": x, "z": savgol_filter(d, **sg),
            "zd": savgol_filter(d, deriv=1, **sg), "ud": savgol_filter(u, deriv=1, **sg),
            "udd": savgol_filter(u, deriv=2, **sg),
            "y": -mass * savgol_filter(x, WIN_ACC, ORDER, deriv=2, delta=dt),
        }
        keep = minimum_filter1d((np.abs(st["zd"]) > V_MOVE).astype(np.uint8), WIN_ACC) > 0
        keep[:WIN_ACC] = keep[-WIN_ACC:] = False
        st["keep"] = keep
        out.append(st)
    return out


def _filtered(prep: list[dict], cols_of, rows: slice | None = None) -> np.ndarray:
    """Columns cols_of(run) -> (n, k), H-filtered per run, on the kept rows, stacked."""
    h = _kernel()
    blocks = []
    for st in prep:
        raw = np.atleast_2d(np.asarray(cols_of(st), dtype=float)).T
        f = convolve1d(raw, h, axis=0, mode="nearest")
        blocks.append(f[st["keep"]][rows or slice(None)])
    return np.concatenate(blocks)


def _base_cols(st: dict, a: float, b: float, dl: float) -> list[np.ndarray]:
    z, zd = st["z"], st["zd"]
    g = np.abs(z) > dl
    return [g * z, g * np.tanh(a * z), zd, g * np.tanh(b * zd)]


def _target(prep: list[dict], rows: slice | None = None) -> np.ndarray:
    return np.concatenate([st["y"][st["keep"]][rows or slice(None)] for st in prep])


def _lstsq_rss(A: np.ndarray, y: np.ndarray) -> tuple[float, np.ndarray]:
    """Least squares by the normal equations of the unit-RMS columns (a few columns)."""
    s = np.sqrt((A * A).mean(axis=0)) + 1e-30
    G, b = (A.T @ A) / np.outer(s, s), (A.T @ y) / s
    coef = np.linalg.lstsq(G, b, rcond=None)[0] / s
    r = y - A @ coef
    return float(r @ r), coef


def _fit_base(prep: list[dict]) -> tuple[float, float, float, np.ndarray]:
    """alpha, beta, delta by coordinate search over the grids; the base coefficients."""
    y = _target(prep)
    best = {"a": 80.0, "b": 80.0, "dl": 0.02}

    def rss(**kw):
        p = {**best, **kw}
        return _lstsq_rss(_filtered(prep, lambda st: _base_cols(st, p["a"], p["b"], p["dl"])), y)

    for _ in range(2):
        for key, grid in (("dl", DELTAS), ("a", ALPHAS), ("b", BETAS)):
            best[key] = float(min(grid, key=lambda v, key=key: rss(**{key: v})[0]))
    return best["a"], best["b"], best["dl"], rss()[1]


def _stop(z: np.ndarray, r: float) -> np.ndarray:
    """Stop operator of width r: z minus its play (backlash) operator, in [-r, r]."""
    s = np.empty_like(z)
    p = z[0]
    for i, v in enumerate(z):
        p = min(max(p, v - r), v + r)
        s[i] = v - p
    return s


def _heat(st: dict, tau: float) -> np.ndarray:
    """First-order low-pass of z'^2 (a dissipated-power proxy), time constant tau."""
    q, acc = np.empty_like(st["zd"]), 0.0
    k = np.exp(-st["dt"] / tau)
    for i, p in enumerate(st["zd"] ** 2):
        acc = k * acc + (1.0 - k) * p
        q[i] = acc
    return q


def _candidates(a: float, b: float, dl: float, coef: np.ndarray) -> dict[str, list]:
    """Product name -> variants (functions run -> column) of its one regressor.

    Sensor delay d: the measured z is z(t-d) - d u', so the true force is the base force
    at (z + d u', z' + d u''): its column is dF/dz u' + dF/dz' u'' from the base fit.
    Sensor gain g: the measured z is z + g x (x'' scales with all coefficients, which the
    fit absorbs), so its column is dF/dz x.
    """
    k1, k2, c1, c2 = coef

    def dfdz(st):
        g = np.abs(st["z"]) > dl
        return g * (k1 + k2 * a / np.cosh(np.clip(a * st["z"], -50, 50)) ** 2)

    def dfdzd(st):
        g = np.abs(st["z"]) > dl
        return c1 + g * c2 * b / np.cosh(np.clip(b * st["zd"], -50, 50)) ** 2

    def gate(st):
        return np.abs(st["z"]) > dl

    return {
        "coulomb_friction": [lambda st: np.tanh(st["zd"] / 0.003)],
        "quadratic_damping": [lambda st: st["zd"] * np.abs(st["zd"])],
        "cubic_stiffness": [lambda st: gate(st) * st["z"] ** 3],
        "asymmetric_stiffness": [lambda st: gate(st) * np.maximum(st["z"], 0.0)],
        "asymmetric_damping": [lambda st: np.maximum(st["zd"], 0.0)],
        "preload": [lambda st: gate(st) * np.sign(st["z"])],
        "force_offset": [lambda st: np.ones_like(st["z"])],
        "thermal_damping_drift": [lambda st, tau=tau: st["zd"] * _heat(st, tau) for tau in TAUS_T],
        "hysteresis": [lambda st, r=r: _stop(st["z"], r) for r in WIDTHS_H],
        "sensor_delay": [lambda st: dfdz(st) * st["ud"] + dfdzd(st) * st["udd"]],
        "sensor_gain": [lambda st: dfdz(st) * st["x"]],
    }


def _library(runs: dict, mass: float, rows: slice | None = None):
    """Target, base columns and every candidate's variant columns (all H-filtered)."""
    prep = _prepare(runs, mass)
    if sum(int(st["keep"].sum()) for st in prep) < 20 * STRIDE:
        return None  # the mass hardly moved: nothing to identify
    a, b, dl, coef = _fit_base(prep)
    base = _filtered(prep, lambda st: _base_cols(st, a, b, dl), rows)
    cands = {name: [_filtered(prep, f, rows) for f in fs]
             for name, fs in _candidates(a, b, dl, coef).items()}
    return _target(prep, rows), base, cands


def stepwise_bic(runs: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]],
                 mass: float) -> list[str]:
    """Forward selection by BIC over one regressor per effect on top of Eq 10."""
    lib = _library(runs, mass, slice(None, None, STRIDE))
    if lib is None:
        return []
    y, A, cands = lib
    n = y.size

    def bic(M):
        return n * np.log(_lstsq_rss(M, y)[0] / n) + M.shape[1] * np.log(n)

    chosen: list[str] = []
    current = bic(A)
    while len(chosen) < len(cands):
        trials = {name: min(bic(np.hstack([A, c])) for c in variants)
                  for name, variants in cands.items() if name not in chosen}
        name = min(trials, key=trials.get)
        if current - trials[name] <= BIC_MARGIN:
            break
        A = np.hstack([A, min(cands[name], key=lambda c: bic(np.hstack([A, c])))])
        current = trials[name]
        chosen.append(name)
    return chosen


def sindy_gated(runs: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]],
                mass: float) -> list[str]:
    """STLSQ (PySINDy) on the scaled dead-band-gated library; survivors are named.

    Eq 10's own terms are never thresholded: target and candidates are first projected
    off them (Frisch-Waugh-Lovell: the candidates' least-squares coefficients are those
    of the joint fit). Each candidate column is then scaled to unit RMS and the target by
    its RMS, so a coefficient is the RMS force that term adds beyond Eq 10, as a fraction
    of the RMS force.
    """
    from pysindy.optimizers import STLSQ

    lib = _library(runs, mass)
    if lib is None:
        return []
    y, A, cands = lib
    names, cols = [], []
    for name, variants in cands.items():  # the variant of each that fits best alone
        rss = [_lstsq_rss(np.hstack([A, c]), y)[0] for c in variants]
        cols.append(variants[int(np.argmin(rss))])
        names.append(name)
    C = np.hstack(cols)
    proj = np.linalg.lstsq(A, np.column_stack([y, C]), rcond=None)[0]
    R = np.column_stack([y, C]) - A @ proj
    scale = np.sqrt((R[:, 1:] ** 2).mean(axis=0)) + 1e-30
    opt = STLSQ(threshold=SINDY_THRESHOLD, alpha=1e-9, max_iter=50)
    with warnings.catch_warnings():  # "eliminated all coefficients" is the clean answer
        warnings.simplefilter("ignore", UserWarning)
        opt.fit(R[:, 1:] / scale, R[:, :1] / np.sqrt((y * y).mean()))
    xi = np.ravel(opt.coef_)
    alive = [(abs(v), name) for v, name in zip(xi, names) if v != 0.0]
    return [name for _, name in sorted(alive, reverse=True)]
