"""Errors in variables: the table-motion estimate's uncertainty carried into the constants.

The model is driven by the table motion estimated from the table sensor (a few
minimum-jerk ramp parameters p fitted to thousands of noisy samples, see
`analysis.table_motion`). Output error then treats that input as exact, and
the Jacobian's covariance counts only the mass sensor's noise. Measured on
runs A, B, C with 25.4 µm on both sensors, that understates the spread of the
constants by up to 4× (bench/identify.py): an error of a few µs in a ramp's
start time moves the simulated x as much as a constant does.

The input's share is added to first order. With r(θ, p) the scaled residual
of x, J = ∂r/∂log θ and J_p = ∂r/∂p, the fitted constants move by
G δp with G = −(JᵀJ)⁻¹ Jᵀ J_p when p is off by δp, and δp has the covariance
C_p = (J_uᵀ J_u)⁻¹ of the ramp fit (J_u: the fitted u's derivative over p in
units of σ_u). So cov(log θ) = σ²(JᵀJ)⁻¹ + Σ_runs G C_p Gᵀ.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from scipy.optimize import least_squares

from analysis.identify.output_error import OutputErrorFit, RunData
from analysis.simulate import simulate
from analysis.table_motion import TableMotion, ramps_motion

TIE = 1e-6  # s: ramps closer than this are back to back
STEP = (1e-5, 1e-6)  # FD steps: s for ramp times, m for levels; both ≪ their spread


def _params(ramps: Sequence[tuple[float, float, float, float]]) -> np.ndarray:
    """[start level, then (begin s, duration s, to m) per ramp]."""
    return np.array([ramps[0][2], *[v for r in ramps for v in (r[0], r[1], r[3])]])


def _tied(ramps: Sequence[tuple[float, float, float, float]]) -> np.ndarray:
    """True for a ramp that starts where the previous one ends (a turn without rest).

    Its start is not a parameter of its own: moving it either way would insert a
    rest or overlap the ramps, a kink no derivative describes.
    """
    return np.array([k > 0 and abs(r[0] - ramps[k - 1][0] - ramps[k - 1][1]) < TIE
                     for k, r in enumerate(ramps)])


def _ramps(p: np.ndarray, tied: np.ndarray) -> list[tuple[float, float, float, float]]:
    out: list[tuple[float, float, float, float]] = []
    level = p[0]
    for j, k in enumerate(range(1, len(p), 3)):
        begin = out[-1][0] + out[-1][1] if tied[j] else p[k]
        out.append((begin, p[k + 1], level, p[k + 2]))
        level = p[k + 2]
    return out


def refine_table(t: np.ndarray, u: np.ndarray, table: TableMotion) -> TableMotion:
    """The step-pulse fit refined on the whole record: every ramp and level at once.

    `analysis.table_motion` fits each moving stretch on its own samples, so a
    level held for 2 s is set by the few samples next to its ramps. Fitted
    together on every sample the levels use all the rest they hold for — the
    least-squares (and, for white noise, maximum-likelihood) input whose
    covariance C_p below assumes. Measured: without this, the spread of k1 over
    noise draws was 2.5× the propagated standard error.
    """
    if not table.ramps:
        return table
    p0, tied = _params(table.ramps), _tied(table.ramps)
    scale = _steps(p0.size) * 1e3

    def residual(p: np.ndarray) -> np.ndarray:
        try:
            return ramps_motion(t, _ramps(p, tied))(t) - u
        except ValueError:  # a step that made two ramps overlap: far from the optimum
            return np.full(u.shape, 1e3 * table.sigma)

    kinds = np.arange(p0.size) % 3  # 0: level, 1: begin, 2: duration
    lo = np.where(kinds == 1, t[0], np.where(kinds == 2, 1e-4, -np.inf))
    hi = np.where(kinds == 0, np.inf, t[-1] - t[0] + t[0] * (kinds == 1))
    sol = least_squares(residual, np.clip(p0, lo, hi), x_scale=scale, bounds=(lo, hi))
    ramps = tuple(_ramps(sol.x, tied))
    if not np.all([r[1] > 0 for r in ramps]):
        return table
    motion = ramps_motion(t, ramps)
    ratio = float(np.sqrt(np.mean(sol.fun**2)) / max(table.sigma, 1e-300))
    return replace(table, motion=motion, ramps=ramps, residual_over_noise=ratio)


def _steps(n: int) -> np.ndarray:
    return np.array([STEP[1]] + [STEP[0], STEP[0], STEP[1]] * ((n - 1) // 3))


def run_share(fit: OutputErrorFit, rows: np.ndarray, run: RunData, table: TableMotion,
              info_inv: np.ndarray) -> np.ndarray:
    """This run's input contribution to cov(log θ), (J, J)."""
    p0, tied = _params(table.ramps), _tied(table.ramps)
    h = _steps(p0.size)
    span = run.t[-1] - run.t[0]
    x0 = simulate(fit.model, ramps_motion(run.t, table.ramps), duration=span, dt=run.dt,
                  t0=run.t[0]).x
    u0 = ramps_motion(run.t, table.ramps)(run.t)
    Jx, Ju = np.empty((run.t.size, p0.size)), np.empty((run.t.size, p0.size))
    for j in range(p0.size):
        p = p0.copy()
        p[j] += h[j]
        motion = ramps_motion(run.t, _ramps(p, tied))
        x = simulate(fit.model, motion, duration=span, dt=run.dt, t0=run.t[0]).x
        Jx[:, j] = (x[:run.t.size] - x0[:run.t.size]) / run.sigma_x / h[j]
        Ju[:, j] = (motion(run.t) - u0) / table.sigma / h[j]
    G = -info_inv @ (fit.jacobian[rows].T @ Jx)
    return G @ np.linalg.pinv(Ju.T @ Ju) @ G.T


def with_input_uncertainty(fit: OutputErrorFit, runs: Sequence[RunData],
                           tables: Sequence[TableMotion]) -> OutputErrorFit:
    """`fit` with the input estimate's share added to its covariance and std.

    Only when every run's input is a step-pulse fit (a spline has no few
    parameters to propagate); otherwise `fit` is returned unchanged.
    """
    if fit.jacobian is None or not all(t.ramps for t in tables):
        return fit
    J = fit.jacobian
    info_inv = np.linalg.pinv(J.T @ J)
    cov_log = fit.covariance / np.outer(fit.values, fit.values)
    start = 0
    for run, table in zip(runs, tables):
        rows = slice(start, start + run.t.size)
        cov_log = cov_log + run_share(fit, rows, run, table, info_inv)
        start += run.t.size
    cov = cov_log * np.outer(fit.values, fit.values)
    return replace(fit, covariance=cov, std=np.sqrt(np.diag(cov)), input_covariance=True)
