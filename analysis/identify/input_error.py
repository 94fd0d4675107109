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
units of σ_u: the white noise of u's low-frequency power, `TableMotion.sigma_lowfreq`,
which for a channel interpolated onto another clock exceeds each sample's σ). So
cov(log θ) = σ²(JᵀJ)⁻¹ + Σ_runs G C_p Gᵀ. p is the ramps' parameters and, when the table motion was fitted with a servo lag
(`TableMotion.lag` > 0), the lag τ: its uncertainty reaches the constants the
same way, and u is perturbed through the same lagged model it was fitted with.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from analysis.identify.output_error import OutputErrorFit, RunData
from analysis.simulate import simulate
from analysis.table_motion import (
    TableMotion,
    params_ramps,
    refine_step_pulse,
    step_pulse_motion,
    step_pulse_params,
    step_pulse_value,
    tied_ramps,
)

STEP = (1e-5, 1e-6)  # FD steps: s for ramp times and the lag, m for levels; ≪ their spread


def _params(table: TableMotion) -> np.ndarray:
    """[start level, (begin s, duration s, to m) per ramp, then the lag s if it was fitted]."""
    return step_pulse_params(table.ramps, table.lag if table.lag > 0 else None)


def _motion(t: np.ndarray, table: TableMotion, p: np.ndarray, tied: np.ndarray):
    """The table motion of parameter vector p (the estimate's own form: lagged or not)."""
    return step_pulse_motion(t, params_ramps(p, tied), p[-1] if table.lag > 0 else 0.0)


def refine_table(t: np.ndarray, u: np.ndarray, table: TableMotion) -> TableMotion:
    """The step-pulse fit refined on the whole record: every ramp, level and the lag at once.

    `analysis.table_motion` fits each moving stretch on its own samples, so a
    level held for 2 s is set by the few samples next to its ramps. Fitted
    together on every sample the levels use all the rest they hold for — the
    least-squares (and, for white noise, maximum-likelihood) input whose
    covariance C_p below assumes. Measured: without this, the spread of k1 over
    noise draws was 2.5× the propagated standard error. The servo lag is refitted
    with them when the estimate has one (`TableMotion.lag` > 0), else held at 0.
    """
    if not table.ramps:
        return table
    free = table.lag > 0
    ramps, lag = refine_step_pulse(t, u, table.ramps, table.lag, free_lag=free)
    motion = step_pulse_motion(t, ramps, lag)
    rms = float(np.sqrt(np.mean((step_pulse_value(t, ramps, lag) - u) ** 2)))
    return replace(table, motion=motion, ramps=tuple(ramps), lag=lag,
                   residual_over_noise=rms / max(table.sigma, 1e-300))


def _steps(table: TableMotion) -> np.ndarray:
    n = len(table.ramps)
    return np.array([STEP[1]] + [STEP[0], STEP[0], STEP[1]] * n + [STEP[0]] * (table.lag > 0))


def run_share(fit: OutputErrorFit, rows: np.ndarray, run: RunData, table: TableMotion,
              info_inv: np.ndarray) -> np.ndarray:
    """This run's input contribution to cov(log θ), (J, J)."""
    p0, tied = _params(table), tied_ramps(table.ramps)
    h = _steps(table)
    noise = table.sigma_lowfreq or table.sigma  # what the few slow parameters average
    span = run.t[-1] - run.t[0]
    base = _motion(run.t, table, p0, tied)
    x0 = simulate(fit.model, base, duration=span, dt=run.dt, t0=run.t[0]).x
    u0 = base(run.t)
    Jx, Ju = np.empty((run.t.size, p0.size)), np.empty((run.t.size, p0.size))
    for j in range(p0.size):
        p = p0.copy()
        p[j] += h[j]
        motion = _motion(run.t, table, p, tied)
        x = simulate(fit.model, motion, duration=span, dt=run.dt, t0=run.t[0]).x
        Jx[:, j] = (x[:run.t.size] - x0[:run.t.size]) / run.sigma_x / h[j]
        Ju[:, j] = (motion(run.t) - u0) / noise / h[j]
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
