"""What the residual of a fit says: is it noise, and if not, where is it?

The residual is (x_pred − x_meas)/σ_x per sample. For a right model it is the
sensor's white noise: RMS 1, no autocorrelation, and no correlation with the
input or the states (the Billings–Voon correlation tests for nonlinear
models: φ_εε, φ_uε, φ_u²'ε, φ_u²'ε², with u the table velocity). When it is
not, the bins of z and ż where its energy concentrates and the frequency band
that holds most of its power say where the model is wrong — the evidence a
person reads before believing a candidate.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from analysis.loop.refit import Fit
from analysis.loop.runs import LoopRun, predicted_states

MAX_LAG = 20  # samples: 20 ms at 1 kHz, past the table's fastest ramp
BINS = 8
BANDS = ((0.0, 2.0), (2.0, 10.0), (10.0, 50.0), (50.0, np.inf))  # Hz
WHITE_P = 1e-3


@dataclass(frozen=True)
class Diagnosis:
    """The residual's statistics; the `*_text` fields are one line each for a person."""

    residual_over_noise: float
    ljung_box: float  # Q over lags 1..MAX_LAG, χ² with MAX_LAG dof for white noise
    ljung_box_p: float
    correlation_bound: float  # 95 % bound of a normalised correlation, 1.96/√N
    cross: dict[str, float]  # largest |normalised correlation| over lags 0..MAX_LAG
    region_text: str
    band_text: str
    band_power: dict[str, float]  # fraction of residual power per band

    @property
    def white(self) -> bool:
        return self.ljung_box_p > WHITE_P

    @property
    def uncorrelated(self) -> bool:
        return all(v <= 2.0 * self.correlation_bound for v in self.cross.values())

    def as_dict(self) -> dict[str, object]:
        return {"residual_over_noise": self.residual_over_noise,
                "ljung_box_Q": self.ljung_box, "ljung_box_p": self.ljung_box_p,
                "white": self.white, "correlation_bound_95": self.correlation_bound,
                "cross_correlation": self.cross, "concentrates_in": self.region_text,
                "band": self.band_text, "band_power": self.band_power}


def diagnose(residuals: Sequence[np.ndarray], z: Sequence[np.ndarray],
             zd: Sequence[np.ndarray], ud: Sequence[np.ndarray], dt: float) -> Diagnosis:
    """Tests and localisation of per-run residuals against per-run states and table velocity."""
    r = np.concatenate(residuals)
    n = r.size
    rho = autocorrelation(residuals)
    q = float(n * (n + 2) * np.sum(rho**2 / (n - np.arange(1, MAX_LAG + 1))))
    uc = [v - v.mean() for v in ud]
    u2 = [v**2 - (v**2).mean() for v in ud]
    e2 = [e**2 - (e**2).mean() for e in residuals]
    cross = {"u_e": max_cross(uc, residuals), "u2_e": max_cross(u2, residuals),
             "u2_e2": max_cross(u2, e2)}
    power = band_power(residuals, dt)
    top = max(power, key=power.get)
    return Diagnosis(
        residual_over_noise=float(np.sqrt(np.mean(r**2))), ljung_box=q,
        ljung_box_p=float(chi2.sf(q, MAX_LAG)), correlation_bound=1.96 / np.sqrt(n),
        cross=cross, region_text=concentration(r, np.concatenate(z), np.concatenate(zd)),
        band_text=f"{top}: {100 * power[top]:.0f} % of the residual power", band_power=power)


def diagnose_fit(fit: Fit, runs: Sequence[LoopRun]) -> Diagnosis:
    """`diagnose` of a fit's residual against the states along its prediction of the runs."""
    z, zd = predicted_states(fit, runs)
    return diagnose(fit.residuals, z, zd, [r.ud for r in runs], runs[0].data.dt)


def autocorrelation(residuals: Sequence[np.ndarray]) -> np.ndarray:
    """Pooled normalised autocorrelation at lags 1..MAX_LAG."""
    den = sum(float(e @ e) for e in residuals)
    return np.array([sum(float(e[k:] @ e[:-k]) for e in residuals) / den
                     for k in range(1, MAX_LAG + 1)])


def max_cross(a: Sequence[np.ndarray], b: Sequence[np.ndarray]) -> float:
    """Largest |normalised cross-correlation| of a (leading) with b over lags 0..MAX_LAG."""
    na = np.sqrt(sum(float(x @ x) for x in a))
    nb = np.sqrt(sum(float(y @ y) for y in b))
    if na == 0 or nb == 0:
        return 0.0
    best = 0.0
    for k in range(MAX_LAG + 1):
        c = sum(float(x[: x.size - k] @ y[k:]) for x, y in zip(a, b)) / (na * nb)
        best = max(best, abs(c))
    return best


def concentration(r: np.ndarray, z: np.ndarray, zd: np.ndarray) -> str:
    """The bin of z or ż that holds the most residual energy for its share of samples."""
    total = float(r @ r)
    best = (0.0, "")
    for name, v, unit in (("z", z, "m"), ("ż", zd, "m/s")):
        edges = np.quantile(v, np.linspace(0, 1, BINS + 1))
        which = np.clip(np.searchsorted(edges, v, side="right") - 1, 0, BINS - 1)
        for b in range(BINS):
            inside = which == b
            share = float(r[inside] @ r[inside]) / total
            ratio = share / max(inside.mean(), 1e-12)
            if ratio > best[0]:
                text = (f"{name} in [{edges[b]:+.4g}, {edges[b + 1]:+.4g}] {unit}: "
                        f"{100 * share:.0f} % of the residual energy in "
                        f"{100 * inside.mean():.0f} % of the samples")
                best = (ratio, text)
    return best[1]


def band_power(residuals: Sequence[np.ndarray], dt: float) -> dict[str, float]:
    """Fraction of the residual power in each band of BANDS, pooled over runs."""
    acc = np.zeros(len(BANDS))
    for e in residuals:
        f = np.fft.rfftfreq(e.size, dt)
        p = np.abs(np.fft.rfft(e - e.mean())) ** 2
        for i, (lo, hi) in enumerate(BANDS):
            acc[i] += p[(f >= lo) & (f < hi)].sum()
    acc /= max(acc.sum(), 1e-300)
    return {_band_name(lo, hi): float(v) for (lo, hi), v in zip(BANDS, acc)}


def _band_name(lo: float, hi: float) -> str:
    return f"{lo:g}–{hi:g} Hz" if np.isfinite(hi) else f"above {lo:g} Hz"
